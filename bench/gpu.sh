#!/usr/bin/env bash
# Full-size benchmarks on the GPU machine, one chunk per command (each well under the
# 10-minute limit there). Results go to $OUT/<machine>/ (e.g. $OUT/nvidia-h100/); copy
# each chunk's files into bench/results/<machine>/ here, then rebuild the headline and
# the README from them: python -m bench.headline bench/results/<machine>
#
# On the GPU machine (checkout carried with .gpu, which bench/carry_gpu.sh prepares here; ../shared/gpu/README.md):
#   bash bench/gpu.sh raster-100M        # one chunk
#   bash bench/gpu.sh list               # the chunks, in the order to run them
#   bash bench/gpu.sh load-100M --max-points 30000   # arguments after the chunk go to its command (a trial run)
#
# Generated files (100M points as LAS, LAZ and fast format, ~5.5 GB) are cached in
# bench/.cache/, kept while the machine stays warm; files-100M makes them (the load chunk too, if absent).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

CHUNKS=(files-100M load-100M load-las-fast-100M kernel-100M layouts-100M raster-100M raster-1B progressive-100M progressive-1B stores-1B winners-1B records-1B accuracy attributes packing upload-100M startup-100M viewer-load-100M mainthread-100M startup-1B convert-1B copc-1B stream-1B stream-gaps-1B stream-200M writes-100M writes-1B reads-100M reads-1B node-decode-100M lazy-positions-10M staging-flush staging-fixes pytest)
chunk="${1:-list}"
if [ "$chunk" = list ]; then
    printf '%s\n' "${CHUNKS[@]}"
    exit 0
fi

[ -f .gpu/env.sh ] && source .gpu/env.sh >&2
OUT="${OUT:-bench/results}"
bench=("${PYTHON:-python3}" -m bench --full --out-root "$OUT")
# the results folder's name for this GPU (bench/report.py), for the commands that take --out
machine() { "${PYTHON:-python3}" -c 'from bench.report import machine_name; from progressive.context import create_context; print(machine_name(create_context().caps))'; }

