"""The COPC node choice for a view (loaders/copc_choice.py) against a brute-force numpy
reference on synthetic octrees: every node's screen-space error from its 8 corners,
every node sorted by it, the longest prefix within the budget and down to the finest
detail; and the properties the
choice promises (a tree cut from the root, within the budget, the same for the same
inputs whatever their order, deeper near the camera)."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from progressive.loaders.copc import ENTRY
from progressive.loaders.copc_choice import Nodes, View, choose

CORNERS = np.array(list(itertools.product((0, 1), repeat=3)), np.float64)


def octree(rng, levels: int, keep: float, files: int = 1) -> tuple[Nodes, list]:
    """Random octrees (each child present with probability `keep`), random point counts
    and cubes; (their Nodes, the (center, halfsize, spacing, entries) of each file)."""
    described = []
    for _ in range(files):
        keys, frontier = [(0, 0, 0, 0)], [(0, 0, 0, 0)]
        while frontier:
            d, x, y, z = frontier.pop()
            if d + 1 >= levels:
                continue
            for dx, dy, dz in itertools.product((0, 1), repeat=3):
                if rng.random() < keep:
                    child = (d + 1, 2 * x + dx, 2 * y + dy, 2 * z + dz)
                    keys.append(child)
                    frontier.append(child)
        entries = np.zeros(len(keys), ENTRY)
        for name, column in zip(("level", "x", "y", "z"), zip(*keys)):
            entries[name] = column
        entries["point_count"] = rng.integers(1, 5000, len(keys))
        half = float(rng.uniform(1, 100))
        described.append((tuple(rng.uniform(-1000, 1000, 3)), half, half / 64 * rng.uniform(0.5, 2), entries))
    return Nodes.of_files(described), described


def on_screen(view: View, corners: np.ndarray) -> bool:
    """Whether a cube (its 8 corners) may meet the image: not all its corners beyond one
    side, in the camera's frame (x right, y up, z ahead); always without sides."""
    if view.up is None:
        return True
    f = np.asarray(view.forward, np.float64) / np.linalg.norm(view.forward)
    r = np.cross(f, view.up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    d = corners - np.asarray(view.position)
    x, y, z = d @ r, d @ u, d @ f
    if view.ortho_height is not None:
        half_x = half_y = view.ortho_height / 2
        half_x *= view.aspect
    else:
        half_y = z * math.tan(math.radians(view.fov_y_deg) / 2)
        half_x = half_y * view.aspect
    return not ((x > half_x).all() or (x < -half_x).all() or (y > half_y).all() or (y < -half_y).all())


def reference(described, view: View, budget: int, finest_px: float = 0.0) -> set:
    """(file, level, x, y, z) of the nodes kept, brute force: cubes from the keys, the
    nearest distance per axis, ahead from the 8 corners, all nodes sorted, taken until
    one does not fit or its error is below finest_px."""
    rows = []
    for f, (center, half, spacing, entries) in enumerate(described):
        for e in entries:
            d = int(e["level"])
            side = 2 * half / 2 ** d
            lo = np.asarray(center) - half + side * np.array([e["x"], e["y"], e["z"]], np.float64)
            eye = np.asarray(view.position, np.float64)
            gap = np.maximum(np.maximum(lo - eye, 0), eye - (lo + side))
            distance = math.sqrt(float(gap @ gap))
            corners = lo + side * CORNERS
            ahead = ((corners - eye) @ np.asarray(view.forward)).max() >= 0 and on_screen(view, corners)
            if view.ortho_height is not None:
                per_unit = view.image_height / view.ortho_height
            else:
                span = 2 * math.tan(math.radians(view.fov_y_deg) / 2)
                per_unit = math.inf if distance == 0 else view.image_height / (span * distance)
            error = spacing / 2 ** d * per_unit if ahead else 0.0
            rows.append((-error, d, f, int(e["x"]), int(e["y"]), int(e["z"]), int(e["point_count"])))
    rows.sort()
    roots = [r for r in rows if r[1] == 0]
    total = sum(r[-1] for r in roots)
    kept = {r[1:6] for r in roots}
    for r in rows:
        if r[1] == 0:
            continue
        if total + r[-1] > budget or -r[0] < finest_px:
            break
        kept.add(r[1:6])
        total += r[-1]
    return kept


def keys_of(nodes: Nodes, rows: np.ndarray) -> set:
    return {(int(nodes.level[i]), int(nodes.file[i]), *map(int, nodes.key[i])) for i in rows}


def random_view(rng, described, ortho: bool, sides: bool = False) -> View:
    center, half = np.asarray(described[0][0]), described[0][1]
    eye = center + rng.uniform(-1.5, 1.5, 3) * half
    forward = tuple((center + rng.uniform(-1, 1, 3) * half - eye).tolist())
    frame = {"up": tuple(rng.normal(size=3).tolist()), "aspect": float(rng.uniform(0.3, 3))} if sides else {}
    if ortho:
        return View(tuple(eye.tolist()), forward, int(rng.integers(50, 2000)), None, float(rng.uniform(1, 300)), **frame)
    return View(tuple(eye.tolist()), forward, int(rng.integers(50, 2000)), float(rng.uniform(10, 120)), **frame)


@pytest.mark.parametrize("sides", [False, True], ids=["behind the eye", "off the image's sides"])
@pytest.mark.parametrize("seed", range(12))
def test_choice_equals_the_brute_force_reference(seed, sides):
    """Without the image's sides a node ranks last only behind the eye; with them (up
    and aspect) also wholly beyond a side, tested from its 8 corners in the camera's frame."""
    rng = np.random.default_rng(seed)
    nodes, described = octree(rng, levels=int(rng.integers(2, 6)), keep=float(rng.uniform(0.3, 0.9)),
                              files=int(rng.integers(1, 3)))
    total = int(nodes.points.sum())
    for ortho in (False, True):
        view = random_view(rng, described, ortho, sides)
        errors = nodes.errors(view)
        finite = errors[(errors > 0) & np.isfinite(errors)]
        finest = [0.0, float(rng.choice(finite)) if finite.size else 1.0, 1e-9]
        for budget, finest_px in itertools.product((0, *rng.integers(0, total, 4).tolist(), total), finest):
            rows = choose(nodes, view, budget, finest_px=finest_px)
            assert keys_of(nodes, rows) == {(d, f, x, y, z) for d, f, x, y, z in
                                            reference(described, view, budget, finest_px)}
            assert (errors[rows][nodes.level[rows] > 0] >= finest_px).all()
            roots = nodes.level == 0
            assert set(np.nonzero(roots)[0]) <= set(rows.tolist())
            assert nodes.points[rows].sum() <= max(budget, nodes.points[roots].sum())
            if budget == total and finest_px == 0:
                assert rows.size == nodes.level.size
            kept = keys_of(nodes, rows)
            for d, f, x, y, z in kept:                  # a tree cut: every parent kept
                assert d == 0 or (d - 1, f, x >> 1, y >> 1, z >> 1) in kept


def errors_of_rows(nodes: Nodes, view: View) -> np.ndarray:
    """Nodes.errors as it was computed over (n, 3) rows: the cubes' nearest points by
    np.clip and np.linalg.norm, their farthest corners by the greater of both ends."""
    eye = np.asarray(view.position, np.float64)
    hi = nodes.lo + nodes.side[:, None]
    nearest = np.linalg.norm(np.clip(eye, nodes.lo, hi) - eye, axis=1)
    forward = np.asarray(view.forward, np.float64)
    ahead = np.maximum((nodes.lo - eye) * forward, (hi - eye) * forward).sum(axis=1) >= 0
    for n, c in view.side_planes() or ():
        ahead &= np.maximum((nodes.lo - eye) * n, (hi - eye) * n).sum(axis=1) + c >= 0
    with np.errstate(invalid="ignore"):
        return np.where(ahead & (nodes.spacing > 0), nodes.spacing * view.pixels_per_unit(nearest), 0.0)


@pytest.mark.parametrize("seed", range(8))
def test_errors_axis_by_axis_equal_those_of_rows(seed):
    """Nodes.errors works axis by axis over contiguous columns (3x faster over 87,000
    nodes); its errors equal, bit for bit, those of the same arithmetic over (n, 3) rows,
    so the choice and its ties are as they were."""
    rng = np.random.default_rng(seed)
    nodes, described = octree(rng, levels=5, keep=0.7, files=2)
    for ortho, sides in itertools.product((False, True), repeat=2):
        view = random_view(rng, described, ortho, sides)
        assert np.array_equal(nodes.errors(view), errors_of_rows(nodes, view))


def test_choice_is_the_same_for_the_same_inputs_in_any_order():
    """Same keys for the same view and budget, whatever the rows' order (ties, such as
    an orthographic view's equal errors within a level, go by key, not by row)."""
    rng = np.random.default_rng(7)
    nodes, described = octree(rng, levels=5, keep=0.7)
    for ortho in (False, True):
        view = random_view(rng, described, ortho)
        budget = int(nodes.points.sum()) // 3
        first = keys_of(nodes, choose(nodes, view, budget))
        assert first == keys_of(nodes, choose(nodes, view, budget))
        order = rng.permutation(nodes.level.size)
        shuffled = Nodes(nodes.file[order], nodes.level[order], nodes.key[order], nodes.points[order],
                         nodes.lo[order], nodes.side[order], nodes.spacing[order])
        assert keys_of(shuffled, choose(shuffled, view, budget)) == first


def deepest_at(nodes: Nodes, rows: np.ndarray, point) -> int:
    inside = np.all((nodes.lo[rows] <= point) & (point <= nodes.lo[rows] + nodes.side[rows, None]), axis=1)
    return int(nodes.level[rows][inside].max())


def test_nodes_near_the_camera_go_deeper():
    """A full octree, the eye just outside one corner looking across it (perspective):
    the kept node at that corner is deeper than the one at the far corner."""
    rng = np.random.default_rng(3)
    nodes, described = octree(rng, levels=5, keep=1.0)
    center, half = np.asarray(described[0][0]), described[0][1]
    near, far = center - 0.99 * half, center + 0.99 * half
    view = View(tuple((center - 1.2 * half).tolist()), tuple((far - near).tolist()), 1000, 60.0)
    rows = choose(nodes, view, int(nodes.points.sum()) // 4)
    assert deepest_at(nodes, rows, near) > deepest_at(nodes, rows, far)


def test_nodes_behind_the_eye_come_last():
    """The eye at the cube's centre looking along +x, room for the nodes at least partly
    ahead of it: those are all kept, and none wholly behind."""
    rng = np.random.default_rng(5)
    nodes, described = octree(rng, levels=4, keep=1.0)
    view = View(tuple(np.asarray(described[0][0]).tolist()), (1.0, 0.0, 0.0), 500, 60.0)
    errors = nodes.errors(view)
    ahead = errors > 0
    rows = choose(nodes, view, int(nodes.points[ahead | (nodes.level == 0)].sum()))
    assert (~ahead).any() and ahead[nodes.level == 0].all()
    assert set(rows.tolist()) == set(np.nonzero(ahead)[0].tolist())


def test_view_needs_one_projection():
    with pytest.raises(ValueError):
        View((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 100, 60.0, 10.0)
    for bad in ({"forward": (0.0, 0.0, 0.0)}, {"image_height": 0}, {"fov_y_deg": 180.0},
                {"fov_y_deg": None, "ortho_height": 0.0}, {"position": (math.nan, 0.0, 0.0)}):
        with pytest.raises(ValueError):
            View(**{"position": (0.0, 0.0, 0.0), "forward": (1.0, 0.0, 0.0), "image_height": 100, **bad})


def test_nodes_off_the_image_rank_last():
    """A narrow view of one corner of a full octree, with room for the roots and half the
    points of the other nodes that meet the image: with the image's sides every node
    kept past the roots meets it, and the choice that knows only what is behind the
    eye spends budget on nodes off screen."""
    rng = np.random.default_rng(5)
    nodes, described = octree(rng, levels=4, keep=1.0)
    center, half = np.asarray(described[0][0]), described[0][1]
    eye = center - np.array([2.5, 0.0, 0.0]) * half
    corner = center + np.array([-1.0, 0.8, 0.8]) * half
    blind = View(tuple(eye.tolist()), tuple((corner - eye).tolist()), 800, 12.0)
    view = dataclasses.replace(blind, up=(0.0, 0.0, 1.0), aspect=1.5)
    seen = np.array([on_screen(view, nodes.lo[i] + nodes.side[i] * CORNERS) for i in range(nodes.level.size)])
    roots = nodes.level == 0
    assert 0 < np.count_nonzero(seen & ~roots) < np.count_nonzero(~roots) // 4
    budget = int(nodes.points[roots].sum() + nodes.points[seen & ~roots].sum() // 2)
    rows = choose(nodes, view, budget)
    cubes = [nodes.lo[i] + nodes.side[i] * CORNERS for i in rows if nodes.level[i] > 0]
    assert cubes and all(on_screen(view, c) for c in cubes)
    others = choose(nodes, blind, budget)
    assert not all(on_screen(view, nodes.lo[i] + nodes.side[i] * CORNERS) for i in others if nodes.level[i] > 0)


def test_a_child_that_outranks_its_parent_still_waits_for_it():
    """Rows made by hand whose deepest node has the largest spacing (no file's nodes are
    so: a child's spacing is half its parent's): the choice is still a tree cut, the
    parent taken first, and stops at the first node that does not fit."""
    level = np.array([0, 1, 2, 1])
    key = np.array([[0, 0, 0], [0, 0, 0], [0, 0, 0], [1, 1, 1]])
    side = 8.0 / np.exp2(level)
    nodes = Nodes(np.zeros(4, int), level, key, np.array([10, 10, 10, 10]), key * side[:, None], side,
                  np.array([1.0, 0.1, 5.0, 0.2]))
    view = View((100.0, 100.0, 100.0), (-1.0, -1.0, -1.0), 500, 60.0)
    errors = nodes.errors(view)
    assert errors[2] > errors[0] > errors[3] > errors[1]
    assert choose(nodes, view, 20).tolist() == [0, 3]          # not 2 before its parent 1, which 3 outranks
    assert choose(nodes, view, 30).tolist() == [0, 1, 3]
    assert choose(nodes, view, 40).tolist() == [0, 1, 2, 3]
    assert choose(nodes, view, 10).tolist() == [0]
    assert choose(nodes, view, 40, finest_px=(errors[3] + errors[1]) / 2).tolist() == [0, 3]    # 1 too fine
    assert choose(nodes, view, 40, finest_px=errors[3] * 1.01).tolist() == [0]


@pytest.mark.parametrize("finest_px", [-0.5, math.nan, math.inf])
def test_the_finest_detail_is_a_number_of_pixels(finest_px):
    nodes, described = octree(np.random.default_rng(0), 3, 0.8)
    with pytest.raises(ValueError, match="finest detail"):
        choose(nodes, random_view(np.random.default_rng(1), described, False), 100, finest_px=finest_px)
