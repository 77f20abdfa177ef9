"""Hard input: LAS numerics at the edges of the format, non-finite values, and the
command-line matrix of bad files (one error line, exit 2, nothing written).

Files are real points (the bundled sample, the shared files) rewritten with laspy or
patched byte by byte. Loader-level bad input lives in test_loaders.py and the first
CLI cases in test_cli.py; this file adds the rest.
"""

from __future__ import annotations

import io
import json
import math
import os
import struct
from pathlib import Path

import laspy
import lazrs
import numpy as np
import pytest
from PIL import Image

from conftest import SAMPLE, shared_file
from progressive.cli import main
from progressive.loaders import BATCH_POINTS, CloudLoader, describe, open_cloud
from progressive.loaders.fastformat import HEADER_BYTES

TINY = ["--width", "64", "--height", "48"]
SUBSET = 20_000
"""Sample points in the rewritten files: enough for several batches, quick to load."""
EMPTY_ID = 0xFFFFFFFF


@pytest.fixture(scope="module")
def sample() -> laspy.LasData:
    return laspy.read(SAMPLE)


def rewrite(path: Path, source: laspy.LasData, *, scale, offset, count: int = SUBSET, xyz=None,
            raw=None, version: str | None = None, extra=()) -> laspy.LasData:
    """The first `count` points of `source` (tiled when it has fewer) under a new scale and
    offset, with coordinates `xyz` (float64) or `raw` (int32) or the source's own; returns
    the file as laspy reads it back."""
    header = laspy.LasHeader(point_format=source.header.point_format.id, version=version or source.header.version)
    header.scales, header.offsets = np.asarray(scale, float), np.asarray(offset, float)
    header.add_extra_dims(list(extra))
    points = np.resize(source.points.array, count)
    las = laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(count, header=header))
    for name in points.dtype.names:          # packed fields: bit fields copy whole
        las.points.array[name] = points[name]
    if raw is not None:
        las.X, las.Y, las.Z = raw
    else:
        xyz = xyz if xyz is not None else [np.resize(np.asarray(getattr(source, d)), count) for d in "xyz"]
        las.x, las.y, las.z = xyz
    las.write(path)
    return laspy.read(path)


def load(path: Path, **kwargs):
    with CloudLoader([path], **kwargs) as loader:
        batches = sorted(loader, key=lambda b: b.start)
    return loader, batches


def column(batches, name=None) -> np.ndarray:
    return np.concatenate([b.positions if name is None else b.attributes[name] for b in batches])


def xyz_of(las: laspy.LasData) -> list[np.ndarray]:
    return [np.asarray(getattr(las, d)) for d in "xyz"]


# --- LAS numerics --------------------------------------------------------------------------

def numeric_cases(sample: laspy.LasData) -> dict:
    xyz = [np.asarray(getattr(sample, d))[:SUBSET] for d in "xyz"]
    centre = np.array([round(float(np.mean(v))) for v in xyz])
    lo = np.array([v.min() for v in xyz])
    limits = np.linspace(-2**31, 2**31 - 1, SUBSET).astype(np.int64)
    limits[:3] = (-2**31, -(2**31 - 1), 2**31 - 1)
    raw = (limits, limits[::-1], np.roll(limits, 7))
    return {
        # 0.1 µm steps at state-plane magnitudes: the sample shrunk 10x about its centre
        "scale 1e-7": dict(scale=[1e-7] * 3, offset=centre,
                           xyz=[c + (v - c) / 10 for v, c in zip(xyz, centre, strict=True)]),
        "scale 1": dict(scale=[1.0] * 3, offset=[0, 0, 0], xyz=[np.round(v) for v in xyz]),
        "offset 1e7 away": dict(scale=[0.01] * 3, offset=lo + [1e7, -1e7, 1e7]),
        "int32 limits": dict(scale=[0.001] * 3, offset=[5e5, 5e6, -1e3], raw=raw),
        "int32 limits, scale 1": dict(scale=[1.0] * 3, offset=[0, 0, 0], raw=raw),
    }


@pytest.mark.parametrize("case", ["scale 1e-7", "scale 1", "offset 1e7 away", "int32 limits", "int32 limits, scale 1"])
def test_positions_are_float32_of_laspy_minus_origin(tmp_path, sample, case):
    """Positions are float32(x - origin) of laspy's float64 x exactly, and info's bounds
    are laspy's extremes exactly, even where float32 cannot resolve one scale step."""
    path = tmp_path / "numeric.las"
    las = rewrite(path, sample, **numeric_cases(sample)[case])
    loader, batches = load(path, batch_points=7_000)
    origin = loader.info.origin
    np.testing.assert_array_equal(origin, (las.header.mins + las.header.maxs) / 2)
    positions = column(batches)
    for axis, values in enumerate(xyz_of(las)):
        np.testing.assert_array_equal(positions[:, axis], np.float32(values - origin[axis]), err_msg="xyz"[axis])
    assert loader.nonfinite_positions == 0 and loader.nonfinite_values == {}
    np.testing.assert_array_equal(column(batches, "intensity"), las.intensity)
    desc = describe([path])
    assert desc["bounds"] == {"min": [v.min() for v in xyz_of(las)], "max": [v.max() for v in xyz_of(las)]}
    assert desc["attributes"]["elevation"]["max"] == las.z.max()


