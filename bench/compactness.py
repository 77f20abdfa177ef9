"""Batch compactness (issue 10, step 1): are the store's batches of BATCH_POINTS
consecutive points more compact when each loaded chunk is sorted by Morton code first?
GPU-free (numpy): per data set and ordering rule, the batch boxes the loader would
compute (progressive.batches.boxes_of, float32 relative to the cloud's centre), their
size against the cloud's box, and what the rasterizer's frustum cull
(progressive.batches.in_view) keeps of them for close-up views; and what the sort costs.

    python -m bench.compactness [--data ../shared/data] [--cap 5000000] [--synthetic-points 5000000]
"""

from __future__ import annotations

import argparse
import enum
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np

from bench.data import SHARED
from bench.report import RunInfo, Table
from bench.synthetic import SAMPLE, Order, morton_order, tiled
from progressive.batches import MORTON_BITS as store_bits
from progressive.batches import boxes_of, in_view, sorted_rows
from progressive.batches import morton_order as store_order
from progressive.camera import Camera, Projection, ViewUniforms, view_uniforms
from progressive.loaders.types import BATCH_POINTS as LOADER_POINTS
from progressive.loaders.types import FIRST_BATCH_POINTS
from progressive.permutation import BATCH_POINTS

OUT = Path(__file__).resolve().parent / "results" / "llvmpipe"
MORTON_BITS = 21
"""Bits per axis of the measurement's Morton codes: 63 of a uint64, as bench.synthetic.morton_order
(the store's own sort, progressive/batches.py morton_order, uses fewer: Rule.STORE)."""
VIEW_CELLS = 10
"""A close-up view spans 1/VIEW_CELLS of the cloud's X and Y extent: at each corner, and
VIEW_CELLS² of them tiling the cloud for the mean over every place."""
VIEW_PIXELS = 1000
"""Image height of the close-up views (the width follows the view's aspect)."""
COST_POINTS = 1_000_000
"""Points of the chunk whose Morton sort is timed."""
SCRAMBLE_SEED = 10
"""Seed of the scrambled reference order (a random permutation of the whole cloud)."""


class Grid(enum.Enum):
    """How a chunk's box is quantised for its Morton codes."""

    CUBE = "cube"    # one scale for every axis (the chunk's largest extent): cells are cubes
    AXES = "axes"    # each axis over its own extent, as bench.synthetic.morton_order: a flat chunk's
                     # Z bits weigh as much as X and Y's, so batches become thin slabs across it


class Rule(enum.Enum):
    """How the points are ordered before the store cuts them into batches."""

    FILE = "file"            # the file's own order: today's store
    MORTON = "morton"        # Morton order inside each chunk (the whole cloud where chunk is 0)
    ADAPTIVE = "adaptive"    # Morton order inside a chunk only where its batches' cull cost is smaller
    SCRAMBLED = "scrambled"  # a random permutation: the worst case, a check that the metric can fail
    STORE = "store"          # as the store sorts (batches.BatchOrder.MORTON): each chunk's whole store batches,
                             # by progressive/batches.py morton_order; the batches a chunk only starts or ends stay


@dataclass(frozen=True)
class Arrangement:
    permutation: np.ndarray   # file indices in the order the store would take them
    sorted_chunks: int        # chunks in Morton order
    chunks: int               # chunks a sort was considered for (0: no chunks, file or scrambled order)


def cull_cost(xyz: np.ndarray, pad: np.ndarray) -> float:
    """Σ over the chunk's batches (BATCH_POINTS consecutive points from its start) of their
    box's volume grown by `pad` on each axis: proportional to how many batches a box of
    size `pad` placed at random meets, what a cull keeps for a close-up. The loader knows
    the cloud's box (the header's), so pad can be a share of it at load time."""
    edges = np.arange(0, len(xyz), BATCH_POINTS)
    size = np.maximum.reduceat(xyz, edges, axis=0) - np.minimum.reduceat(xyz, edges, axis=0)
    return float(np.prod(size + pad, axis=1).sum())