case "$chunk" in
    # the LAS, LAZ and fast-format files of 100M points the load chunk measures, made apart so that it fits
    # the time limit (a smaller count after the chunk name, for a trial run)
    files-100M)       "${PYTHON:-python3}" -c 'import sys; from bench import data; data.scaled(int(sys.argv[1]))' "${2:-100000000}" ;;
    # LAS, LAZ and fast format of 100M points, warm and cold, at 1, 2, 4 parser threads and every core, each
    # beside laspy.read, the raw read and (LAZ) lazrs's own all-core decode in the same run; then the time
    # to first image and to every point on the GPU (issue 11's targets)
    load-100M)        "${bench[@]}" --sections load --max-points 100000000 "${@:2}" ;;
    # the LAS and fast-format rows of load-100M alone (their files made here, no LAZ): the default parser threads
    # and every core, warm and cold, 3 repeats a row, beside laspy.read and the raw read, and the first image
    # (issue 11's LAS and fast targets; about 3 min: 2 repeats took 134 s on the H100)
    load-las-fast-100M) "${bench[@]}" --sections load --max-points 100000000 --load-formats LAS fast --load-threads 16 \
                          --load-repeats 3 "${@:2}" ;;
    kernel-100M)      "${PYTHON:-python3}" -m bench.kernel --points 100000000 --out-root "$OUT" "${@:2}" ;;
    # the batched layouts side by side at 100M (word store, float records, scan order, scan order with batches
    # sorted by Morton code), 1920x1080 only: the four-word walk, --batch-order morton's culling and the
    # wall-clock column in one table
    layouts-100M)     "${PYTHON:-python3}" -m bench.raster --points 100000000 --size 1920x1080 --repeats 5 --copy-mib 2048 \
                          --layouts batched "batched, float records" "batched, scan order" \
                          "batched, scan order, Morton in loaded batches" --out "$OUT/$(machine)" "${@:2}" ;;
    raster-100M)      "${bench[@]}" --sections raster --raster-points 100000000 "${@:2}" ;;
    raster-1B)        "${bench[@]}" --sections raster --raster-points 1000000000 "${@:2}" ;;
    progressive-100M) "${bench[@]}" --sections progressive --progressive-points 100000000 "${@:2}" ;;
    progressive-1B)   "${bench[@]}" --sections progressive --progressive-points 1000000000 "${@:2}" ;;
    # every progressive case at 1B on the word store and on float records in turn, one run (3 min on the H200)
    stores-1B)        "${PYTHON:-python3}" -m bench.progressive --points 1000000000 --size 1920x1080 --fixed 10000000 \
                          --targets-ms 16.6 --motion-frames 60 --max-frames 600 --stores words "float records" --out "$OUT/$(machine)" "${@:2}" ;;
    # every progressive case at 1B with prepare's records from the winners pass and gathered, side by side
    winners-1B)       "${PYTHON:-python3}" -m bench.progressive --points 1000000000 --size 1920x1080 --fixed 10000000 \
                          --targets-ms 16.6 --motion-frames 60 --max-frames 600 --records "winners pass" gathered \
                          --out "$OUT/$(machine)" "${@:2}" ;;
    # every progressive case at 1B with the store's records in slot order and batch after batch, then brute force
    # in both orders, 1920x1080 (7 min on the H200: bench/results/nvidia-h200/record_order/)
    records-1B)       "${PYTHON:-python3}" -m bench.progressive --points 1000000000 --size 1920x1080 --fixed 10000000 \
                          --targets-ms 16.6 --motion-frames 60 --max-frames 600 --record-orders "slot order" "batch after batch" \
                          --out "$OUT/$(machine)" "${@:2}"
                      "${PYTHON:-python3}" -m bench.raster --points 1000000000 --size 1920x1080 --repeats 5 --copy-mib 2048 \
                          --layouts batched "batched, records in slot order" --out "$OUT/$(machine)" "${@:2}" ;;
    accuracy)         "${bench[@]}" --sections accuracy "${@:2}" ;;
    attributes)       "${bench[@]}" --sections attributes "${@:2}" ;;
    # the host side of an attribute switch: words packed on the CPU at 1, 2, 4, 8 threads and every core,
    # 200M points of their own memory (no GPU; a minute)
    packing)          "${PYTHON:-python3}" -m bench.packing --points 200000000 --machine "$(machine)" --out "$OUT" "${@:2}" ;;
    # the GPU side of loading 100M points through the staging ring and copied, in loader-sized pieces (2 min)
    upload-100M)      "${PYTHON:-python3}" -m bench.upload --points 100000000 --repeats 1 --startup-repeats 1 \
                          --out "$OUT/$(machine)" "${@:2}" ;;
    # where the time to the first image goes at 100M points (LAS, LAZ, fast; view, both caches warm): what grows
    # with the cloud (files-100M makes the files, this chunk too if absent)
    startup-100M)     "${PYTHON:-python3}" -m bench.startup --scaled 100000000 --commands view \
                          --caches "Mesa + program cache" --out "$OUT/$(machine)" "${@:2}" ;;
    # convert to COPC out of core at 1 B points (the sample tiled as LAZ, kept in bench/.cache for the two
    # chunks after), timed with its peak memory, with the convert's own limits; its 48 GB of scratch in
    # /dev/shm (the disk has 64 GB)
    convert-1B)       "${PYTHON:-python3}" -m bench.convert --points 1000000000 --laz --builds "out of core" \
                          --memory-points 0 --scratch /dev/shm --machine "$(machine)" --out "$OUT" "${@:2}" ;;
    # the 1 B-point COPC file stream-1B reads, converted once (a call that runs out of time leaves the LAZ:
    # the next one only converts); its 46 GB of scratch in /dev/shm, as convert-1B's. On the H200 machine the
    # LAZ took 104-127 s and the convert 184-203 s (bench/results/nvidia-h200/copc_1B/README.md)
    copc-1B)          "${PYTHON:-python3}" -m bench.stream --points 1000000000 --laz --build-only --scratch /dev/shm "${@:2}" ;;
    # where a still streamed overview of the 1 B-point COPC spends the seconds outside its frames (about 0.45 s
    # in bench/results/nvidia-h100/stream_detail_1B/), under switch intervals of 5 and 0.5 ms taking turns
    # (bench/results/llvmpipe/stream_gaps/): the COPC built as copc-1B where absent (about 250 s), then 2 rounds;
    # then the first reads at the open against at the first frame, 3 rounds taking turns
    stream-gaps-1B)   "${PYTHON:-python3}" -m bench.stream --points 1000000000 --laz --build-only --scratch /dev/shm
                      PYTHONPATH=".:${PYTHONPATH:-}" "${PYTHON:-python3}" bench/results/llvmpipe/stream_gaps/gaps.py \
                          1000000000 4G 1920x1080 "$OUT/gaps_1B.json" 2 > "$OUT/gaps_1B.txt" 2>&1 || true
                      head -n 12 "$OUT/gaps_1B.txt"
                      # the first reads asked for at the open against at the first frame (bench/results/llvmpipe/first_reads/)
                      PYTHONPATH=".:${PYTHONPATH:-}" "${PYTHON:-python3}" bench/results/llvmpipe/first_reads/first_reads.py \
                          1000000000 3 "$OUT/first_reads_1B.json" 4G:1920x1080 2>&1 | tail -n 4 ;;
    # issue 15's targets: the 1 B-point COPC streamed with a 4 GB GPU limit, from the file and over HTTP; a
    # machine without the file builds it first, as copc-1B (about 300 s, then 130 s of streaming: one call)
    stream-1B)        "${PYTHON:-python3}" -m bench.stream --points 1000000000 --laz --limit 4G --size 1920x1080 --still-seconds 20 \
                          --scratch /dev/shm --out "$OUT/$(machine)" "${@:2}" ;;
    # a quicker streaming check, one call of about 2 minutes with the COPC built in it (about 50 s): 200 M points,
    # 1 GB limit, from the file and over HTTP with each answer 30 ms late (bench/results/nvidia-h100/stream_http_requests/)
    stream-200M)      "${PYTHON:-python3}" -m bench.stream --points 200000000 --laz --limit 1G --size 1920x1080 --still-seconds 20 \
                          --http-latency 30 --scratch /dev/shm --out "$OUT/$(machine)" "${@:2}" ;;
    # where a streamed node's write spends the frame thread's time, part by part, running apart from waiting for
    # the GIL: the 100 M-point COPC (built once, about 30 s), 1 GiB limit, a still overview until it converges
    # (bench/results/nvidia-h100/stream_writes/); its table on stdout
    # (the file's path: the last line --build-only prints, "PATH: N points, ...")
    writes-100M)      copc="$("${PYTHON:-python3}" -m bench.stream --points 100000000 --laz --build-only --scratch /dev/shm "${@:2}" \
                          | tail -n 1 | cut -d: -f1)"
                      PYTHONPATH=".:${PYTHONPATH:-}" "${PYTHON:-python3}" bench/results/nvidia-h100/stream_writes/write_parts.py \
                          "$copc" 1073741824 1920x1080 12 ;;
    # the same at 1 B points, as stream-1B --detail 0.25 streams it (4 GiB limit, finest detail 0.25 px; the COPC
    # built first, about 250 s), with the reading threads' node reads and parses summed
    writes-1B)        copc="$("${PYTHON:-python3}" -m bench.stream --points 1000000000 --laz --build-only --scratch /dev/shm "${@:2}" \
                          | tail -n 1 | cut -d: -f1)"
                      PYTHONPATH=".:${PYTHONPATH:-}" "${PYTHON:-python3}" bench/results/nvidia-h100/stream_writes/write_parts.py \
                          "$copc" 4294967296 1920x1080 20 0.25 ;;
    # a still streamed overview's time to settle with 1, 2 and 3 node reads in flight per LAZ decoder process
    # (laz_pool.READS_PER_PROCESS), alternating, 3 rounds (at 1 B points 2e too: 2 with each node's float32
    # positions computed, as the parse did before): the 100 M-point COPC (1 GiB limit) and the 1 B-point
    # one (4 GiB; built first as copc-1B, about 250 s), 0.25 px; tables on stdout
    reads-100M)       copc="$("${PYTHON:-python3}" -m bench.stream --points 100000000 --laz --build-only --scratch /dev/shm \
                          | tail -n 1 | cut -d: -f1)"
                      PYTHONPATH=".:${PYTHONPATH:-}" "${PYTHON:-python3}" bench/results/nvidia-h200/stream_reads/stream_reads.py \
                          "$copc" 1073741824 1920x1080 20 0.25 3 1 2 3 ;;
    reads-1B)         copc="$("${PYTHON:-python3}" -m bench.stream --points 1000000000 --laz --build-only --scratch /dev/shm \
                          | tail -n 1 | cut -d: -f1)"
                      PYTHONPATH=".:${PYTHONPATH:-}" "${PYTHON:-python3}" bench/results/nvidia-h200/stream_reads/stream_reads.py \
                          "$copc" 4294967296 1920x1080 20 0.25 3 1 2 3 2e ;;
    # a streamed node's decode in a decoder process against lazrs in the process, one at a time, then 1-16 lanes at
    # once: the 100 M-point COPC's first 2,000 nodes by level (bench/results/llvmpipe/node_decode/)
    node-decode-100M) copc="$("${PYTHON:-python3}" -m bench.stream --points 100000000 --laz --build-only --scratch /dev/shm \
                          | tail -n 1 | cut -d: -f1)"
                      PYTHONPATH=".:${PYTHONPATH:-}" "${PYTHON:-python3}" bench/results/llvmpipe/node_decode/node_decode.py \
                          "$copc" 2000 3 1 4 8 16 ;;
    # the loader on a 10 M-point tiled LAS with the LAS parse as it is (no float32 positions) against the same
    # parse computing them as before, taking turns (bench/results/llvmpipe/las_lazy_positions/): 1, 8, 16 threads
    lazy-positions-10M) ROUNDS=3 REPEATS=3 PYTHONPATH=".:${PYTHONPATH:-}" "${PYTHON:-python3}" \
                          bench/results/llvmpipe/las_lazy_positions/lazy_positions.py 10000000 8 16 1 ;;
    # the staging ring as committed (not coherent: each piece flushed, then a client-mapped buffer barrier) against
    # the coherent mapping before 14e6b92, taking turns: the two test files that failed on the H100 with the
    # coherent ring (bench/results/nvidia-h100/pytest_64de055/), 3 rounds, failures counted; then the GPU side
    # of loading 100M points (bench.upload) with each; bench/results/nvidia-h100/staging_flush/ (about 6 min)
    staging-flush)    variants="bench/results/nvidia-h100/staging_flush"
                      for round in 1 2 3; do for v in coherent flushed; do
                          VARIANT=$v PYTHONPATH="$variants:${PYTHONPATH:-}" "${PYTHON:-python3}" -m pytest -q \
                              -p no:cacheprovider --tb=no -rf -k "not flushed_before" \
                              tests/test_switch_words.py tests/test_upload_ring.py > "$OUT/staging_$v.txt" 2>&1 || true
                          echo "round $round $v: $(tail -n 1 "$OUT/staging_$v.txt")"
                          grep FAILED "$OUT/staging_$v.txt" | sed 's/ - .*//' || true
                      done; done
                      for v in coherent flushed; do
                          VARIANT=$v PYTHONPATH="$variants:${PYTHONPATH:-}" "${PYTHON:-python3}" -m bench.upload \
                              --points 100000000 --repeats 1 --startup-repeats 1 --out "$OUT/staging_flush_$v" "${@:2}"
                      done ;;
    # which change ends the wrong words the flushed ring still gave: ways of staging taking turns in one
    # process for SECONDS (default 150), failures counted (bench/results/nvidia-h100/staging_race/)
    # staging-fixes SECONDS [TEST_FILES...]: the files given run first in the same process (the
    # failures came late in a process), their output in $OUT/pytest_before_probe.txt
    staging-fixes)    cp bench/results/nvidia-h100/staging_race/race_fixes_test.py tests/test_zz_race_fixes.py
                      PROBE_SECONDS="${2:-150}" PROBE_OUT="$OUT/race_fixes.json" "${PYTHON:-python3}" -m pytest -q -s \
                          -p no:cacheprovider -rf --durations=0 "${@:3}" tests/test_zz_race_fixes.py > "$OUT/pytest_before_probe.txt" 2>&1 || true
                      tail -n 40 "$OUT/pytest_before_probe.txt"
                      rm -f tests/test_zz_race_fixes.py ;;
    # what the window reads against what render reads, at 100M points: the sample (point format 3) and a LAZ of
    # point format 8 tiled as LAS and LAZ, each session warm, 3 repeats (bench.load first_image_table); render's
    # session at 8 and 16 parser threads too, beside the default 4 (do more take the frame loop's core?)
    viewer-load-100M) "${PYTHON:-python3}" -m bench.load --points 100000000 --size 1920x1080 --repeats 3 \
                          --parser-threads 8 16 \
                          --sources progressive/data/autzen_trim.las \
                          "${PROGRESSIVE_SHARED_DATA:-../shared/data}/las_with_several_extra_byte_bloc.laz" \
                          --out "$OUT/$(machine)/viewer_load" "${@:2}" ;;
    # how busy the frame loop's thread is while 100M points of LAS, LAZ and the fast format load (render's and
    # the window's sessions, the fast format's one; warm, 3 repeats), beside the loader alone
    mainthread-100M)  "${PYTHON:-python3}" -m bench.mainthread --points 100000000 --repeats 3 \
                          --out "$OUT/$(machine)/mainthread" "${@:2}" ;;
    # the time to the first image of a 1 B-point LAZ (view, both caches warm): the store's 16 GB filled at
    # once (the LAZ tiled first, about 5.5 GB, shared with convert-1B)
    startup-1B)       "${PYTHON:-python3}" -m bench.startup --scaled 1000000000 --laz-only --commands view \
                          --caches "Mesa + program cache" --out "$OUT/$(machine)" "${@:2}" ;;
    # the whole test suite on this machine, compact (dots, one line a failure, the summary: -v made a file too
    # large to come back); redirect it into $OUT/<machine>/pytest.txt. Each test's time and each failure's
    # report are written as it ends to $OUT/<machine>/pytest/ (bench/pytest_timing.py), kept if the call's limit kills it.
    # Test files after the chunk name run those alone (the whole suite took over 330 s on the H200 machine with the
    # real files: split it over two calls, e.g. tests/test_[a-c]*.py, then tests/test_[d-z]*.py; on the 2-core
    # machine they took 185 and 198 s, bench/results/llvmpipe/pytest_timing_1120226/by_file.tsv)
    pytest)           mkdir -p "$OUT/$(machine)/pytest"
                      tests=("${@:2}"); [ ${#tests[@]} -gt 0 ] || tests=(tests)
                      PYTEST_TIMING_DIR="$OUT/$(machine)/pytest" "${PYTHON:-python3}" -m pytest -q -p no:cacheprovider \
                          -p bench.pytest_timing --tb=line -rfEs "${tests[@]}" ;;
    *) echo "unknown chunk '$chunk'; one of: ${CHUNKS[*]}" >&2; exit 2 ;;
esac
