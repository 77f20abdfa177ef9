"""COPC clouds larger than the GPU, streamed by level of detail as the camera moves.

The store holds whole batches of nodes: loaders/copc_residency.py plans which nodes a
view needs and which batches each takes, loaders/copc_stream.py reads them on threads,
and the Streamer, driven by the frame loop, writes what has arrived into its batches
and empties the batches of evicted nodes. Nothing here waits: a view whose nodes are
still on their way draws the coarser ones already resident. A node is written only once
its whole path from the root is resident (Residency shows it then), so the resident set
is always a tree cut: no point twice, no hole. Points keep their cloud indices (the
store's way back, PointStore.place_run), so ids and picks mean what they mean for the
file read whole; a still view converges to the exact render of the resident nodes.
"""

from __future__ import annotations

import enum
import time
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from progressive.batches import runs
from progressive.loaders.copc_choice import View
from progressive.loaders.copc_residency import PlanOptions, Residency, Status, ViewPart, plan
from progressive.loaders.copc_stream import NodeReader
from progressive.loaders.types import Batch
from progressive.permutation import BATCH_POINTS
from progressive.scene import Scene

WRITE_SECONDS = 0.004
"""Time a frame of a moving camera spends writing arrived nodes to the GPU at most (at
least one node is written), so arrivals never stall motion for long."""
WRITE_STILL_SECONDS = 0.012
"""The same for a camera that holds still: no motion to keep smooth, and the view is
complete sooner (at 1 B points, writing at most 4 ms a frame, the H200's overview of
8,873 nodes settled in 39 s)."""
READS_QUEUED = 4
"""Reads a session's plan keeps requested for each reader thread, so that a thread's next
read waits in the pool's queue rather than for the frame loop to see an arrival and plan
again (on the H200 at 1 B points, with one read a thread, 16 threads brought the
overview 6,547 nodes in 20 s, about 330 a second; the frames that wrote nodes took a
median 19 ms against 12 ms for the others, so their writing stayed under its 12 ms: most
likely the reads, not the writes, held it back)."""
FINEST_PX = 0.0
"""The finest detail a streamed view reads where the memory limit cannot hold every node
(SessionOptions.stream_detail_px), in pixels: 0, nodes until the memory is full, since
detail finer than a pixel still decides which point a pixel shows. On the tiled sample
at 20 M points, 640x360, a store of 90 % of them, a still overview read 15.5 M points and
differed from the render of every point by a mean 1.9 of 255 per colour channel; with
0.25 px it read 2.4 M and differed by 16.1, with 0.5 px 0.5 M and 26.0
(bench/results/llvmpipe/detail/). The reads come largest error first either way, so a
floor gives no earlier image: it saves reads (bytes over HTTP) and memory."""
PLAN = PlanOptions()
"""How many nodes are read at once and how readily resident ones are evicted."""
PLAN_SECONDS = 0.1
"""Least time between two plans for the new views of a moving camera. Nodes that arrive
in between are planned for the last view planned, whose errors, order and target are
kept (bench/plan.py: most of a plan made anew), so a frame that takes arrivals during
motion does not also walk every node for its view."""


class StoreChange(enum.Flag):
    """What an update did to the store: WRITTEN, batches that were empty now hold points
    (drawn whole in the next frame); EMPTIED, batches emptied (and maybe written again),
    so the fill starts again and copies of their points kept from the last frame are
    stale too."""

    NONE = 0
    WRITTEN = enum.auto()
    EMPTIED = enum.auto()


@dataclass(frozen=True)
class StreamStatus:
    """What the panel and --stats report of a streamed cloud."""

    nodes: int                  # in the hierarchies
    points: int
    resident_nodes: int
    resident_points: int
    loading_nodes: int          # requested, not yet arrived
    held_nodes: int             # arrived, waiting for an ancestor (or their turn to be written)
    failed_nodes: int
    capacity_points: int        # what the store's batches hold
    evicted_nodes: int          # since opening
    settled: bool               # nothing more to read or write for the current view
    missing_px: float           # the coarsest detail the view still waits for: the largest screen-space
                                # error of a node it keeps not yet shown, in pixels (0: settled; inf: the
                                # view not planned yet)
    finest_px: float            # the finest detail a view reads (0: until the memory is full, or every node fits)

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass(frozen=True)
class FirstReads:
    """The plan of a session's first view, its reads requested before the store and the
    passes are made (Streamer.request_first), which the Streamer goes on from."""

    view: View
    part: ViewPart


