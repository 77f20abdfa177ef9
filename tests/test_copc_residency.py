"""The COPC streaming planner (loaders/copc_residency.py) against a naive reference on
random octrees (those of tests/test_copc_choice.py): the target is the brute-force
sorted cut in store batches, and each plan is the one a slow set-by-set reading of the
rules gives. Random walks of the eye with random arrival orders and failures check
every invariant after every event: the shown and booked sets are tree cuts within the
capacity, and the batches are booked once each and all accounted for. Also: a still
view converges and then plans nothing, a small back-and-forth evicts nothing within
the hysteresis, and a failed node is not asked for again."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_copc_choice import keys_of, octree, random_view, reference

from progressive.loaders.copc_choice import Nodes, View, choose
from progressive.loaders.copc_residency import BOOKED, PlanOptions, Residency, Status, ViewPart, plan


def parent_key(k: tuple) -> tuple:
    d, f, x, y, z = k
    return (d - 1, f, x >> 1, y >> 1, z >> 1)


def key(nodes: Nodes, i: int) -> tuple:
    return (int(nodes.level[i]), int(nodes.file[i]), *map(int, nodes.key[i]))


def in_batches(described, batch_points: int, lost: set) -> list:
    """The files' descriptions with each node's points counted in whole store batches,
    and the lost nodes left out."""
    out = []
    for f, (center, half, spacing, entries) in enumerate(described):
        keep = np.array([(int(e["level"]), f, int(e["x"]), int(e["y"]), int(e["z"])) not in lost for e in entries], bool)
        entries = entries[keep].copy()
        entries["point_count"] = [math.ceil(int(c) / batch_points) for c in entries["point_count"]]
        out.append((center, half, spacing, entries))
    return out


def naive_plan(state: Residency, described, batch_points: int, view: View, options: PlanOptions):
    """(target, requests, evictions) as keys, by the rules read one at a time over sets."""
    nodes = state.nodes
    keys = [key(nodes, i) for i in range(nodes.level.size)]
    row = {k: i for i, k in enumerate(keys)}
    status = {k: Status(int(state.status[row[k]])) for k in keys}
    cost = {k: math.ceil(int(nodes.points[row[k]]) / batch_points) for k in keys}
    lost = {k for k in keys if state.lost[row[k]]}
    target = reference(in_batches(described, batch_points, lost), view, state.budget, state.finest_px)
    errors = dict(zip(keys, nodes.errors(view).tolist()))
    booked = {k for k in keys if status[k] in BOOKED}
    missing = [k for k in sorted(keys, key=lambda k: (-errors[k], k)) if k in target and k not in booked]
    capacity = max(state.budget, sum(cost[k] for k in keys if k[0] == 0))
    free = capacity - sum(cost[k] for k in booked)
    cancelled = {keys[i] for i in state.cancelled}
    in_flight = sum(status[k] is Status.LOADING for k in keys) + len(cancelled)
    requests, evictions = [], []
    for r in missing:
        if in_flight + len(requests) >= options.max_in_flight or r in cancelled:
            break
        taken = []
        while free + sum(cost[e] for e in taken) < cost[r]:
            gone = set(evictions) | set(taken)
            still = booked - gone
            leaves = [e for e in still if status[e] is Status.RESIDENT and e not in target
                      and not any(parent_key(c) == e for c in still if c[0] > 0)
                      and errors[e] < options.hysteresis * errors[r]]
            if not leaves:
                break
            taken.append(min(leaves, key=lambda e: (errors[e], tuple(-v for v in e))))
        if free + sum(cost[e] for e in taken) < cost[r]:
            break
        evictions += taken
        free += sum(cost[e] for e in taken) - cost[r]
        requests.append(r)
    return target, requests, evictions


class Scene:
    """What a scene would know from the plans and events alone: the nodes shown, and
    the batches each written node holds."""

    def __init__(self):
        self.shown: set[int] = set()
        self.written: dict[int, tuple[int, ...]] = {}
        self.requested: dict[int, tuple[int, ...]] = {}
        self.dropped_log: list[tuple] = []

    def begin(self, p) -> None:
        for e in p.evict:
            assert e.row in self.shown and self.written.pop(e.row) == e.batches
            self.shown.remove(e.row)
        for r in p.request:
            self.requested[r.row] = r.batches

    def arrived(self, row: int, a) -> None:
        if a.keep:
            assert a.batches == self.requested.pop(row)
            self.written[row] = a.batches
        assert not set(a.shown) & self.shown and set(a.shown) <= set(self.written)
        self.shown |= set(a.shown)

    def dropped(self, placements) -> None:
        self.dropped_log.append(placements)
        for p in placements:
            self.shown.discard(p.row)
            assert self.written.pop(p.row, None) in (None, p.batches)
            self.requested.pop(p.row, None)


def check(state: Residency, scene: Scene | None = None) -> None:
    """Every invariant the state promises, read from scratch."""
    nodes = state.nodes
    resident = keys_of(nodes, state.rows(Status.RESIDENT))
    booked = keys_of(nodes, state.rows(*BOOKED))
    for k in booked:                                    # tree cuts from the root: no holes
        assert k[0] == 0 or parent_key(k) in booked
    for k in resident:
        assert k[0] == 0 or parent_key(k) in resident
    for i in state.rows(Status.HELD).tolist():          # held only while a node above is missing
        k = key(nodes, i)
        assert k[0] > 0 and parent_key(k) not in resident
    cost = -(-nodes.points // state.store_batch_points)
    roots = int(cost[nodes.level == 0].sum())
    assert state.capacity == max(state.budget, roots)
    assert int(cost[state.rows(Status.RESIDENT)].sum()) <= max(state.budget, roots)
    rows = state.rows(*BOOKED).tolist()
    assert sorted(state.batches) == rows
    assert all(len(state.batches[i]) == cost[i] for i in rows)
    held = [b for i in rows for b in state.batches[i]] + list(state.free)
    assert sorted(held) == list(range(state.capacity))  # each batch booked once or free
    lost = state.lost
    assert not lost[rows].any()
    assert (state.status[lost] != Status.LOADING).all()
    assert all(lost[c] for i in np.nonzero(lost)[0] for c in state.children[i])
    assert (state.status == Status.FAILED).sum() <= lost.sum()
    assert not any(state.status[i] in BOOKED for i in state.cancelled)
    assert state.in_flight == int((state.status == Status.LOADING).sum()) + len(state.cancelled)
    if scene is not None:
        assert scene.shown == set(state.rows(Status.RESIDENT).tolist())
        assert set(scene.written) == set(state.rows(Status.HELD, Status.RESIDENT).tolist())
        assert all(scene.written[i] == state.batches[i] for i in scene.written)


def assert_evicts_only_for_room(state: Residency, p) -> None:
    """Without its last eviction the plan's requests would not fit: a plan evicts only
    what they need room for."""
    if p.evict:
        freed = sum(len(e.batches) for e in p.evict[:-1])
        assert len(state.free) + freed < sum(len(r.batches) for r in p.request)


def walk(rng, view: View, described, step: float) -> View:
    """The eye moved a random step, looking at a point near the first file's centre."""
    center, half = np.asarray(described[0][0]), described[0][1]
    eye = np.asarray(view.position) + rng.normal(size=3) * step * half
    forward = center + rng.uniform(-0.5, 0.5, 3) * half - eye
    return dataclasses.replace(view, position=tuple(eye.tolist()), forward=tuple(forward.tolist()))


