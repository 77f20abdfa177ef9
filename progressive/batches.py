"""Batch boxes of the batched layout and the frustum test the rasterizer makes with
them (shaders/camera.glsl box_in_view), GPU-free: a work group whose batch's box is
outside the view skips its points. The box is of the float32 positions relative to
the cloud origin, exactly what the GPU projects."""

from __future__ import annotations

import enum

import numpy as np

from progressive.camera import ViewUniforms
from progressive.loaders.types import Runs, run_edges
from progressive.permutation import BATCH_POINTS

BOX_FLOATS = 8
"""A box on the GPU: min xyz, a pad, max xyz, a pad (two std430 vec4)."""
BOX_MARGIN = 1e-5
"""Relative slack of the test, far above float32 rounding of a corner's projection:
culling may keep a batch that is just outside, never drop one that is inside."""


class BatchOrder(enum.Enum):
    """Which consecutive points make a store batch: the file's own (FILE), or, inside each
    loaded batch, its whole store batches sorted by Morton code first (MORTON): compacter
    boxes where the file's order wanders (bench/results/llvmpipe/compactness.md), for 4
    bytes a point of host memory that map the store's order back to the file's."""

    FILE = "file"
    MORTON = "morton"


BATCH_ORDER = BatchOrder.FILE
"""The renderer's batch order (MORTON is not the default yet: it is unmeasured on a GPU,
and the loaded batch is sorted on the thread that uploads it)."""


MORTON_BITS = 5
"""Bits per axis of the Morton code a loaded batch is sorted by: 32³ cells over its box,
far finer than the few dozen store batches it holds, and a 15-bit code that numpy sorts
by radix (bench/compactness.py times it beside 63-bit codes)."""


def spread3(v: np.ndarray) -> np.ndarray:
    """The low MORTON_BITS bits of each uint16 spread to every third bit."""
    v = v & np.uint16((1 << MORTON_BITS) - 1)
    for shift, mask in ((8, 0x100F), (4, 0x10C3), (2, 0x1249)):
        v = (v | (v << np.uint16(shift))) & np.uint16(mask)
    return v


def morton_order(positions: np.ndarray) -> np.ndarray:
    """Indices sorting points by their 3D Morton code on a grid of cubes over their box
    (one scale, the largest extent); stable, so points of one cell keep file order; rows
    with a coordinate not finite last."""
    xyz = np.asarray(positions)
    finite = np.isfinite(xyz).all(axis=1)
    codes = np.full(xyz.shape[0], np.iinfo(np.uint16).max, dtype=np.uint16)
    if finite.any():
        shown = xyz[finite] if not finite.all() else xyz
        lo = shown.min(axis=0).astype(np.float64)
        extent = max(float((shown.max(axis=0) - lo).max()), np.finfo(np.float64).tiny)
        cells = 1 << MORTON_BITS
        q = [np.minimum((shown[:, a] - lo[a]) * (cells / extent), cells - 1).astype(np.uint16) for a in range(3)]
        codes[finite] = spread3(q[0]) | spread3(q[1]) << np.uint16(1) | spread3(q[2]) << np.uint16(2)
    return np.argsort(codes, kind="stable")


