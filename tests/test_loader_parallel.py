"""The parallel LAZ decoder and the direct LAS reads against laspy: every core and thread
count, batch sizes that cut chunks and reads, partial reads of damaged files."""

from __future__ import annotations

import io
import os
import platform
import subprocess
import sys
import time

import laspy
import lazrs
import numpy as np
import pytest
from test_loaders import assert_covers, expected_values, joined, load, one_line_naming

from conftest import SAMPLE, shared_file
from progressive.errors import InputError
from progressive.loaders import CloudLoader
from progressive.loaders import las as las_module
from progressive.loaders.fastformat import HEADER_BYTES
from progressive.loaders.las import open_las
from progressive.loaders.laz import decode_chunks
from progressive.loaders.types import PARSER_THREADS

CHUNKED = ("lone-star.copc.laz", "lion_takanawa.copc.laz", "las_with_several_extra_byte_bloc.laz",
           "pine_plot.laz", "fullwave.laz")
"""Real LAZ files with sound chunk tables: variable-size (COPC) and fixed-size chunks,
point formats 0, 6, 7, 8 and 10, extra bytes."""
CORES = (1, 2, 3, 8)


def records_of(path) -> np.ndarray:
    return laspy.read(path).points.array


@pytest.mark.parametrize("name", CHUNKED)
def test_decode_chunks_equals_laspy_for_every_core_count(name):
    path = shared_file(name)
    source = open_las(path)
    laz = source.laz
    assert laz.chunks, "the file should take the parallel path"
    expected = records_of(path)
    chunk = laz.chunks[0][0]
    cut = min(len(expected), 2 * chunk + 17)            # inside the third chunk
    for cores in CORES:
        for first_read in (1, chunk + 1, len(expected)):
            reads = list(decode_chunks(str(path), laz, len(expected), first_read, source.records.dtype, cores))
            got = np.concatenate(reads)
            assert got.dtype == expected.dtype
            np.testing.assert_array_equal(got, expected, err_msg=f"{cores} cores, first read {first_read}")
        partial = np.concatenate(list(decode_chunks(str(path), laz, cut, 1, source.records.dtype, cores)))
        np.testing.assert_array_equal(partial, expected[:cut])


@pytest.mark.parametrize("short_chunks", [0, 3, 100])
def test_reads_hold_rounds_of_chunks_per_core(monkeypatch, short_chunks):
    """A read holds the first read's chunks, then one chunk per core for the next
    SHORT_READS_POINTS (here those of `short_chunks` chunks), then ROUNDS_PER_READ
    chunks per core; together the file's records in order."""
    from progressive.loaders import laz as laz_module
    path = shared_file("las_with_several_extra_byte_bloc.laz")
    source = open_las(path)
    sizes = [n for n, _ in source.laz.chunks]
    monkeypatch.setattr(laz_module, "SHORT_READS_POINTS", sum(sizes[1:1 + short_chunks]))
    expected_records = records_of(path)
    for cores in (1, 2, 3):
        got = list(decode_chunks(str(path), source.laz, source.info.points, 1, source.records.dtype, cores))
        expected, at = [sizes[0]], 1
        while at < len(sizes):
            take = cores if at < 1 + short_chunks else laz_module.ROUNDS_PER_READ * cores
            expected.append(sum(sizes[at:at + take]))
            at += take
        assert [len(r) for r in got] == expected, f"{cores} cores"
        np.testing.assert_array_equal(np.concatenate(got), expected_records)


def assert_equals_laspy(loader, batches, las) -> None:
    assert_covers(batches, len(las.points), loader.batch_points)
    positions = joined(batches)
    for axis, dim in enumerate("xyz"):
        np.testing.assert_array_equal(positions[:, axis], np.float32(np.asarray(getattr(las, dim)) - loader.info.origin[axis]))
    for attr in loader.info.attributes:
        if attr.name != "elevation":
            values = joined(batches, attr.name)
            assert values.dtype == attr.dtype
            np.testing.assert_array_equal(values, expected_values(las, attr.name), err_msg=attr.name)


