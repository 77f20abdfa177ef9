"""The colour contract's reference, independent of the renderer: laspy's values,
numpy's percentiles and matplotlib's colormaps (test_colors.py, viewer_cases.py)."""

from __future__ import annotations

import re

import laspy
import matplotlib
import numpy as np

from progressive.loaders.types import BATCH_POINTS

EMPTY = 0xFFFFFFFF
PERCENTILES = (1.0, 99.0)


def las_values(las: laspy.LasData, name: str) -> np.ndarray:
    """What a user means by the attribute, straight from laspy, in float64."""
    if name == "elevation":
        return np.asarray(las.z, dtype=np.float64)
    element = re.fullmatch(r"(.+)\[(\d+)\]", name)
    if element:
        return np.asarray(las[element.group(1)], dtype=np.float64)[:, int(element.group(2))]
    return np.asarray(las[name], dtype=np.float64)


def las_rgb(las: laspy.LasData) -> np.ndarray:
    """8 bits decided per file: 16-bit (shifted right by 8) iff a channel among the
    file's first BATCH_POINTS points exceeds 255, else 8-bit, clipped."""
    rgb = np.stack([np.asarray(las[c], dtype=np.int64) for c in ("red", "green", "blue")], axis=1)
    return np.minimum(rgb >> 8 if rgb[:BATCH_POINTS].max() > 255 else rgb, 255)


def shown(image: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    covered = ids != EMPTY
    assert np.count_nonzero(covered) >= 500, "the view shows too few points to test colours"
    return image[covered], ids[covered].astype(np.int64)


def palette(colormap: str) -> np.ndarray:
    """matplotlib's 256 entries of the colormap, as 0-255 integers."""
    return np.round(matplotlib.colormaps[colormap](np.arange(256))[:, :3] * 255).astype(np.int32)


def assert_scalar_colours(image, ids, values: np.ndarray, value_range, colormap="viridis") -> None:
    """Each covered pixel is the colormap at its point's value over the range: the
    palette index may differ by one where GPU float rounding meets an index boundary,
    a channel by one where two libraries round the same colormap."""
    pixels, which = shown(image, ids)
    lo, hi = value_range
    t = np.clip((values[which] - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.full(which.size, 0.5)
    index = np.floor(t * 255.0 + 0.5).astype(np.int64)
    lut = palette(colormap)
    error = np.min([np.abs(pixels - lut[np.clip(index + k, 0, 255)]).max(axis=1) for k in (-1, 0, 1)], axis=0)
    exact = np.abs(pixels - lut[index]).max(axis=1) <= 1
    assert error.max() <= 1, f"{np.count_nonzero(error > 1)} of {which.size} pixels have another colour"
    assert exact.mean() > 0.99


def reference_range(values: np.ndarray) -> tuple[float, float]:
    finite = values[np.isfinite(values)]
    lo, hi = np.percentile(finite, PERCENTILES)
    return float(lo), float(hi)