@dataclass(frozen=True)
class Ordering:
    """A rule and its chunks: the first chunk of `first` points, then chunks of `chunk`
    (0: one chunk, the whole cloud), as a loader yields batches of a file."""

    label: str
    rule: Rule
    first: int = 0
    chunk: int = 0
    grid: Grid = Grid.CUBE

    def arrange(self, xyz: np.ndarray) -> Arrangement:
        """File indices in this order, and how many chunks were sorted."""
        n = xyz.shape[0]
        if self.rule is Rule.FILE:
            return Arrangement(np.arange(n), 0, 0)
        if self.rule is Rule.SCRAMBLED:
            return Arrangement(np.random.default_rng(SCRAMBLE_SEED).permutation(n), 0, 0)
        pad = (xyz.max(axis=0) - xyz.min(axis=0)) / VIEW_CELLS
        parts, sorted_chunks, bounds = [], 0, list(self.chunks(n))
        if self.rule is Rule.STORE:
            for lo, hi in bounds:
                order = np.arange(hi - lo)
                rows = sorted_rows(lo, xyz[lo:hi].astype(np.float32))
                if rows is not None:
                    at, inner = rows
                    order[at: at + inner.shape[0]] = at + inner
                    sorted_chunks += 1
                parts.append(lo + order)
            return Arrangement(np.concatenate(parts), sorted_chunks, len(bounds))
        for lo, hi in bounds:
            order = morton_sort(xyz[lo:hi], self.grid)
            if self.rule is Rule.ADAPTIVE and cull_cost(xyz[lo:hi], pad) <= cull_cost(xyz[lo:hi][order], pad):
                order = np.arange(hi - lo)
            else:
                sorted_chunks += 1
            parts.append(lo + order)
        return Arrangement(np.concatenate(parts), sorted_chunks, len(bounds))

    def chunks(self, n: int) -> Iterator[tuple[int, int]]:
        if not self.chunk:
            yield 0, n
            return
        lo, size = 0, self.first or self.chunk
        while lo < n:
            yield lo, min(n, lo + size)
            lo, size = lo + size, self.chunk

    @property
    def chunk_label(self) -> str:
        if self.rule not in (Rule.MORTON, Rule.ADAPTIVE, Rule.STORE):
            return ""
        if not self.chunk:
            return "whole cloud"
        size = f"{self.chunk:,}" if self.first in (0, self.chunk) else f"{self.first:,} then {self.chunk:,}"
        return size + (", whole store batches" if self.aligned else "")

    @property
    def aligned(self) -> bool:
        """Whether every chunk holds whole store batches: none straddles two chunks."""
        return self.first % BATCH_POINTS == 0 and self.chunk % BATCH_POINTS == 0

    @property
    def name(self) -> str:
        return f"{self.label} ({self.chunk_label})" if self.chunk else self.label


def whole_batches(points: int) -> int:
    """`points` rounded to whole store batches: a chunk a loader cut so that no batch straddles two."""
    return max(1, round(points / BATCH_POINTS)) * BATCH_POINTS


ALIGNED_FIRST, ALIGNED_CHUNK = whole_batches(FIRST_BATCH_POINTS), whole_batches(LOADER_POINTS)
"""The loader's batches cut at whole store batches, as a loader that sorts them would cut them."""

CHUNKS = ((100_000, 100_000), (FIRST_BATCH_POINTS, LOADER_POINTS), (1_000_000, 1_000_000))
"""(first, then) chunk sizes: fixed ones and the loader's LAS/LAZ batches."""

ORDERINGS = (
    Ordering("file order", Rule.FILE),
    *(Ordering("Morton", Rule.MORTON, first, chunk) for first, chunk in CHUNKS),
    *(Ordering("Morton", Rule.MORTON, whole_batches(first), whole_batches(chunk)) for first, chunk in CHUNKS),
    Ordering("Morton, per-axis grid", Rule.MORTON, ALIGNED_FIRST, ALIGNED_CHUNK, Grid.AXES),
    Ordering("Morton where it culls better", Rule.ADAPTIVE, ALIGNED_FIRST, ALIGNED_CHUNK),
    Ordering("Morton as the store sorts (BatchOrder.MORTON)", Rule.STORE, FIRST_BATCH_POINTS, LOADER_POINTS),
    Ordering("Morton, whole cloud (reference)", Rule.MORTON),
    Ordering("scrambled (reference)", Rule.SCRAMBLED),
)