@pytest.mark.parametrize("name", ["autzen_trim.las", "lone-star.copc.laz", "pine_plot.laz"])
def test_every_thread_and_core_count_equals_laspy(name, monkeypatch):
    """Batches that cut chunks (chunk size +- 1, a prime) and reads, any parser threads."""
    path = SAMPLE if name == SAMPLE.name else shared_file(name)
    las = laspy.read(path)
    chunk = 50_000 if name.endswith(".las") else open_las(path).laz.chunks[0][0]
    for cores, threads, batch in ((1, 1, chunk - 1), (2, 3, chunk + 1), (3, 2, 7_919), (8, 5, 500_000)):
        monkeypatch.setattr(las_module, "available_cores", lambda cores=cores: cores)
        loader, batches = load([path], parser_threads=threads, batch_points=batch)
        assert loader.done and not loader.warnings
        assert_equals_laspy(loader, batches, las)


def test_default_threads_follow_the_cpu_affinity(monkeypatch):
    """Parser threads default to one a core this process may run on (its affinity, not
    every core of the machine), at most PARSER_THREADS; decoder processes to one a core."""
    from progressive.loaders.laz_pool import DecoderPool
    from progressive.loaders.types import PARSER_THREADS

    for cores, threads in (({0, 2, 5}, 3), (set(range(0, 4 * PARSER_THREADS, 2)), PARSER_THREADS)):
        monkeypatch.setattr(os, "sched_getaffinity", lambda pid, cores=cores: cores, raising=False)
        with CloudLoader([SAMPLE]) as loader:
            assert loader.parser_threads == threads
            assert sum(b.count for b in loader) == loader.total
        with DecoderPool() as pool:
            assert pool.processes == len(cores)


def sequential_prefix(path) -> np.ndarray:
    """The points lazrs's sequential decoder gives, one at a time, until its first failure."""
    data = path.read_bytes()
    header = laspy.LasHeader.read_from(io.BytesIO(data))
    stream = io.BytesIO(data)
    stream.seek(header.offset_to_point_data)
    decoder = lazrs.LasZipDecompressor(stream, bytes(header.vlrs.get("LasZipVlr")[0].record_data))
    out = np.empty(header.point_count, header.point_format.dtype())
    view = memoryview(out).cast("B")
    size = header.point_format.size
    for i in range(header.point_count):
        try:
            decoder.decompress_many(view[i * size:(i + 1) * size])
        except BaseException:       # lazrs errors and panics
            return out[:i]
    return out


@pytest.fixture(scope="module")
def sample_laz(tmp_path_factory):
    """The sample as a LAZ of laspy's 50,000-point chunks."""
    path = tmp_path_factory.mktemp("laz") / "sample.laz"
    laspy.read(SAMPLE).write(path, laz_backend=laspy.LazBackend.Lazrs)
    return path


