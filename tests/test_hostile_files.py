"""Hostile input files (issue 14, loader side): inputs that are not regular files, LASzip
VLRs and chunk tables that make lazrs panic or abort, fast-format headers with damaged
fields, header bounds the points contradict, counts a file cannot hold.

Every case runs the command line in-process (or, where a Rust panic or a hang could
reach past Python, in a child process with a timeout) and ends either in a rendered
image showing the points or in one line `progressive: error: ...` with exit status 2,
with nothing written and no traceback or numpy warning. Files are real points (the
bundled sample, the shared files) rewritten with laspy or patched byte by byte;
references come from laspy.
"""

from __future__ import annotations

import io
import json
import os
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

import laspy
import lazrs
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_hard_input import TINY, assert_one_error_line, cli

from conftest import REPO, SAMPLE
from progressive.loaders import las as las_module

POINTS = 3_000
"""Points in the small files: a few batches' worth, cheap to render many times."""
EMPTY_ID = 0xFFFFFFFF
CHILD_TIMEOUT_S = 60
LASZIP_ITEMS = 32                       # offset of the item count in the LASzip VLR data
LEGACY_COUNT = 107                      # the 32-bit point count in a LAS header


def run_child(*argv: str, timeout: float = CHILD_TIMEOUT_S) -> subprocess.CompletedProcess:
    """`python -m progressive ...` in a child: a Rust panic writes to fd 2 directly, and a
    regression that hangs must fail the test, not the run."""
    return subprocess.run([sys.executable, "-m", "progressive", *map(str, argv)], capture_output=True,
                          text=True, timeout=timeout, cwd=REPO)


CHILD_CLI = ("import json, sys\n"
             "from progressive.cli import main\n"
             "print(json.dumps([main(argv) for argv in json.loads(sys.argv[1])]))\n")


def run_children(runs: list[list]) -> tuple[list[int], list[str]]:
    """Several command lines in one child process (one start-up): their exit codes and
    the stderr lines of them all."""
    child = subprocess.run([sys.executable, "-c", CHILD_CLI, json.dumps([[str(a) for a in r] for r in runs])],
                           capture_output=True, text=True, timeout=CHILD_TIMEOUT_S, cwd=REPO)
    assert child.returncode == 0, child.stderr[-3000:]
    return json.loads(child.stdout.splitlines()[-1]), child.stderr.splitlines()


def assert_child_error(child: subprocess.CompletedProcess) -> None:
    assert child.returncode == 2, child.stderr
    assert child.stderr.startswith("progressive: error: ") and child.stderr.count("\n") == 1, child.stderr
    assert "panicked" not in child.stderr and "Traceback" not in child.stderr


@pytest.fixture(scope="module")
def sample() -> laspy.LasData:
    return laspy.read(SAMPLE)


@pytest.fixture(scope="module")
def small(tmp_path_factory, sample) -> dict[str, Path]:
    """The sample's first POINTS points as LAS 1.2 (bounds exact), LAZ point format 3
    (pointwise chunked) and 7 (layered), and the whole sample as LAZ (three chunks)."""
    folder = tmp_path_factory.mktemp("small")
    las = laspy.LasData(sample.header)
    las.points = sample.points[:POINTS]
    las.update_header()
    paths = {"las": folder / "small.las", "laz": folder / "small.laz", "laz14": folder / "small14.laz",
             "chunks3": folder / "chunks3.laz"}
    las.write(paths["las"])
    las.write(paths["laz"], laz_backend=laspy.LazBackend.Lazrs)
    laspy.convert(las, point_format_id=7, file_version="1.4").write(paths["laz14"],
                                                                    laz_backend=laspy.LazBackend.Lazrs)
    sample.write(paths["chunks3"], laz_backend=laspy.LazBackend.Lazrs)
    return paths


@pytest.fixture(scope="module")
def variable(tmp_path_factory, small) -> Path:
    """The small layered LAZ rewritten with variable-size chunks (of 1000, 1200 and 800
    points, as COPC files have), compressed by lazrs."""
    source = laspy.read(small["laz14"])
    vlr = lazrs.LazVlr.new_for_compression(7, 0, use_variable_size_chunks=True)
    header = laspy.LasHeader(point_format=7, version="1.4")
    header.scales, header.offsets = source.header.scales, source.header.offsets
    header.mins, header.maxs = source.header.mins, source.header.maxs
    header.point_count = POINTS
    header.vlrs.append(laspy.VLR("laszip encoded", 22204, "lazrs", vlr.record_data()))
    head = io.BytesIO()
    header.write_to(head)
    data = bytearray(head.getvalue())
    data[104] |= 0x80                                   # compressed
    body = io.BytesIO()
    compressor = lazrs.LasZipCompressor(body, vlr)
    compressor.reserve_offset_to_chunk_table()
    raw, size = source.points.array.tobytes(), source.points.array.itemsize
    for lo, hi in ((0, 1000), (1000, 2200), (2200, POINTS)):
        compressor.compress_many(raw[lo * size:hi * size])
        compressor.finish_current_chunk()
    compressor.done()
    points = bytearray(body.getvalue())
    struct.pack_into("<q", points, 0, struct.unpack_from("<q", points, 0)[0] + len(data))
    path = tmp_path_factory.mktemp("variable") / "variable.laz"
    path.write_bytes(bytes(data + points))
    assert np.array_equal(laspy.read(path).points.array, source.points.array)
    return path