def sorted_rows(start: int, positions: np.ndarray) -> tuple[int, np.ndarray] | None:
    """What BatchOrder.MORTON sorts of a loaded batch whose first point has file index
    `start`: (lo, order), its rows lo.. lo + len(order) being the whole store batches it
    holds (two or more) and `order` theirs by morton_order; None where it holds fewer.
    The store batches it only starts or ends stay in file order: their other rows come in
    another loaded batch."""
    first = -(-start // BATCH_POINTS) * BATCH_POINTS
    end = (start + positions.shape[0]) // BATCH_POINTS * BATCH_POINTS
    if end - first < 2 * BATCH_POINTS:
        return None
    lo = first - start
    return lo, morton_order(positions[lo: lo + end - first])


def glsl_defines() -> str:
    """The box test's constant for every shader (shaders/batches.glsl)."""
    return f"#define BOX_MARGIN {BOX_MARGIN!r}\n"


def empty_boxes(batches: int) -> np.ndarray:
    """(batches, BOX_FLOATS) float32 boxes that hold nothing (min +inf, max -inf): culled."""
    boxes = np.zeros((batches, BOX_FLOATS), dtype=np.float32)
    boxes[:, 0:3], boxes[:, 4:7] = np.inf, -np.inf
    return boxes


def boxes_of(positions: np.ndarray, start: int, finite: bool | None = None) -> tuple[int, np.ndarray]:
    """The first batch that file indices [start, start+n) touch and the boxes of their
    points in each batch touched, (k, BOX_FLOATS); points with a non-finite coordinate
    are left out (they never draw), a batch of only those stays empty. finite: whether
    every coordinate is, where the caller knows (None: tested here)."""
    n = positions.shape[0]
    first = start // BATCH_POINTS
    if n == 0:
        return first, empty_boxes(0)
    edges = run_edges(start, n, BATCH_POINTS)
    p = np.asarray(positions, dtype=np.float32)
    boxes = empty_boxes(edges.size)
    if all_finite(p) if finite is None else finite:     # the common case: no row test (ten times the boxes' cost)
        boxes[:, 0:3] = np.minimum.reduceat(p, edges, axis=0)
        boxes[:, 4:7] = np.maximum.reduceat(p, edges, axis=0)
        return first, boxes
    finite = np.isfinite(p).all(axis=1)
    p = np.where(finite[:, None], p, np.float32(np.nan))    # a point with any coordinate not finite never draws
    with np.errstate(invalid="ignore"):
        boxes[:, 0:3] = np.fmin.reduceat(p, edges, axis=0)
        boxes[:, 4:7] = np.fmax.reduceat(p, edges, axis=0)
    nan = np.isnan(boxes[:, 0])
    boxes[nan] = empty_boxes(int(nan.sum()))
    return first, boxes


def box_runs(positions: np.ndarray, start: int, finite: bool | None = None) -> Runs:
    """boxes_of as the Runs a fast-format batch carries (found on its parser thread)."""
    first, boxes = boxes_of(positions, start, finite)
    return Runs(BATCH_POINTS, first, boxes[:, 0:3], boxes[:, 4:7], start, positions.shape[0])


def boxes_from_runs(runs: Runs) -> np.ndarray:
    """(k, BOX_FLOATS) boxes of box_runs' runs, as boxes_of gives them."""
    boxes = empty_boxes(runs.least.shape[0])
    boxes[:, 0:3], boxes[:, 4:7] = runs.least, runs.most
    return boxes


def all_finite(values: np.ndarray) -> bool:
    """Whether every value is finite, from the least and the greatest (NaN propagates
    through both): two passes, far cheaper than a test per value where the values are
    contiguous."""
    if values.size == 0:
        return True
    with np.errstate(invalid="ignore"):
        return bool(np.isfinite(values.min()) and np.isfinite(values.max()))


def merge(boxes: np.ndarray, first: int, new: np.ndarray) -> None:
    """In place: boxes[first:first+k] grow to hold `new` (a batch may arrive in parts)."""
    part = boxes[first: first + new.shape[0]]
    part[:, 0:3] = np.fmin(part[:, 0:3], new[:, 0:3])
    part[:, 4:7] = np.fmax(part[:, 4:7], new[:, 4:7])


def corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(k, 8, 3) corners of k boxes."""
    pick = np.array([[(c >> a) & 1 for a in range(3)] for c in range(8)], dtype=bool)
    return np.where(pick[None], hi[:, None, :], lo[:, None, :])


def section_meets(boxes: np.ndarray, view: ViewUniforms) -> np.ndarray:
    """Whether each box's XY rectangle can meet the view's section (shaders/cull.comp
    section_meets): the projections on the section's axis and on its normal overlap,
    with BOX_MARGIN of slack (the other two axes of a separating-axis test are left
    out: culling stays conservative). No section: infinite ranges, always true."""
    lo, hi = boxes[:, 0:2].astype(np.float64), boxes[:, 4:6].astype(np.float64)
    line, (start, end, half) = view.section_line.astype(np.float64), view.section_range.astype(np.float64)
    u = line[2:4]
    with np.errstate(invalid="ignore", over="ignore"):
        c, e = 0.5 * (lo + hi) - line[0:2], 0.5 * (hi - lo)
        t, rt = c @ u, e @ np.abs(u)
        d, rd = c[:, 1] * u[0] - c[:, 0] * u[1], e @ np.abs(u[::-1])
        m = (np.maximum(np.abs(lo), np.abs(hi)) + np.abs(line[0:2])).sum(axis=1)   # the magnitudes c was rounded at
        st = BOX_MARGIN * (np.abs(t) + rt + abs(start) + abs(end) + m) + 1e-30
        sd = BOX_MARGIN * (np.abs(d) + rd + half + m) + 1e-30
        return (t + rt >= start - st) & (t - rt <= end + st) & (np.abs(d) - rd <= half + sd)


def least_depths(boxes: np.ndarray, view: ViewUniforms) -> np.ndarray:
    """Each box's least corner depth, padded as in_view pads it (shaders/cull.comp
    depth_min: the adaptive precision's nearest point of the batch)."""
    lo, hi = boxes[:, 0:3].astype(np.float64), boxes[:, 4:7].astype(np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        pad = BOX_MARGIN * ((hi - lo) + np.maximum(np.abs(lo), np.abs(hi))) + 1e-30
        v = corners(lo - pad, hi + pad) @ view.rotation.astype(np.float64).T + view.translation.astype(np.float64)
    return (-v[..., 2]).min(axis=1)


def in_view(boxes: np.ndarray, view: ViewUniforms) -> np.ndarray:
    """Which boxes the GPU's test keeps: no frustum plane (near, far, the four sides)
    has all eight corners of the box, padded by BOX_MARGIN, outside it by more than
    BOX_MARGIN of the terms it compares. Empty boxes, boxes that miss the clip box
    (compared exactly, in float32) and boxes that cannot meet its section are culled."""
    lo, hi = boxes[:, 0:3].astype(np.float64), boxes[:, 4:7].astype(np.float64)
    empty = ~(lo <= hi).all(axis=1)
    empty |= ~((boxes[:, 0:3] <= view.clip_hi).all(axis=1) & (boxes[:, 4:7] >= view.clip_lo).all(axis=1))
    empty |= ~section_meets(boxes, view)
    with np.errstate(invalid="ignore", over="ignore"):
        pad = BOX_MARGIN * ((hi - lo) + np.maximum(np.abs(lo), np.abs(hi))) + 1e-30
        v = corners(lo - pad, hi + pad) @ view.rotation.astype(np.float64).T + view.translation.astype(np.float64)
        depth = -v[..., 2]
        fa, f, near, far = (float(x) for x in view.projection)
        w = depth if view.perspective else np.ones_like(depth)      # the side planes: |x| <= w
        d, aw, x, y = np.abs(depth), np.abs(w), fa * v[..., 0], f * v[..., 1]
        planes = np.stack([depth - near + BOX_MARGIN * (d + near), far - depth + BOX_MARGIN * (d + far),
                           w - x + BOX_MARGIN * (aw + np.abs(x)), w + x + BOX_MARGIN * (aw + np.abs(x)),
                           w - y + BOX_MARGIN * (aw + np.abs(y)), w + y + BOX_MARGIN * (aw + np.abs(y))], axis=-1)
        outside = (planes < 0).all(axis=1).any(axis=1)
    return ~empty & ~outside


def runs(sorted_batches) -> list[tuple[int, int]]:
    """[lo, hi) runs of consecutive numbers in a sorted sequence (batches written or
    emptied together, each run one GPU call)."""
    b = np.asarray(sorted_batches, dtype=np.int64)
    if b.size == 0:
        return []
    cuts = np.flatnonzero(np.diff(b) != 1) + 1
    return [(int(run[0]), int(run[-1]) + 1) for run in np.split(b, cuts)]
