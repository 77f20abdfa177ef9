"""Which COPC nodes stay on the GPU as the camera moves: the plan streaming follows.

How the Scene and the frame loop would use it (neither does yet). The Scene allocates a
store of `Residency.capacity` whole batches of the batched layout (the core passes
progressive.permutation.BATCH_POINTS as `store_batch_points`: the loaders stand below
the core and do not import it). When the camera has moved or an event has come in, the
frame loop calls `plan(state, view)` and `state.begin(plan)`. The evicted nodes' batches
are hidden at once (marked empty, so the fill and the reprojection skip them) and go
back to the free list. Each request goes to a pool of reader threads (parallel range
requests for a URL) with the batches it will fill. The readers never touch the state:
they post (row, points) or (row, reason) to a queue, and the frame loop drains it
without waiting, calling `arrived` or `failed` on its own thread (so the state needs no
lock). Where `arrived` says keep, the Scene writes the node's points into its batches
through the distribute pass (its i-th batch takes its points [i·B, (i+1)·B), shuffled
within the batch like any batch's; a node's batches need not be consecutive) and hides
them until `shown` lists the node. Then the progressive fill restarts only the changed
batches; what the other batches drew is reprojected as before. Nothing here blocks, and
a view whose nodes are still missing draws the coarser ones already resident, so the
viewer's frame budget never waits for the network.

Rules, with the reasons:
- The target is `copc_choice.choose`'s tree cut, counted in store batches (a node takes
  ceil(points / B) whole batches), down to the finest detail asked for where the budget
  cannot hold every node (a still overview of a 1 B-point cloud with 4 GB of GPU memory
  otherwise reads about 100 points a pixel: fine for the image, costly over a network).
  Failed nodes and everything below them are left out, so the room goes to nodes that
  can be read.
- Requests are the target's missing nodes, largest screen-space error first (ties by
  level, file and key, as choose breaks them). A child is requested only once its
  parent is resident or requested, and at most `max_in_flight` are in flight. Requests
  are a prefix of that order: the first that cannot be placed stops the plan, as the
  first node that does not fit stops choose.
- A resident node outside the target is evicted only to make room for a request, so a
  still view that has converged evicts nothing. Candidates go smallest error first, and
  only leaves of the booked set (a node with a resident, arrived or loading child stays),
  so the resident set stays a tree cut from the root: no duplicates, no holes. A node
  is evicted for request r only when its error is below `hysteresis` × r's error. From a
  converged view A, take a view B for which every node's error is within a factor
  1/sqrt(hysteresis) of its error for A. Going back and forth between A and B then
  evicts nothing: every node kept for A has at least the error, for A, of every node
  left out, and each move costs at most one factor of 1/sqrt(hysteresis).
- A node that arrives before its parent is held (written, not shown) until its whole
  path from the root is resident, so the shown set is always a tree cut.
- A failed node is never requested again. Its loading descendants are cancelled (their
  late arrivals are discarded, but they count as in flight until they come) and its held
  ones are dropped. A node whose cancelled read is still out is not requested again
  until that read is back (the plan stops there), so no node has two reads in flight.
"""

from __future__ import annotations

import dataclasses
import enum
import heapq
import math
from dataclasses import dataclass

import numpy as np

from progressive.loaders.copc_choice import Nodes, View, choose, finest_detail, rank_of


class Status(enum.IntEnum):
    """Where a node is: HELD has arrived but waits for an ancestor before it is shown."""

    ABSENT = 0
    LOADING = 1
    HELD = 2
    RESIDENT = 3
    FAILED = 4


BOOKED = (Status.LOADING, Status.HELD, Status.RESIDENT)
"""The states that hold store batches."""


