"""Loaders against laspy on the real files, the fast format, and every kind of bad input."""

from __future__ import annotations

import json
import math
import os
import struct
import threading
import time
from pathlib import Path

import laspy
import numpy as np
import pytest

from conftest import SAMPLE, shared_file, shared_files
from progressive.errors import InputError
from progressive.loaders import BATCH_POINTS, CloudLoader, describe, format_text, open_cloud, write_fast
from progressive.loaders.fastformat import HEADER_BYTES
from progressive.loaders.las import LasSource
from progressive.loaders.records import pack_records

LARGE = 2_000_000
"""Files above this many points stay out of the full comparison to keep the suite quick."""


def load(paths, **kwargs):
    with CloudLoader(paths, **kwargs) as loader:
        batches = sorted(loader, key=lambda b: b.start)
    return loader, batches


def joined(batches, name=None) -> np.ndarray:
    return np.concatenate([b.positions if name is None else b.attributes[name] for b in batches])


def assert_covers(batches, total: int, batch_points: int = BATCH_POINTS) -> None:
    """Batches tile [0, total) exactly once, each within the size limit."""
    expected = 0
    for batch in batches:
        assert batch.start == expected
        assert 0 < batch.count <= batch_points
        expected += batch.count
    assert expected == total


def expected_values(las: laspy.LasData, name: str) -> np.ndarray:
    """What the loader must give for one attribute, computed straight from laspy."""
    if name == "rgb":
        rgb = np.stack([las.red, las.green, las.blue], axis=1)
        sixteen = rgb[:BATCH_POINTS].max() > 255
        return np.minimum(rgb >> 8 if sixteen else rgb, 255).astype(np.uint8)
    if name == "scan_angle":
        if las.point_format.id < 6:
            return np.asarray(las.scan_angle_rank).astype(np.float32)
        return (np.asarray(las.scan_angle) * 0.006).astype(np.float32)
    if name.endswith("]"):
        base, index = name[:-1].split("[")
        return np.asarray(las[base])[:, int(index)]
    return np.asarray(las[name])


def one_line_naming(exc: InputError, path: Path) -> None:
    message = str(exc)
    assert "\n" not in message
    assert str(path) in message


# --- every real file against laspy ------------------------------------------------------

@pytest.mark.parametrize("path", shared_files() or [pytest.param(None, marks=pytest.mark.skip("no shared data"))],
                         ids=lambda p: getattr(p, "name", "none"))
def test_matches_laspy(path: Path):
    with laspy.open(path) as reader:
        if reader.header.point_count > LARGE:
            pytest.skip(f"{path.name} is large; the loader is measured in bench/")
    las = laspy.read(path)
    loader, batches = load([path])
    info = loader.info
    n = len(las.points)
    assert info.points == loader.total == loader.loaded == n
    assert loader.done and not loader.warnings
    assert_covers(batches, n)

    positions = joined(batches)
    for axis, dim in enumerate("xyz"):
        expected = np.float32(np.asarray(getattr(las, dim)) - info.origin[axis])
        np.testing.assert_array_equal(positions[:, axis], expected)

    names = [a.name for a in info.attributes]
    assert "elevation" in names
    assert info.attribute("elevation").offset == info.origin[2]
    for attr in info.attributes:
        if attr.name == "elevation":
            assert all("elevation" not in b.attributes for b in batches)
            continue
        values = joined(batches, attr.name)
        assert values.dtype == attr.dtype
        np.testing.assert_array_equal(values, expected_values(las, attr.name), err_msg=attr.name)
    for extra in las.point_format.extra_dimension_names:
        assert extra in names or f"{extra}[0]" in names
    if "gps_time" in names:
        assert info.attribute("gps_time").offset == math.floor(las.gps_time[0])
    has_rgb = "red" in las.point_format.dimension_names
    assert ("rgb" in names) == has_rgb
    assert (info.files[0].rgb_16bit is None) == (not has_rgb)
    if has_rgb:     # opening decodes only the layers it needs of a LAZ of point format 6-10
        first = slice(0, BATCH_POINTS)
        most = max(las.red[first].max(), las.green[first].max(), las.blue[first].max())
        assert info.files[0].rgb_16bit == bool(most > 255)
        assert info.files[0].rgb_zero == (most == 0)
    else:
        assert not info.files[0].rgb_zero