@pytest.fixture
def folders(tmp_path) -> tuple[Path, Path]:
    (tmp_path / "in").mkdir()
    (tmp_path / "out").mkdir()
    return tmp_path / "in", tmp_path / "out"


def laszip_vlr_at(data: bytes) -> int:
    """Offset of the LASzip VLR's data in a LAZ file."""
    header = laspy.LasHeader.read_from(io.BytesIO(data))
    return data.index(bytes(header.vlrs.get("LasZipVlr")[0].record_data))


def chunk_table_at(data: bytes) -> tuple[int, int]:
    """(offset of the point data, offset of the chunk table) of a chunked LAZ."""
    (point_data,) = struct.unpack_from("<I", data, 96)
    return point_data, struct.unpack_from("<q", data, point_data)[0]


def xyz(las: laspy.LasData) -> np.ndarray:
    return np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], axis=1)


def render(capsys, path: Path, out: Path, *extra) -> tuple[int, str, np.ndarray | None]:
    """Render `path` with ids; (exit code, stderr, ids or None)."""
    code, _, err = cli(capsys, "render", *TINY, path, "--out", out / "x.png", "--ids", out / "x.npy", *extra)
    return code, err, np.load(out / "x.npy") if code == 0 else None


# --- inputs that are not regular files --------------------------------------------------------

@pytest.mark.parametrize("command", ["render", "info", "convert"])
def test_fifo_without_writer_is_refused_at_once(folders, command):
    """Opening a FIFO for reading blocks until a writer comes: the render, info and convert
    of one hung for ever. Now it is refused in one line."""
    inputs, outputs = folders
    fifo = inputs / "cloud.las"
    os.mkfifo(fifo)
    argv = {"render": ["render", *TINY, fifo, "--out", outputs / "x.png"], "info": ["info", fifo],
            "convert": ["convert", fifo, outputs / "x.prgs"]}[command]
    child = run_child(*argv, timeout=30)
    assert_child_error(child)
    assert "FIFO" in child.stderr and not any(outputs.iterdir())


@pytest.mark.parametrize("device", ["/dev/null", "/dev/zero"])
def test_device_is_refused(folders, capsys, device):
    if not os.path.exists(device):
        pytest.skip(f"no {device}")
    code, _, err = cli(capsys, "render", *TINY, device, "--out", folders[1] / "x.png")
    assert_one_error_line(code, err, folders[1])
    assert "character device" in err


def test_directory_is_refused(folders, capsys):
    code, _, err = cli(capsys, "info", folders[0])
    assert_one_error_line(code, err, folders[1])
    assert "is a directory" in err


# --- LASzip VLRs lazrs panics on --------------------------------------------------------------

LASZIP_DAMAGE = {
    "item count 0": lambda d, at: struct.pack_into("<H", d, at + LASZIP_ITEMS, 0),
    "first item size 7": lambda d, at: struct.pack_into("<H", d, at + 36, 7),
    "second item a Point10": lambda d, at: struct.pack_into("<H", d, at + 40, 6),
    "last item size 0": lambda d, at: struct.pack_into("<H", d, at + 34 + 6 * (struct.unpack_from(
        "<H", d, at + LASZIP_ITEMS)[0] - 1) + 2, 0),
    "compressor 9": lambda d, at: struct.pack_into("<H", d, at, 9),
    "chunk size 0": lambda d, at: struct.pack_into("<I", d, at + 12, 0),
}


def test_laszip_vlr_damage_is_one_line_and_no_panic(folders, small):
    """lazrs divides by the item count (0: a panic), slices records by the item sizes (a
    panic where they do not make up the record) and prints the panic on stderr before
    Python sees it: such VLRs are refused before lazrs sees them, with or without
    --partial, for both the pointwise (format 3) and layered (format 7) items."""
    inputs, outputs = folders
    runs = []
    for case, damage in LASZIP_DAMAGE.items():
        for name in ("laz", "laz14"):
            data = bytearray(small[name].read_bytes())
            damage(data, laszip_vlr_at(data))
            path = inputs / f"{case.replace(' ', '_')}_{name}.laz"
            path.write_bytes(data)
            runs += [["render", *TINY, path, "--out", outputs / "x.png", *partial] for partial in ([], ["--partial"])]
    codes, lines = run_children(runs)
    assert codes == [2] * len(runs)
    assert len(lines) == len(runs), "\n".join(lines)
    assert all(line.startswith("progressive: error: ") and "LASzip" in line for line in lines), "\n".join(lines)
    assert not any(outputs.iterdir())