def test_partial_read_of_a_corrupt_chunk_keeps_every_point_before_it(tmp_path, monkeypatch, sample_laz):
    """Bytes of the second chunk overwritten (the chunk table still adds up): the parallel
    read of that chunk fails, and what a partial load keeps is a prefix of what the
    sequential decoder gives, at least every point before the damage, for any cores."""
    source = laspy.read(SAMPLE)
    data = bytearray(sample_laz.read_bytes())
    header = laspy.LasHeader.read_from(io.BytesIO(bytes(data)))
    stream = io.BytesIO(bytes(data))
    stream.seek(header.offset_to_point_data)
    table = lazrs.read_chunk_table(stream, lazrs.LazVlr(bytes(header.vlrs.get("LasZipVlr")[0].record_data)))
    assert len(table) >= 2
    second = header.offset_to_point_data + 8 + table[0][1]
    data[second + table[1][1] // 3: second + table[1][1] // 3 + 64] = bytes(range(64))
    path = tmp_path / "damaged.laz"
    path.write_bytes(bytes(data))
    reference = sequential_prefix(path)
    for cores, batch in ((1, 20_000), (2, 500_000), (3, 7_919)):
        monkeypatch.setattr(las_module, "available_cores", lambda cores=cores: cores)
        loader, batches = load([path], partial=True, batch_points=batch)
        read = sum(b.count for b in batches)
        assert_covers(batches, read, batch)
        assert table[0][0] <= read <= len(reference)
        z = source.header.scales[2] * reference["Z"][:read] + source.header.offsets[2]
        np.testing.assert_array_equal(joined(batches)[:, 2], np.float32(z - loader.info.origin[2]))
    with pytest.raises(InputError) as err:
        load([path])
    one_line_naming(err.value, path)


def test_las_cut_after_it_was_opened_is_one_line(tmp_path):
    """The size is checked at open; a file cut before its spans are read fails in one
    line naming the points that could be read, not with a short array."""
    path = tmp_path / "shrinking.las"
    data = SAMPLE.read_bytes()
    path.write_bytes(data)
    loader = CloudLoader([path], batch_points=10_000, parser_threads=2)
    with open(path, "r+b") as f:
        f.truncate(len(data) - 34 * 30_000)
    with pytest.raises(InputError) as err, loader:
        for _ in loader:
            pass
    one_line_naming(err.value, path)
    assert "could be read" in str(err.value)


def test_las_spans_are_read_by_the_parser_threads():
    """An uncompressed file's reader hands out spans, not records: the reads happen in
    the parser threads."""
    source = open_las(SAMPLE)
    spans = list(source.chunks(30_000))
    assert [(s.first, s.count) for s in spans] == [(0, 30_000), (30_000, 30_000), (60_000, 30_000), (90_000, 20_000)]
    expected = records_of(SAMPLE)
    batch = source.parse(spans[1], 30_000, np.zeros(3), ("intensity",))
    np.testing.assert_array_equal(batch.attributes["intensity"], expected["intensity"][30_000:60_000])


def test_fast_records_are_read_by_the_parser_threads(fast_sample):
    """A fast-format file's batches are read by the parser threads, each its own: at any
    thread count and batch size (a prime, and one past the file) they are the file's
    records exactly, each batch from its own offset."""
    expected = np.fromfile(fast_sample, dtype=np.uint32, offset=HEADER_BYTES).reshape(-1, 4)
    for threads, batch in ((1, 7_919), (3, 7_919), (4, 30_000), (2, len(expected) + 1)):
        loader, batches = load([fast_sample], parser_threads=threads, batch_points=batch)
        assert_covers(batches, len(expected), batch)
        np.testing.assert_array_equal(np.concatenate([b.records for b in batches]), expected, err_msg=f"{threads}, {batch}")
        np.testing.assert_array_equal(joined(batches), expected[:, :3].view(np.float32))


LAYERED = ("lone-star.copc.laz", "lion_takanawa.copc.laz", "las_with_several_extra_byte_bloc.laz", "fullwave.laz")
"""Real LAZ files of point formats 6, 7, 8 and 10, whose records lazrs decodes in layers."""


@pytest.mark.parametrize("name", LAYERED)
def test_selective_decoding_equals_full_decoding(name):
    """Asking for one attribute decodes only its layer and the positions', and gives
    exactly what a full load gives for them; every other attribute is left out."""
    path = shared_file(name)
    full_loader, full = load([path], batch_points=100_000)
    for attr in full_loader.info.attributes:
        loader, batches = load([path], batch_points=100_000, attributes=(attr.name,))
        assert loader.attributes == (attr.name,)
        np.testing.assert_array_equal(joined(batches), joined(full))
        if attr.name == "elevation":
            assert all(not b.attributes for b in batches)
        else:
            assert all(set(b.attributes) == {attr.name} for b in batches)
            np.testing.assert_array_equal(joined(batches, attr.name), joined(full, attr.name), err_msg=attr.name)


def test_selection_leaves_the_other_layers_undecoded():
    """The selection reaches lazrs: fields of layers not asked for are not the file's."""
    path = shared_file("las_with_several_extra_byte_bloc.laz")
    source = open_las(path)
    expected = records_of(path)
    only = np.concatenate(list(decode_chunks(str(path), source.laz, source.info.points, 1, source.records.dtype, 2,
                                             las_module.selection(("intensity",)))))
    np.testing.assert_array_equal(only["intensity"], expected["intensity"])
    for field in ("X", "Y", "Z"):
        np.testing.assert_array_equal(only[field], expected[field])
    for field in ("gps_time", "red"):
        assert not np.array_equal(only[field], expected[field]), field


def test_unknown_attribute_is_refused():
    with pytest.raises(ValueError, match="no attribute nir"):
        CloudLoader([SAMPLE], attributes=("intensity", "nir"))


@pytest.mark.parametrize("name", [None, "pine_plot.laz", "lone-star.copc.laz"])
def test_first_batch_is_small(name):
    """The first image waits for a file's first batch: it holds FIRST_BATCH_POINTS (a
    LAZ: whole chunks, at most those that first cover them), later ones up to the batch size, and
    together they are the file's points as laspy reads them."""
    from progressive.loaders.las import Span, read_span
    from progressive.loaders.types import BATCH_POINTS, FIRST_BATCH_POINTS
    path = SAMPLE if name is None else shared_file(name)
    source = open_las(path)
    expected = records_of(path)
    assert len(expected) > FIRST_BATCH_POINTS, "the file should have more than a first batch"
    chunks = [read_span(str(path), source.records, c, source.info.points) if isinstance(c, Span) else c
              for c in source.chunks(BATCH_POINTS)]
    if source.laz is None:
        assert len(chunks[0]) == FIRST_BATCH_POINTS
    else:       # whole chunks, no more than first cover FIRST_BATCH_POINTS (fewer: a read's byte limit)
        ends = np.cumsum([n for n, _ in source.laz.chunks])
        assert len(chunks[0]) in ends and len(chunks[0]) <= ends[np.searchsorted(ends, FIRST_BATCH_POINTS)]
    assert len(chunks[0]) < len(expected)
    assert all(len(c) <= BATCH_POINTS for c in chunks[1:])
    np.testing.assert_array_equal(np.concatenate(chunks), expected)


SYNTHETIC_POINTS = 560_000
"""More than the BATCH_POINTS the colour depth is decided on, in 50,000-point chunks."""


def synthetic_laz(path, sixteen_at: int | None):
    """A LAZ of point format 3 with 8-bit colours but for one channel of 256 at point
    `sixteen_at` (None: none), and random positions, intensity and GPS time."""
    rng = np.random.default_rng(11)
    las = laspy.LasData(laspy.LasHeader(point_format=3, version="1.2"))
    las.header.scales = np.array([0.01, 0.01, 0.01])
    n = SYNTHETIC_POINTS
    las.X, las.Y, las.Z = (rng.integers(0, 10**6, n, dtype=np.int32) for _ in range(3))
    rgb = rng.integers(0, 256, (3, n), dtype=np.uint16)
    if sixteen_at is not None:
        rgb[1, sixteen_at] = 256
    las.red, las.green, las.blue = rgb
    las.intensity = rng.integers(0, 2**16, n, dtype=np.uint16)
    las.gps_time = rng.uniform(0, 1e6, n)
    las.write(path, laz_backend=laspy.LazBackend.Lazrs)
    return path


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    made = {}

    def make(sixteen_at: int | None):
        if sixteen_at not in made:
            made[sixteen_at] = synthetic_laz(tmp_path_factory.mktemp("rgb") / f"rgb_{sixteen_at}.laz", sixteen_at)
        return made[sixteen_at]
    return make


def count_decoded(monkeypatch) -> list[int]:
    """Points lazrs's parallel decoder decodes from now on (one running total)."""
    decoded = [0]
    original = lazrs.decompress_points_with_chunk_table

    def counting(compressed, vlr, out, chunks, selection=None):
        decoded[0] += sum(n for n, _ in chunks)
        return original(compressed, vlr, out, chunks, selection)
    monkeypatch.setattr(lazrs, "decompress_points_with_chunk_table", counting)
    return decoded


def first_points_rule(las) -> bool:
    """The colour contract's rule, from laspy: a channel above 255 among the first 500,000 points."""
    first = slice(0, 500_000)
    return bool(max(las.red[first].max(), las.green[first].max(), las.blue[first].max()) > 255)


@pytest.mark.parametrize("sixteen_at", [None, 60_000, 260_000, 499_999, 500_000])
def test_probe_kept_for_the_first_batches_equals_laspy(sixteen_at, synthetic, monkeypatch):
    """A loader's first LAZ is decoded once: its first batches are the records opening it
    decoded to decide the colour depth. With and without that reuse the batches equal
    laspy's, and the depth follows the first 500,000 points whether its one 16-bit value
    lies in the first read, after the first chunks, at the last point that counts or
    at the first that does not."""
    path = synthetic(sixteen_at)
    las = laspy.read(path)
    for reused in (True, False):
        if not reused:
            monkeypatch.setattr(las_module, "KEPT_BYTES", 0)
        decoded = count_decoded(monkeypatch)
        loader, batches = load([path])
        assert loader.done and not loader.warnings
        assert loader.info.files[0].rgb_16bit is first_points_rule(las)
        assert_equals_laspy(loader, batches, las)
        if reused:
            assert decoded[0] == len(las.points), "the probe's records were decoded again"
        else:
            assert decoded[0] > len(las.points)


@pytest.mark.parametrize("name, attributes", [
    ("TLSSparseCloud_xyzOnly.laz", None), ("las_with_several_extra_byte_bloc.laz", ("rgb",)),
    ("las_with_several_extra_byte_bloc.laz", None), ("fullwave.laz", ("rgb", "gps_time"))])
def test_probe_kept_on_real_rgb_laz(name, attributes, monkeypatch):
    """Real RGB LAZ files: point format 2 reuses what opening decoded; formats 6-10 reuse
    it where the batches need no layer the probe left out (rgb, gps_time), else decode
    again. Either way the batches equal laspy's and the depth follows the rule."""
    path = shared_file(name)
    las = laspy.read(path)
    decoded = count_decoded(monkeypatch)
    loader, batches = load([path], attributes=attributes)
    assert loader.info.files[0].rgb_16bit is first_points_rule(las)
    assert_covers(batches, len(las.points))
    for axis, dim in enumerate("xyz"):
        np.testing.assert_array_equal(joined(batches)[:, axis],
                                      np.float32(np.asarray(getattr(las, dim)) - loader.info.origin[axis]))
    for attr in loader.attributes:
        if attr != "elevation":
            np.testing.assert_array_equal(joined(batches, attr), expected_values(las, attr), err_msg=attr)
    needs_more = las.point_format.id >= 6 and attributes is None
    assert (decoded[0] > len(las.points)) is needs_more


def test_kept_records_stay_within_their_bound(synthetic, monkeypatch):
    """What the probe keeps is at most KEPT_BYTES (here three chunks' records: one read
    of two), whole chunks from the first; opening holds no more memory for it than that,
    the loader decodes only what was not kept, and once its batches are made the source
    holds none of it. Two cores, so that the probe's later reads are of two chunks too: on
    16 its second read holds every point the probe wants, and the peak is that read's
    whether the records are kept or not."""
    import tracemalloc
    monkeypatch.setattr(las_module, "available_cores", lambda: 2)
    path = synthetic(None)
    las = laspy.read(path)
    record = open_las(path).records.dtype.itemsize
    bound = 3 * 50_000 * record

    def peak(keep: bool) -> int:
        tracemalloc.start()
        try:
            open_las(path, keep=keep)
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    unbounded = peak(True) - peak(False)
    assert unbounded > bound, "kept without a bound, the records would take more than it here"
    monkeypatch.setattr(las_module, "KEPT_BYTES", bound)
    source = open_las(path, keep=True)
    assert 0 < source.kept.nbytes <= bound
    assert peak(True) - peak(False) <= bound
    decoded = count_decoded(monkeypatch)
    loader, batches = load([path])
    assert_equals_laspy(loader, batches, las)
    assert decoded[0] == len(las.points) + 500_000 - 100_000     # the probe's points but its first read's
    assert loader._sources[0].kept.nbytes == 0


def test_a_held_loader_parses_its_first_batches_until_resumed():
    """start(first=2): two batches come, then none however long the caller waits (the
    session builds its renderer meanwhile); resume() brings the rest, equal to an
    unheld load."""
    _, expected = load([SAMPLE], batch_points=9_000, parser_threads=4)
    with CloudLoader([SAMPLE], batch_points=9_000, parser_threads=4) as loader:
        loader.start(first=2)
        got, deadline = [], time.monotonic() + 10
        while len(got) < 2 and time.monotonic() < deadline:
            got += loader.poll()
            time.sleep(0.01)
        time.sleep(0.3)
        got += loader.poll()
        assert len(got) == 2 and not loader.done
        loader.resume()
        got += list(loader)
    got.sort(key=lambda b: b.start)
    assert_covers(got, loader.total, 9_000)
    np.testing.assert_array_equal(joined(got), joined(expected))


def test_a_held_loader_of_fewer_batches_finishes_and_iterating_resumes():
    """A loader held at as many batches as the cloud has is done without resume();
    iterating a held loader resumes it (a blocking consumer wants every batch)."""
    _, expected = load([SAMPLE], parser_threads=3)
    with CloudLoader([SAMPLE], parser_threads=3) as loader:
        loader.start(first=len(expected))
        got, deadline = [], time.monotonic() + 10
        while not loader.done and time.monotonic() < deadline:
            got += loader.poll()
            time.sleep(0.01)
        assert loader.done and len(got) == len(expected)
    with CloudLoader([SAMPLE], batch_points=9_000, parser_threads=3) as loader:
        loader.start(first=1)
        batches = list(loader)
    assert_covers(sorted(batches, key=lambda b: b.start), loader.total, 9_000)


def test_a_held_loader_closes_at_once():
    """Closing a loader whose parsers wait to be resumed ends every thread within the
    wait of one look at the stop flag (a session closed before its first frame)."""
    loader = CloudLoader([SAMPLE], batch_points=9_000, parser_threads=4)
    loader.start(first=1)
    deadline = time.monotonic() + 10
    while not loader.poll() and time.monotonic() < deadline:
        time.sleep(0.01)
    t0 = time.monotonic()
    loader.close()
    assert time.monotonic() - t0 < 1.0
    assert not any(t.is_alive() for t in loader._threads)


@pytest.mark.parametrize("name", [None, "las_with_several_extra_byte_bloc.laz", "pine_plot.laz"])
def test_later_pass_reads_the_other_attributes_after_the_first(name):
    """keep_only(first, later): the first pass's batches carry only `first` and come in
    full before `done`; poll_later then hands batches of the `later` attributes (none
    before), which together cover every point with the values a full load gives."""
    path = SAMPLE if name is None else shared_file(name)
    full_loader, full = load([path], batch_points=100_000)
    names = tuple(a.name for a in full_loader.info.attributes if a.name != "elevation")
    first, later = names[:1], names[1:]
    with CloudLoader([path], batch_points=100_000) as loader:
        loader.keep_only(first, later=later)
        assert loader.later == later
        assert loader.poll_later() == []
        batches = sorted(loader, key=lambda b: b.start)
        assert loader.done
        rest: list = []
        deadline = time.monotonic() + 60
        while not loader.later_done and time.monotonic() < deadline:
            rest += loader.poll_later()
            time.sleep(0.01)
        assert loader.later_done
    assert all(set(b.attributes) == set(first) for b in batches)
    assert all(set(b.attributes) == set(later) for b in rest)
    rest.sort(key=lambda b: b.start)
    assert_covers(batches, full_loader.info.points, 100_000)
    assert_covers(rest, full_loader.info.points, 100_000)
    np.testing.assert_array_equal(joined(batches, first[0]), joined(full, first[0]))
    for n in later:
        np.testing.assert_array_equal(joined(rest, n), joined(full, n), err_msg=n)


# --- the allocator's large blocks -------------------------------------------------------

MAPPED_PROBE = """
import ctypes, sys
import numpy as np
from progressive.loaders.allocator import keep_large_blocks

class MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]

libc = ctypes.CDLL(None)
libc.mallinfo2.restype = MallInfo2
if sys.argv[1] == "kept":
    assert keep_large_blocks()
before = libc.mallinfo2().hblkhd
block = np.ones(2 << 20)        # 16 MiB, a loader batch's array
print(libc.mallinfo2().hblkhd - before)
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's mallopt and mallinfo2")
def test_large_blocks_come_from_the_heap():
    """A fresh process maps a 16 MiB array by itself (glibc's first threshold is 128 KiB);
    after keep_large_blocks the heap serves it, so its pages are reused batch after batch."""
    mapped = {mode: int(subprocess.run([sys.executable, "-c", MAPPED_PROBE, mode], capture_output=True, text=True,
                                       check=True, timeout=60).stdout) for mode in ("default", "kept")}
    assert mapped["default"] >= 16 << 20
    assert mapped["kept"] == 0


def test_loader_keeps_large_blocks(monkeypatch):
    """Every loader sets the allocator up before its threads allocate."""
    from progressive.loaders import pipeline

    calls = []
    monkeypatch.setattr(pipeline, "keep_large_blocks", lambda: calls.append(1))
    with pipeline.CloudLoader([SAMPLE]):
        assert calls == [1]


def test_a_frame_loop_waits_for_the_next_batch_without_taking_it():
    """CloudLoader.wait: true at once while a batch is ready (and it stays for poll),
    false after the timeout while none comes (the loader held after its first), true
    once one does. As many parser threads as a default loader starts at most, and more
    batches than threads: a thread that finds no batch left to parse hands over its end,
    which wakes wait (on the 16-core H100 machine 20,000-point batches, six of them, woke
    it beside 8 threads)."""
    with CloudLoader([SAMPLE], batch_points=5_000, parser_threads=PARSER_THREADS) as loader:
        loader.start(first=1)
        assert loader.wait(10.0) and loader.wait(0.0)
        assert len(loader.poll()) == 1
        t0 = time.perf_counter()
        assert not loader.wait(0.05)
        assert time.perf_counter() - t0 >= 0.05
        loader.resume()
        assert loader.wait(10.0) and loader.poll()