def test_colour_depth_detection():
    assert open_cloud([SAMPLE]).files[0].rgb_16bit is False
    assert open_cloud([shared_file("extrabytes.las")]).files[0].rgb_16bit is False
    lion = shared_file("lion_takanawa.copc.laz")
    assert open_cloud([lion]).files[0].rgb_16bit is True
    _, batches = load([lion])
    las = laspy.read(lion)
    np.testing.assert_array_equal(joined(batches, "rgb")[:, 0], (las.red >> 8).astype(np.uint8))


def test_header_facts():
    info = open_cloud([SAMPLE])
    f = info.files[0]
    assert (f.format, f.version, f.point_format, f.points) == ("LAS", "1.2", 3, 110_000)
    assert f.scale == (0.01, 0.01, 0.01) and f.crs == "NAD_1983_HARN_Lambert_Conformal_Conic"
    np.testing.assert_array_equal(info.origin, (np.array(f.bounds_min) + np.array(f.bounds_max)) / 2)
    assert [a.name for a in info.attributes] == [
        "rgb", "intensity", "classification", "elevation", "return_number", "number_of_returns",
        "gps_time", "point_source_id", "user_data", "scan_angle"]
    assert info.attribute("classification").kind.value == "category"
    assert info.attribute("rgb").kind.value == "rgb"


def test_las14_uses_64bit_count_when_legacy_is_zero(tmp_path):
    data = bytearray(shared_file("extrabytes.las").read_bytes())
    struct.pack_into("<I", data, 107, 0)
    path = tmp_path / "legacy0.las"
    path.write_bytes(data)
    loader, batches = load([path])
    assert loader.info.points == 1065
    assert_covers(batches, 1065)


# --- several files, threads and batch sizes -----------------------------------------------

def test_default_colouring_passes_over_rgb_only_where_every_file_has_it_zero(tmp_path):
    """The sample with its RGB zeroed (beyond the first 500,000 points the probe reads
    nothing: the file has 110,000) beside the sample itself: RGB is the default while one
    file has colour; with only zeroed files, elevation, and a note saying why."""
    from progressive.attributes import default_choice

    las = laspy.read(SAMPLE)
    for channel in ("red", "green", "blue"):
        setattr(las, channel, np.zeros(len(las.points), dtype=np.uint16))
    dark = tmp_path / "dark.las"
    las.write(dark)
    assert open_cloud([dark]).files[0].rgb_zero and not open_cloud([SAMPLE]).files[0].rgb_zero
    for paths, expected in (([dark, SAMPLE], "rgb"), ([SAMPLE, dark], "rgb"), ([dark], "elevation"),
                            ([dark, dark], "elevation")):
        attribute, note = default_choice(open_cloud(paths))
        assert attribute.name == expected
        assert (note is None) == (expected == "rgb")
        if note:
            assert note.startswith("rgb all zero in the first") and note.endswith("colouring by elevation")
            assert ("110,000 points;" in note) == (len(paths) == 1) and ("every file" in note) == (len(paths) > 1)


def test_multi_file_cloud_is_concatenated():
    second = shared_file("vegetation_1_3.las")
    loader, batches = load([SAMPLE, second], batch_points=20_000)
    info = loader.info
    assert info.points == 110_000 + 10_683
    assert_covers(batches, info.points, 20_000)
    assert "rgb" not in [a.name for a in info.attributes]          # only SAMPLE has colour
    lo = np.minimum(info.files[0].bounds_min, info.files[1].bounds_min)
    hi = np.maximum(info.files[0].bounds_max, info.files[1].bounds_max)
    np.testing.assert_array_equal(info.origin, (lo + hi) / 2)
    a, b = laspy.read(SAMPLE), laspy.read(second)
    x = np.concatenate([a.x, b.x]) - info.origin[0]
    np.testing.assert_array_equal(joined(batches)[:, 0], np.float32(x))
    np.testing.assert_array_equal(joined(batches, "intensity"), np.concatenate([a.intensity, b.intensity]))
    assert any(batch.start == 110_000 for batch in batches)