def setup(rng, levels=None):
    nodes, described = octree(rng, levels=levels or int(rng.integers(2, 6)), keep=float(rng.uniform(0.3, 0.9)),
                              files=int(rng.integers(1, 3)))
    batch_points = int(rng.integers(300, 3000))
    total = int((-(-nodes.points // batch_points)).sum())
    return nodes, described, batch_points, int(rng.integers(0, total + 2)) * batch_points + int(rng.integers(0, batch_points))


def events(rng, state: Residency, scene: Scene, fail: float, per_event=None) -> None:
    """A random share of the reads in flight come back, some failing: in a random order,
    or shallowest first (deep reads left on their way under resident nodes)."""
    flying = rng.permutation(np.array(state.rows(Status.LOADING).tolist() + sorted(state.cancelled), np.int64))
    if rng.random() < 0.5:
        flying = flying[np.argsort(state.nodes.level[flying], kind="stable")]
    for row in flying[: int(rng.integers(0, len(flying) + 1))].tolist():
        if rng.random() < fail:
            scene.dropped(state.failed(row, "test").dropped)
        else:
            scene.arrived(row, state.arrived(row))
        if per_event:
            per_event()


def settle(rng, state: Residency, scene: Scene, view: View, options: PlanOptions) -> list:
    """Plans and random arrivals until nothing is planned or in flight; the plans made.
    Each round half the reads in flight come back on average, so a few rounds a node."""
    plans = []
    for _ in range(10 * state.nodes.level.size + 100):
        p = plan(state, view, options)
        if p.empty and state.in_flight == 0:
            return plans
        plans.append(p)
        assert_evicts_only_for_room(state, p)
        state.begin(p)
        scene.begin(p)
        events(rng, state, scene, 0.0)
    raise AssertionError("did not settle")


@pytest.mark.parametrize("sides", [False, True], ids=["behind the eye", "off the image's sides"])
@pytest.mark.parametrize("seed", range(8))
def test_target_is_the_choice_in_store_batches(seed, sides):
    """The target equals the brute-force sorted cut over batch counts, and choose's over
    Nodes whose points are those counts; a node of k·B + 1 points takes k + 1 batches."""
    rng = np.random.default_rng(seed)
    nodes, described, batch_points, budget = setup(rng)
    state = Residency(nodes, budget, batch_points)
    assert state.budget == budget // batch_points
    assert (state.cost == [math.ceil(int(p) / batch_points) for p in nodes.points]).all()
    counted = dataclasses.replace(nodes, points=state.cost)
    for ortho in (False, True):
        view = random_view(rng, described, ortho, sides)
        rows = state.target(view)
        assert keys_of(nodes, rows) == reference(in_batches(described, batch_points, set()), view, state.budget)
        assert (rows == choose(counted, view, state.budget)).all()


@pytest.mark.parametrize("seed", range(8))
def test_the_finest_detail_bounds_the_target_where_the_budget_cannot_hold_every_node(seed):
    """With a finest detail (here the median of the view's distinct errors) the target is
    the cut that also stops at it, while the budget is short of the whole tree; a budget
    that holds every node reads every node (the still view then becomes the whole
    cloud's exact render)."""
    rng = np.random.default_rng(seed)
    nodes, described, batch_points, budget = setup(rng)
    for ortho in (False, True):
        view = random_view(rng, described, ortho, True)
        errors = nodes.errors(view)
        levels = np.unique(errors[(errors > 0) & np.isfinite(errors)])
        finest = float(levels[levels.size // 2]) if levels.size > 1 else float(levels[0]) * 1.5
        short = Residency(nodes, budget, batch_points, finest)
        whole = Residency(nodes, int(short.cost.sum()) * batch_points, batch_points, finest)
        assert short.cost.sum() > short.budget and short.finest_px == finest and whole.finest_px == 0.0
        rows = short.target(view)
        assert keys_of(nodes, rows) == reference(in_batches(described, batch_points, set()), view, short.budget,
                                                 finest)
        assert (errors[rows][nodes.level[rows] > 0] >= finest).all() and (errors < finest).any()
        assert whole.target(view).size == nodes.points.size


def same_plan(a, b) -> bool:
    return a.version == b.version and (a.target == b.target).all() and a.evict == b.evict and a.request == b.request


def random_walk(seed: int) -> dict:
    """One walk of the eye, every plan compared with the naive one and every invariant
    checked after every plan and event; how often each case came up."""
    rng = np.random.default_rng(100 + seed)
    nodes, described, batch_points, budget = setup(rng)
    options = PlanOptions(int(rng.integers(1, 10)), float(rng.choice([1.0, 0.5, 0.25])))
    state = Residency(nodes, budget, batch_points, (0.0, 0.0, 0.5, 4.0)[seed % 4])
    scene = Scene()
    view = random_view(rng, described, bool(rng.random() < 0.3), bool(rng.random() < 0.5))
    met = {"requested": 0, "evicted": 0, "held": 0, "dropped": 0, "discarded": 0, "kept": 0}
    part = None

    def after_event():
        check(state, scene)
        met["held"] += len(state.rows(Status.HELD))
    for _ in range(40):
        view = walk(rng, view, described, float(rng.choice([0.02, 0.2, 1.0])))
        p = plan(state, view, options)
        again = plan(state, view, options)
        assert same_plan(again, p)
        if part is not None:            # made before the last events, for the view before this step's
            assert part.holds(state, view) == (part.view == view and part.lost == state.lost.sum())
            assert same_plan(plan(state, view, options, part), p)
        part = ViewPart.of(state, view)
        assert same_plan(plan(state, view, options, part), p)
        target, requests, evictions = naive_plan(state, described, batch_points, view, options)
        assert keys_of(nodes, p.target) == target
        assert [key(nodes, r.row) for r in p.request] == requests
        assert [key(nodes, e.row) for e in p.evict] == evictions
        assert not state.lost[[r.row for r in p.request]].any()
        assert len(p.request) + state.in_flight <= options.max_in_flight or not p.request
        met["requested"] += len(p.request)
        met["evicted"] += len(p.evict)
        assert_evicts_only_for_room(state, p)
        state.begin(p)
        scene.begin(p)
        check(state, scene)
        dropped, cancelled = sum(map(len, scene.dropped_log)), len(state.cancelled)
        events(rng, state, scene, 0.05, after_event)
        met["dropped"] += sum(map(len, scene.dropped_log)) - dropped
        met["discarded"] += cancelled > len(state.cancelled)
        assert state.in_flight <= options.max_in_flight
        if part.holds(state, view):      # the same view after arrivals: the part kept gives the plan anew
            met["kept"] += 1
            assert same_plan(plan(state, view, options, part), plan(state, view, options))
        if rng.random() < 0.05:
            scene.dropped(state.clear())
            check(state, scene)
    scene.dropped(state.clear())
    check(state, scene)
    assert state.free == tuple(range(state.capacity)) and not scene.written and not scene.shown
    return met


@pytest.mark.parametrize("seed", range(16))
def test_random_walks_keep_every_invariant(seed):
    """Random arrival orders, failures and an occasional clear: each plan is the naive
    one and the same twice, no lost node is asked for, in flight stays within the limit,
    the shown set and the batches are what the plans and events told the scene, and
    clearing everything frees every batch."""
    assert random_walk(seed)["requested"] > 0


def test_the_walks_meet_what_they_test():
    """Over the walks, evictions, early arrivals (held), failures with nodes on their way
    below them and discarded late arrivals all happen: the invariants are not vacuous."""
    met = [random_walk(seed) for seed in range(16)]
    totals = {k: sum(m[k] for m in met) for k in met[0]}
    assert all(totals.values()), totals


@pytest.mark.parametrize("seed", range(10))
def test_a_still_view_converges_to_the_target_and_then_plans_nothing(seed):
    """From nothing resident, a still view loads exactly its target, never evicting;
    after a walk, it settles where the first missing target node cannot be placed (room
    only from nodes below the hysteresis), and plans nothing more."""
    rng = np.random.default_rng(200 + seed)
    nodes, described, batch_points, budget = setup(rng)
    options = PlanOptions(int(rng.integers(2, 9)), float(rng.choice([1.0, 0.5])))
    state, scene = Residency(nodes, budget, batch_points), Scene()
    view = random_view(rng, described, bool(rng.random() < 0.3), bool(rng.random() < 0.5))
    plans = settle(rng, state, scene, view, options)
    assert not any(p.evict for p in plans)
    assert set(state.rows(Status.RESIDENT).tolist()) == set(state.target(view).tolist())
    assert plan(state, view, options).empty
    check(state, scene)

    for _ in range(5):
        view = walk(rng, view, described, 0.3)
        p = plan(state, view, options)
        state.begin(p)
        scene.begin(p)
        events(rng, state, scene, 0.0)
    settle(rng, state, scene, view, options)
    check(state, scene)
    assert plan(state, view, options).empty
    errors = nodes.errors(view)
    target = set(state.target(view).tolist())
    resident = set(state.rows(Status.RESIDENT).tolist())
    missing = sorted(target - resident, key=lambda i: (-errors[i], key(nodes, i)))
    if missing:
        r = missing[0]
        assert nodes.level[r] == 0 or state.parent[r] in resident
        room = len(state.free) + sum(int(state.cost[e]) for e in resident - target
                                     if errors[e] < options.hysteresis * errors[r])
        assert room < state.cost[r]


def band(a: np.ndarray, b: np.ndarray) -> float:
    """The largest factor by which a node's error differs between two views (inf where
    one is 0 or infinite and the other not)."""
    if not ((a == 0) == (b == 0)).all() or not (np.isinf(a) == np.isinf(b)).all():
        return math.inf
    finite = (a > 0) & np.isfinite(a)
    return float(np.max(np.maximum(a[finite] / b[finite], b[finite] / a[finite]), initial=1.0))


def back_and_forth(seed: int, hysteresis: float):
    """(evictions, whether the two targets differ) over views A and B, converged at A
    first, then five times to B and back, each settled. B is a perspective step of the
    eye small enough that every node's error stays within 1/sqrt(0.5) of A's."""
    rng = np.random.default_rng(300 + seed)
    nodes, described, batch_points, budget = setup(rng, levels=4)
    budget = int(nodes.points.sum()) // 3
    options = PlanOptions(4, hysteresis)
    state, scene = Residency(nodes, budget, batch_points), Scene()
    center, half = np.asarray(described[0][0]), described[0][1]
    eye = center + rng.uniform(-1, 1, 3) * half * 1.6
    a = View(tuple(eye.tolist()), tuple((center - eye).tolist()), 800, 60.0)
    for step in 0.3 * 0.5 ** np.arange(20):
        b = walk(rng, a, described, step)
        if band(nodes.errors(a), nodes.errors(b)) <= 1 / math.sqrt(0.5):
            break
    else:
        return 0, False
    settle(rng, state, scene, a, options)
    evicted = 0
    for _ in range(5):
        for view in (b, a):
            evicted += sum(len(p.evict) for p in settle(rng, state, scene, view, options))
            check(state, scene)
    return evicted, set(state.target(a).tolist()) != set(state.target(b).tolist())


def test_a_small_back_and_forth_evicts_nothing_within_the_hysteresis():
    """With hysteresis 0.5 nothing is evicted while the errors stay within 1/sqrt(0.5);
    without it (1.0) the same motions swap nodes at the margin."""
    differ = swapped = 0
    for seed in range(24):
        evicted, targets_differ = back_and_forth(seed, 0.5)
        assert evicted == 0, seed
        differ += targets_differ
        swapped += back_and_forth(seed, 1.0)[0] > 0
    assert differ >= 8 and swapped >= 8, (differ, swapped)


def test_a_node_with_a_read_on_its_way_below_it_is_not_evicted():
    """Converged near one corner, then closer (deeper reads left on their way), then at
    the far corner, which needs room: the nodes above the reads on their way are
    outside its target and small on screen, yet stay, so the booked set stays a tree."""
    rng = np.random.default_rng(11)
    nodes, described = octree(rng, levels=4, keep=1.0)
    state, scene = Residency(nodes, 60 * 5000, 5000), Scene()      # every node one batch
    options = PlanOptions(max_in_flight=64, hysteresis=1.0)
    center, half = np.asarray(described[0][0]), described[0][1]

    def corner(sign: float, distance: float) -> View:
        eye = center + sign * distance * half
        return View(tuple(eye.tolist()), tuple((center - eye).tolist()), 1000, 60.0)
    settle(rng, state, scene, corner(-1, 1.5), options)
    p = plan(state, corner(-1, 1.05), options)
    state.begin(p)
    scene.begin(p)
    far = corner(1, 1.5)
    target = set(state.target(far).tolist())
    loading = state.rows(Status.LOADING)
    above = {int(state.parent[i]) for i in loading} - target
    assert above and all(state.status[i] == Status.RESIDENT for i in above)
    p = plan(state, far, options)
    assert p.evict and not {e.row for e in p.evict} & above
    state.begin(p)
    scene.begin(p)
    check(state, scene)


def test_a_failed_node_is_skipped_with_its_subtree_and_not_asked_again():
    """A root fails while its children load: the children are cancelled (their points,
    when they come, are not kept, and they count as in flight until then), the warning
    names the node, and no later plan asks for anything of that subtree."""
    rng = np.random.default_rng(9)
    nodes, described = octree(rng, levels=4, keep=1.0, files=2)
    state, scene = Residency(nodes, int(nodes.points.sum()), 1000), Scene()
    view = random_view(rng, described, False)
    p = plan(state, view, PlanOptions(max_in_flight=20))
    state.begin(p)
    scene.begin(p)
    root = next(r.row for r in p.request if nodes.level[r.row] == 0 and state.children[r.row])
    file = nodes.file[root]
    subtree = np.nonzero(nodes.file == file)[0]
    loading_below = [i for i in subtree.tolist() if i != root and state.status[i] == Status.LOADING]
    assert loading_below
    failure = state.failed(root, "connection reset")
    scene.dropped(failure.dropped)
    level, (x, y, z) = nodes.level[root], nodes.key[root]
    assert f"COPC node {level}-{x}-{y}-{z} of file {file} could not be read (connection reset)" in failure.warning
    assert {d.row for d in failure.dropped} == set(loading_below)
    assert set(loading_below) <= state.cancelled
    assert state.in_flight == len(p.request) - 1
    check(state, scene)
    assert state.lost[subtree].all()
    for row in loading_below:
        assert not state.arrived(row).keep
    assert state.in_flight == len(p.request) - 1 - len(loading_below)
    settle(rng, state, scene, view, PlanOptions(max_in_flight=20))
    assert not (np.isin(state.status, BOOKED) & state.lost).any()
    assert not set(state.target(view).tolist()) & set(subtree.tolist())
    assert set(state.rows(Status.RESIDENT).tolist()) == set(np.nonzero(nodes.file != file)[0].tolist())
    with pytest.raises(ValueError):
        state.arrived(root)
    with pytest.raises(ValueError):
        state.failed(root, "again")


def test_a_stale_plan_is_refused_and_options_are_checked():
    rng = np.random.default_rng(4)
    nodes, described = octree(rng, levels=3, keep=1.0)
    state = Residency(nodes, int(nodes.points.sum()), 500)
    view = random_view(rng, described, False)
    p = plan(state, view)
    state.begin(p)
    with pytest.raises(ValueError):
        state.begin(p)
    for bad in ({"max_in_flight": 0}, {"hysteresis": 0.0}, {"hysteresis": 1.5}, {"hysteresis": math.nan}):
        with pytest.raises(ValueError):
            PlanOptions(**bad)
    with pytest.raises(ValueError):
        Residency(nodes, 100, 0)
    for finest_px in (-1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="finest detail"):
            Residency(nodes, 100, 500, finest_px)


def test_a_view_part_that_holds_spares_the_errors(monkeypatch):
    """plan() with a ViewPart of the same view and lost nodes computes no errors (nor
    their sort and the choice); for another view, once a node was lost, or for another
    finest detail, it makes the part anew."""
    rng = np.random.default_rng(7)
    nodes, described, batch_points, budget = setup(rng, levels=4)
    state = Residency(nodes, budget, batch_points)
    view = random_view(rng, described, False, False)
    part = ViewPart.of(state, view)
    calls = []
    errors = Nodes.errors
    monkeypatch.setattr(Nodes, "errors", lambda self, v: calls.append(v) or errors(self, v))
    first = plan(state, view, PlanOptions(), part)
    assert calls == [] and first.request
    state.begin(first)
    plan(state, view, PlanOptions(), part)
    assert calls == []
    other = walk(rng, view, described, 0.2)
    plan(state, other, PlanOptions(), part)
    assert calls == [other]
    state.failed(first.request[0].row, "test")
    plan(state, view, PlanOptions(), part)
    assert calls == [other, view]
    part = ViewPart.of(state, view)
    assert part.holds(state, view)
    state.set_finest(0.5)           # another finest detail: another target
    assert not part.holds(state, view)
