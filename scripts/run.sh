#!/usr/bin/env bash
# Set up, then render the given files (default: the bundled sample) to progressive.png.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
.venv/bin/progressive render "$@" --out progressive.png --stats progressive-stats.json
echo "wrote $(pwd)/progressive.png and progressive-stats.json"
