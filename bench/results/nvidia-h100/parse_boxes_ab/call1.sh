set -u
source .gpu/env.sh
ROOT=$PWD
mkdir -p $OUT
t=$EPOCHREALTIME; bash bench/gpu.sh files-100M > $OUT/files.txt 2>&1; echo "files-100M $(awk "BEGIN{print $EPOCHREALTIME - $t}") s" | tee -a $OUT/files.txt
for d in A C P; do
  (cd .probe/$d && ln -sfn ../loaders progressive/loaders && ln -sfn ../shaders progressive/shaders && ln -sfn $ROOT/bench/.cache bench/.cache)
done
tree() { if [ $1 = B ]; then echo $ROOT; else echo $ROOT/.probe/$1; fi; }
for r in 1 2; do for d in A B C; do
  PYTHONPATH=/tmp/site:$(tree $d) timeout 120 python3 .probe/sessab.py $d >> $OUT/sessions.txt 2>&1
done; done
for r in 1 2 3 4 5; do for d in P A; do
  PYTHONPATH=/tmp/site:$(tree $d) python3 .probe/ctxprobe.py $d >> $OUT/context.txt 2>&1
  t=$EPOCHREALTIME; (cd $(tree $d) && PYTHONPATH=/tmp/site:$(tree $d) python3 -m progressive render $ROOT/progressive/data/autzen_trim.las --out /tmp/x.png >/dev/null 2>&1); echo "$d render $(awk "BEGIN{print $EPOCHREALTIME - $t}")" >> $OUT/context.txt
done; done
cat $OUT/sessions.txt $OUT/context.txt
for r in 1 2; do for d in A B; do
  PYTHONPATH=/tmp/site:$(tree $d) timeout 150 python3 .probe/loadab.py $d >> $OUT/loader.txt 2>&1
done; done
cat $OUT/loader.txt
