set -u
source .gpu/env.sh
ROOT=$PWD
START=$EPOCHREALTIME
left() { awk "BEGIN{exit !($EPOCHREALTIME - $START < $1)}"; }
mkdir -p $OUT/a
{ nvidia-smi --query-gpu=name --format=csv,noheader; nproc; } > $OUT/a/loader.txt 2>&1
python3 -c 'from bench import data; print(data.tiled(100_000_000, False))' >> $OUT/a/loader.txt 2>&1
(cd .probe/R && ln -sfn ../loaders progressive/loaders && ln -sfn ../shaders progressive/shaders && rm -f bench/.cache && ln -sfn $ROOT/bench/.cache bench/.cache)
tree() { if [ $1 = after ]; then echo $ROOT; else echo $ROOT/.probe/R; fi; }
LAS=$ROOT/bench/.cache/autzen_trim_x100000000.las
for r in 1 2 3; do for d in before after; do
  left 200 || break
  (cd /tmp && PYTHONPATH=/tmp/site:$(tree $d) timeout 40 python3 $ROOT/.probe/alloc_ab.py $d $LAS 8 3) >> $OUT/a/loader.txt 2>&1
done; done
cat $OUT/a/loader.txt