@pytest.mark.parametrize("name", ["autzen_trim.las", "lion_takanawa.copc.laz"])
def test_threads_and_batch_sizes_give_identical_arrays(name):
    path = SAMPLE if name == SAMPLE.name else shared_file(name)
    _, reference = load([path])
    for kwargs in ({"parser_threads": 1}, {"batch_points": 7_000}, {"batch_points": 7_000, "parser_threads": 3}):
        loader, batches = load([path], **kwargs)
        assert_covers(batches, loader.total, kwargs.get("batch_points", BATCH_POINTS))
        np.testing.assert_array_equal(joined(batches), joined(reference))
        for attr in loader.info.attributes:
            if attr.name != "elevation":
                np.testing.assert_array_equal(joined(batches, attr.name), joined(reference, attr.name))


def test_poll_is_non_blocking_and_reaches_done():
    loader = CloudLoader([SAMPLE], batch_points=10_000, parser_threads=2)
    assert loader.info.points == 110_000 and loader.loaded == 0 and not loader.done
    batches, deadline = [], time.monotonic() + 20
    with loader:
        loader.start()
        while not loader.done:
            assert time.monotonic() < deadline
            got = loader.poll(max_batches=1)
            assert len(got) <= 1
            batches += got
    assert loader.loaded == loader.total == sum(b.count for b in batches)
    assert_covers(sorted(batches, key=lambda b: b.start), 110_000, 10_000)
    assert loader.poll() == []


def test_memory_stays_bounded_when_nobody_consumes(monkeypatch):
    made = []
    parse = LasSource.parse
    with CloudLoader([SAMPLE], batch_points=1_000, parser_threads=2) as loader:
        monkeypatch.setattr(LasSource, "parse", lambda self, *a: made.append(1) or parse(self, *a))
        loader.start()
        time.sleep(0.5)
        assert len(made) <= 2 * 2 + 2
        assert len(loader.poll()) <= 2 * 2 + 1


def test_close_mid_file_stops_threads():
    before = set(threading.enumerate())
    loader = CloudLoader([SAMPLE], batch_points=1_000)
    next(iter(loader))
    started = time.monotonic()
    loader.close()
    assert time.monotonic() - started < 2
    assert not [t for t in set(threading.enumerate()) - before if t.is_alive()]
    assert list(loader) == []


def test_close_after_an_interrupted_start_stops_the_started_threads(monkeypatch):
    """A signal during start() (the CLI's Interrupted, or Ctrl+C, raised while it waits
    for a parser thread to run: on 16 cores it starts 17 threads while the reader decodes
    holding the GIL): close() stops those that started and raises nothing of its own about
    those that did not, so the interrupt is what reaches the caller."""
    before = set(threading.enumerate())
    start = threading.Thread.start
    started = []

    def interrupted_third(thread):
        if len(started) == 2:
            raise KeyboardInterrupt
        started.append(thread)
        start(thread)
    monkeypatch.setattr(threading.Thread, "start", interrupted_third)
    with pytest.raises(KeyboardInterrupt), CloudLoader([SAMPLE], batch_points=1_000, parser_threads=4) as loader:
        loader.start()
    monkeypatch.undo()
    assert len(started) == 2 and not [t for t in set(threading.enumerate()) - before if t.is_alive()]


def test_parser_exception_reaches_consumer(monkeypatch):
    def boom(self, *args):
        raise RuntimeError("boom\nsecond line")

    iterated = CloudLoader([SAMPLE], batch_points=5_000)
    polled = CloudLoader([SAMPLE])
    monkeypatch.setattr(LasSource, "parse", boom)
    with pytest.raises(InputError) as err, iterated:
        list(iterated)
    one_line_naming(err.value, SAMPLE)
    assert "boom" in str(err.value)
    with pytest.raises(InputError), polled:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            polled.poll()
            time.sleep(0.01)


# --- fast format -------------------------------------------------------------------------

