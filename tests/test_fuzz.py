"""Fuzzing the loaders: mutated headers and truncations of real files either load or
fail with one InputError line; never another exception, never a hang.

Derandomized (the same examples on every run) and bounded in time; each load runs in
a thread so that a hang fails the example instead of the suite.
"""

from __future__ import annotations

import math
import struct
import subprocess
import sys
from pathlib import Path

import laspy
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import SAMPLE, bounded, shared_file
from progressive.errors import InputError
from progressive.loaders import CloudLoader, describe, open_cloud, write_fast

POINTS = 2_000
"""Points in each base file: enough for several batches, quick to load many times."""
HEAD = 400
"""Bytes of a LAS file mutated: the header and the start of the VLRs."""
TIMEOUT_S = 10.0
FUZZ = settings(max_examples=80, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow])

SPECIAL = [0, 1, 2**31 - 1, 2**31, 2**32 - 1, 2**63, 2**64 - 1]
"""Integers that break size arithmetic: written as u16/u32/u64 at any offset."""
SPECIAL_FLOATS = [0.0, -0.0, 1e-300, 1e300, -1e300, math.inf, -math.inf, math.nan, 5e-324]


def small_las(source: Path, out: Path) -> None:
    """At most the first POINTS points of `source`, its header and VLRs unchanged but the
    count."""
    with laspy.open(source) as reader:
        header = reader.header
        point_data, record = header.offset_to_point_data, header.point_format.size
    count = min(POINTS, header.point_count)
    data = bytearray(source.read_bytes()[:point_data + count * record])
    struct.pack_into("<I", data, 107, count if header.version.minor < 4 or data[104] < 6 else 0)
    if header.version.minor >= 4:
        struct.pack_into("<QIQ", data, 235, 0, 0, count)      # no EVLRs, 64-bit count
    out.write_bytes(bytes(data))


@pytest.fixture(scope="module")
def bases(tmp_path_factory) -> dict[str, bytes]:
    """Real files cut to POINTS points: LAS 1.2 (the sample), LAS 1.4 (extrabytes.las, when
    present), LAZ of the sample's points (point format 3, chunked; and 7, layered) and the
    fast format."""
    folder = tmp_path_factory.mktemp("bases")
    small_las(SAMPLE, folder / "las12.las")
    points = laspy.read(folder / "las12.las")
    points.write(folder / "laz.laz", laz_backend=laspy.LazBackend.Lazrs)
    laspy.convert(points, point_format_id=7, file_version="1.4").write(folder / "laz14.laz",
                                                                        laz_backend=laspy.LazBackend.Lazrs)
    info = open_cloud([folder / "las12.las"])
    write_fast(folder / "fast.prgs", CloudLoader([folder / "las12.las"]), info, info.attribute("gps_time"))
    found = {name: (folder / name).read_bytes() for name in ("las12.las", "laz.laz", "laz14.laz", "fast.prgs")}
    try:
        small_las(shared_file("extrabytes.las"), folder / "las14.las")
        found["las14.las"] = (folder / "las14.las").read_bytes()
    except pytest.skip.Exception:
        pass
    for name in found:                 # a base that fails already would make the fuzz moot
        with CloudLoader([folder / name]) as loader:
            assert sum(b.count for b in loader) == loader.total > 0 and not loader.warnings
    return found


def mutations(limit: int):
    """Byte writes, and u16/u32/u64/f64 writes of boundary values, within [4, limit): a
    broken signature is one known error (test_loaders), not worth many examples."""
    byte = st.tuples(st.just("B"), st.integers(4, limit - 1), st.integers(0, 255))
    word = st.tuples(st.sampled_from(["<H", "<I", "<Q"]), st.integers(4, limit - 8),
                     st.sampled_from(SPECIAL) | st.integers(0, 2**16))
    real = st.tuples(st.just("<d"), st.integers(4, limit - 8), st.sampled_from(SPECIAL_FLOATS))
    return st.lists(byte | word | real, min_size=1, max_size=6)


def mutate(base: bytes, edits, cut: int | None) -> bytes:
    data = bytearray(base)
    for fmt, offset, value in edits:
        if fmt == "B":
            data[offset] = value
        elif fmt == "<d":
            struct.pack_into(fmt, data, offset, value)
        else:
            struct.pack_into(fmt, data, offset, value % (1 << (8 * struct.calcsize(fmt))))
    return bytes(data[:cut] if cut is not None else data)


UNFORESEEN = "cannot be loaded: "
"""How the loader words an exception it did not anticipate (a bug, say, or a numpy
warning raised as an error here): such an InputError fails the example too."""


