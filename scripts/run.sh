#!/usr/bin/env bash
# Set up, then view the given files (default: the bundled sample): a window where
# there is a display, else a headless render to progressive-view.png.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
exec .venv/bin/progressive view "$@"