def spread3(v: np.ndarray) -> np.ndarray:
    """The low 21 bits of each uint64 spread to every third bit (the usual magic masks):
    a Morton code in 5 shifts an axis where a bit loop takes 63."""
    v = v & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


def morton_codes(xyz: np.ndarray, grid: Grid = Grid.CUBE) -> np.ndarray:
    """3D Morton codes on a 2^21 grid over the points' own box, bit 3b+axis as
    bench.synthetic.morton_order (with Grid.AXES, sorting them gives its order)."""
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    ext = np.maximum(hi - lo, 1e-12)
    q = ((xyz - lo) / (ext if grid is Grid.AXES else ext.max()) * (2**MORTON_BITS - 1)).astype(np.uint64)
    return spread3(q[:, 0]) | spread3(q[:, 1]) << np.uint64(1) | spread3(q[:, 2]) << np.uint64(2)


def morton_sort(xyz: np.ndarray, grid: Grid = Grid.CUBE) -> np.ndarray:
    """Indices sorting a chunk by Morton code (stable: ties keep file order)."""
    return np.argsort(morton_codes(xyz, grid), kind="stable") if len(xyz) else np.arange(0)


@dataclass(frozen=True)
class Cloud:
    name: str
    kind: str
    xyz: np.ndarray       # (n, 3) float64 in file order, relative to the centre of its box


def centred(name: str, kind: str, xyz: np.ndarray) -> Cloud:
    xyz = np.asarray(xyz, dtype=np.float64)
    return Cloud(name, kind, xyz - (xyz.min(axis=0) + xyz.max(axis=0)) / 2)


def real_clouds(folder: Path, cap: int) -> tuple[list[Cloud], list[str]]:
    """Each LAS/LAZ of `folder` (its first `cap` points) and a line for each one skipped."""
    clouds, skipped = [], []
    for path in sorted(p for p in folder.glob("*") if p.suffix.lower() in (".las", ".laz")):
        try:
            with laspy.open(path) as f:
                n = min(f.header.point_count, cap)
                points = f.read_points(n)
            xyz = np.stack([np.asarray(points.x), np.asarray(points.y), np.asarray(points.z)], axis=1)
        except Exception as e:   # a file laspy cannot read is reported, not fatal
            skipped.append(f"{path.name}: {type(e).__name__}: {e}")
            continue
        if n < 2:
            skipped.append(f"{path.name}: {n} points")
            continue
        clouds.append(centred(path.name, "real file" + (f", first {n:,}" if n == cap else ""), xyz))
    return clouds, skipped


def synthetic_cloud(points: int, order: Order) -> Cloud:
    """bench.synthetic's tiled sample in `order`, as the benchmarks stream it."""
    cloud = tiled(str(SAMPLE), points)
    rec = np.concatenate([r for _, r in cloud.batches(order)])
    return centred(f"{SAMPLE.name} tiled", f"synthetic, {order.value} order", rec[:, :3].view(np.float32))


def grid_views(xyz: np.ndarray) -> dict[tuple[int, int], ViewUniforms]:
    """Orthographic top views tiling the cloud's XY box in VIEW_CELLS × VIEW_CELLS cells,
    by cell (i, j): each 1/VIEW_CELLS of the box's X and Y extent across, seeing all of Z."""
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    ext = np.maximum(hi - lo, 1e-9)
    side = ext[:2] / VIEW_CELLS
    width = max(1, round(VIEW_PIXELS * side[0] / side[1]))
    depth = float(np.linalg.norm(ext))
    views = {}
    for i in range(VIEW_CELLS):
        for j in range(VIEW_CELLS):
            cx, cy = lo[:2] + (np.array([i, j]) + 0.5) * side
            camera = Camera(position=(cx, cy, hi[2] + depth), target=(cx, cy, lo[2]), up=(0.0, 1.0, 0.0),
                            near=0.5 * depth, far=2.5 * depth, projection=Projection.ORTHOGRAPHIC,
                            height=float(side[1]))
            views[i, j] = view_uniforms(camera, np.zeros(3), width, VIEW_PIXELS)
    return views


