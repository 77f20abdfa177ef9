# Device call: GL state calls holding the GIL (after, this tree) against every raw GL call releasing it
# (before), and dispatches, copies and clears holding it too (hold): the frame loop while a 100 M-point
# LAS and fast file load (bench.mainthread), then a 100 M-point COPC streamed with a 1 GiB limit (bench.stream).
set -u
source .gpu/env.sh
START=$EPOCHREALTIME
el() { awk "BEGIN{printf \"%.0f\", $EPOCHREALTIME - $START}"; }
left() { awk "BEGIN{exit !($EPOCHREALTIME - $START < $1)}"; }
arm() { case $1 in before) echo ".probe/as_before.py $2";; hold) echo ".probe/as_hold_dispatch.py $2";; *) echo "-m $2";; esac; }
R=$OUT/r; mkdir -p $R
{ nvidia-smi --query-gpu=name --format=csv,noheader; nproc; uptime; } > $R/log.txt 2>&1
python3 -c 'from bench import data; data.scaled(100_000_000)' >> $R/log.txt 2>&1
echo "files $(el) s" | tee -a $R/log.txt
for d in before after hold before after; do
  left 230 || break
  t=$(el)
  timeout 90 python3 $(arm $d bench.mainthread) --points 100000000 --repeats 1 --formats fast LAS --label $d --out $R/mt_${d}_$t > $R/mt_${d}_$t.log 2>&1
  echo "mainthread $d rc $? at $(el) s" | tee -a $R/log.txt
done
left 300 && timeout 100 python3 -m bench.stream --points 100000000 --build-only >> $R/log.txt 2>&1
echo "copc built at $(el) s" | tee -a $R/log.txt
for d in after before hold; do
  left 450 || break
  t=$(el)
  timeout 130 python3 $(arm $d bench.stream) --points 100000000 --limit 1G --size 1920x1080 --still-seconds 6 --out $R/st_${d}_$t > $R/st_${d}_$t.log 2>&1
  echo "stream $d rc $? at $(el) s" | tee -a $R/log.txt
done
uptime >> $R/log.txt
for f in $R/mt_*/mainthread.md; do grep "^| [abh]" $f; done
for f in $R/st_*/stream.md; do echo "== $f"; grep "^| file\|^| HTTP" $f | cut -d'|' -f2-12; done
(cd $OUT && tar czf r.tgz r && rm -rf r)
