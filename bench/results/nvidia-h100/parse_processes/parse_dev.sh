#!/usr/bin/env bash
# parse_processes.py on the GPU machine: a 10 M-point tiled LAS, 1, 4, 8 and 16 workers, 3 rounds
set -uo pipefail
source .gpu/env.sh >&2
export PYTHONPATH=".:${PYTHONPATH:-}"
las=$(python3 -c 'from bench import data; print(data.tiled(10000000, False))')
ROUNDS=3 python3 bench/results/nvidia-h100/parse_processes/parse_processes.py "$las" 1 4 8 16 2>&1 | tee "$OUT/parse_processes_10M.txt"
