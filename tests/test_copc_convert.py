"""convert's speed-ups keep what it writes (loaders/copc_write.py): the root cube placed
from the header bounds, and from the points' own where a header lies (the same bytes as
from an honest header); the same bytes whatever the number of threads building the
cubes or decoding a LAZ input; and the fast record conversion equal to laspy's for every point format pair."""

from __future__ import annotations

import os
import struct

import laspy
import numpy as np
import pytest
from test_copc import assert_same_points, assert_valid_hierarchy

from conftest import SAMPLE
from progressive.loaders import copc_write, laz_pool
from progressive.loaders.copc import open_copc
from progressive.loaders.laz_pool import DEFAULTS as LAZ_DEFAULTS
from progressive.loaders.laz_pool import Decoders, LazOptions
from progressive.loaders.types import available_memory

BOUNDS_AT = 179
"""Offset of the header's max x, min x, max y, min y, max z, min z (doubles)."""


def without_rgb(tmp_path, name: str, order: np.ndarray | None = None) -> laspy.LasData:
    """The sample as point format 1 (no RGB: open_las checks only its first points
    against the header bounds), its points in `order`, written to tmp_path / name."""
    source = laspy.read(SAMPLE)
    data = laspy.convert(source, point_format_id=1)
    if order is not None:
        data.points = data.points[order]
    data.write(tmp_path / name)
    return data


def patch_bounds(path, mins, maxs) -> None:
    data = bytearray(path.read_bytes())
    struct.pack_into("<6d", data, BOUNDS_AT, maxs[0], mins[0], maxs[1], mins[1], maxs[2], mins[2])
    path.write_bytes(bytes(data))


def written(tmp_path, path, name: str, memory_points: int | None, workers: int | None = None,
            laz: LazOptions = LAZ_DEFAULTS) -> bytes:
    out = tmp_path / name
    scratch = tmp_path / f"scratch-{name}"
    scratch.mkdir()
    with open(out, "w+b") as f:
        copc_write.write_copc(f, [str(path)], memory_points=memory_points, scratch=scratch, workers=workers, laz=laz)
    assert list(scratch.iterdir()) == []
    return out.read_bytes()


@pytest.mark.parametrize("memory_points", [None, 20_000], ids=["in memory", "out of core"])
def test_header_bounds_too_small_fall_back_to_the_points(tmp_path, memory_points):
    """A header whose max x is the median x of points sorted by x (the first points,
    which open_las checks, lie inside): the cube comes from the points' bounds, so the
    file is byte for byte the one written from the honest header."""
    honest = without_rgb(tmp_path, "honest.las", np.argsort(laspy.read(SAMPLE).X, kind="stable"))
    lying = tmp_path / "lying.las"
    lying.write_bytes((tmp_path / "honest.las").read_bytes())
    maxs = np.array(honest.header.maxs)
    maxs[0] = float(np.median(honest.x))
    patch_bounds(lying, honest.header.mins, maxs)
    assert laspy.open(lying).header.maxs[0] == maxs[0]
    good = written(tmp_path, tmp_path / "honest.las", "honest.copc.laz", memory_points)
    bad = written(tmp_path, lying, "lying.copc.laz", memory_points)
    assert good == bad
    out = tmp_path / "lying.copc.laz"
    assert_valid_hierarchy(out)
    assert_same_points([tmp_path / "honest.las"], out)
    np.testing.assert_array_equal(laspy.open(out).header.maxs, [honest.x.max(), honest.y.max(), honest.z.max()])


def test_header_bounds_place_the_cube(tmp_path):
    """Header bounds wider than the points place the root cube (no pass for the points'
    own), in both builds alike; the output header holds the points' own bounds."""
    data = without_rgb(tmp_path, "wide.las")
    mins, maxs = np.array(data.header.mins) - 100, np.array(data.header.maxs) + 50
    patch_bounds(tmp_path / "wide.las", mins, maxs)
    tables = []
    for m in (None, 20_000):
        written(tmp_path, tmp_path / "wide.las", f"{m}.copc.laz", m)
        out = tmp_path / f"{m}.copc.laz"
        assert_valid_hierarchy(out)
        with laspy.CopcReader.open(out) as reader:
            np.testing.assert_allclose(reader.copc_info.center, (mins + maxs) / 2)
            assert reader.copc_info.halfsize == pytest.approx(float((maxs - mins).max()) / 2 + 0.01)
            np.testing.assert_array_equal(reader.header.mins, [data.x.min(), data.y.min(), data.z.min()])
            np.testing.assert_array_equal(reader.header.maxs, [data.x.max(), data.y.max(), data.z.max()])
        nodes = open_copc(str(out)).hierarchy.nodes
        tables.append(sorted(zip(*(nodes[k].tolist() for k in ("level", "x", "y", "z", "point_count")))))
    assert tables[0] == tables[1]