def test_scale_1e7_real_file_bounds_and_zero_colours():
    """TLSSparseCloud_xyzOnly: scale 1e-7 and RGB/intensity all zero (MANIFEST)."""
    path = shared_file("TLSSparseCloud_xyzOnly.laz")
    las = laspy.read(path)
    desc = describe([path])
    assert desc["bounds"] == {"min": [v.min() for v in xyz_of(las)], "max": [v.max() for v in xyz_of(las)]}
    assert desc["files"][0]["rgb_16bit"] is False
    assert desc["attributes"]["rgb"] == {"kind": "rgb", "min": [0, 0, 0], "max": [0, 0, 0]}
    assert desc["attributes"]["intensity"] == {"kind": "scalar", "min": 0, "max": 0}


# --- header bounds the records cannot reach --------------------------------------------------

MAX_X, MIN_Z = 179, 219
"""Byte offsets of two header bounds (float64) in a LAS 1.0-1.4 header."""
UNREACHABLE = {
    "max x 1e300": [(MAX_X, 1e300)],
    "min z beyond int32": [(MIN_Z, -1e8)],          # scale 0.01, offset 0: |z| <= 2.2e7
    "every max far away": [(MAX_X, 4e13), (MAX_X + 16, -7e12), (MAX_X + 32, 1e18)],
}


@pytest.fixture(scope="module")
def exact_sample(tmp_path_factory) -> Path:
    """The sample as laspy writes it: header bounds equal to the points' extremes."""
    path = tmp_path_factory.mktemp("exact") / "exact.las"
    laspy.read(SAMPLE).write(path)
    return path


@pytest.mark.parametrize("case", list(UNREACHABLE))
def test_unreachable_header_bounds_are_ignored(tmp_path, capsys, exact_sample, case):
    """Header bounds that no int32 coordinate can reach under the scale and offset once
    set the origin, and every position overflowed float32 ('not drawn'). They are now
    replaced by the points' bounds: the same ids as the intact file, one warning."""
    data = bytearray(exact_sample.read_bytes())
    for offset, value in UNREACHABLE[case]:
        struct.pack_into("<d", data, offset, value)
    bad = tmp_path / "bad_bounds.las"
    bad.write_bytes(data)
    ids = {}
    for name, path in (("good", exact_sample), ("bad", bad)):
        code, _, err = cli(capsys, "render", *TINY, path, "--ids", tmp_path / f"{name}.npy",
                           "--stats", tmp_path / f"{name}.json")
        assert code == 0, err
        ids[name] = np.load(tmp_path / f"{name}.npy")
        warnings = err.splitlines()
        assert json.loads((tmp_path / f"{name}.json").read_text())["points_not_drawn"] == 0
    assert len(warnings) == 1 and warnings[0].startswith("progressive: warning: ") and "header bounds" in warnings[0]
    assert (ids["good"] != EMPTY_ID).sum() > 300
    np.testing.assert_array_equal(ids["bad"], ids["good"])
    code, out, err = cli(capsys, "info", "--json", bad)
    assert code == 0, err
    desc, las = json.loads(out), laspy.read(exact_sample)
    assert desc["header_bounds"] == {"min": las.header.mins.tolist(), "max": las.header.maxs.tolist()}
    assert desc["origin"] == ((las.header.mins + las.header.maxs) / 2).tolist()
    assert len(desc["warnings"]) == 1 and "header bounds" in desc["warnings"][0]


def test_reachable_header_bounds_are_kept(tmp_path, exact_sample):
    """Bounds the records could reach are trusted, even where they are not the points' own
    (a cheaper header check, not a second pass over every file)."""
    data = bytearray(exact_sample.read_bytes())
    struct.pack_into("<d", data, MAX_X, 2e7)
    path = tmp_path / "wide.las"
    path.write_bytes(data)
    with CloudLoader([path]) as loader:
        assert loader.info.bounds_max[0] == 2e7 and not loader.warnings


# --- VLR text that is not UTF-8 -------------------------------------------------------------

def vlr_offsets(data: bytes) -> list[int]:
    """Where each VLR of a LAS/LAZ file starts."""
    (at,), (count,) = struct.unpack_from("<H", data, 94), struct.unpack_from("<I", data, 100)
    offsets = []
    for _ in range(count):
        offsets.append(at)
        at += 54 + struct.unpack_from("<H", data, at + 20)[0]
    return offsets