def fast_round_trip(path: Path, attribute: str, out: Path):
    loader, las_batches = load([path], batch_points=50_000)
    info, attr = loader.info, loader.info.attribute(attribute)
    with CloudLoader([path], batch_points=50_000) as again:
        assert write_fast(out, again, info, attr) == info.points
    fast, fast_batches = load([out], batch_points=30_000)
    assert fast.info.points == info.points
    assert fast.info.files[0].format == "PRGS" and fast.info.files[0].point_format == -1
    (carried,) = fast.info.attributes         # the fast format does not store the source dtype
    assert (carried.name, carried.kind, carried.offset) == (attr.name, attr.kind, attr.offset)
    np.testing.assert_array_equal(fast.info.origin, info.origin)
    np.testing.assert_array_equal(fast.info.bounds_min, info.bounds_min)
    assert_covers(fast_batches, info.points, 30_000)
    expected = np.concatenate([pack_records(b, attr, info.origin[2]) for b in las_batches])
    records = np.concatenate([b.records for b in fast_batches])
    assert records.tobytes() == expected.tobytes()
    np.testing.assert_array_equal(joined(fast_batches), joined(las_batches))
    return info, attr, las_batches


@pytest.mark.parametrize("attribute", ["rgb", "elevation", "gps_time", "classification"])
def test_fast_round_trip_sample(tmp_path, attribute):
    out = tmp_path / "sample.prgs"
    info, attr, batches = fast_round_trip(SAMPLE, attribute, out)
    shuffled = tmp_path / "shuffled.prgs"
    write_fast(shuffled, reversed(batches), info, attr)          # out of order
    assert shuffled.read_bytes() == out.read_bytes()


def test_fast_round_trip_laz_extra_bytes(tmp_path):
    fast_round_trip(shared_file("lion_takanawa.copc.laz"), "OriginId", tmp_path / "lion.prgs")


def test_fast_write_is_atomic(tmp_path):
    info = open_cloud([SAMPLE])

    def broken():
        yield from CloudLoader([SAMPLE], batch_points=10_000)
        raise RuntimeError("interrupted")

    with pytest.raises(RuntimeError):
        write_fast(tmp_path / "out.prgs", broken(), info, info.attribute("rgb"))
    with pytest.raises(InputError, match="only 0"):
        write_fast(tmp_path / "out.prgs", [], info, info.attribute("rgb"))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("patch, message", [
    (lambda d: d.__setitem__(slice(0, 8), b"PRGSPC\x00\x02"), "bad fast-format magic"),
    (lambda d: d.__setitem__(slice(0, 8), b"PRGSXX\x00\x01"), "not a LAS/LAZ or fast-format file"),
    (lambda d: struct.pack_into("<I", d, 8, 2), "version 2"),
    (lambda d: struct.pack_into("<I", d, 12, 128), "header size"),
    (lambda d: struct.pack_into("<I", d, 96, 7), "attribute kind"),
    (lambda d: d.__delitem__(slice(-5, None)), "does not match"),
    (lambda d: d.extend(b"\x00" * 16), "does not match"),
    (lambda d: struct.pack_into("<Q", d, 16, 0), "has no points"),
])
def test_fast_bad_headers(tmp_path, fast_sample, patch, message):
    data = bytearray(fast_sample.read_bytes())
    patch(data)
    path = tmp_path / "bad.prgs"
    path.write_bytes(data)
    with pytest.raises(InputError, match=message) as err:
        load([path])
    one_line_naming(err.value, path)


def test_fast_write_of_partial_load(tmp_path):
    cut = tmp_path / "cut.las"
    cut.write_bytes(SAMPLE.read_bytes()[:SAMPLE_POINT_DATA + 34 * 5_000 + 11])
    out = tmp_path / "cut.prgs"
    with CloudLoader([cut], partial=True, batch_points=1_500) as loader:
        assert write_fast(out, loader, loader.info, loader.info.attribute("rgb")) == 5_000
    assert out.stat().st_size == HEADER_BYTES + 16 * 5_000
    info = open_cloud([SAMPLE])
    batches = [b for b in CloudLoader([SAMPLE], batch_points=1_000) if b.start >= 1_000]
    with pytest.raises(InputError, match="contiguous"):
        write_fast(tmp_path / "holes.prgs", batches, info, info.attribute("rgb"))