@pytest.mark.parametrize("leaf", [100_000, 150])
def test_threads_write_the_same_bytes(tmp_path, monkeypatch, leaf):
    """Out of core, the cubes built on 1, 3 or 8 threads, several in flight at once (a
    limit above most cubes): the same file."""
    monkeypatch.setattr(copc_write, "LEAF_POINTS", leaf)
    one = written(tmp_path, SAMPLE, "1.copc.laz", 60_000, workers=1)
    for workers in (3, 8):
        assert written(tmp_path, SAMPLE, f"{workers}.copc.laz", 60_000, workers=workers) == one
    assert_valid_hierarchy(tmp_path / "1.copc.laz")


@pytest.mark.skipif(not laz_pool.available(), reason="no decoder processes on this platform")
@pytest.mark.parametrize("memory_points", [None, 60_000], ids=["in memory", "out of core"])
def test_laz_decoded_by_processes_gives_the_same_file(tmp_path, memory_points):
    """A LAZ input of several chunks decoded by decoder processes (as a large file is by
    default on four cores or more) and by lazrs in this process: the same file."""
    source = tmp_path / "sample.laz"
    laspy.read(SAMPLE).write(source, do_compress=True)
    threads = written(tmp_path, source, "threads.copc.laz", memory_points, laz=LazOptions(Decoders.THREADS))
    processes = written(tmp_path, source, "processes.copc.laz", memory_points,
                        laz=LazOptions(Decoders.PROCESSES, processes=2))
    assert processes == threads
    assert_same_points([SAMPLE], tmp_path / "processes.copc.laz")


def test_cubes_built_at_once_fill_half_the_free_memory(monkeypatch):
    """The default limit on the cubes' points in flight follows the memory free after the
    spill (so a flat cloud's few large cubes are built on every core where memory allows),
    and falls back to MEMORY_POINTS where that is not known."""
    monkeypatch.setattr(copc_write, "available_memory", lambda: 64 << 30)
    assert copc_write.build_limit() == (32 << 30) // copc_write.BUILD_BYTES
    monkeypatch.setattr(copc_write, "available_memory", lambda: 1 << 20)
    assert copc_write.build_limit() == copc_write.BATCH_POINTS
    monkeypatch.setattr(copc_write, "available_memory", lambda: None)
    assert copc_write.build_limit() == copc_write.MEMORY_POINTS


def test_available_memory_is_below_the_machine_s():
    """MemAvailable read from /proc/meminfo: positive and below the physical memory."""
    available = available_memory()
    if available is None:
        pytest.skip("no /proc/meminfo")
    assert 0 < available <= os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def random_records(rng, point_format: laspy.PointFormat, n: int) -> np.ndarray:
    """Records of random bytes (every bit field and flag set at random), finite GPS times."""
    records = np.frombuffer(rng.bytes(n * point_format.size), point_format.dtype()).copy()
    if "gps_time" in records.dtype.names:
        records["gps_time"] = rng.normal(size=n) * 1e6
    return records


def with_extra(point_format_id: int, extra: list[tuple[str, str]]) -> laspy.PointFormat:
    point_format = laspy.PointFormat(point_format_id)
    for name, kind in extra:
        point_format.add_extra_dimension(laspy.ExtraBytesParams(name, kind))
    return point_format


EXTRA = [("amplitude", "u2"), ("vector", "3f8"), ("flag", "i1")]
PAIRS = [(s, copc_write.TARGET_FORMAT[s]) for s in range(11)] + [(6, 7), (6, 8), (7, 8), (1, 8), (3, 8), (0, 7)]


@pytest.mark.parametrize(("source", "target"), PAIRS)
@pytest.mark.parametrize("extra", [[], EXTRA], ids=["plain", "extra bytes"])
def test_fast_conversion_equals_laspy(source, target, extra):
    """Every field as laspy's field-by-field conversion gives it, byte for byte (fields
    the target lacks dropped, those the source lacks zero), extra bytes the target
    keeps copied and those it drops left out."""
    rng = np.random.default_rng(source * 16 + target)
    src = with_extra(source, extra)
    dst = with_extra(target, extra[:2])
    records = random_records(rng, src, 5_000)
    fast = copc_write._fast_converted(records, src, dst)
    slow = laspy.PackedPointRecord.from_point_record(laspy.PackedPointRecord(records, src), dst).array
    assert fast.dtype == slow.dtype
    assert fast.tobytes() == slow.tobytes()


def test_fast_conversion_leaves_other_types_to_laspy():
    """An extra dimension of the same name but another type: not converted here."""
    src, dst = with_extra(3, [("amplitude", "u2")]), with_extra(7, [("amplitude", "f4")])
    records = random_records(np.random.default_rng(0), src, 10)
    assert copc_write._fast_converted(records, src, dst) is None
