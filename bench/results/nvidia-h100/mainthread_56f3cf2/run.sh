#!/usr/bin/env bash
# One device call: bench.mainthread at 100M, 56f3cf2 (this tree) at 4, then at 8 and 16 parser threads, 38483a3 (oldtree) at 4.
set -u
source .gpu/env.sh >&2
N=${N:-100000000}
T0=$(date +%s)
python3 -c "import sys; from bench import data; data.tiled(int(sys.argv[1]), False); data.tiled(int(sys.argv[1]), True)" $N
echo "files made in $(( $(date +%s) - T0 )) s"; nproc; python3 --version
ln -sfn ../loaders oldtree/progressive/loaders; ln -sfn ../shaders oldtree/progressive/shaders
(cd oldtree && PYTHONPATH="$PWD:${PYTHONPATH:-}" timeout 200 python3 -m bench.mainthread --points $N --repeats 3 \
    --label 38483a3 --cache ../bench/.cache --out "$OUT/mainthread_38483a3")
echo "old done at $(( $(date +%s) - T0 )) s"
timeout 200 python3 -m bench.mainthread --points $N --repeats 3 --label 56f3cf2 --out "$OUT/mainthread_56f3cf2"
echo "new done at $(( $(date +%s) - T0 )) s"
timeout $(( 540 - ($(date +%s) - T0) )) python3 -m bench.mainthread --points $N --repeats 3 --label 56f3cf2 \
    --parser-threads 8 16 --out "$OUT/mainthread_56f3cf2_threads"
echo "threads done at $(( $(date +%s) - T0 )) s"
