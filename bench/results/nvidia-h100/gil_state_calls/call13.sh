set -u
source .gpu/env.sh
START=$EPOCHREALTIME
el() { awk "BEGIN{printf \"%.0f\", $EPOCHREALTIME - $START}"; }
left() { awk "BEGIN{exit !($EPOCHREALTIME - $START < $1)}"; }
arm() { case $1 in before) echo ".probe/as_before.py $2";; *) echo "-m $2";; esac; }
R=$OUT/q; mkdir -p $R
{ nvidia-smi --query-gpu=name --format=csv,noheader; ls bench/.cache; uptime; } > $R/log.txt 2>&1
for d in before after before after; do
  left 200 || break
  t=$(el)
  timeout 60 python3 $(arm $d bench.stream) --points 100000000 --limit 1G --size 1920x1080 --still-seconds 6 --out $R/st_${d}_$t > $R/st_${d}_$t.log 2>&1
  echo "stream $d rc $? at $(el) s" | tee -a $R/log.txt
done
for d in before after before after; do
  left 330 || break
  t=$(el)
  timeout 60 python3 $(arm $d bench.mainthread) --points 100000000 --repeats 1 --formats LAS --label $d --out $R/mt_${d}_$t > $R/mt_${d}_$t.log 2>&1
  echo "mainthread $d rc $? at $(el) s" | tee -a $R/log.txt
done
for f in $R/mt_*/mainthread.md; do grep "^| [ab]" $f; done
for f in $R/st_*/stream.md; do echo "== $f"; grep "^| file\|^| HTTP" $f | cut -d'|' -f2-12; done
(cd $OUT && tar czf q.tgz q && rm -rf q)
