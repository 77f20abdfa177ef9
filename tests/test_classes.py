"""Class filters that do not depend on the colouring: with elevation (or any attribute)
shown, hidden classes are left out of every rasterizer and both methods exactly as
the float64 render contract of the remaining points says."""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from conftest import BUNNY, SAMPLE, shared_file
from progressive.camera import auto_camera
from progressive.cli import main
from progressive.reference import EMPTY, subset_reference_ids

W, H = 160, 120


def render_ids(tmp_path, path, *args) -> np.ndarray:
    ids = tmp_path / "ids.npy"
    assert main(["render", str(path), "--width", str(W), "--height", str(H), "--ids", str(ids), *args]) == 0
    return np.load(ids)


def reference(path, hidden: set[int], slots_of, returns: str = "all") -> np.ndarray:
    las = laspy.read(path)
    xyz = np.stack([las.x, las.y, las.z], axis=1)
    number, count = np.asarray(las.return_number), np.asarray(las.number_of_returns)
    wanted = {"all": np.ones(len(number), bool), "first": number <= 1, "last": number >= count,
              "single": (number <= 1) & (number >= count)}[returns]
    keep = np.nonzero(~np.isin(np.asarray(las.classification), list(hidden)) & wanted)[0]
    cam = auto_camera(xyz.min(axis=0), xyz.max(axis=0), W / H)
    return subset_reference_ids(xyz, keep, cam, W, H, slots_of(np.arange(len(xyz)))), cam


@pytest.mark.parametrize("raster, method", [("compute", "brute"), ("compute32", "progressive"), ("points", "brute"),
                                            ("points", "progressive")])
@pytest.mark.parametrize("color_by", ["elevation", "intensity", "rgb"])
def test_hidden_classes_with_any_colouring_equal_the_reference(tmp_path, raster, method, color_by):
    from progressive.loaders import open_cloud
    from progressive.permutation import LAYOUT, Permutation

    las = laspy.read(SAMPLE)
    common = int(np.bincount(np.asarray(las.classification)).argmax())
    perm = Permutation.for_count(open_cloud([SAMPLE]).points, order=LAYOUT)
    expected, _ = reference(SAMPLE, {common}, lambda k: perm.forward(k).astype(np.int64))
    # GL_POINTS resolves depth to (far - near) / 2^24, so its progressive frames are held to
    # the float64 reference like its brute ones, not to the compute render (--converge).
    extra = ["--method", method, *(["--frames", "60"] if raster == "points" else ["--converge"])] \
        if method == "progressive" else []
    got = render_ids(tmp_path, SAMPLE, "--color-by", color_by, "--raster", raster, "--hide-classes", str(common), *extra)
    shown = got[got != EMPTY]
    assert shown.size > 500 and not np.isin(np.asarray(las.classification)[shown], [common]).any()
    assert np.mean(got == expected) >= 0.999
    unfiltered = render_ids(tmp_path, SAMPLE, "--color-by", color_by, "--raster", raster, *extra)
    assert not np.array_equal(got, unfiltered)


def test_real_file_with_several_classes(tmp_path):
    path = shared_file("wires.laz")
    las = laspy.read(path)
    got = render_ids(tmp_path, path, "--color-by", "elevation", "--hide-classes", "2,5")
    shown = np.asarray(las.classification)[got[got != EMPTY]]
    assert shown.size > 500 and set(np.unique(shown).tolist()) <= {1, 9}


def test_hiding_classes_of_a_cloud_without_them_is_one_line(tmp_path, capsys):
    capsys.readouterr()
    assert main(["render", str(BUNNY), "--out", str(tmp_path / "x.png"),
                 "--hide-classes", "2"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("progressive: error: ") and err.count("\n") == 1 and not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("raster", ["compute", "points"])
@pytest.mark.parametrize("returns", ["first", "last", "single"])
def test_return_filters_equal_the_reference(tmp_path, raster, returns):
    from progressive.loaders import open_cloud
    from progressive.permutation import LAYOUT, Permutation

    perm = Permutation.for_count(open_cloud([SAMPLE]).points, order=LAYOUT)
    expected, _ = reference(SAMPLE, set(), lambda k: perm.forward(k).astype(np.int64), returns)
    got = render_ids(tmp_path, SAMPLE, "--color-by", "elevation", "--raster", raster, "--returns", returns)
    assert np.mean(got == expected) >= 0.999
    everything = render_ids(tmp_path, SAMPLE, "--color-by", "elevation", "--raster", raster)
    assert not np.array_equal(got, everything) and np.count_nonzero(got != EMPTY) > 500


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.uint32, np.uint64, np.int16, np.int64])
def test_codes_present_are_numpys_unique_codes(dtype):
    """The category codes a panel lists: those of np.unique, over 255 clamped to 255,
    negative ones (signed category attributes) left out."""
    from progressive.scene import codes_present

    rng = np.random.default_rng(7)
    low = -40 if np.issubdtype(dtype, np.signedinteger) else 0
    for values in (rng.integers(low, 400, 5_000).astype(dtype), np.zeros(0, dtype), np.full(9, 3, dtype)):
        expected = np.zeros(256, dtype=bool)
        codes = np.unique(np.clip(values.astype(np.int64), None, 255))
        expected[codes[codes >= 0]] = True
        assert np.array_equal(codes_present(values), expected)