def test_vlr_text_not_utf8_loads(tmp_path, capsys):
    """A Latin-1 'é' in a VLR's user_id made laspy (strict UTF-8) reject the file; one in a
    description laspy keeps as bytes. Both are read with '?' and one warning line."""
    data = bytearray(SAMPLE.read_bytes())
    vlrs = vlr_offsets(data)
    data[vlrs[4] + 2:vlrs[4] + 8] = "élias".encode("latin-1") + b"\0"      # user_id 'liblas'
    data[vlrs[1] + 22:vlrs[1] + 29] = "Géotiff".encode("latin-1")             # a description
    path = tmp_path / "latin1.las"
    path.write_bytes(data)
    loader, batches = load(path)
    original, expected = load(SAMPLE)
    assert loader.loaded == loader.total == 110_000
    np.testing.assert_array_equal(column(batches), column(expected))
    assert loader.info.files[0].crs == original.info.files[0].crs is not None
    assert len(loader.warnings) == 1 and "not UTF-8" in loader.warnings[0], loader.warnings
    code, _, err = cli(capsys, "render", *TINY, path, "--out", tmp_path / "x.png")
    assert code == 0 and len(err.splitlines()) == 1 and err.startswith("progressive: warning: "), err
    code, out, err = cli(capsys, "info", "--json", path)
    assert code == 0 and len(json.loads(out)["warnings"]) == 1, err


def test_extra_bytes_name_not_utf8_laz(tmp_path):
    """An extra-bytes dimension named in Latin-1, in a LAZ read through lazrs: the
    dimension keeps its values under its name with '?' for the bad byte."""
    source = shared_file("las_with_several_extra_byte_bloc.laz")
    data = bytearray(source.read_bytes())
    data[data.index(b"Deviation\0") + 4] = 0xE9
    path = tmp_path / "latin1.laz"
    path.write_bytes(data)
    loader, batches = load(path, batch_points=100_000)
    las = laspy.read(source)
    assert loader.loaded == loader.total == len(las.points)
    np.testing.assert_array_equal(column(batches, "Devi?tion"), las["Deviation"])
    assert len(loader.warnings) == 1 and "Devi\\xe9tion" in loader.warnings[0], loader.warnings


# --- colour depth ------------------------------------------------------------------------

def colour_file(path: Path, sample: laspy.LasData, index: int, value: int) -> laspy.LasData:
    """BATCH_POINTS + 10 sample points (8-bit colour) with one colour raised to `value`."""
    points = np.resize(sample.points.array, BATCH_POINTS + 10)
    points["red"][index] = value
    header = laspy.LasHeader(point_format=sample.header.point_format.id, version="1.2")
    header.scales, header.offsets = sample.header.scales, sample.header.offsets
    las = laspy.LasData(header, points=laspy.ScaleAwarePointRecord(points, header.point_format,
                                                                     header.scales, header.offsets))
    las.write(path)
    return las


@pytest.mark.parametrize("index, sixteen", [(BATCH_POINTS - 1, True), (BATCH_POINTS, False)])
def test_rgb_depth_rule(tmp_path, sample, index, sixteen):
    """16-bit iff some channel among the first BATCH_POINTS points exceeds 255; an 8-bit
    file clips later values to 255; the loader's batch size changes nothing."""
    path = tmp_path / "colour.las"
    las = colour_file(path, sample, index, 40_000)
    assert open_cloud([path]).files[0].rgb_16bit is sixteen
    rgb = np.stack([las.red, las.green, las.blue], axis=1)
    expected = (rgb >> 8) if sixteen else np.minimum(rgb, 255)
    for kwargs in ({}, {"batch_points": 7_000, "parser_threads": 2}):
        _, batches = load(path, **kwargs)
        np.testing.assert_array_equal(column(batches, "rgb"), expected.astype(np.uint8))


# --- zero and constant attributes ------------------------------------------------------------

@pytest.fixture(scope="module")
def constant_file(tmp_path_factory, sample) -> Path:
    """A flat cloud (one z) whose every other attribute is one value, colour all zero."""
    path = tmp_path_factory.mktemp("constant") / "constant.las"
    xyz = [np.asarray(sample.x)[:SUBSET], np.asarray(sample.y)[:SUBSET], np.full(SUBSET, 450.25)]
    las = rewrite(path, sample, scale=sample.header.scales, offset=sample.header.offsets, xyz=xyz)
    for name, value in (("intensity", 0), ("classification", 5), ("gps_time", 123456.5), ("user_data", 9),
                        ("point_source_id", 3), ("red", 0), ("green", 0), ("blue", 0), ("return_number", 1),
                        ("number_of_returns", 1), ("scan_angle_rank", -4)):
        las[name] = np.full(SUBSET, value, dtype=las[name].dtype)
    las.write(path)
    return path


