#!/usr/bin/env bash
# parse_blocks probe on the GPU machine: a 10 M-point tiled LAS, threads 1 4 8 16, blocks of 16 K, 64 K, 256 K against whole batches
set -uo pipefail
source .gpu/env.sh >&2
export PYTHONPATH=".:${PYTHONPATH:-}"
las=$(python3 -c 'from bench import data; print(data.tiled(10000000, False))')
nproc
ROUNDS=3 python3 bench/results/llvmpipe/parse_blocks/parse_blocks.py "$las" 1 4 8 16 --rows 16384 65536 262144 2>&1 | tee "$OUT/parse_blocks_10M.txt"
NAMES=rgb ROUNDS=3 python3 bench/results/llvmpipe/parse_blocks/parse_blocks.py "$las" 1 8 16 --rows 65536 2>&1 | tee "$OUT/parse_blocks_10M_rgb.txt"
python3 -m pytest -q -p no:cacheprovider --tb=short tests/test_bench.py -k mainthread 2>&1 | tail -5 | tee "$OUT/pytest_mainthread.txt"