@dataclass(frozen=True)
class PlanOptions:
    """max_in_flight: requests read at once (range requests for a URL). hysteresis in
    (0, 1]: a node is evicted for a request only when its error is below this fraction of
    the request's. 1 evicts anything smaller than what it makes room for, so a view that
    moves back and forth swaps nodes at the margin every time."""

    max_in_flight: int = 8
    hysteresis: float = 0.5

    def __post_init__(self) -> None:
        if self.max_in_flight < 1:
            raise ValueError("at least one request must be allowed in flight")
        if not (math.isfinite(self.hysteresis) and 0 < self.hysteresis <= 1):
            raise ValueError("hysteresis must be in (0, 1]")


@dataclass(frozen=True)
class Placement:
    """A node's row and the store batches it occupies (or will fill), in point order."""

    row: int
    batches: tuple[int, ...]


@dataclass(frozen=True, eq=False)
class Plan:
    """What to do for a view: evict first (in this order), then request (in priority
    order, each into its batches). `target` is the tree cut the plan works towards
    (an array, so plans are compared field by field)."""

    version: int
    target: np.ndarray
    evict: tuple[Placement, ...]
    request: tuple[Placement, ...]

    @property
    def empty(self) -> bool:
        return not (self.evict or self.request)


@dataclass(frozen=True)
class Arrival:
    """keep: write the node's points into `batches` (False: a cancelled request; discard
    the points). shown: the nodes to show now, parents first (the node and any held
    descendants whose path from the root is now complete)."""

    keep: bool
    batches: tuple[int, ...]
    shown: tuple[int, ...]


@dataclass(frozen=True)
class Failure:
    """The warning to show, and the descendants given up (held ones, whose written batches
    are now free, and loading ones, whose requests are cancelled)."""

    warning: str
    dropped: tuple[Placement, ...]