@pytest.mark.filterwarnings("error")
def test_constant_attributes_describe(constant_file):
    """min == max everywhere, without a warning (no division by a zero range)."""
    desc = describe([constant_file])
    json.dumps(desc, allow_nan=False)
    attrs = desc["attributes"]
    assert attrs["rgb"]["min"] == attrs["rgb"]["max"] == [0, 0, 0]
    assert attrs["elevation"]["min"] == attrs["elevation"]["max"] == 450.25
    assert desc["files"][0]["rgb_16bit"] is False
    for name, value in (("intensity", 0), ("classification", 5), ("gps_time", 123456.5), ("user_data", 9),
                        ("point_source_id", 3), ("scan_angle", -4)):
        assert attrs[name]["min"] == attrs[name]["max"] == value, name


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("color_by", ["rgb", "intensity", "elevation", "gps_time"])
def test_constant_attributes_render_one_colour(tmp_path, capsys, constant_file, color_by):
    out = tmp_path / "x.png"
    code, _, err = cli(capsys, "render", *TINY, constant_file, "--color-by", color_by,
                       "--background", "255,255,255", "--out", out, "--ids", tmp_path / "x.npy")
    assert code == 0, err
    ids, image = np.load(tmp_path / "x.npy"), np.asarray(Image.open(out))
    colours = np.unique(image[ids != EMPTY_ID], axis=0)
    assert len(colours) == 1, colours
    if color_by == "rgb":
        assert colours.tolist() == [[0, 0, 0]]


# --- non-finite values ---------------------------------------------------------------------

NAN_AT = {"f32": [3, 4000, 19_999], "f64": [0, 12_345], "vec[1]": [7], "gps_time": [0]}
INF_AT = {"f32": [5, 8_000], "f64": [1], "vec[1]": [8, 9]}
SIGNALLING_AT = {"f32": (11, np.uint32(0x7F800001)), "f64": (13, np.uint64(0x7FF0000000000001))}
"""Signalling NaNs: numpy arithmetic on them warns 'invalid value' (found by fuzzing)."""


def expected_nonfinite() -> dict[str, int]:
    tables = (NAN_AT, INF_AT, {name: [i] for name, (i, _) in SIGNALLING_AT.items()})
    return {name: sum(len(t.get(name, [])) for t in tables) for name in {*NAN_AT, *INF_AT}}


@pytest.fixture(scope="module")
def nan_extra_bytes(tmp_path_factory, sample) -> tuple[Path, laspy.LasData]:
    """Sample points with float32, float64 and float32[3] extra bytes holding NaN (quiet
    and signalling) and ±Inf, and a NaN GPS time at the first point (which sets the GPS
    offset)."""
    path = tmp_path_factory.mktemp("nan") / "nan_extra.las"
    extra = [laspy.ExtraBytesParams("f32", "f4"), laspy.ExtraBytesParams("f64", "f8"),
             laspy.ExtraBytesParams("vec", "3f4")]
    las = rewrite(path, sample, scale=sample.header.scales, offset=sample.header.offsets, extra=extra)
    rng = np.random.default_rng(4)
    las.f32 = rng.normal(size=SUBSET).astype(np.float32)
    las.f64 = rng.normal(1e9, 1, size=SUBSET)
    las.vec = rng.normal(size=(SUBSET, 3)).astype(np.float32)
    for table, value in ((NAN_AT, np.nan), (INF_AT, np.inf)):
        for name, indices in table.items():
            for k, i in enumerate(indices):
                signed = value if k % 2 == 0 else -value
                if name == "vec[1]":
                    las.vec[i, 1] = signed
                else:
                    las[name][i] = signed
    for name, (i, bits) in SIGNALLING_AT.items():
        las[name][i] = bits.view(las[name].dtype)
    las.write(path)
    return path, laspy.read(path)


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("kwargs", [{}, {"batch_points": 3_000, "parser_threads": 3}])
def test_nonfinite_extra_bytes_are_counted_and_kept(nan_extra_bytes, kwargs):
    path, las = nan_extra_bytes
    loader, batches = load(path, **kwargs)
    assert loader.nonfinite_values == expected_nonfinite()
    assert loader.nonfinite_positions == 0
    assert math.isfinite(loader.info.attribute("gps_time").offset)
    for name in ("f32", "f64", "gps_time"):
        np.testing.assert_array_equal(column(batches, name), las[name])      # NaN where NaN
    np.testing.assert_array_equal(column(batches, "vec[1]"), las.vec[:, 1])