def test_absurd_chunk_size_does_not_abort(folders, small, capsys):
    """lazrs's parallel decoder allocates a whole chunk (chunk size x record length) at
    once: a chunk size of 4e9 in the VLR aborted the process. Such chunks are decoded in
    sequence, which reads every point."""
    inputs, outputs = folders
    data = bytearray(small["laz14"].read_bytes())
    struct.pack_into("<I", data, laszip_vlr_at(data) + 12, 0xFF00C350)
    path = inputs / "big_chunks.laz"
    path.write_bytes(data)
    code = ("import sys\nfrom progressive.loaders import CloudLoader\n"
            "with CloudLoader([sys.argv[1]]) as loader:\n    print(sum(b.count for b in loader))\n")
    child = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True,
                           timeout=CHILD_TIMEOUT_S)
    assert child.returncode == 0 and child.stdout.split() == [str(POINTS)], child.stderr[-2000:]


def test_chunk_table_byte_counts_that_do_not_add_up(folders, small):
    """A chunk table entry of absurd bytes made lazrs panic ('capacity overflow'): a table
    is used only when its byte counts add up to the chunk data."""
    inputs, outputs = folders
    data = bytearray(small["chunks3"].read_bytes())
    _, table = chunk_table_at(data)
    data[table + 8] ^= 0x02                 # the first entry, arithmetic-coded
    path = inputs / "table.laz"
    path.write_bytes(data)
    assert_child_error(run_child("render", *TINY, path, "--out", outputs / "x.png"))
    child = run_child("render", *TINY, path, "--partial", "--out", outputs / "x.png")
    assert child.returncode == 0 and "panicked" not in child.stderr, child.stderr
    assert all(line.startswith("progressive: warning: ") for line in child.stderr.splitlines())


# --- chunk tables that disagree with the header, read with --partial --------------------------

def chunk_count(data: bytearray, chunks: int) -> None:
    _, table = chunk_table_at(data)
    struct.pack_into("<I", data, table + 4, chunks)


CHUNK_TABLE = {
    "table says 0 chunks": lambda d: chunk_count(d, 0),
    "table says 1 chunk": lambda d: chunk_count(d, 1),
    "header count beyond the table": lambda d: struct.pack_into("<I", d, LEGACY_COUNT, 110_000 + 60_000),
    "header count a little more": lambda d: struct.pack_into("<I", d, LEGACY_COUNT, 110_000 + 5),
}


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("case", list(CHUNK_TABLE))
def test_partial_reads_laz_whose_chunk_table_disagrees(folders, capsys, small, sample, case):
    """laspy's sequential reader decodes these files' points; a plain load refuses them in
    one line, and --partial renders every point of the file's chunks (the same points as
    laspy's, in file order) with warnings. Where the header promises more, the decoder
    may take a few bytes of the chunk table for points before it fails, as laspy's does
    (tests/test_hard_input.py holds that equality)."""
    inputs, outputs = folders
    data = bytearray(small["chunks3"].read_bytes())
    CHUNK_TABLE[case](data)
    path = inputs / "table.laz"
    path.write_bytes(data)
    code, _, err = cli(capsys, "render", *TINY, path, "--out", outputs / "x.png")
    assert_one_error_line(code, err, outputs)
    code, err, ids = render(capsys, path, outputs, "--partial")
    assert code == 0, err
    lines = err.splitlines()
    assert lines and all(line.startswith("progressive: warning: ") for line in lines), err
    shown = ids[ids != EMPTY_ID]
    assert shown.size > 100
    from progressive.loaders import CloudLoader
    with CloudLoader([path], partial=True) as loader:
        batches = sorted(loader, key=lambda b: b.start)
    positions = np.concatenate([b.positions for b in batches])
    expected = xyz(sample)
    assert len(expected) <= len(positions) < len(expected) + 10 and shown.max() < len(positions)
    np.testing.assert_array_equal(positions[:len(expected)], np.float32(expected - loader.info.origin))


# --- header bounds the points contradict ------------------------------------------------------

MAX_X, MIN_X = 179, 187
"""Byte offsets of the first header bounds (float64, max then min per axis) and scales."""
SCALE_X = 131


def set_bounds(data: bytearray, mins, maxs) -> None:
    for axis in range(3):
        struct.pack_into("<dd", data, MAX_X + 16 * axis, maxs[axis], mins[axis])