class Residency:
    """Which nodes hold which store batches, and which are loading. The budget is in
    whole store batches, because the GPU allocates batches, not points. The roots are
    kept even past the budget (nothing is coarser), so the capacity is the larger of the
    two. finest_px: the finest detail a view asks for (choose's) where the budget cannot
    hold every node; where it can, every node is read, so the still view becomes the
    whole cloud's exact render. Not thread-safe: one thread (the frame loop) drives it."""

    def __init__(self, nodes: Nodes, budget_points: int, store_batch_points: int, finest_px: float = 0.0):
        if store_batch_points < 1 or budget_points < 0:
            raise ValueError("a store batch holds at least one point, and a budget is not negative")
        self.nodes = nodes
        self.store_batch_points = store_batch_points
        n = nodes.level.size
        self.parent = nodes.parents()
        self.rank = rank_of(nodes)
        self.children: list[list[int]] = [[] for _ in range(n)]
        for i in np.argsort(self.rank).tolist():
            if self.parent[i] >= 0:
                self.children[self.parent[i]].append(i)
        self.cost = batch_cost(nodes.points, store_batch_points)
        self.budget = int(budget_points) // store_batch_points
        self.capacity = max(self.budget, int(self.cost[self.parent < 0].sum()))
        self.set_finest(finest_px)
        self.status = np.zeros(n, np.int8)
        self.lost = np.zeros(n, bool)            # failed, or below a failed node: never requested
        self.batches: dict[int, tuple[int, ...]] = {}
        self.cancelled: set[int] = set()         # requests still in flight whose points are not wanted
        self.version = 0                         # bumped by every change, so a stale plan is refused
        self._free = list(range(self.capacity))  # a heap: the lowest free batch is taken first

    def set_finest(self, finest_px: float) -> None:
        """The finest detail a view asks for from the next target on (ignored where the
        budget holds every node)."""
        finest_px = finest_detail(finest_px)
        self.finest_px = finest_px if int(self.cost.sum()) > self.budget else 0.0

    def rows(self, *status: Status) -> np.ndarray:
        return np.nonzero(np.isin(self.status, status))[0]

    @property
    def in_flight(self) -> int:
        return int(np.count_nonzero(self.status == Status.LOADING)) + len(self.cancelled)

    @property
    def free(self) -> tuple[int, ...]:
        return tuple(sorted(self._free))

    def target(self, view: View, errors: np.ndarray | None = None, order: np.ndarray | None = None) -> np.ndarray:
        """Rows of choose's tree cut for `view` in store batches, the lost left out
        (errors: nodes.errors(view), order: the rows by decreasing error, ties by rank,
        where the caller has them)."""
        errors = self.nodes.errors(view) if errors is None else errors
        if not self.lost.any():
            return choose(dataclasses.replace(self.nodes, points=self.cost), view, self.budget, self.parent, errors,
                          np.lexsort((self.rank, -errors)) if order is None else order, self.finest_px)
        rows = np.nonzero(~self.lost)[0]
        columns = {f.name: getattr(self.nodes, f.name)[rows] for f in dataclasses.fields(Nodes)}
        # The lost go with their whole subtrees, so every other row's parent is among the rows.
        at = np.full(self.parent.size, -1, np.int64)
        at[rows] = np.arange(rows.size)
        up = self.parent[rows]
        parent = np.where(up >= 0, at[np.maximum(up, 0)], -1)
        return rows[choose(Nodes(**{**columns, "points": self.cost[rows]}), view, self.budget, parent, errors[rows],
                           np.lexsort((self.rank[rows], -errors[rows])), self.finest_px)]

    def begin(self, plan: Plan) -> None:
        """Book a plan: its evictions freed, its requests loading in their batches."""
        if plan.version != self.version:
            raise ValueError("the plan was made for an earlier state")
        for p in plan.evict:
            self.status[p.row] = Status.ABSENT
            del self.batches[p.row]
        self._free, placed = _allocate(self._free, plan.evict, [p.row for p in plan.request], self.cost)
        for p in placed:
            self.status[p.row] = Status.LOADING
            self.batches[p.row] = p.batches
        self.version += 1

    def arrived(self, row: int) -> Arrival:
        if row in self.cancelled:
            self.cancelled.remove(row)
            self.version += 1
            return Arrival(False, (), ())
        if self.status[row] != Status.LOADING:
            raise ValueError(f"node row {row} was not requested")
        self.status[row] = Status.HELD
        shown: list[int] = []
        p = self.parent[row]
        if p < 0 or self.status[p] == Status.RESIDENT:
            stack = [row]
            while stack:
                i = stack.pop()
                self.status[i] = Status.RESIDENT
                shown.append(i)
                stack += [c for c in reversed(self.children[i]) if self.status[c] == Status.HELD]
        self.version += 1
        return Arrival(True, self.batches[row], tuple(shown))

    def failed(self, row: int, reason: str) -> Failure:
        """A node that cannot be read: skipped, with its subtree, and never asked again."""
        if row in self.cancelled:
            self.cancelled.remove(row)
        elif self.status[row] == Status.LOADING:
            self._release(row)
        else:
            raise ValueError(f"node row {row} was not requested")
        self.status[row] = Status.FAILED
        dropped, stack = [], [row]
        while stack:
            i = stack.pop()
            self.lost[i] = True
            stack += self.children[i]
            if i != row and self.status[i] == Status.LOADING:
                self.cancelled.add(i)
            if i != row and self.status[i] in BOOKED:
                dropped.append(Placement(i, self._release(i)))
                self.status[i] = Status.ABSENT
        self.version += 1
        key = self.nodes.key[row].tolist()
        name = f"COPC node {int(self.nodes.level[row])}-{key[0]}-{key[1]}-{key[2]} of file {int(self.nodes.file[row])}"
        below = f", with the {len(dropped)} node(s) below it that were on their way" if dropped else ""
        return Failure(f"{name} could not be read ({reason}); skipped{below}", tuple(dropped))

    def clear(self) -> tuple[Placement, ...]:
        """Give up every node (the store is released): what held batches, every batch
        free again. Loading requests are cancelled; failures are remembered."""
        given_up = []
        for row in self.rows(*BOOKED).tolist():
            if self.status[row] == Status.LOADING:
                self.cancelled.add(row)
            given_up.append(Placement(row, self._release(row)))
            self.status[row] = Status.ABSENT
        self.version += 1
        return tuple(given_up)

    def _release(self, row: int) -> tuple[int, ...]:
        batches = self.batches.pop(row)
        for b in batches:
            heapq.heappush(self._free, b)
        return batches