def check_loads_or_fails_cleanly(path: Path, partial: bool = False) -> str | None:
    """Open, iterate and describe, within TIMEOUT_S: success (None) or one InputError
    line naming the file (returned); anything else (or a hang) fails."""
    def work():
        with CloudLoader([path], batch_points=700, parser_threads=2, partial=partial) as loader:
            batches = sorted(loader, key=lambda b: b.start)
        starts = np.cumsum([0] + [b.count for b in batches])
        assert [b.start for b in batches] == starts[:-1].tolist()
        assert starts[-1] == loader.loaded <= loader.total
        assert loader.loaded == loader.total or (partial and loader.warnings)
        assert 0 <= loader.nonfinite_positions <= loader.loaded
        describe([path], partial=partial)

    try:
        bounded(work, TIMEOUT_S)
    except InputError as exc:
        message = str(exc)
        assert "\n" not in message and str(path) in message and UNFORESEEN not in message, message
        return message
    return None


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("name", ["las12.las", "las14.las", "laz.laz"])
@FUZZ
@given(data=st.data())
def test_fuzz_las_header(bases, scratch, name, data):
    if name not in bases:
        pytest.skip(f"no base file {name}")
    base = bases[name]
    edits = data.draw(mutations(HEAD), label="edits")
    cut = data.draw(st.none() | st.integers(0, len(base)), label="cut")
    path = scratch / name
    path.write_bytes(mutate(base, edits, cut))
    check_loads_or_fails_cleanly(path)


@pytest.mark.filterwarnings("error")
@FUZZ
@given(data=st.data())
def test_fuzz_fast_header(bases, scratch, data):
    base = bases["fast.prgs"]
    edits = data.draw(mutations(256), label="edits")
    cut = data.draw(st.none() | st.integers(0, len(base)), label="cut")
    path = scratch / "fast.prgs"
    path.write_bytes(mutate(base, edits, cut))
    check_loads_or_fails_cleanly(path)


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("name", ["las12.las", "las14.las", "laz.laz", "laz14.laz", "fast.prgs"])
@settings(FUZZ, max_examples=25)
@given(data=st.data())
def test_fuzz_truncation_and_point_bytes(bases, scratch, name, data):
    """Anywhere in the file, header or points: a cut, and random bytes in the records
    (which decode to garbage but must not crash); loaded whole or with --partial."""
    if name not in bases:
        pytest.skip(f"no base file {name}")
    base = bases[name]
    edits = data.draw(st.lists(st.tuples(st.just("B"), st.integers(0, len(base) - 1), st.integers(0, 255)),
                               max_size=20), label="edits")
    cut = data.draw(st.none() | st.integers(0, len(base)), label="cut")
    path = scratch / name
    path.write_bytes(mutate(base, edits, cut))
    check_loads_or_fails_cleanly(path, partial=data.draw(st.booleans(), label="partial"))


# --- what fuzzing found ----------------------------------------------------------------------

def test_vlr_count_beyond_the_file_fails_at_once(bases, scratch):
    """laspy reads as many VLRs as the header says, empty ones past the end of the file:
    with 2^32 - 1 it never returned."""
    data = bytearray(bases["las12.las"])
    struct.pack_into("<I", data, 100, 2**32 - 1)
    path = scratch / "vlrs.las"
    path.write_bytes(data)
    assert "VLRs cannot fit" in check_loads_or_fails_cleanly(path)


def test_absurd_chunk_table_does_not_abort(bases, scratch):
    """lazrs allocates for every chunk a table declares and aborts the process when it
    cannot: a table of 2^32 - 1 chunks killed the CLI. Run in a child process so that a
    regression fails this test rather than the whole run. The table is corrupt, so a
    plain load fails; the points are intact, so a partial one reads them all."""
    data = bytearray(bases["laz.laz"])
    (point_data,) = struct.unpack_from("<I", data, 96)
    (table,) = struct.unpack_from("<q", data, point_data)
    struct.pack_into("<I", data, table + 4, 2**32 - 1)
    path = scratch / "chunks.laz"
    path.write_bytes(data)
    code = ("import sys\n"
            "from progressive.errors import InputError\n"
            "from progressive.loaders import CloudLoader\n"
            "try:\n"
            "    CloudLoader([sys.argv[1]])\n"
            "except InputError as exc:\n"
            "    print(exc)\n"
            "with CloudLoader([sys.argv[1]], partial=True) as loader:\n"
            "    print(sum(b.count for b in loader))\n")
    child = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120)
    assert child.returncode == 0, child.stderr[-2000:]
    error, loaded = child.stdout.splitlines()
    assert "chunk table is missing or corrupt" in error and loaded == str(POINTS)


def test_unfindable_chunk_table_is_never_shown_to_lazrs(bases, scratch):
    """With the table offset pointing past the end of the file, lazrs took chunk-table
    bytes for a chunk header and allocated 3.6 GB (2.6 s here; an abort with less
    memory). Now a plain load refuses the file and a partial one reads every point."""
    data = bytearray(bases["laz14.laz"])
    (point_data,) = struct.unpack_from("<I", data, 96)
    struct.pack_into("<q", data, point_data, 2**46)
    data[-1] ^= 0xFF                                   # nor is it found in the last 8 bytes
    path = scratch / "no_table.laz"
    path.write_bytes(data)
    assert "chunk table is missing or corrupt" in check_loads_or_fails_cleanly(path)
    with CloudLoader([path], partial=True) as loader:
        assert sum(b.count for b in loader) == POINTS and not loader.warnings
