"""Which COPC nodes a view needs: the nodes whose points are farthest apart on screen
first, within a point budget.

A node's screen-space error is its spacing (the distance between its points: the file's
root spacing halved at each level) projected at its nearest distance to the eye, in
pixels; a node wholly behind the eye, or (where the view knows its up direction and
aspect) wholly beyond a side of the image, has none. Nodes are taken greedily, the largest
error first, a node only once its parent is taken (so the kept set is a tree cut from
the root and, since a child does not repeat its parent's points, a set without
duplicates), until the next one does not fit or its error is below the finest detail
asked for (a screen-space error threshold, as Potree and 3D Tiles have; finer nodes
still change which point a pixel shows). A child's
error is at most half its parent's, so the order is also the one of every node sorted by
error. Ties go to the shallower node, then the lower file index and key: the same inputs
give the same nodes.

Plain numbers and arrays only (no camera objects): the loaders stand below the core.
"""

from __future__ import annotations

import functools
import heapq
import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class View:
    """What the node choice needs of a camera, in the files' coordinates: the eye, the
    direction it looks, the image height in pixels and either the vertical field of view
    (perspective) or the world height the image spans (orthographic); with `up` and
    `aspect` (width over height) also the sides of the image, so nodes off screen rank
    last. Without them only what is behind the eye does."""

    position: tuple[float, float, float]
    forward: tuple[float, float, float]
    image_height: int
    fov_y_deg: float | None = 60.0
    ortho_height: float | None = None
    up: tuple[float, float, float] | None = None
    aspect: float | None = None

    def __post_init__(self) -> None:
        if (self.fov_y_deg is None) == (self.ortho_height is None):
            raise ValueError("a view has a field of view (perspective) or an orthographic height, not both")
        if not (all(map(math.isfinite, self.position)) and all(map(math.isfinite, self.forward))):
            raise ValueError("a view's position and forward must be finite")
        if not any(self.forward):
            raise ValueError("a view's forward is zero")
        if self.image_height < 1:
            raise ValueError("a view's image height must be at least 1 pixel")
        if self.fov_y_deg is not None and not 0 < self.fov_y_deg < 180:
            raise ValueError("a view's field of view must be in (0, 180) degrees")
        if self.ortho_height is not None and not (math.isfinite(self.ortho_height) and self.ortho_height > 0):
            raise ValueError("a view's orthographic height must be a positive number")
        if (self.up is None) != (self.aspect is None):
            raise ValueError("a view's sides need both its up direction and its aspect")
        if self.aspect is not None and not (math.isfinite(self.aspect) and self.aspect > 0):
            raise ValueError("a view's aspect must be a positive number")
        if self.up is not None and not all(map(math.isfinite, self.up)):
            raise ValueError("a view's up must be finite")

    def side_planes(self) -> list[tuple[np.ndarray, float]] | None:
        """The image's four sides as (n, c): a point p is on the image's side of one where
        (p - eye)·n + c >= 0. None where the sides are unknown, or up is along forward."""
        if self.up is None:
            return None
        f = np.asarray(self.forward, np.float64)
        f = f / np.linalg.norm(f)
        r = np.cross(f, np.asarray(self.up, np.float64))
        if not np.linalg.norm(r) > 1e-9:
            return None
        r /= np.linalg.norm(r)
        u = np.cross(r, f)
        if self.ortho_height is not None:
            half_h = self.ortho_height / 2.0
            half_w = half_h * self.aspect
            return [(-r, half_w), (r, half_w), (-u, half_h), (u, half_h)]
        tan_y = math.tan(math.radians(self.fov_y_deg) / 2.0)
        tan_x = tan_y * self.aspect
        return [(tan_x * f - r, 0.0), (tan_x * f + r, 0.0), (tan_y * f - u, 0.0), (tan_y * f + u, 0.0)]

    def pixels_per_unit(self, distance: np.ndarray) -> np.ndarray:
        """Pixels one world unit spans at each `distance` from the eye (inf at 0)."""
        if self.ortho_height is not None:
            return np.full(np.shape(distance), self.image_height / self.ortho_height)
        span = 2.0 * math.tan(math.radians(self.fov_y_deg) / 2.0)
        with np.errstate(divide="ignore"):
            return self.image_height / (span * np.asarray(distance, np.float64))


