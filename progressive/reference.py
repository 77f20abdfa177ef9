"""The render contract evaluated in float64 on the CPU: the ground truth for tests,
`--reference` comparisons and benchmarks of accuracy."""

from __future__ import annotations

import numpy as np

from progressive.camera import Camera, Clip, project

EMPTY = 0xFFFFFFFF


def reference_ids(xyz: np.ndarray, camera: Camera, width: int, height: int,
                  tie_key: np.ndarray | None = None) -> np.ndarray:
    """(H, W) uint32 file-order index of the nearest point per pixel, EMPTY elsewhere.

    Ties in depth go to the least `tie_key` (the GPU uses the shuffled slot), else
    to the least index."""
    pixel, depth = project(camera, xyz, width, height)
    hit = np.nonzero(pixel >= 0)[0]
    key = hit if tie_key is None else np.asarray(tie_key)[hit]
    order = np.lexsort((key, depth[hit], pixel[hit]))
    p = pixel[hit][order]
    first = np.r_[True, p[1:] != p[:-1]] if p.size else np.zeros(0, dtype=bool)
    ids = np.full(width * height, EMPTY, dtype=np.uint32)
    ids[p[first]] = hit[order][first]
    return ids.reshape(height, width)


def subset_reference_ids(xyz: np.ndarray, keep: np.ndarray, camera: Camera, width: int, height: int,
                         tie_key: np.ndarray) -> np.ndarray:
    """reference_ids over the points `keep` (indices into xyz) only, as indices into xyz:
    what a clip box, hidden classes or a memory limit leaves drawn. `tie_key` is of
    every point (the GPU's slots)."""
    keep = np.asarray(keep, dtype=np.int64)
    if keep.size == 0:
        return np.full((height, width), EMPTY, dtype=np.uint32)
    local = reference_ids(np.asarray(xyz)[keep], camera, width, height, tie_key=np.asarray(tie_key)[keep])
    return np.where(local == EMPTY, EMPTY, keep[np.minimum(local, keep.size - 1)]).astype(np.uint32)


def clipped_reference_ids(xyz: np.ndarray, clip: Clip, camera: Camera, width: int, height: int,
                          tie_key: np.ndarray) -> np.ndarray:
    """reference_ids over the points inside `clip` by its float64 test on file
    coordinates (Clip.contains: box and section), as indices into xyz."""
    return subset_reference_ids(xyz, np.nonzero(clip.contains(xyz))[0], camera, width, height, tie_key)


def agreement(a: np.ndarray, b: np.ndarray) -> float:
    """Fraction of pixels whose ids are equal (empty counts as a value)."""
    return float(np.mean(a == b))


def covered_agreement(a: np.ndarray, b: np.ndarray) -> float:
    """Fraction of pixels covered in either image whose ids are equal."""
    covered = (a != EMPTY) | (b != EMPTY)
    return float(np.mean(a[covered] == b[covered])) if covered.any() else 1.0
