#!/usr/bin/env bash
# Set up, then run the test suite (headless, Mesa llvmpipe where there is no GPU).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
exec .venv/bin/python -m pytest -q "$@"