def test_fast_partial_short_file(tmp_path, fast_sample):
    path = tmp_path / "short.prgs"
    path.write_bytes(fast_sample.read_bytes()[:HEADER_BYTES + 16 * 1234 + 7])
    loader, batches = load([path], partial=True)
    assert loader.info.points == 1234 and loader.warnings
    assert_covers(batches, 1234)


def test_fast_and_las_cannot_mix(fast_sample):
    with pytest.raises(InputError, match="cannot be mixed"):
        open_cloud([SAMPLE, fast_sample])


# --- bad input ---------------------------------------------------------------------------

def patched(source: Path, edit) -> bytes:
    data = bytearray(source.read_bytes())
    edit(data)
    return bytes(data)


def set_u32(offset: int, value):
    return lambda d: struct.pack_into("<I", d, offset, value(struct.unpack_from("<I", d, offset)[0]))


def corrupt_middle(d: bytearray) -> None:
    middle = len(d) // 2
    d[middle:middle + 256] = np.random.default_rng(1).integers(0, 256, 256, dtype=np.uint8).tobytes()


SAMPLE_POINT_DATA = laspy.LasHeader.read_from(SAMPLE.open("rb")).offset_to_point_data
BAD_LAS = {
    "random bytes": (None, lambda: np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes(),
                     "not a LAS/LAZ or fast-format file"),
    "wrong signature": (SAMPLE, lambda d: d.__setitem__(slice(0, 4), b"LASX"), "not a LAS/LAZ or fast-format file"),
    "empty": (None, lambda: b"", "is empty"),
    "short header": (SAMPLE, lambda d: d.__delitem__(slice(150, None)), "too short"),
    "header only, no points": (SAMPLE, lambda d: (d.__delitem__(slice(SAMPLE_POINT_DATA, None)),
                                                  struct.pack_into("<I", d, 107, 0)), "has no points"),
    "header only, points promised": (SAMPLE, lambda d: d.__delitem__(slice(SAMPLE_POINT_DATA, None)),
                                     "truncated"),
    "truncated mid-points": (SAMPLE, lambda d: d.__delitem__(slice(len(d) // 2, None)), "truncated"),
    "count larger than data": (SAMPLE, set_u32(107, lambda c: c + 1000), "truncated"),
    "count smaller than data": (SAMPLE, set_u32(107, lambda c: c - 1000), "more point data"),
    "point format 11": (SAMPLE, lambda d: d.__setitem__(104, 11), "unsupported point format 11"),
    "version 1.9": (SAMPLE, lambda d: d.__setitem__(25, 9), "unsupported LAS version 1.9"),
    "version 2.0": (SAMPLE, lambda d: d.__setitem__(slice(24, 26), b"\x02\x00"), "unsupported LAS version 2.0"),
    "bad offset to points": (SAMPLE, set_u32(96, lambda c: 10), "invalid LAS header"),
    "laz truncated": ("pine_plot.laz", lambda d: d.__delitem__(slice(len(d) // 2, None)), "truncated or corrupt"),
    "laz truncated pointwise": ("TO_core_last_zoom.laz", lambda d: d.__delitem__(slice(len(d) // 2, None)),
                                "truncated or corrupt"),
    "laz count larger": ("pine_plot.laz", set_u32(107, lambda c: c + 1000), "truncated or corrupt"),
    "laz count smaller by chunks": ("pine_plot.laz", set_u32(107, lambda c: c - 60_000), "chunk table"),
    "laz 1.4 count larger": ("lion_takanawa.copc.laz",
                             lambda d: struct.pack_into("<Q", d, 247, struct.unpack_from("<Q", d, 247)[0] + 5),
                             "chunk table holds"),
    "laz corrupt chunk": ("pine_plot.laz", corrupt_middle, "truncated or corrupt"),
}


@pytest.mark.parametrize("case", list(BAD_LAS))
def test_bad_input(tmp_path, case):
    source, edit, message = BAD_LAS[case]
    if source is None:
        data = edit()
    else:
        data = patched(source if isinstance(source, Path) else shared_file(source), edit)
    path = tmp_path / ("bad.laz" if str(source).endswith(".laz") else "bad.las")
    path.write_bytes(data)
    with pytest.raises(InputError, match=message) as err:
        load([path])
    one_line_naming(err.value, path)


@pytest.mark.parametrize("kind", ["missing", "directory", "unreadable"])
def test_unopenable_paths(tmp_path, monkeypatch, kind):
    path = tmp_path / "cloud.las"
    if kind == "directory":
        path.mkdir()
    elif kind == "unreadable":
        path.write_bytes(SAMPLE.read_bytes())
        path.chmod(0)
        if os.geteuid() == 0:                   # root ignores permissions: refuse the open
            real_open = open

            def refuse(file, *args, **kwargs):
                if Path(file) == path:
                    raise PermissionError(13, "Permission denied", str(file))
                return real_open(file, *args, **kwargs)

            monkeypatch.setattr("builtins.open", refuse)
    with pytest.raises(InputError) as err:
        CloudLoader([path])
    one_line_naming(err.value, path)


def test_second_file_bad_names_that_file(tmp_path):
    bad = tmp_path / "second.las"
    bad.write_bytes(b"")
    with pytest.raises(InputError, match="second.las: is empty"):
        open_cloud([SAMPLE, bad])


def test_partial_truncated_las_yields_complete_points(tmp_path):
    data = SAMPLE.read_bytes()
    path = tmp_path / "cut.las"
    path.write_bytes(data[:SAMPLE_POINT_DATA + 34 * 5_000 + 11])
    loader, batches = load([path], partial=True, batch_points=2_000)
    assert loader.info.points == 5_000 and len(loader.warnings) == 1
    assert "truncated" in loader.warnings[0]
    assert_covers(batches, 5_000, 2_000)
    las = laspy.read(SAMPLE)
    np.testing.assert_array_equal(joined(batches)[:, 2], np.float32(las.z[:5_000] - loader.info.origin[2]))


def test_partial_truncated_laz_yields_complete_chunks(tmp_path):
    source = shared_file("pine_plot.laz")
    path = tmp_path / "cut.laz"
    path.write_bytes(source.read_bytes()[: source.stat().st_size * 6 // 10])
    loader, batches = load([path], partial=True)
    read = sum(b.count for b in batches)
    assert 0 < read < loader.total and len(loader.warnings) == 1
    assert_covers(batches, read)
    las = laspy.read(source)
    np.testing.assert_array_equal(joined(batches)[:, 0], np.float32(las.x[:read] - loader.info.origin[0]))


# --- describe ----------------------------------------------------------------------------

def test_describe_sample():
    desc = describe([SAMPLE])
    json.dumps(desc)
    las = laspy.read(SAMPLE)
    assert desc["points"] == 110_000
    assert (desc["format"], desc["version"], desc["point_format"]) == ("LAS", "1.2", 3)
    assert desc["bounds"]["min"] == [las.x.min(), las.y.min(), las.z.min()]
    assert desc["bounds"]["max"] == [las.x.max(), las.y.max(), las.z.max()]
    attrs = desc["attributes"]
    assert attrs["intensity"] == {"kind": "scalar", "min": int(las.intensity.min()), "max": int(las.intensity.max())}
    assert attrs["classification"]["kind"] == "category"
    assert attrs["rgb"]["max"] == [int(las.red.max()), int(las.green.max()), int(las.blue.max())]
    assert attrs["elevation"]["min"] == las.z.min()
    assert len(desc["files"]) == 1 and desc["files"][0]["points"] == 110_000
    text = format_text(desc)
    assert "110,000" in text and "intensity" in text


def test_describe_several_files():
    second = shared_file("extrabytes.las")
    desc = describe([SAMPLE, second])
    assert desc["points"] == 111_065
    assert desc["version"] == "1.2" and [f["version"] for f in desc["files"]] == ["1.2", "1.4"]
    las = laspy.read(second)
    assert desc["files"][1]["bounds"]["max"] == [las.x.max(), las.y.max(), las.z.max()]
    assert "second" not in format_text(desc) and "extrabytes.las" in format_text(desc)