@pytest.mark.filterwarnings("error")
def test_nonfinite_extra_bytes_describe(nan_extra_bytes):
    path, las = nan_extra_bytes
    desc = describe([path])
    json.dumps(desc, allow_nan=False)
    assert desc["nonfinite_values"] == expected_nonfinite() == desc["files"][0]["nonfinite_values"]
    assert desc["nonfinite_positions"] == 0
    for name in ("f32", "f64"):
        finite = las[name][np.isfinite(las[name])]
        assert (desc["attributes"][name]["min"], desc["attributes"][name]["max"]) == (finite.min(), finite.max())


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("color_by", ["f32", "f64"])
def test_nonfinite_extra_bytes_render(tmp_path, capsys, nan_extra_bytes, color_by):
    code, _, err = cli(capsys, "render", *TINY, nan_extra_bytes[0], "--color-by", color_by, "--out", tmp_path / "x.png")
    assert code == 0, err


NAN32, SNAN32, INF32, NEG_INF32 = 0x7FC00000, 0x7F800001, 0x7F800000, 0xFF800000
"""float32 bit patterns, written raw: a signalling NaN passed through a Python float turns quiet."""
NONFINITE_POINTS = {10: (NAN32, None, None), 20_000: (None, INF32, None), 60_001: (None, None, NEG_INF32),
                    77_777: (None, SNAN32, None), 109_999: (NAN32, NAN32, SNAN32)}
NAN_VALUES_AT = {500: NAN32, 501: SNAN32}


@pytest.fixture(scope="module")
def fast_nonfinite(tmp_path_factory, fast_sample) -> Path:
    data = bytearray(fast_sample.read_bytes())
    for index, xyz in NONFINITE_POINTS.items():
        for axis, value in enumerate(xyz):
            if value is not None:
                struct.pack_into("<I", data, HEADER_BYTES + 16 * index + 4 * axis, value)
    for index, value in NAN_VALUES_AT.items():
        struct.pack_into("<I", data, HEADER_BYTES + 16 * index + 12, value)
    path = tmp_path_factory.mktemp("fastnan") / "nonfinite.prgs"
    path.write_bytes(data)
    return path


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("batch_points", [BATCH_POINTS, 9_999])
def test_fast_nonfinite_positions_are_counted(fast_nonfinite, batch_points):
    loader, batches = load(fast_nonfinite, batch_points=batch_points)
    assert loader.loaded == 110_000
    assert loader.nonfinite_positions == len(NONFINITE_POINTS)
    assert loader.nonfinite_values == {"intensity": len(NAN_VALUES_AT)}
    assert sum(b.nonfinite_positions for b in batches) == len(NONFINITE_POINTS)


@pytest.mark.filterwarnings("error")
def test_fast_nonfinite_describe(fast_nonfinite, fast_sample):
    desc, clean = describe([fast_nonfinite]), describe([fast_sample])
    json.dumps(desc, allow_nan=False)
    assert desc["nonfinite_positions"] == len(NONFINITE_POINTS) and clean["nonfinite_positions"] == 0
    assert desc["nonfinite_values"] == {"intensity": len(NAN_VALUES_AT)} and clean["nonfinite_values"] == {}
    records = np.fromfile(fast_sample, dtype=np.uint32, offset=HEADER_BYTES).reshape(-1, 4)
    kept = np.delete(records[:, :3].view(np.float32), list(NONFINITE_POINTS), axis=0).astype(np.float64)
    origin = np.array(desc["origin"])
    assert desc["bounds"] == {"min": (origin + kept.min(axis=0)).tolist(), "max": (origin + kept.max(axis=0)).tolist()}


@pytest.mark.filterwarnings("error")
def test_fast_nonfinite_points_are_never_drawn(tmp_path, capsys, fast_nonfinite):
    ids = tmp_path / "ids.npy"
    code, _, err = cli(capsys, "render", *TINY, fast_nonfinite, "--ids", ids)
    assert code == 0 and all(line.startswith("progressive: ") for line in err.splitlines()), err
    shown = np.load(ids)
    assert (shown != EMPTY_ID).sum() > 100
    assert not np.isin(shown, list(NONFINITE_POINTS)).any()


# --- the command line on bad files ------------------------------------------------------------