class Streamer:
    """Keeps a Scene's batches holding the nodes a view needs (the Scene was made
    streamed, with the state's capacity in whole batches). With `keep`, the resident
    nodes' points stay in host memory (read with every attribute), so another attribute
    is written from them, node by node, instead of read again."""

    def __init__(self, scene: Scene, reader: NodeReader, state: Residency, options: PlanOptions = PLAN,
                 keep: bool = False, first_in_flight: int | None = None, first: FirstReads | None = None):
        """first_in_flight: reads requested at once until a frame has shown points (then
        options.max_in_flight): one a reader thread, so that no reads queue behind the
        first nodes while the first image is made (with READS_QUEUED from the start, as
        since 86e7d3d, the H200's first image of the 1 B-point COPC took 1.22 s at
        40ce040 against 0.86 s at c0f0c82: bench/results/nvidia-h200/stream_c0f0c82/).
        first: the first view's plan, made and requested by request_first with the same
        reader, state, options and first_in_flight."""
        self.scene, self.reader, self.state, self.options = scene, reader, state, options
        self._first_options = self.first_options(options, first_in_flight)
        self.keep = keep
        self._arrived: dict[int, Batch] = {}
        self._kept: dict[int, Batch] = {}           # keep: each resident node's points
        self._to_write: deque[int] = deque()
        self._to_rewrite: deque[int] = deque()      # resident nodes to write again with the attribute shown
        self._view: View | None = None             # the view of the last plan
        self._asked: View | None = None            # the view of the last update
        self._part: ViewPart | None = None       # the last plan's view part, reused while it holds
        self._events = True
        self._planned_at = -np.inf
        self.evicted = 0
        self.warnings: list[str] = []
        self.written: list[int] = []
        """The batches the last update wrote (into empty ones, where it emptied none)."""
        if first is not None:       # the first frame's view, where it is another, is planned at once
            self._view, self._part, self._events = first.view, first.part, False

    @staticmethod
    def first_options(options: PlanOptions, first_in_flight: int | None) -> PlanOptions:
        """The plan's options until a frame has shown points (__init__'s first_in_flight)."""
        if first_in_flight is None:
            return options
        return replace(options, max_in_flight=max(1, min(options.max_in_flight, first_in_flight)))

    @classmethod
    def request_first(cls, reader: NodeReader, state: Residency, view: View, options: PlanOptions = PLAN,
                      first_in_flight: int | None = None) -> FirstReads:
        """Plan `view` and request its first reads before the Scene exists, so that decoder
        processes decode them while the session makes its store and passes (on the H100 0.3 s
        of a 1 B-point COPC's open, before its first node was asked for). Where the nodes
        are decoded in the session's process, lazrs would hold the GIL through the open
        instead: over HTTP on 2 cores the open took 0.03-0.04 s longer and the first image
        came no sooner (bench/results/llvmpipe/first_reads/), so the session asks only
        where it has decoder processes. Nothing is resident yet: the plan evicts nothing."""
        part = ViewPart.of(state, view)
        p = plan(state, view, cls.first_options(options, first_in_flight), part)
        state.begin(p)
        for r in p.request:
            reader.request(r.row)
        return FirstReads(view, part)

    def _plan_due(self) -> float:
        """Seconds until the last view asked for may be planned (inf: it was planned)."""
        if self._asked == self._view:
            return np.inf
        return self._planned_at + PLAN_SECONDS - time.perf_counter()

    @property
    def busy(self) -> bool:
        """The next update has work without a read ending: nodes to write (or write again),
        arrivals to plan for, or a view whose plan is due."""
        return bool(self._to_write or self._to_rewrite or self._events) or self._plan_due() <= 0

    def wait(self, timeout: float) -> None:
        """Wait at most `timeout` seconds for the next update to have work: a read ending,
        or a view's plan falling due; at once where neither can come."""
        due = self._plan_due()
        timeout = min(timeout, max(0.0, due))
        if self.state.in_flight > 0:
            self.reader.wait(timeout)
        elif due < np.inf:
            time.sleep(timeout)

    @staticmethod
    def residency(reader: NodeReader, budget_points: int, finest_px: float = FINEST_PX) -> Residency:
        """The plan's state for a budget of points (the store gets its capacity) and the
        finest detail a view reads."""
        return Residency(reader.nodes, budget_points, BATCH_POINTS, finest_px)

    def set_finest(self, finest_px: float) -> None:
        """Another finest detail (SessionOptions.stream_detail_px), planned for at the
        next update; nodes finer than it stay until their batches are needed."""
        self.state.set_finest(finest_px)
        self._events = True

    def update(self, view: View) -> StoreChange:
        """Take the reads that have finished, write what may be shown, plan for `view`;
        what that did to the store (the batches it wrote: `written`)."""
        changed = StoreChange.NONE
        self.written = []
        shown_before = self.scene.loaded > 0      # a frame has shown points: reads may queue up
        for row, got in self.reader.arrivals():
            self._events = True
            if isinstance(got, str):
                failure = self.state.failed(row, got)
                self.warnings.append(failure.warning)
                for p in failure.dropped:
                    self._arrived.pop(p.row, None)
                self.reader.cancel([p.row for p in failure.dropped])     # those not begun come back at once
                continue
            arrival = self.state.arrived(row)
            if arrival.keep:
                self._arrived[row] = got
                self._to_write.extend(arrival.shown)
        self._asked = view
        moved = view != self._view
        began = time.perf_counter()
        limit = WRITE_SECONDS if moved else WRITE_STILL_SECONDS
        while self._to_write and (not changed or time.perf_counter() - began < limit):
            self._write(self._to_write.popleft())
            changed |= StoreChange.WRITTEN
        while self._to_rewrite and (not changed or time.perf_counter() - began < limit):
            if self._rewrite(self._to_rewrite.popleft()):
                changed |= StoreChange.WRITTEN | StoreChange.EMPTIED
        now = time.perf_counter()
        # No plan while shown nodes wait to be written: an eviction must not meet a node not yet written.
        fresh = moved and now - self._planned_at >= PLAN_SECONDS
        if not self._to_write and (self._events or fresh):
            # arrivals while the camera moves are planned for the last view planned (its part kept)
            planned = view if fresh or not moved else self._view
            if self._part is None or not self._part.holds(self.state, planned):
                self._part = ViewPart.of(self.state, planned)
            p = plan(self.state, planned, self.options if shown_before else self._first_options, self._part)
            self._view, self._events = planned, False
            if planned == view:
                self._planned_at = now
            if not p.empty:
                self.state.begin(p)
                for e in p.evict:
                    self.scene.clear_store_batches(e.batches)
                    self._kept.pop(e.row, None)
                    self.evicted += 1
                    changed |= StoreChange.EMPTIED
                for r in p.request:
                    self.reader.request(r.row)
        self.scene.settled = (self._view == view and not self._events and not self._to_write
                              and not self._to_rewrite and self.state.in_flight == 0)
        return changed

    def _write(self, row: int) -> None:
        """Node `row`'s points into its batches: its i-th takes points [i·B, (i+1)·B)."""
        batch = self._arrived.pop(row)
        placed = self.state.batches[row]            # ascending: Residency takes the lowest free in turn
        consecutive = runs(placed)
        i = 0
        for lo, hi in consecutive:                  # each run of consecutive batches in one write
            j = i + hi - lo
            self.scene.write_store_batches(batch.rows(i * BATCH_POINTS, min(j * BATCH_POINTS, batch.count)), lo)
            i = j
        self.written.extend(placed)
        if self.keep:
            self._kept[row] = batch

    def kept(self) -> list[Batch]:
        """The resident nodes' points (with `keep`; those written, not those on their way)."""
        return list(self._kept.values())

    def _rewrite(self, row: int) -> bool:
        """A resident node written again from its kept points (in one frame: emptied and
        written, so it never leaves the image); False for one evicted since."""
        if row not in self._kept:
            return False
        self.scene.clear_store_batches(self.state.batches[row])
        self._arrived[row] = self._kept.pop(row)
        self._write(row)
        return True

    def restart(self, names: tuple[str, ...]) -> StoreChange:
        """Show another attribute. With `keep`, the resident nodes are written again from
        their kept points (the others' reads carry every attribute already); else every
        node is read again with the attributes `names`: the store empties, the plan starts
        from the roots, reads under way are discarded."""
        if self.keep:
            self._to_rewrite = deque(self._kept)
            return StoreChange.NONE
        self.reader.names = names
        given_up = self.state.clear()
        self.reader.cancel([p.row for p in given_up])      # reads queued, not begun, come back at once
        self.scene.clear_store_batches([b for p in given_up for b in p.batches])
        self._arrived.clear()
        self._to_write.clear()
        self._events = True
        return StoreChange.EMPTIED

    def status(self) -> StreamStatus:
        s, points = self.state.status, self.state.nodes.points
        resident = s == Status.RESIDENT
        return StreamStatus(int(s.size), int(points.sum()), int(resident.sum()), int(points[resident].sum()),
                            int(np.count_nonzero(s == Status.LOADING)), int(np.count_nonzero(s == Status.HELD)),
                            int(np.count_nonzero(s == Status.FAILED)), self.state.capacity * BATCH_POINTS,
                            self.evicted, bool(self.scene.settled), self.missing_px(), self.state.finest_px)

    def missing_px(self) -> float:
        """StreamStatus.missing_px: 0 once settled; unknown (inf) until the view of the
        last update has been planned; else the largest error of its target's nodes not yet
        shown. Under a pixel, what is still on its way only changes which of a pixel's
        points is in front."""
        if self.scene.settled:
            return 0.0
        if self._part is None or self._view != self._asked:
            return float("inf")
        target = self._part.target
        waiting = target[self.state.status[target] != Status.RESIDENT]
        return float(self._part.errors[waiting].max()) if waiting.size else 0.0

    def close(self) -> None:
        self.reader.close()