def batch_cost(points: np.ndarray, store_batch_points: int) -> np.ndarray:
    """Store batches each node takes: whole ones (its points [i·B, (i+1)·B) in its i-th)."""
    return -(-np.asarray(points, np.int64) // store_batch_points)


@dataclass(frozen=True, eq=False)
class ViewPart:
    """What a plan computes from the view alone: the nodes' errors, their order and the
    target. It holds while the view and the lost nodes stay the same, so a plan after an
    arrival (most plans while nodes stream in) skips the errors, their sort and the
    choice, most of a plan's time (bench/plan.py)."""

    view: View
    lost: int               # nodes lost when it was made (lost ones leave the target)
    finest_px: float        # the state's finest detail when it was made
    errors: np.ndarray
    order: np.ndarray
    target: np.ndarray
    in_target: np.ndarray

    @classmethod
    def of(cls, state: Residency, view: View) -> ViewPart:
        errors = state.nodes.errors(view)
        order = np.lexsort((state.rank, -errors))
        target = state.target(view, errors, order)
        in_target = np.zeros(errors.size, bool)
        in_target[target] = True
        return cls(view, int(np.count_nonzero(state.lost)), state.finest_px, errors, order, target, in_target)

    def holds(self, state: Residency, view: View) -> bool:
        return (self.view == view and self.lost == int(np.count_nonzero(state.lost))
                and self.finest_px == state.finest_px)


def plan(state: Residency, view: View, options: PlanOptions = PlanOptions(), part: ViewPart | None = None) -> Plan:
    """What to evict and request for `view` (the module docstring says by which rules).
    It only reads `state`: the same state and view give the same plan. part: a ViewPart
    made earlier, used where it still holds for this state and view."""
    if part is None or not part.holds(state, view):
        part = ViewPart.of(state, view)
    errors, order, target, in_target = part.errors, part.order, part.target, part.in_target
    booked = np.isin(state.status, BOOKED)
    missing = order[in_target[order] & ~booked[order]].tolist()

    booked_children = np.bincount(state.parent[booked & (state.parent >= 0)], minlength=errors.size)
    leaves = [(errors[i], -state.rank[i], i) for i in
              np.nonzero((state.status == Status.RESIDENT) & ~in_target & (booked_children == 0))[0].tolist()]
    heapq.heapify(leaves)
    free = len(state._free)
    room = options.max_in_flight - state.in_flight
    evict: list[int] = []
    request: list[int] = []
    for r in missing:
        if len(request) >= room or r in state.cancelled:    # a cancelled read of it is still out
            break
        threshold = options.hysteresis * errors[r]
        taken, freed = [], 0
        while free + freed < state.cost[r] and leaves and leaves[0][0] < threshold:
            e = heapq.heappop(leaves)[-1]
            taken.append(e)
            freed += int(state.cost[e])
            p = state.parent[e]
            if p >= 0:
                booked_children[p] -= 1
                if booked_children[p] == 0 and state.status[p] == Status.RESIDENT and not in_target[p]:
                    heapq.heappush(leaves, (errors[p], -state.rank[p], p))
        if free + freed < state.cost[r]:
            break
        evict += taken
        free += freed - int(state.cost[r])
        request.append(r)
    evicted = tuple(Placement(e, state.batches[e]) for e in evict)
    _, placed = _allocate(list(state._free), evicted, request, state.cost)
    return Plan(state.version, target, evicted, tuple(placed))


def _allocate(free: list[int], evicted, rows: list[int], cost: np.ndarray) -> tuple[list[int], list[Placement]]:
    """The free heap with the evicted nodes' batches back in it, then the lowest free
    batches taken for each row in turn; the same for the plan and for begin."""
    for p in evicted:
        for b in p.batches:
            heapq.heappush(free, b)
    placed = [Placement(r, tuple(heapq.heappop(free) for _ in range(int(cost[r])))) for r in rows]
    return free, placed
