#!/usr/bin/env bash
# parse_positions.py on the GPU machine: a 10 M-point tiled LAS, 1, 8 and 16 threads, 3 rounds
set -uo pipefail
source .gpu/env.sh >&2
export PYTHONPATH=".:${PYTHONPATH:-}"
las=$(python3 -c 'from bench import data; print(data.tiled(10000000, False))')
ROUNDS=3 python3 bench/results/nvidia-h100/parse_positions/parse_positions.py "$las" 1 8 16 2>&1 | tee "$OUT/parse_positions_10M.txt"