def corner_keys() -> list[tuple[int, int]]:
    """The cells of the four views at the box's corners."""
    last = VIEW_CELLS - 1
    return [(i, j) for i in (0, last) for j in (0, last)]


def points_in_view(xyz: np.ndarray, view: ViewUniforms) -> np.ndarray:
    """Which points the view's frustum holds (float64, the same uniforms as the cull)."""
    v = xyz @ view.rotation.astype(np.float64).T + view.translation.astype(np.float64)
    fa, f, near, far = (float(x) for x in view.projection)
    depth = -v[:, 2]
    w = depth if view.perspective else 1.0
    return (np.abs(fa * v[:, 0]) <= w) & (np.abs(f * v[:, 1]) <= w) & (depth >= near) & (depth <= far)


@dataclass(frozen=True)
class Score:
    batches: int
    mean_diagonal: float      # of the batch boxes, relative to the cloud box's diagonal
    p95_diagonal: float
    volume: float             # summed batch box volume / the cloud box's volume
    area: float               # summed batch box XY area / the cloud box's XY area
    kept: float               # share of batches the corner views keep (mean over the four)
    kept_grid: float          # share of batches kept, mean over the views tiling the cloud


def score(xyz: np.ndarray, perm: np.ndarray, views: dict[tuple[int, int], ViewUniforms]) -> Score:
    """The batches of BATCH_POINTS consecutive points of xyz[perm], boxed as the store boxes them."""
    _, boxes = boxes_of(xyz[perm].astype(np.float32), 0, finite=True)
    size = boxes[:, 4:7].astype(np.float64) - boxes[:, 0:3]
    ext = xyz.max(axis=0) - xyz.min(axis=0)
    diagonal = np.linalg.norm(size, axis=1) / np.linalg.norm(ext)
    volume = np.prod(size, axis=1).sum() / np.prod(ext) if np.prod(ext) > 0 else float("nan")
    area = np.prod(size[:, :2], axis=1).sum() / np.prod(ext[:2]) if np.prod(ext[:2]) > 0 else float("nan")
    kept = {key: float(in_view(boxes, v).mean()) for key, v in views.items()}
    corners = float(np.mean([kept[key] for key in corner_keys()]))
    return Score(len(boxes), float(diagonal.mean()), float(np.percentile(diagonal, 95)), float(volume),
                 float(area), corners, float(np.mean(list(kept.values()))))


def best_of(repeats: int, fn) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def sort_cost(xyz: np.ndarray, repeats: int) -> dict[str, float]:
    """Seconds (best of `repeats`) to Morton-sort one chunk and to apply its permutation
    to the chunk's 16-byte GPU records, as a loader would before handing the batch on."""
    records = np.zeros((len(xyz), 4), dtype=np.uint32)
    perm = morton_sort(xyz)
    return {"points": len(xyz), "load": os.getloadavg()[0],
            "codes_s": best_of(repeats, lambda: morton_codes(xyz)),
            "sort_s": best_of(repeats, lambda: morton_sort(xyz)),
            "bit_loop_sort_s": best_of(repeats, lambda: morton_order(xyz, MORTON_BITS)),
            "store_sort_s": best_of(repeats, lambda: store_order(xyz.astype(np.float32))),
            "permute_records_s": best_of(repeats, lambda: records[perm])}


COLUMNS = ("data set", "kind", "points", "batches", "rule", "chunk points", "chunks sorted",
           "mean batch diagonal, % of cloud's", "p95 batch diagonal, %", "Σ batch box volume / cloud box", "Σ batch XY area / cloud XY area",
           "points in a corner view, %", "batches kept by the cull there, %",
           f"batches kept, mean over {VIEW_CELLS}×{VIEW_CELLS} views, %")


