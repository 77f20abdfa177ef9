#!/usr/bin/env bash
# Prepares .gpu/ (ignored by git) for carrying to the lent GPU machine, from ../shared/gpu
# (see its README.md): a writable copy; glvnd's unversioned names as real files (the shared
# folder keeps libGL.so and libEGL.so as 10-byte files naming their targets, and links do
# not travel); and wheels for that machine's Python 3.12 of the package's dependencies the
# shared folder lacks (plyfile, pye57 and its pyquaternion, pyproj: without plyfile nothing imports there);
# and ../shared/data as .gpu/data, which env.sh names in PROGRESSIVE_SHARED_DATA, so the tests on real
# files run there too (they skipped without it). The checkout and what it carries must stay under 64 MiB:
# the data leaves out autzen_trim.las and bunnyDouble.e57 (the tests read the bundled copies) and the wheels PyOpenGL (only the
# windowed viewer imports it, and that machine has no display); the benches write their JSON compact
# (bench/report.py), and a result folder's JSON over 100 kB is committed xz-compressed (NAME.json.xz; `xz -dk` it to read).
# With that (2026-12-08): tracked files 13.2 MB, .gpu without the data 31.5 MB, the data 17.1 MB (61.8 MB of the 67.1); the last
# lines below print the sum.
# Run here, then `run` with carry [".gpu"] and `source .gpu/env.sh` there.
#   bash bench/carry_gpu.sh
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
SHARED="${SHARED_GPU:-../shared/gpu}"
PY="${PYTHON:-.venv/bin/python}"

rm -rf .gpu
cp -r "$SHARED" .gpu
chmod -R u+w .gpu
for name in .gpu/glvnd/*; do
    # a file of a few bytes that names another file of the folder stands for a link to it
    if [ -f "$name" ] && [ "$(stat -c %s "$name")" -lt 64 ]; then
        target=".gpu/glvnd/$(tr -d '\n' < "$name")"
        [ -f "$target" ] && cp "$target" "$name"
    fi
done
for requirement in plyfile pye57 pyquaternion pyproj; do
    version="$("$PY" -c "import importlib.metadata as m, sys; print(m.version(sys.argv[1]))" "$requirement")"
    "$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
        -d .gpu/wheels "$requirement==$version" 2>&1 | grep -v '^WARNING' || true
done
cp -r "${SHARED_DATA:-../shared/data}" .gpu/data
chmod -R u+w .gpu/data
rm -f .gpu/data/autzen_trim.las .gpu/data/bunnyDouble.e57 .gpu/wheels/pyopengl-*.whl
echo 'export PROGRESSIVE_SHARED_DATA="$_gpu_here/data"' >> .gpu/env.sh
# That machine sets PYTHONDONTWRITEBYTECODE=1 and the wheels go in with --no-compile: without this
# every process compiles each module it imports, which an installed package never does
# (bench/results/nvidia-h200/startup_compiled/README.md).
echo 'python3 -m compileall -q -j 0 /tmp/site "$PWD/progressive" "$PWD/loaders" "$PWD/bench" "$PWD/tests" > /dev/null 2>&1 || true' >> .gpu/env.sh
mkdir -p .git/info
grep -qx '/.gpu/' .git/info/exclude 2>/dev/null || echo '/.gpu/' >> .git/info/exclude
ls .gpu/wheels
tracked="$(git ls-files -z | xargs -0 stat -c %s 2>/dev/null | awk '{s+=$1} END{print s}')"
carried="$(du -sb .gpu | cut -f1)"
echo "tracked $((tracked >> 20)) MiB + .gpu $((carried >> 20)) MiB = $(((tracked + carried) >> 20)) MiB of the 64 a call may carry"
[ $((tracked + carried)) -lt $((64 << 20)) ] || echo "over the limit: compress or drop large result files, or carry less of .gpu" >&2