def cli(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_error_line(code: int, err: str, out_dir: Path) -> None:
    assert code == 2, err
    assert err.startswith("progressive: error: ") and err.count("\n") == 1, err
    assert not any(out_dir.iterdir()), "nothing may be written"


def u32(offset: int, value):
    return lambda d: struct.pack_into("<I", d, offset, value(struct.unpack_from("<I", d, offset)[0]))


def f64(offset: int, value: float):
    return lambda d: struct.pack_into("<d", d, offset, value)


def cut(fraction: float):
    return lambda d: d.__delitem__(slice(int(len(d) * fraction), None))


def corrupt_middle(d: bytearray) -> None:
    middle = len(d) // 2
    d[middle:middle + 256] = np.random.default_rng(1).integers(0, 256, 256, dtype=np.uint8).tobytes()


POINT_DATA = laspy.LasHeader.read_from(SAMPLE.open("rb")).offset_to_point_data
FAST = "fast"
"""Stands for the fast-format sample as the source of a case."""

BAD = {
    "header only, points promised": (SAMPLE, lambda d: d.__delitem__(slice(POINT_DATA, None))),
    "count smaller than data": (SAMPLE, u32(107, lambda c: c - 1000)),
    "point format 11": (SAMPLE, lambda d: d.__setitem__(104, 11)),
    "version 1.9": (SAMPLE, lambda d: d.__setitem__(25, 9)),
    "version 2.0": (SAMPLE, lambda d: d.__setitem__(slice(24, 26), b"\x02\x00")),
    "NaN scale": (SAMPLE, f64(131, math.nan)),
    "zero scale": (SAMPLE, f64(139, 0.0)),
    "infinite offset": (SAMPLE, f64(163, -math.inf)),
    "NaN bounds": (SAMPLE, f64(179, math.nan)),
    "VLR count 2^32-1": (SAMPLE, u32(100, lambda c: 2**32 - 1)),
    "laz truncated": ("pine_plot.laz", cut(0.5)),
    "laz truncated pointwise": ("TO_core_last_zoom.laz", cut(0.5)),
    "laz corrupt chunk": ("pine_plot.laz", corrupt_middle),
    "laz count larger": ("pine_plot.laz", u32(107, lambda c: c + 1000)),
    "laz count smaller": ("pine_plot.laz", u32(107, lambda c: c - 60_000)),
    "laz 1.4 count larger": ("lion_takanawa.copc.laz",
                             lambda d: struct.pack_into("<Q", d, 247, struct.unpack_from("<Q", d, 247)[0] + 5)),
    "fast bad magic": (FAST, lambda d: d.__setitem__(slice(0, 8), b"PRGSPC\x00\x02")),
    "fast version 2": (FAST, u32(8, lambda v: 2)),
    "fast short": (FAST, lambda d: d.__delitem__(slice(-5, None))),
    "fast long": (FAST, lambda d: d.extend(bytes(16))),
    "fast header only": (FAST, lambda d: d.__delitem__(slice(HEADER_BYTES, None))),
    "fast NaN origin": (FAST, f64(24, math.nan)),
}
PARTIAL = {"count smaller than data", "laz truncated", "laz truncated pointwise", "laz corrupt chunk", "fast short"}
"""Cases that --partial renders, with a warning."""


@pytest.fixture
def folders(tmp_path) -> tuple[Path, Path]:
    (tmp_path / "in").mkdir()
    (tmp_path / "out").mkdir()
    return tmp_path / "in", tmp_path / "out"


def bad_file(case: str, folder: Path, fast_sample: Path) -> Path:
    source, edit = BAD[case]
    source = fast_sample if source == FAST else source if isinstance(source, Path) else shared_file(source)
    data = bytearray(source.read_bytes())
    edit(data)
    path = folder / f"bad{source.suffix}"
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("case", list(BAD))
def test_render_bad_file(folders, capsys, fast_sample, case):
    inputs, outputs = folders
    path = bad_file(case, inputs, fast_sample)
    code, _, err = cli(capsys, "render", *TINY, path, "--out", outputs / "x.png")
    assert_one_error_line(code, err, outputs)
    assert str(path) in err


@pytest.mark.parametrize("case", sorted(PARTIAL))
def test_render_partial(folders, capsys, fast_sample, case):
    """Warnings only, and every point shown is one the partial load read."""
    inputs, outputs = folders
    path = bad_file(case, inputs, fast_sample)
    with CloudLoader([path], partial=True) as loader:
        read = sum(b.count for b in loader)
    assert 0 < read <= loader.total
    code, _, err = cli(capsys, "render", *TINY, path, "--partial", "--out", outputs / "x.png",
                       "--ids", outputs / "x.npy")
    assert code == 0, err
    lines = err.splitlines()
    assert lines and all(line.startswith("progressive: warning: ") for line in lines), err
    ids = np.load(outputs / "x.npy")
    assert (ids != EMPTY_ID).sum() > 10 and ids[ids != EMPTY_ID].max() < read
    assert (outputs / "x.png").is_file()


def test_partial_corrupt_laz_keeps_what_decodes(folders, fast_sample):
    """A corrupt chunk in the middle: the points before it are all there."""
    path = bad_file("laz corrupt chunk", folders[0], fast_sample)
    with CloudLoader([path], partial=True) as loader:
        read = sum(b.count for b in loader)
    assert loader.total // 4 < read < loader.total and len(loader.warnings) == 1


class EndsAt(io.RawIOBase):
    """A file's bytes that end at `cut` for the point data but still hold its header and
    its chunk table (at `table` and after): the truncated file as laspy could open it."""

    def __init__(self, data: bytes, cut: int, table: int):
        super().__init__()
        self._data, self._cut, self._table, self._pos = data, cut, table, 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, pos: int, whence: int = io.SEEK_SET) -> int:
        self._pos = {io.SEEK_SET: 0, io.SEEK_CUR: self._pos, io.SEEK_END: len(self._data)}[whence] + pos
        return self._pos

    def tell(self) -> int:
        return self._pos

    def readinto(self, buffer) -> int:
        end = self._cut if self._pos < self._cut else len(self._data) if self._pos >= self._table else self._pos
        data = self._data[self._pos:min(end, self._pos + len(buffer))]
        buffer[:len(data)] = data
        self._pos += len(data)
        return len(data)