def run(clouds: list[Cloud], orderings: tuple[Ordering, ...] = ORDERINGS, cost: dict | None = None,
        skipped: tuple[str, ...] = ()) -> Table:
    table = Table("compactness", "Batch compactness: file order against Morton order inside each loaded chunk",
                  ", ".join(dict.fromkeys(c.name for c in clouds)), f"{sum(len(c.xyz) for c in clouds):,} in all",
                  COLUMNS)
    raw = []
    for c in clouds:
        views = grid_views(c.xyz)
        share = float(np.mean([points_in_view(c.xyz, views[key]).mean() for key in corner_keys()]))
        scores = {}
        for o in orderings:
            a = o.arrange(c.xyz)
            s = score(c.xyz, a.permutation, views)
            scores[o] = s
            sorted_label = f"{a.sorted_chunks} of {a.chunks}" if a.chunks else ""
            table.rows.append((c.name, c.kind, len(c.xyz), s.batches, o.label, o.chunk_label, sorted_label,
                               100 * s.mean_diagonal, 100 * s.p95_diagonal, s.volume, s.area, 100 * share,
                               100 * s.kept, 100 * s.kept_grid))
            raw.append({"data": c.name, "kind": c.kind, "points": len(c.xyz), "rule": o.rule, "first": o.first,
                        "chunk": o.chunk, "grid": o.grid,
                        "label": o.label, "sorted_chunks": a.sorted_chunks, "chunks": a.chunks, "points_in_view": share, **vars(s)})
        table.notes.append(verdict(c, scores))
    table.notes[:0] = notes(cost, skipped)
    table.raw = {"rows": raw, "cost": cost, "skipped": list(skipped), "batch_points": BATCH_POINTS,
                 "view_cells": VIEW_CELLS, "morton_bits": MORTON_BITS, "scramble_seed": SCRAMBLE_SEED}
    return table


def verdict(c: Cloud, scores: dict[Ordering, Score]) -> str:
    """One line a data set: the batches a close-up keeps (the mean over the grid of views)
    under the loader's batches sorted as they are and at whole store batches, the best
    chunked rule and the whole-cloud sort, against file order."""
    file = next(s for o, s in scores.items() if o.rule is Rule.FILE)
    if file.batches < 2:
        return f"- {c.name} ({c.kind}): one batch, nothing to order."
    chunked = {o: s for o, s in scores.items() if o.rule in (Rule.MORTON, Rule.ADAPTIVE) and o.chunk}
    best = min(chunked, key=lambda o: chunked[o].kept_grid)
    loader = [o for o in chunked if o.rule is Rule.MORTON and o.grid is Grid.CUBE and o.chunk
              in (LOADER_POINTS, ALIGNED_CHUNK)]
    whole = [o for o, s in scores.items() if o.rule is Rule.MORTON and not o.chunk]
    parts = [f"{o.name} {100 * scores[o].kept_grid:.1f} % ({ratio(scores[o].kept_grid, file.kept_grid)}"
             + (", the best chunked rule)" if o is best else ")") for o in dict.fromkeys([*loader, best, *whole])]
    return (f"- {c.name} ({c.kind}, {file.batches:,} batches): file order {100 * file.kept_grid:.1f} %; "
            + "; ".join(parts) + ".")


def ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}×" if b > 0 else "file order's is 0"