def get_bounds(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    pairs = [struct.unpack_from("<dd", data, MAX_X + 16 * axis) for axis in range(3)]
    return np.array([p[1] for p in pairs]), np.array([p[0] for p in pairs])


LAS_BOUNDS = {
    "inverted": lambda d, lo, hi: set_bounds(d, hi, lo),
    "all zero": lambda d, lo, hi: set_bounds(d, np.zeros(3), np.zeros(3)),
    "shifted by 1e6": lambda d, lo, hi: set_bounds(d, lo + 1e6, hi + 1e6),
    "min x above the points": lambda d, lo, hi: set_bounds(d, lo + [(hi[0] - lo[0]) / 2, 0, 0], hi),
    "negative scale": lambda d, lo, hi: struct.pack_into("<d", d, SCALE_X, -struct.unpack_from("<d", d, SCALE_X)[0]),
}
SAME_POINTS = {"inverted", "all zero", "shifted by 1e6", "min x above the points"}


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("kind", ["las", "laz"])
@pytest.mark.parametrize("case", list(LAS_BOUNDS))
def test_wrong_header_bounds_frame_the_points(folders, capsys, small, case, kind):
    """The auto camera framed the header's box and the image was empty. Bounds the first
    points contradict are replaced by the points' own (one warning): the bounds laspy
    gives, and the image of the intact file where the points are the same."""
    inputs, outputs = folders
    data = bytearray(small[kind].read_bytes())
    LAS_BOUNDS[case](data, *get_bounds(data))
    path = inputs / f"bounds.{kind}"
    path.write_bytes(data)
    code, err, ids = render(capsys, path, outputs)
    assert code == 0, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("progressive: warning: ") and "header bounds" in lines[0], err
    assert (ids != EMPTY_ID).sum() > 100
    if case in SAME_POINTS:
        good_code, good_err, good_ids = render(capsys, small[kind], outputs)
        assert good_code == 0 and not good_err, good_err
        np.testing.assert_array_equal(ids, good_ids)
    code, out, err = cli(capsys, "info", "--json", path)
    assert code == 0, err
    points = xyz(laspy.read(path))
    desc = json.loads(out)
    assert desc["origin"] == ((points.min(axis=0) + points.max(axis=0)) / 2).tolist()
    assert desc["bounds"] == {"min": points.min(axis=0).tolist(), "max": points.max(axis=0).tolist()}


def test_header_bounds_holding_the_points_are_kept(folders, small):
    """Bounds a little wider than the points (rounded outwards, as writers do) are the
    header's own: no warning, no extra pass."""
    from progressive.loaders import CloudLoader

    data = bytearray(small["las"].read_bytes())
    lo, hi = get_bounds(data)
    set_bounds(data, np.floor(lo) - 1, np.ceil(hi) + 1)
    path = folders[0] / "wide.las"
    path.write_bytes(data)
    with CloudLoader([path]) as loader:
        assert not loader.warnings
        np.testing.assert_array_equal(loader.info.bounds_min, np.floor(lo) - 1)


# --- fast-format headers ----------------------------------------------------------------------

FAST_ORIGIN, FAST_MIN, FAST_MAX, FAST_KIND, FAST_NAME = 24, 48, 72, 96, 112
"""Byte offsets in the fast-format header (see loaders/fastformat.py HEADER)."""
NAME_FIELD = 64


@pytest.fixture(scope="module")
def fast(tmp_path_factory, small) -> dict[str, Path]:
    """The small LAS in the fast format, its word the RGB and the intensity."""
    from progressive.loaders import CloudLoader, open_cloud, write_fast

    folder = tmp_path_factory.mktemp("fast")
    info = open_cloud([small["las"]])
    paths = {}
    for name in ("rgb", "intensity"):
        paths[name] = folder / f"{name}.prgs"
        write_fast(paths[name], CloudLoader([small["las"]]), info, info.attribute(name))
    return paths


def name_field(data: bytearray, raw: bytes) -> None:
    data[FAST_NAME:FAST_NAME + NAME_FIELD] = raw.ljust(NAME_FIELD, b"\x00")


def flip(offset: int, bit: int):
    def edit(data: bytearray) -> None:
        data[offset] ^= 1 << bit
    return edit


FAST_BAD = {
    "name empty": ("rgb", lambda d: name_field(d, b"")),
    "name not NUL-terminated": ("intensity", lambda d: name_field(d, b"i" * NAME_FIELD)),
    "name not UTF-8": ("intensity", lambda d: name_field(d, b"intens\xffity")),
    "name with a control character": ("intensity", lambda d: name_field(d, b"inten\x07sity")),
    "name garbage after its NUL": ("rgb", lambda d: name_field(d, b"rgb\x00x")),
    "rgb with a flipped bit": ("rgb", flip(FAST_NAME + 2, 0)),
    "intensity stored as rgb": ("intensity", lambda d: struct.pack_into("<I", d, FAST_KIND, 0)),
    "origin 1e300": ("rgb", lambda d: struct.pack_into("<d", d, FAST_ORIGIN, 1e300)),
    "count beyond the file": ("rgb", lambda d: struct.pack_into("<Q", d, 16, 2**40)),
}


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("command", ["render", "info"])
@pytest.mark.parametrize("case", list(FAST_BAD))
def test_fast_header_damage_is_one_line(folders, capsys, fast, case, command):
    """A fast-format name that is empty, unterminated, not UTF-8 or that no longer names
    its kind crashed the default colouring with StopIteration; an origin no float32
    position can be placed against gave an empty image. Each is one error line."""
    inputs, outputs = folders
    source, edit = FAST_BAD[case]
    data = bytearray(fast[source].read_bytes())
    edit(data)
    path = inputs / "bad.prgs"
    path.write_bytes(data)
    argv = ["render", *TINY, path, "--out", outputs / "x.png"] if command == "render" else ["info", path]
    code, _, err = cli(capsys, *argv)
    assert_one_error_line(code, err, outputs)
    assert str(path) in err


@pytest.mark.filterwarnings("error")
def test_fast_name_with_a_flipped_bit_of_its_kind_renders(folders, capsys, fast):
    """A scalar whose name lost a bit is still a scalar: it renders under its new name."""
    inputs, outputs = folders
    data = bytearray(fast["intensity"].read_bytes())
    flip(FAST_NAME + 8, 0)(data)                   # intensity -> intensitx
    path = inputs / "renamed.prgs"
    path.write_bytes(data)
    code, err, ids = render(capsys, path, outputs)
    assert code == 0 and not err, err
    assert (ids != EMPTY_ID).sum() > 100


FAST_BOUNDS = {
    "inverted": lambda d: d.__setitem__(slice(FAST_MIN, FAST_MAX + 24),
                                        d[FAST_MAX:FAST_MAX + 24] + d[FAST_MIN:FAST_MIN + 24]),
    "all zero": lambda d: d.__setitem__(slice(FAST_MIN, FAST_MAX + 24), bytes(48)),
    "max 1e300": lambda d: struct.pack_into("<ddd", d, FAST_MAX, 1e300, 1e300, 1e300),
    "shifted by 1e6": lambda d: struct.pack_into("<6d", d, FAST_MIN, *(
        v + 1e6 for v in struct.unpack_from("<6d", d, FAST_MIN))),
}


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("case", list(FAST_BOUNDS))
def test_fast_wrong_bounds_frame_the_points(folders, capsys, fast, case):
    """Fast-format bounds the records contradict are replaced by the records' own: the
    image of the intact file, one warning."""
    inputs, outputs = folders
    data = bytearray(fast["rgb"].read_bytes())
    FAST_BOUNDS[case](data)
    path = inputs / "bounds.prgs"
    path.write_bytes(data)
    code, err, ids = render(capsys, path, outputs)
    assert code == 0, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("progressive: warning: ") and "header bounds" in lines[0], err
    good_code, good_err, good_ids = render(capsys, fast["rgb"], outputs)
    assert good_code == 0 and not good_err, good_err
    assert (good_ids != EMPTY_ID).sum() > 100
    np.testing.assert_array_equal(ids, good_ids)


# --- declared counts the file cannot hold, names that are not one line ------------------------

@pytest.mark.parametrize("field, fmt, value", [(LEGACY_COUNT, "<I", 2**32 - 1), (247, "<Q", 2**62)])
def test_count_beyond_the_file_fails_before_reading(folders, capsys, small, field, fmt, value):
    """A header promising billions of points the file cannot hold is refused at once (the
    point data's size against the file's), and --partial reads the points there are."""
    inputs, outputs = folders
    source = laspy.read(small["las"])
    path = inputs / "promise.las"
    laspy.convert(source, file_version="1.4").write(path) if fmt == "<Q" else source.write(path)
    data = bytearray(path.read_bytes())
    struct.pack_into(fmt, data, field, value)
    path.write_bytes(data)
    code, _, err = cli(capsys, "render", *TINY, path, "--out", outputs / "x.png")
    assert_one_error_line(code, err, outputs)
    assert "truncated" in err
    code, err, ids = render(capsys, path, outputs, "--partial")
    assert code == 0 and err.startswith("progressive: warning: ") and err.count("\n") == 1, err
    assert (ids != EMPTY_ID).sum() > 100 and ids[ids != EMPTY_ID].max() < POINTS


def test_file_name_with_a_newline_is_one_error_line(folders, capsys):
    inputs, outputs = folders
    path = inputs / "two\nlines.las"
    path.write_bytes(b"LASF" + bytes(20))
    code, _, err = cli(capsys, "render", *TINY, path, "--out", outputs / "x.png")
    assert_one_error_line(code, err, outputs)
    assert "two\\nlines.las" in err


# --- property-based: header fields, VLR layouts, chunk tables, fast-format headers ------------
#
# tests/test_fuzz.py writes random bytes and boundary integers at random offsets and checks
# the loader; these draw values for the named fields the format has (so that most examples
# reach past the first check) and check the whole command line: exit 0 with the points in
# view, or exit 2 with one error line, and nothing else on stderr (panics included: capfd
# sees what Rust writes to fd 2).

FUZZ = settings(max_examples=int(os.environ.get("PROGRESSIVE_FUZZ_EXAMPLES", "12")), deadline=None,
                derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
NAN, INF = float("nan"), float("inf")


def field(offset: int, fmt: str, *changes):
    """A header field and the changes drawn for it: each a value, or a function of the
    field's value in the real file."""
    return st.tuples(st.just((offset, fmt)), st.sampled_from(changes))


def apply(data: bytearray, edits) -> bytes:
    for (offset, fmt), change in edits:
        if offset + struct.calcsize(fmt) > len(data):
            continue
        value = change(struct.unpack_from(fmt, data, offset)[0]) if callable(change) else change
        if fmt[-1] not in "df":
            value %= 1 << (8 * struct.calcsize(fmt))
            value -= (1 << (8 * struct.calcsize(fmt))) if fmt[-1] == "q" and value >= 1 << 63 else 0
        struct.pack_into(fmt, data, offset, value)
    return bytes(data)


def reals(*extra):
    return (lambda v: -v, lambda v: v * (1 + 1e-12), lambda v: v + 1e6, 0.0, 1e-9, 1e300, -1e300, NAN, INF, *extra)


def counts(*extra):
    return (0, 1, lambda v: v - 1, lambda v: v + 1, lambda v: 2 * v, 2**32 - 1, *extra)


LAS_FIELDS = st.one_of(
    *(field(offset, "<d", *reals(1.0, 1e-3, 1e3)) for offset in (131, 139, 147)),          # scale
    *(field(offset, "<d", *reals(1e12)) for offset in (155, 163, 171)),                     # offset
    *(field(offset, "<d", *reals(lambda v: v - 1e6)) for offset in range(179, 227, 8)),     # bounds
    field(LEGACY_COUNT, "<I", *counts()),
    field(247, "<Q", *counts(2**62, 2**64 - 1)),                                           # LAS 1.4 count
    field(96, "<I", *counts(lambda v: v - 54, lambda v: v + 54)),                          # point data offset
    field(105, "<H", *counts(65535)),                                                      # record length
    field(100, "<I", *counts()),                                                           # VLR count
    field(94, "<H", 0, 227, 375, lambda v: v + 1, lambda v: v - 1),                        # header size
    field(24, "<H", 0x0001, 0x0201, 0x0301, 0x0401, 0x0501, 0x0101),                       # version
    field(104, "<B", *range(0, 12), *range(0x80, 0x8C), 0x40),                            # point format
)


def check_cli(capfd, path: Path, partial: bool) -> int:
    """Render `path`: exit 0 with the points in view (unless none is drawable) and only
    warnings on stderr, or exit 2 with one error line; outputs only on success."""
    out = Path(tempfile.mkdtemp(dir=path.parent))
    code, _, err = cli(capfd, "render", *TINY, path, "--out", out / "x.png", "--ids", out / "x.npy",
                       "--stats", out / "s.json", *(["--partial"] if partial else []))
    for bad in ("Traceback", "panicked", "RuntimeWarning", "thread '"):
        assert bad not in err, err
    if code != 0:
        assert_one_error_line(code, err, out)
        return code
    assert all(line.startswith("progressive: warning: ") for line in err.splitlines()), err
    assert sorted(p.name for p in out.iterdir()) == ["s.json", "x.npy", "x.png"]
    stats = json.loads((out / "s.json").read_text())
    ids = np.load(out / "x.npy")
    if stats["points_not_drawn"] < stats["points_on_gpu"]:
        assert (ids != EMPTY_ID).any(), f"{stats['points_on_gpu']} points, none in view: {err}"
    return code


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("name", ["las", "laz", "laz14"])
@FUZZ
@given(data=st.data())
def test_property_las_header_fields(tmp_path, capfd, small, name, data):
    edits = data.draw(st.lists(LAS_FIELDS, min_size=1, max_size=3), label="edits")
    path = tmp_path / f"case.{'las' if name == 'las' else 'laz'}"
    path.write_bytes(apply(bytearray(small[name].read_bytes()), edits))
    check_cli(capfd, path, data.draw(st.booleans(), label="partial"))


def laszip_fields(at: int):
    """The LASzip VLR's fields, its VLR header's record length, and its items."""
    item = st.integers(0, 4).flatmap(lambda i: st.one_of(
        field(at + 34 + 6 * i, "<H", *range(0, 16), 99),                                   # type
        field(at + 36 + 6 * i, "<H", 0, 1, 6, 7, 8, 20, 29, 30, 65535, lambda v: v + 1),    # size
        field(at + 38 + 6 * i, "<H", 0, 1, 2, 3, 4, 9)))                                   # version
    return st.one_of(
        field(at, "<H", 0, 1, 2, 3, 4, 65535),                                             # compressor
        field(at + 2, "<H", 0, 1, 2),                                                      # coder
        field(at + 4, "<B", 0, 1, 2, 3, 9, 255),                                           # version major
        field(at + 12, "<I", 0, 1, 2, 100, 50_000, 2**31, 2**32 - 2, 2**32 - 1),           # chunk size
        field(at + 16, "<q", -1, 0, 1, 2**40),                                             # special EVLRs
        field(at + LASZIP_ITEMS, "<H", 0, 1, 2, 3, 4, 5, 65535),                           # item count
        field(at - VLR_HEADER + 20, "<H", 0, 33, 34, lambda v: v - 6, lambda v: v + 6, 65535),
        item,
    )


VLR_HEADER = 54


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("name", ["laz", "laz14"])
@FUZZ
@given(data=st.data())
def test_property_laszip_vlr(tmp_path, capfd, small, name, data):
    base = bytearray(small[name].read_bytes())
    edits = data.draw(st.lists(laszip_fields(laszip_vlr_at(base)), min_size=1, max_size=3), label="edits")
    path = tmp_path / "case.laz"
    path.write_bytes(apply(base, edits))
    check_cli(capfd, path, data.draw(st.booleans(), label="partial"))


def chunk_table_fields(data: bytes):
    point_data, table = chunk_table_at(data)
    size = len(data)
    return st.one_of(
        field(point_data, "<q", -1, 0, point_data, point_data + 8, size - 8, size, 2**62,
              lambda v: v - 1, lambda v: v + 1, lambda v: v - 100),                      # table offset
        field(table, "<I", 0, 1, 2**32 - 1),                                             # table version
        field(table + 4, "<I", 0, 1, 2, 3, 4, 1000, 2**32 - 1),                          # chunk count
        st.tuples(st.tuples(st.integers(table + 8, size - 1), st.just("<B")), st.integers(0, 255)),
    )


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("name", ["laz", "laz14", "variable"])
@FUZZ
@given(data=st.data())
def test_property_laz_chunk_table(tmp_path, capfd, small, variable, name, data):
    base = bytearray((variable if name == "variable" else small[name]).read_bytes())
    edits = data.draw(st.lists(chunk_table_fields(base), min_size=1, max_size=3), label="edits")
    path = tmp_path / "case.laz"
    path.write_bytes(apply(base, edits))
    check_cli(capfd, path, data.draw(st.booleans(), label="partial"))


@pytest.fixture(scope="module")
def extra_bytes(tmp_path_factory, small) -> Path:
    """The small LAS with a float32, a uint16[3] and an int8 extra-bytes dimension."""
    source = laspy.read(small["las"])
    header = laspy.LasHeader(point_format=3, version="1.4")
    header.scales, header.offsets = source.header.scales, source.header.offsets
    header.add_extra_dims([laspy.ExtraBytesParams("f32", "f4"), laspy.ExtraBytesParams("triple", "3u2"),
                           laspy.ExtraBytesParams("small", "i1")])
    las = laspy.LasData(header)
    las.x, las.y, las.z = source.x, source.y, source.z
    las.red, las.green, las.blue = source.red, source.green, source.blue
    las.f32 = np.arange(POINTS, dtype=np.float32)
    path = tmp_path_factory.mktemp("eb") / "eb.las"
    las.write(path)
    return path


@pytest.mark.filterwarnings("error")
@FUZZ
@given(data=st.data())
def test_property_extra_bytes_vlr(tmp_path, capfd, extra_bytes, data):
    base = bytearray(extra_bytes.read_bytes())
    at = base.index(b"LASF_Spec") - 2 + VLR_HEADER            # the extra-bytes VLR's data
    entry = st.integers(0, 3).flatmap(lambda i: st.one_of(
        field(at + 192 * i + 2, "<B", *range(0, 32), 255),                               # data type
        field(at + 192 * i + 3, "<B", 0, 1, 2, 4, 8, 16, 255),                            # options
        field(at + 192 * i + 4, "<B", 0, 0x80, 0xFF, ord("["), ord("]")),                 # name
        field(at + 192 * i + 4, "<I", 0, 0xFFFFFFFF, 0x00616161)))
    length = field(at - VLR_HEADER + 20, "<H", 0, 191, 193, 384, 576, 768, 65535)
    edits = data.draw(st.lists(entry | length, min_size=1, max_size=3), label="edits")
    path = tmp_path / "case.las"
    path.write_bytes(apply(base, edits))
    check_cli(capfd, path, data.draw(st.booleans(), label="partial"))


FAST_FIELDS = st.one_of(
    field(8, "<I", 0, 2, 2**32 - 1),                                                     # version
    field(12, "<I", 0, 255, 257),                                                        # header size
    field(16, "<Q", *counts(2**40)),                                                     # count
    *(field(offset, "<d", *reals(1e12, 2e12)) for offset in range(FAST_ORIGIN, FAST_ORIGIN + 24, 8)),
    *(field(offset, "<d", *reals(lambda v: v - 1e6)) for offset in range(FAST_MIN, FAST_MAX + 24, 8)),
    field(FAST_KIND, "<I", 0, 1, 2, 3, 2**32 - 1),
    field(100, "<I", 0, 1, 2**32 - 1),                                                   # reserved
    field(104, "<d", 0.0, 1e9, 1e300, NAN, lambda v: -v),                                 # attribute offset
    st.tuples(st.tuples(st.integers(FAST_NAME, FAST_NAME + NAME_FIELD - 1), st.just("<B")),
              st.sampled_from([0, 1, 0x20, 0x41, 0x7F, 0x80, 0xC3, 0xFF])),               # name bytes
)


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("name", ["rgb", "intensity"])
@FUZZ
@given(data=st.data())
def test_property_fast_header(tmp_path, capfd, fast, name, data):
    edits = data.draw(st.lists(FAST_FIELDS, min_size=1, max_size=3), label="edits")
    path = tmp_path / "case.prgs"
    path.write_bytes(apply(bytearray(fast[name].read_bytes()), edits))
    check_cli(capfd, path, data.draw(st.booleans(), label="partial"))


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("case", ["plain", "cut", "count more", "count less"])
def test_variable_size_chunks(folders, capsys, variable, case):
    """Variable-size chunks need the table's point counts: without a table (a cut file)
    nothing decodes, in one line, with or without --partial (lazrs panicked); a count the
    table contradicts is refused, and read as far as both agree with --partial."""
    inputs, outputs = folders
    data = bytearray(variable.read_bytes())
    if case == "cut":
        del data[len(data) * 2 // 3:]
    elif case != "plain":
        struct.pack_into("<Q", data, 247, POINTS + (100 if case == "count more" else -100))
    path = inputs / "variable.laz"
    path.write_bytes(data)
    code, _, err = cli(capsys, "render", *TINY, path, "--out", outputs / "x.png")
    if case == "plain":
        assert code == 0 and not err, err
        return
    assert_one_error_line(code, err, outputs)
    code, err, ids = render(capsys, path, outputs, "--partial")
    if case == "cut":
        assert_one_error_line(code, err, outputs)
        assert "variable size" in err
        return
    assert code == 0 and err.count("\n") == 1 and err.startswith("progressive: warning: "), err
    read = POINTS - 100 if case == "count less" else POINTS
    assert (ids != EMPTY_ID).sum() > 100 and ids[ids != EMPTY_ID].max() < read


def test_more_points_than_slots_is_one_line(folders, capsys, monkeypatch):
    """A (sparse) file that does hold 2^32 - 1 points of 34 bytes: more than the uint32
    slots of the shuffled buffer address. It failed with a ValueError deep in the renderer;
    now it is refused when the cloud is opened, before any point is read: its zeros
    contradict the header bounds, and the bounds pass would read all 146 GB first."""
    def no_reads(*args, **kwargs):
        raise AssertionError("points were read before the file was refused")
    monkeypatch.setattr(las_module, "decode", no_reads)
    inputs, outputs = folders
    data = bytearray(SAMPLE.read_bytes())
    (point_data,) = struct.unpack_from("<I", data, 96)
    struct.pack_into("<I", data, LEGACY_COUNT, 2**32 - 1)
    path = inputs / "sparse.las"
    with path.open("wb") as stream:
        stream.write(data[:point_data + 34 * 10])
        try:
            stream.truncate(point_data + 34 * (2**32 - 1))
        except OSError as exc:
            pytest.skip(f"no sparse file of 146 GB here: {exc}")
    code, _, err = cli(capsys, "render", *TINY, path, "--out", outputs / "x.png")
    assert_one_error_line(code, err, outputs)
    assert "4,294,967,295 points" in err
