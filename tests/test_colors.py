"""The colour contract, held against an independent reference: the rendered PNG's
pixels against laspy's values of the points the ids name, numpy's percentiles of
every point and matplotlib's colormaps, for every rasterizer, both methods, every
attribute kind and several files at once."""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pytest
from PIL import Image

from colour_reference import assert_scalar_colours, las_rgb, las_values, reference_range, shown
from conftest import SAMPLE, shared_file
from progressive.cli import main
from progressive.colors import ASPRS_CLASSES, UNKNOWN_CLASS

W, H = 200, 150


def render(tmp_path: Path, files: list[Path], *args: str) -> tuple[np.ndarray, np.ndarray, dict]:
    out, ids, stats = tmp_path / "out.png", tmp_path / "ids.npy", tmp_path / "stats.json"
    code = main(["render", *map(str, files), "--width", str(W), "--height", str(H), "--out", str(out),
                 "--ids", str(ids), "--stats", str(stats), *args])
    assert code == 0
    image = np.asarray(Image.open(out).convert("RGB")).astype(np.int32)
    return image, np.load(ids), json.loads(stats.read_text())


def assert_range(stats: dict, expected: tuple[float, float]) -> None:
    """The range in --stats is numpy's percentile of every point (to float32 rounding of
    the stored values)."""
    got = stats["color_range"]
    span = max(expected[1] - expected[0], abs(expected[1]), 1.0)
    assert got == pytest.approx(expected, abs=1e-6 * span)


def cloud(files: list[Path]) -> list[laspy.LasData]:
    return [laspy.read(f) for f in files]


def concat(parts: list[np.ndarray]) -> np.ndarray:
    return np.concatenate(parts, axis=0)


RASTER_METHODS = [(r, m) for r in ("compute", "compute32", "points") for m in ("brute", "progressive")]


def method_args(method: str, raster: str = "compute") -> list[str]:
    """Progressive frames until they equal brute force; GL_POINTS' own until every point
    was drawn: its depth buffer (2^-24 of the depth range) ties close points, which
    draw order then decides, and a frame draws last frame's points first, so its image
    may keep another of two tied points than the brute-force draw in slot order."""
    if method != "progressive":
        return ["--method", method]
    return ["--method", method, "--frames", "60"] if raster == "points" else ["--method", method, "--converge"]


def check_scalar(tmp_path, path, name: str, *args: str, default: bool = False, source=None) -> None:
    """Render `path` coloured by `name` (with `default`, by its default colouring, which
    must be `name`): its range and its pixels against the reference of `source` (the LAS
    file a fast-format `path` was made from; default `path`)."""
    las = laspy.read(source or path)
    image, ids, stats = render(tmp_path, [path], *args) if default else \
        render(tmp_path, [path], "--color-by", name, *args)
    assert stats["attribute"] == name
    values = las_values(las, name)
    expected = reference_range(values)
    assert_range(stats, expected)
    assert_scalar_colours(image, ids, values, expected)


@pytest.mark.parametrize("raster, method", RASTER_METHODS)
def test_elevation_every_rasterizer_and_method(tmp_path, raster, method):
    check_scalar(tmp_path, SAMPLE, "elevation", "--raster", raster, *method_args(method, raster))


@pytest.mark.parametrize("name", ["intensity", "gps_time", "return_number", "point_source_id"])
def test_scalar_attributes(tmp_path, name):
    check_scalar(tmp_path, SAMPLE, name)


@pytest.mark.parametrize("colormap", ["inferno", "plasma", "turbo", "gray"])
def test_colormaps(tmp_path, colormap):
    las = laspy.read(SAMPLE)
    flag = "grayscale" if colormap == "gray" else colormap
    image, ids, stats = render(tmp_path, [SAMPLE], "--color-by", "intensity", "--colormap", flag)
    values = las_values(las, "intensity")
    assert_scalar_colours(image, ids, values, reference_range(values), colormap)


@pytest.mark.parametrize("raster, method", [("compute", "brute"), ("points", "progressive")])
def test_rgb_and_classification(tmp_path, raster, method):
    las = laspy.read(SAMPLE)
    image, ids, stats = render(tmp_path, [SAMPLE], "--raster", raster, *method_args(method, raster))
    assert stats["attribute"] == "rgb" and stats["color_range"] is None
    pixels, which = shown(image, ids)
    assert np.array_equal(pixels, las_rgb(las)[which])

    image, ids, stats = render(tmp_path, [SAMPLE], "--color-by", "classification", "--raster", raster,
                               *method_args(method, raster))
    table = np.array([ASPRS_CLASSES.get(c, (None, UNKNOWN_CLASS))[1] for c in range(256)])
    pixels, which = shown(image, ids)
    assert np.array_equal(pixels, table[np.asarray(las.classification, dtype=np.int64)[which]])


def test_given_range(tmp_path):
    las = laspy.read(SAMPLE)
    image, ids, stats = render(tmp_path, [SAMPLE], "--color-by", "elevation", "--range", "420,460")
    assert stats["color_range"] == [420.0, 460.0]
    assert_scalar_colours(image, ids, las_values(las, "elevation"), (420.0, 460.0))


def test_fast_format_colours_its_stored_attribute(tmp_path, fast_sample):
    check_scalar(tmp_path, fast_sample, "intensity", default=True, source=SAMPLE)


def test_several_files_are_one_range_and_one_rgb_rule_each(tmp_path):
    """Two files: the percentiles are over both, RGB depth is each file's own."""
    files = [SAMPLE, shared_file("extrabytes.las")]
    parts = cloud(files)
    for method in ("brute", "progressive"):
        image, ids, stats = render(tmp_path, files, "--color-by", "elevation", *method_args(method))
        values = concat([las_values(p, "elevation") for p in parts])
        expected = reference_range(values)
        assert_range(stats, expected)
        assert_scalar_colours(image, ids, values, expected)
    image, ids, stats = render(tmp_path, files)
    pixels, which = shown(image, ids)
    assert np.array_equal(pixels, concat([las_rgb(p) for p in parts])[which])


def test_sixteen_bit_rgb_file(tmp_path):
    path = shared_file("lion_takanawa.copc.laz")
    las = laspy.read(path)
    image, ids, _ = render(tmp_path, [path])
    pixels, which = shown(image, ids)
    assert np.array_equal(pixels, las_rgb(las)[which])


@pytest.mark.parametrize("name, attribute", [("las_with_several_extra_byte_bloc.laz", "Deviation"),
                                             ("extrabytes.las", "Colors[1]"),
                                             ("wires.laz", "elevation")])
def test_real_files(tmp_path, name, attribute):
    check_scalar(tmp_path, shared_file(name), attribute)


def test_default_without_rgb_is_coloured_over_every_point(tmp_path):
    """pine_plot has no RGB and all-zero intensity: the default moves on to elevation,
    coloured over the whole cloud's percentiles, not the first batch's."""
    check_scalar(tmp_path, shared_file("pine_plot.laz"), "elevation", default=True)