def notes(cost: dict | None, skipped: tuple[str, ...]) -> list[str]:
    lines = [
        (f"Each data set's points are cut, in the rule's order, into batches of BATCH_POINTS = {BATCH_POINTS:,} "
         "consecutive points (progressive/permutation.py), and each batch is boxed as the store boxes it "
         "(progressive.batches.boxes_of, float32 positions relative to the centre of the cloud's box). Diagonals "
         "are 3D, relative to the cloud box's diagonal; volume and XY area are summed over the batches and divided "
         "by the cloud box's (1.00 would tile the box once; overlapping boxes sum above it)."),
        (f"Rules: file order (today); Morton order (3D, {MORTON_BITS} bits an axis, stable) inside each chunk of "
         "the file, on a grid of cubes over the chunk's box (one scale, its largest extent) or, in the per-axis "
         "rows, on bench.synthetic.morton_order's grid (each axis over its own extent). Chunks are counted from "
         "the file's first point: fixed sizes, and the loader's LAS/LAZ batches (FIRST_BATCH_POINTS = "
         f"{FIRST_BATCH_POINTS:,}, then BATCH_POINTS = {LOADER_POINTS:,}, progressive/loaders/types.py), each "
         "as it is, where one store batch straddles every chunk boundary, and rounded to the nearest whole "
         f"number of store batches ('whole store batches': {ALIGNED_FIRST:,} then {ALIGNED_CHUNK:,} for the "
         "loader's), where none does. A chunk as large as the cloud is the whole-cloud sort. 'Where it culls "
         "better': a chunk is sorted only where that lowers the sum over its batches of the box's volume grown "
         f"on each axis by 1/{VIEW_CELLS} of the cloud box's extent (a loader knows the cloud's box from the "
         "header), which is proportional to how many of its batches a close-up box of that size placed at random "
         "meets. References: Morton order over the whole cloud (no chunk boundaries) and a random permutation "
         f"(seed {SCRAMBLE_SEED}: the worst case)."),
        (f"Cull: orthographic top views 1/{VIEW_CELLS} of the cloud box's X and Y extent across, holding its "
         f"whole Z range, {VIEW_CELLS}×{VIEW_CELLS} of them tiling the box; a batch is kept where "
         "progressive.batches.in_view (the GPU's box test) keeps its box. Corner: the mean over the four views at "
         "the box's corners, beside the share of points those views hold (the same for every rule: what an ideal "
         "layout would read; the batches kept are what the rasterizer reads). Grid: the mean over every view, "
         f"where the points in view average about 1/{VIEW_CELLS**2} of the cloud."),
        ("Real files: every LAS/LAZ in ../shared/data (MANIFEST.md), read with laspy in file order (COPC files "
         "in their node order, as a plain LAZ reader yields them). Synthetic: bench/synthetic.py's bundled sample "
         "tiled on a grid, tiles row by row, points in the sample's file order or in scan order (a scanner station "
         "per tile, vertical scan lines by azimuth)."),
    ]
    if cost:
        lines.append(
            f"Cost (best of {cost['repeats']}, numpy {np.__version__}, one thread, {os.cpu_count()} cores shared "
            f"with other work, load average {cost['load']:.1f} before; on {cost['data']}'s first "
            f"{cost['points']:,} points): Morton codes {cost['codes_s']:.3f} s, codes and stable argsort "
            f"{cost['sort_s']:.3f} s, bench.synthetic.morton_order's bit loop (per-axis grid) {cost['bit_loop_sort_s']:.3f} s, "
            f"the store's own order (progressive.batches.morton_order, {store_bits} bits an axis) "
            f"{cost['store_sort_s']:.3f} s; "
            f"applying the permutation to the chunk's 16-byte records {cost['permute_records_s']:.3f} s.")
    lines += [f"Skipped: {s}." for s in skipped]
    lines.append(f"Per data set, from the rows below: batches kept by a close-up (the mean over the "
                 f"{VIEW_CELLS}×{VIEW_CELLS} views), and × file order's:")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.compactness", description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=SHARED, help="folder of real LAS/LAZ files")
    ap.add_argument("--cap", type=int, default=5_000_000, help="points read from each real file at most")
    ap.add_argument("--synthetic-points", type=int, default=5_000_000)
    ap.add_argument("--cost-points", type=int, default=COST_POINTS)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    clouds, skipped = real_clouds(args.data, args.cap) if args.data.is_dir() else ([], [f"{args.data}: no folder"])
    clouds += [synthetic_cloud(args.synthetic_points, order) for order in (Order.FILE, Order.SCAN)]
    source = clouds[-2]
    cost = {**sort_cost(source.xyz[:args.cost_points], args.repeats), "repeats": args.repeats,
            "data": f"{source.name} ({source.kind})"}
    table = run(clouds, ORDERINGS, cost, tuple(skipped))
    info = RunInfo.cpu_only(f"cap {args.cap:,} points a file, synthetic {args.synthetic_points:,}")
    table.write(args.out, info)
    print(table.markdown(info))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