def decodable_points(stream) -> np.ndarray:
    """x, y, z of the points laspy's sequential LAZ reader gives one at a time before its
    first failure. (Where bytes are damaged rather than missing, some are garbage: LAZ has
    no checksum.)"""
    points = []
    with laspy.LasReader(stream, laz_backend=laspy.LazBackend.Lazrs) as reader:
        try:
            while len(points) < reader.header.point_count:
                point = reader.read_points(1)
                points.append([point.x[0], point.y[0], point.z[0]])
        except lazrs.LazrsError:
            pass
    return np.array(points)


def truncated_in_chunk(source: Path, folder: Path) -> tuple[Path, np.ndarray]:
    """`source` cut 30 % into its second chunk, and how many points laspy decodes from
    the bytes before the cut (its chunk table left where it can find it)."""
    data = source.read_bytes()
    header = laspy.LasHeader.read_from(io.BytesIO(data))
    point_data = header.offset_to_point_data
    (table,) = struct.unpack_from("<q", data, point_data)
    stream = io.BytesIO(data)
    stream.seek(point_data)
    chunks = lazrs.read_chunk_table(stream, lazrs.LazVlr(header.vlrs.get("LasZipVlr")[0].record_data))
    second = point_data + 8 + chunks[0][1]
    cut = second + int(chunks[1][1] * 0.3)
    path = folder / f"cut{source.suffix}"
    path.write_bytes(data[:cut])
    return path, decodable_points(io.BufferedReader(EndsAt(data, cut, table)))


@pytest.mark.parametrize("case", ["truncated in a chunk", "laz corrupt chunk"])
def test_partial_laz_keeps_every_decodable_point(folders, fast_sample, case):
    """--partial keeps every point that decodes before the damage, not whole reads of
    1000: as many as laspy reading one point at a time gets, and the same points."""
    if case == "truncated in a chunk":
        path, expected = truncated_in_chunk(shared_file("pine_plot.laz"), folders[0])
    else:
        path = bad_file(case, folders[0], fast_sample)
        expected = decodable_points(path.open("rb"))
    with CloudLoader([path], partial=True, batch_points=20_000) as loader:
        batches = sorted(loader, key=lambda b: b.start)
    assert 50_000 < len(expected) < loader.total and len(expected) % 1000, len(expected)
    assert loader.loaded == len(expected) and len(loader.warnings) == 1, loader.warnings
    np.testing.assert_array_equal(column(batches), np.float32(expected - loader.info.origin))


@pytest.mark.parametrize("name", ["extrabytes.las", "fullwave.laz"])
def test_las14_legacy_count_zero_renders(folders, capsys, name):
    """LAS 1.4 keeps the count in 64 bits; the legacy 32-bit field may be 0 (it must be
    for point formats 6-10, as in fullwave.laz)."""
    inputs, outputs = folders
    data = bytearray(shared_file(name).read_bytes())
    count = struct.unpack_from("<Q", data, 247)[0]
    struct.pack_into("<I", data, 107, 0)
    path = inputs / name
    path.write_bytes(data)
    code, out, err = cli(capsys, "info", "--json", path)
    assert code == 0 and json.loads(out)["points"] == count, err
    code, _, err = cli(capsys, "render", *TINY, path, "--ids", outputs / "x.npy")
    assert code == 0 and err == "", err
    ids = np.load(outputs / "x.npy")
    assert ids[ids != EMPTY_ID].size > 100 and ids[ids != EMPTY_ID].max() < count