@dataclass(frozen=True)
class Nodes:
    """The nodes to choose from, one row each: the file they belong to (its index), their
    key, points, cube (least corner and side) and spacing."""

    file: np.ndarray          # int
    level: np.ndarray         # int
    key: np.ndarray           # (n, 3) int: x, y, z
    points: np.ndarray        # int64
    lo: np.ndarray            # (n, 3) float64
    side: np.ndarray          # float64
    spacing: np.ndarray       # float64

    @classmethod
    def of_files(cls, files) -> Nodes:
        """The nodes of files given as (center, halfsize, root spacing, ENTRY rows)."""
        parts = []
        for i, (center, halfsize, spacing, entries) in enumerate(files):
            level = entries["level"].astype(np.int64)
            key = np.stack([entries[a] for a in "xyz"], axis=1).astype(np.int64)
            side = 2.0 * halfsize / np.exp2(level)
            lo = np.asarray(center, np.float64) - halfsize + key * side[:, None]
            parts.append((np.full(level.size, i), level, key, entries["point_count"].astype(np.int64), lo, side,
                          spacing / np.exp2(level)))
        return cls(*(np.concatenate(column) for column in zip(*parts)))

    @functools.cached_property
    def corners(self) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
        """Each axis's least and greatest cube coordinate, as contiguous columns: errors()
        works axis by axis over them (over the rows of an (n, 3) array numpy loops three
        elements at a time: 33 of a plan's 57 ms for 87,381 nodes on a 2-core Xeon)."""
        lo = tuple(np.ascontiguousarray(self.lo[:, a]) for a in range(3))
        return lo, tuple(least + self.side for least in lo)

    def errors(self, view: View) -> np.ndarray:
        """Each node's screen-space error in pixels for `view` (0 wholly behind the eye,
        beyond a side of the image or without a spacing; inf for a node the eye is in)."""
        lo, hi = self.corners
        eye = tuple(map(float, view.position))
        gaps = [np.minimum(np.maximum(e, a), b) - e for e, a, b in zip(eye, lo, hi)]   # to the nearest point
        nearest = np.sqrt(gaps[0] * gaps[0] + gaps[1] * gaps[1] + gaps[2] * gaps[2])
        ahead = self._farthest(np.asarray(view.forward, np.float64), eye) >= 0
        for n, c in view.side_planes() or ():
            # the cube's corner farthest along n: on screen's side of the plane, or none is
            ahead &= self._farthest(n, eye) + c >= 0
        with np.errstate(invalid="ignore"):
            return np.where(ahead & (self.spacing > 0), self.spacing * view.pixels_per_unit(nearest), 0.0)

    def _farthest(self, n: np.ndarray, eye: tuple[float, ...]) -> np.ndarray:
        """(corner - eye)·n of each cube's corner farthest along n: per axis the greater
        cube end where n points up that axis, else the lesser (the greater product, as
        rounding keeps order)."""
        lo, hi = self.corners
        terms = [((b if k >= 0 else a) - e) * k for a, b, e, k in zip(lo, hi, eye, map(float, n))]
        return (terms[0] + terms[1]) + terms[2]

    def parents(self) -> np.ndarray:
        """Each node's parent row (its nearest ancestor among the rows: a node without
        points is not listed), -1 for a root."""
        index = {(int(f), int(d), *map(int, k)): i for i, (f, d, k) in enumerate(zip(self.file, self.level, self.key))}
        parent = np.full(self.level.size, -1, np.int64)
        for i, (f, d, k) in enumerate(zip(self.file.tolist(), self.level.tolist(), self.key.tolist())):
            for up in range(1, d + 1):
                found = index.get((f, d - up, k[0] >> up, k[1] >> up, k[2] >> up))
                if found is not None:
                    parent[i] = found
                    break
        return parent


def choose(nodes: Nodes, view: View, budget: int, parent: np.ndarray | None = None,
           errors: np.ndarray | None = None, order: np.ndarray | None = None, finest_px: float = 0.0) -> np.ndarray:
    """Rows of the nodes kept for `view` within `budget` points, ascending: every root
    (even past the budget: there is nothing coarser to show), then greedily by error
    down to `finest_px` (0: as far as the budget goes; a node on screen whose points lie
    closer than that is left out, and its subtree with it).
    parent, errors, order: nodes.parents(), nodes.errors(view) and the rows by
    decreasing error, ties by rank_of(nodes), where the caller has them (a choice made
    every time the camera moves need not find them anew)."""
    finest_px = finest_detail(finest_px)
    errors = nodes.errors(view) if errors is None else errors
    parent = nodes.parents() if parent is None else parent
    root = parent < 0
    up = np.where(root, np.arange(parent.size), parent)
    if np.all(errors <= errors[up]):
        # No child outranks its parent (its cube lies in the parent's, its spacing is half:
        # always so for Nodes.of_files; a tie goes to the parent's lower level), so the
        # greedy order below is the whole order by the same keys: its prefix that fits.
        order = np.lexsort((rank_of(nodes), -errors)) if order is None else order
        rest = order[~root[order]]
        fits = (int(nodes.points[root].sum()) + np.cumsum(nodes.points[rest]) <= budget) & (errors[rest] >= finest_px)
        taken = rest[: fits.size if fits.all() else int(np.argmin(fits))]
        return np.sort(np.concatenate([np.nonzero(root)[0], taken]).astype(np.int64))
    children: dict[int, list[int]] = {}
    for i, p in enumerate(parent.tolist()):
        children.setdefault(p, []).append(i)

    def entry(i: int) -> tuple:
        return (-errors[i], int(nodes.level[i]), int(nodes.file[i]), *map(int, nodes.key[i]), i)

    kept = children.get(-1, [])
    total = int(nodes.points[kept].sum())
    frontier = [entry(c) for r in kept for c in children.get(r, [])]
    heapq.heapify(frontier)
    kept = list(kept)
    while frontier:
        i = frontier[0][-1]
        if total + int(nodes.points[i]) > budget or errors[i] < finest_px:
            break
        heapq.heappop(frontier)
        kept.append(i)
        total += int(nodes.points[i])
        for c in children.get(i, []):
            heapq.heappush(frontier, entry(c))
    return np.sort(np.asarray(kept, np.int64))


def finest_detail(px: float) -> float:
    """`px` as choose's finest detail: a number of pixels, 0 or more."""
    if not (math.isfinite(px) and px >= 0):
        raise ValueError("the finest detail must be a number of pixels, 0 or more")
    return float(px)


def rank_of(nodes: Nodes) -> np.ndarray:
    """Each node's place in the order of the ties: shallower first, then the lower file
    index and key (a permutation of the rows)."""
    rank = np.empty(nodes.level.size, np.int64)
    rank[np.lexsort((nodes.key[:, 2], nodes.key[:, 1], nodes.key[:, 0], nodes.file, nodes.level))] = \
        np.arange(nodes.level.size)
    return rank
