#!/usr/bin/env bash
# Scripted for the next device call, not run yet: what the NVIDIA driver's program
# binaries say of each compute program's registers (occupancy may be what bounds the
# batch walk's load, README.md). A render fills a fresh program cache; each entry's
# readable text (NVIDIA binaries have carried the program's assembly) is searched for
# its register count. Run from the repository root with .gpu/env.sh sourced:
#   OUT=/some/dir bash bench/results/nvidia-h100/kernel_clocks/sustained/registers.sh
set -u
export PROGRESSIVE_PROGRAM_CACHE="$OUT/programs"
python3 -m progressive render --width 1920 --height 1080 --method brute -o "$OUT/brute.png"
python3 -m progressive render --width 1920 --height 1080 --method progressive --converge -o "$OUT/progressive.png"
for f in "$OUT"/programs/*; do
    echo "== $f $(stat -c %s "$f") bytes"
    strings -n 6 "$f" | grep -m 8 -i -E 'register|REG |\.reg|!!NV|local_size|raster' || true
done > "$OUT/registers.txt"
head -c 12000 "$OUT/registers.txt"