def test_unreadable_file(folders, capsys, monkeypatch):
    """chmod 000; where that does not stop reading (root), open() refuses the path."""
    inputs, outputs = folders
    path = inputs / "locked.las"
    path.write_bytes(SAMPLE.read_bytes())
    path.chmod(0)
    if os.access(path, os.R_OK):
        real_open = open

        def refuse(file, *args, **kwargs):
            if isinstance(file, (str, os.PathLike)) and Path(file) == path:
                raise PermissionError(13, "Permission denied", str(file))
            return real_open(file, *args, **kwargs)

        monkeypatch.setattr("builtins.open", refuse)
    for argv in (["render", *TINY, path, "--out", outputs / "x.png"], ["info", path],
                 ["convert", path, outputs / "x.prgs"]):
        code, out, err = cli(capsys, *argv)
        assert_one_error_line(code, err, outputs)
        assert "locked.las" in err and "Permission denied" in err and out == ""


@pytest.mark.parametrize("case", ["header only, points promised", "laz corrupt chunk", "fast bad magic", "NaN scale"])
def test_info_bad_file(folders, capsys, fast_sample, case):
    inputs, outputs = folders
    path = bad_file(case, inputs, fast_sample)
    for json_flag in ([], ["--json"]):
        code, out, err = cli(capsys, "info", *json_flag, path)
        assert_one_error_line(code, err, outputs)
        assert out == ""


@pytest.mark.parametrize("case", ["count smaller than data", "laz truncated", "fast long", "version 1.9"])
def test_convert_bad_file(folders, capsys, fast_sample, case):
    inputs, outputs = folders
    path = bad_file(case, inputs, fast_sample)
    code, out, err = cli(capsys, "convert", path, outputs / "x.prgs")
    assert_one_error_line(code, err, outputs)
    assert out == ""


def test_switching_to_and_from_a_nonfinite_attribute(gl, nan_extra_bytes):
    """Points hidden by NaN in the shown attribute come back when another attribute is
    shown, and go again when it is shown back: the switch rewrites whole records for
    those batches and the progressive image converges to brute force each time."""
    from progressive.budget import BudgetParams
    from progressive.camera import auto_camera
    from progressive.frame_loop import ProgressiveOptions, ProgressiveRenderer
    from progressive.renderer import Renderer

    path, las = nan_extra_bytes
    with CloudLoader([path], batch_points=3_000) as loader:
        info = loader.info
        loader.start()
        batches = sorted(loader, key=lambda b: b.start)
    w, h = 120, 90
    cam = auto_camera(info.bounds_min, info.bounds_max, w / h)
    pr = ProgressiveRenderer(gl, info, info.attribute("f32"),
                             ProgressiveOptions(w, h, budget=BudgetParams(fixed=50_000), batches_per_frame=100,
                                                keep_batches=True))
    for b in batches:
        pr.add_batch(b)
    for name in ("f32", "intensity", "f32"):
        if name != pr.scene.attribute.name:
            pr.switch_attribute(info.attribute(name))
        for _ in range(30):
            pr.frame(cam, pr.scene.style())
            pr.flush()
            if pr.converged and not pr.switching:
                break
        pr.frame(cam, pr.scene.style())
        brute = Renderer(gl, info, info.attribute(name), width=w, height=h)
        for b in batches:
            brute.add_batch(b)
        expected = brute.render(cam, w, h, brute.style())
        np.testing.assert_array_equal(pr.read_ids(), expected.ids)
        assert pr.scene.skipped == brute.scene.skipped
        assert (pr.scene.skipped > 0) == (name == "f32")
        brute.release()
    assert pr.scene.positions_changed
    pr.release()


def test_extra_bytes_arrays_named_like_bit_fields(tmp_path):
    """Extra bytes may carry the name of a bit field of the point format (laspy's
    record[name] then gives the bit field): their elements are read from the extra bytes,
    scaled where the file scales them, and the bit field keeps its own values."""
    path = tmp_path / "named.las"
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.add_extra_dims([laspy.ExtraBytesParams("return_number", "3u1"),
                           laspy.ExtraBytesParams("synthetic", "2i2", scales=np.array([0.5, 0.25]),
                                                  offsets=np.array([1.0, -2.0]))])
    n = 1_000
    las = laspy.LasData(header)
    rng = np.random.default_rng(8)
    las.x, las.y, las.z = (rng.uniform(0, 100, n) for _ in range(3))
    las.return_number = rng.integers(1, 8, n)
    raw = las.points.array
    raw["return_number"] = rng.integers(0, 256, (n, 3))
    raw["synthetic"] = rng.integers(-1000, 1000, (n, 2))
    las.write(path)
    loader, batches = load(path)
    back = laspy.read(path).points.array
    np.testing.assert_array_equal(column(batches, "return_number"), np.asarray(laspy.read(path).return_number))
    for i in range(3):
        np.testing.assert_array_equal(column(batches, f"return_number[{i}]"), back["return_number"][:, i])
    for i, (scale, offset) in enumerate(((0.5, 1.0), (0.25, -2.0))):
        np.testing.assert_array_equal(column(batches, f"synthetic[{i}]"), back["synthetic"][:, i] * scale + offset)
