"""Progressive rendering (paper 3.4): each frame reprojects what was visible, fills
holes with the next range of shuffled points within a GPU-measured budget, and
prepares the next reprojection. A still camera converges to the brute-force image;
once it has (or, while a cloud loads, once what has loaded is filled), frames do no
GPU work at all. The CPU never waits for the GPU here."""

from __future__ import annotations

import bisect
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from progressive.batches import BATCH_ORDER, BatchOrder, runs
from progressive.budget import GROW_STAGES, BudgetParams
from progressive.camera import NO_CLIP, Camera, Clip, Returns, ViewUniforms, view_uniforms
from progressive.colors import ColorStyle
from progressive.context import GLContext
from progressive.effects import Effects
from progressive.loaders.types import AttributeInfo, Batch, CloudInfo
from progressive.passes.budget import BudgetPass
from progressive.passes.compare import ComparePass
from progressive.passes.handles import GROW_STAMPS, TIMESTAMP_SLOTS, Stamp, StateWord
from progressive.passes.prepare import PreparePass
from progressive.passes.raster_compute import DEFAULT_TUNING, ComputeTuning
from progressive.passes.stats import GPURecord, StatsRing
from progressive.passes.visibility import VisibilityBuffer
from progressive.pointstore import PointStore, RecordOrder
from progressive.renderer import Raster, ids_for, make_raster, raster_path
from progressive.scene import Scene
from progressive.shading import Shading

PASS_TIMES = {"reproject": (Stamp.FRAME, Stamp.FILL), "fill": (Stamp.FILL, Stamp.FILL_END),
              "prepare": (Stamp.FILL_END, Stamp.PREPARE_END), "resolve": (Stamp.PREPARE_END, Stamp.END),
              "frame": (Stamp.FRAME, Stamp.END),
              "fill first pass": (Stamp.FILL, Stamp.PASS_END), "fill later passes": (Stamp.PASS_END, Stamp.FILL_END)}
COLD_TIMES = {"first fill": (Stamp.FILL, Stamp.FIRST_END), "adaptive": (Stamp.FIRST_END, Stamp.GROW_1),
              "grow 1": (Stamp.GROW_1, Stamp.GROW_2), "grow 2": (Stamp.GROW_2, Stamp.PASS_END)}
"""A cold frame's parts of its first pass (budget.GROW_STAGES), whose stamps only it writes:
where the time of the frame that fills before it knows a rate goes."""



def _frame_of(stats: FrameStats) -> int:
    return stats.frame


@dataclass(frozen=True)
class ProgressiveOptions:
    width: int = 1280
    height: int = 720
    raster: Raster = Raster.COMPUTE
    budget: BudgetParams = field(default_factory=BudgetParams)
    batches_per_frame: int = 2          # loading never holds a frame longer than this many distributes
    reference: bool = False             # count pixels equal to the brute-force render (costs a brute render a frame)
    chunk_points: int | None = None
    frames_in_flight: int | None = None  # headless pacing, as a swap chain paces a window; None: no limit
    capacity: int | None = None         # points kept on the GPU (progressive/memory.py); None: all
    history_frames: int = 10_000        # per-frame statistics kept (a viewer runs for hours)
    keep_batches: bool = False          # keep loaded attributes in host memory to switch attributes
    class_filter: bool = False          # keep classification codes on the GPU: hidden classes apply to any colouring
    tuning: ComputeTuning = DEFAULT_TUNING  # how the compute raster walks the store (benchmarks compare them)
    batch_order: BatchOrder = BATCH_ORDER  # which consecutive points make a store batch (progressive/batches.py)
    records: RecordOrder = RecordOrder.SLOTS
    """Where the store keeps each slot's record. A frame fills the next slice of every
    batch in view, and in slot order those slices lie together: on the H200 at 1 B
    points a fill of 10 M points took 0.48 ms against 1.24 ms with each batch's records
    together, and a still view from a cold start was exact after 3 frames against 5;
    brute force walks batch by batch and keeps RecordOrder.BATCHES (8.52 ms against
    6.11 ms; bench/results/nvidia-h200/record_order/)."""
    prepare_ballot: bool | None = None
    """Prepare's pixels take their list entries a subgroup at a time by ballot, without
    barriers, instead of a work group at a time after one (PreparePass); None: where
    GL_ARB_shader_ballot is. The same lists either way; bench.progressive --prepare
    compares them."""


@dataclass(frozen=True)
class FrameTag:
    """What the CPU knew when it issued a frame."""

    frame: int
    change: int
    passes: tuple[str, ...]
    points_loaded: int
    pixels: int
    reference: bool
    cold: bool = False      # no fill rate known: the growth stages ran (COLD_TIMES)


@dataclass(frozen=True)
class FrameStats:
    frame: int
    passes: tuple[str, ...]
    points_loaded: int
    first_fill: int
    budget: int
    filled_since_change: int
    covered_pixels: int
    gathered: int                   # visible points prepare read from the shuffled store (new winners)
    gpu_ms: dict[str, float]
    equal_fraction: float | None

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


class ReferenceCheck:
    """Accuracy on the GPU each frame: a brute-force render of the frame's camera into
    a visibility buffer of its own (the compute raster), and the count of pixels whose
    visible point equals the frame's (into `counter`)."""

    def __init__(self, glc: GLContext, store: PointStore, vis: VisibilityBuffer):
        self.store, self.vis = store, vis
        self.reference = VisibilityBuffer(glc, vis.width, vis.height, label="reference visibility")
        # the index pass over every point: a reference independent of the candidates it checks
        self.raster = make_raster(glc, store, self.reference, Raster.COMPUTE, ComputeTuning(candidates=False))
        self.compare = ComparePass(glc, vis)

    @property
    def counter(self):
        return self.compare.counter

    def run(self, view: ViewUniforms) -> None:
        self.reference.resize(self.vis.width, self.vis.height)
        self.reference.clear()
        self.raster.draw(view, 0, self.store.capacity)
        self.compare.run(self.reference)

    def release(self) -> None:
        for obj in (self.raster, self.reference, self.compare):
            obj.release()


class ProgressiveRenderer:
    def __init__(self, glc: GLContext, info: CloudInfo, attribute: AttributeInfo,
                 options: ProgressiveOptions = ProgressiveOptions(), scene: Scene | None = None):
        """`scene`: a cloud already on the GPU to render (kept on release)."""
        self.glc, self.info, self.options = glc, info, options
        self._own_scene = scene is None
        self.scene = scene or Scene(glc, info, attribute, chunk_points=options.chunk_points,
                                    capacity=options.capacity, keep_batches=options.keep_batches,
                                    class_filter=options.class_filter, batch_order=options.batch_order,
                                    records=options.records)
        self.store = self.scene.store
        self.vis = VisibilityBuffer(glc, options.width, options.height)
        self.raster = make_raster(glc, self.store, self.vis, options.raster, options.tuning)
        self.budget = BudgetPass(glc, self.store.capacity, options.budget, self.store.permutation.batches)
        self.prepare = PreparePass(glc, self.store, self.vis, winners=self.raster.winners is not None,
                                   ballot=options.prepare_ballot)
        self.shading = Shading(glc, self.store, self.vis, pixel_words=True)
        self.compare = ReferenceCheck(glc, self.store, self.vis) if options.reference else None
        self.stats_ring = StatsRing(glc)
        self.pending: deque[Batch] = deque()
        self.frame_index = 0
        self.change = 0
        self.filled_change = -1
        self.history: list[FrameStats] = []
        self._camera: tuple[Camera, frozenset[int], Clip, Returns] | None = None
        self._look: tuple[ColorStyle, Effects] | None = None
        self._regather = False
        self._has_visible = False
        self._nodes_changed = False
        self._fresh: set[int] = set()   # batches written into empty ones since the last frame: drawn whole
        self._refresh = False           # the last frame's visible points are read anew before they are reprojected
        self._in_flight: deque[int] = deque()
        self.pacing_waits = 0

    @property
    def raster_path(self) -> str:
        return raster_path(self.options.raster, self.raster)

    @property
    def converged(self) -> bool:
        """Resting with every point there will be (Scene.complete): the still image is exact."""
        return self.resting and self.scene.complete

    @property
    def resting(self) -> bool:
        """Filled (known a few frames late), no batch waits to be distributed and no switch
        is left to show (words still to stream, or the visible points' copies to read anew
        once they are: the next frame's regather): until the camera, the style or the
        points change, a frame does no GPU work. While a cloud loads, frames rest between
        batches instead of filling again what is drawn (a loop may wait for the next one)."""
        return self._filled and not self.pending and not self.switching and not self._regather

    @property
    def _filled(self) -> bool:
        """The GPU reported a full ring of fills since the last change: no fill is left to run."""
        return self.filled_change == self.change

    def add_batch(self, batch: Batch) -> None:
        """Queue a loaded batch; frames distribute a bounded number each."""
        self.pending.append(batch)

    @property
    def wanted_batches(self) -> int:
        """Batches the next frame will distribute beyond those queued: taking no more
        leaves the rest in the loader's bounded queues, so host memory stays bounded
        when loading outruns the frames."""
        return max(0, self.options.batches_per_frame - len(self.pending))

    def nodes_changed(self, emptied: bool, written: Iterable[int] = ()) -> None:
        """A streamed cloud's batches were written (progressive/streaming.py). Batches
        `written` into empty ones, none emptied: the next frame draws them whole over
        what the fill has drawn (the image with them is the least of both), and the fill
        goes on. Else the next frame fills again; `emptied`: before it reprojects the last
        frame's points it reads them anew from the store. (Stale copies drawn in the first
        frame of a fill would hide the points they cover until the fill came round again,
        after the view was taken to have converged.) A raster that cannot draw whole
        batches fills again either way."""
        written = list(written)
        if written and not emptied and self.raster.draws_batches:
            self._fresh.update(written)
            return
        self._nodes_changed = True
        self._refresh |= emptied

    def resize(self, width: int, height: int) -> None:
        if (width, height) != (self.vis.width, self.vis.height):
            self.vis.resize(width, height)
            self.prepare.invalidate()
            self._has_visible = False
            self._camera = None

    def switch_attribute(self, attribute: AttributeInfo) -> None:
        """Show another attribute: frames stream its words to the GPU (showing the last
        image meanwhile), then refresh the visible points' words; nothing reloads."""
        self.scene.begin_switch(attribute)

    @property
    def switching(self) -> bool:
        return self.scene.switch is not None and not self.scene.switch.done

    def frame(self, camera: Camera, style: ColorStyle, effects: Effects = Effects(),
              hidden: frozenset[int] = frozenset(), clip: Clip = NO_CLIP,
              returns: Returns = Returns.ALL) -> tuple[str, ...]:
        """Issue one frame's GPU work; returns the passes that ran. `hidden`: category
        codes left out (with a category attribute shown), and `clip`: the box points must
        lie in; each a change like a camera move."""
        self._pace()
        self._take(self.stats_ring.collect())
        if self.switching:
            return self._stream()
        passes: list[str] = []
        reencoded = self.scene.reencoded
        for _ in range(min(self.options.batches_per_frame, len(self.pending))):
            self.scene.add_batch(self.pending.popleft())
            passes.append("distribute")
        if self._nodes_changed:
            self._nodes_changed = False
            passes.append("nodes")
        if self.scene.reencoded != reencoded:
            self._refresh = True        # copies moved: read anew before they are reprojected (nodes_changed says why)
        restart = bool(passes)
        if self._fresh:
            passes.append("batches")
        style = self.scene.resolved(style)
        hidden, returns = self.scene.drawable(hidden), self.scene.drawable_returns(returns)
        moved = (camera, hidden, clip, returns) != self._camera
        if passes or moved:
            self.change += 1
        restyled = (style, effects) != self._look
        self._camera, self._look = (camera, hidden, clip, returns), (style, effects)
        if self.scene.loaded == 0:
            self.vis.clear()
            passes += self.shading.run(style, effects, self.prepare.pixel_words)
        elif self._filled and not passes:
            regather, self._regather = self._regather, False
            if regather:
                self.prepare.run(regather=True, winners=self.raster.winners)
                passes.append("prepare")
            if restyled or regather:
                passes += self.shading.run(style, effects, self.prepare.pixel_words)
        else:
            return self._render(camera, hidden, clip, returns, style, effects, passes, reset=restart or moved)
        self.budget.end_frame(complete=False)
        self._idle_frame(tuple(passes))
        return tuple(passes)

    def _stream(self) -> tuple[str, ...]:
        """One frame of an attribute switch. Words in the reprojection list are copies:
        once the store is rewritten, the next prepare reads every visible record anew;
        a switch that changed which points are drawn starts the image again."""
        if self.scene.stream():
            if self.scene.positions_changed:
                self.change += 1
                self.prepare.invalidate()
                self._has_visible = False
            else:
                self._regather = True
            self._look = None
        self.budget.end_frame(complete=False)
        self._idle_frame(("stream",))
        return ("stream",)

    def _render(self, camera: Camera, hidden: frozenset[int], clip: Clip, returns: Returns, style: ColorStyle,
                effects: Effects,
                passes: list[str], reset: bool) -> tuple[str, ...]:
        view = view_uniforms(camera, self.info.origin, self.vis.width, self.vis.height, hidden, clip, returns)
        b, raster = self.budget, self.raster
        pieces, reprojection = b.pieces, self.prepare.reprojection
        if self._has_visible:
            passes.append("reproject")
        b.stamp(Stamp.FRAME)
        if self._refresh and self._has_visible:
            self.prepare.run(regather=True, winners=self.raster.winners)     # from the last frame's visibility, before it is cleared
            reprojection = self.prepare.reprojection
        self._refresh = False
        self.vis.clear()
        raster.begin_frame(view)
        fresh = runs(sorted(self._fresh))
        self._fresh.clear()
        stages = GROW_STAGES if b.cold else 0
        for p in range(raster.frame_passes):
            if self._has_visible:
                raster.draw_list(view, reprojection, p)
            if p == 0:
                b.stamp(Stamp.FILL)
                b.begin(reset)
            raster.draw_piece(view, pieces, 0, p)
            raster.draw_piece(view, pieces, 1, p)
            if p == 0:
                b.stamp(Stamp.FIRST_END)
                b.adapt()
            raster.draw_piece(view, pieces, 2, p)
            raster.draw_piece(view, pieces, 3, p)
            for stage, end_stamp in enumerate(GROW_STAMPS[:stages], start=1):
                if p == 0:
                    b.stamp(end_stamp)
                    b.grow(stage)
                raster.draw_piece(view, pieces, 2 + 2 * stage, p)
                raster.draw_piece(view, pieces, 3 + 2 * stage, p)
            for first, end in fresh:
                raster.draw_batches(view, first, end - first, p)
            raster.end_pass(view, p, pieces, reprojection if self._has_visible else None)
            if p == 0:
                b.stamp(Stamp.PASS_END)
        raster.end_frame(view)
        b.stamp(Stamp.FILL_END)
        self.prepare.run(regather=self._regather, winners=raster.winners)
        self._regather = False
        self._has_visible = True
        b.stamp(Stamp.PREPARE_END)
        passes += ["fill", "prepare", *self.shading.run(style, effects, self.prepare.pixel_words)]
        b.stamp(Stamp.END)
        reference = self.compare is not None and self.scene.complete
        if reference:
            self.compare.run(view)
            passes.append("reference")
        tag = FrameTag(self.frame_index, self.change, tuple(passes), self.scene.loaded, self.vis.pixels, reference,
                       stages > 0)
        self.stats_ring.record(tag, b.state, b.stamps, b.parity * TIMESTAMP_SLOTS * 8, self.prepare.previous.meta,
                               self.compare.counter if reference else None)
        b.end_frame(complete=True)
        if self.options.frames_in_flight:
            self._in_flight.append(self.glc.gl.fence())
        self.frame_index += 1
        return tuple(passes)

    def _pace(self) -> None:
        """With frames_in_flight = k, wait until frame n-k is done before issuing frame n
        (what swapping buffers does in a window); the wait is for an old frame, never a readback."""
        limit = self.options.frames_in_flight
        while limit and len(self._in_flight) >= limit:
            sync = self._in_flight.popleft()
            if not self.glc.gl.signaled(sync):
                self.pacing_waits += 1
                self.glc.gl.wait(sync)
            self.glc.gl.delete_sync(sync)

    def _idle_frame(self, passes: tuple[str, ...]) -> None:
        """A frame without fill (converged, or nothing loaded yet): nothing to measure on the GPU."""
        self._record(FrameStats(self.frame_index, passes, self.scene.loaded, 0, 0, self.store.capacity, 0, 0, {}, None))
        self.frame_index += 1

    def _record(self, stats: FrameStats) -> None:
        """Into the history in frame order (a frame's GPU record comes frames later, after
        idle frames issued since), the oldest dropped past history_frames: no frame sorts
        the whole history."""
        bisect.insort(self.history, stats, key=_frame_of)
        if len(self.history) > self.options.history_frames:
            del self.history[0]

    def _take(self, records: list[GPURecord]) -> None:
        for r in records:
            tag: FrameTag = r.tag
            filled = int(r.state[StateWord.FILLED])
            if tag.change == self.change and filled >= self.store.capacity:
                self.filled_change = tag.change
            t = r.stamps.astype(np.int64)
            gpu_ms = {name: (t[b] - t[a]) / 1e6 for name, (a, b) in (PASS_TIMES | (COLD_TIMES if tag.cold else {})).items()}
            equal = r.equal / tag.pixels if tag.reference else None
            self._record(FrameStats(tag.frame, tag.passes, tag.points_loaded, int(r.state[StateWord.FIRST]),
                                    int(r.state[StateWord.BUDGET]), filled, r.visible, r.gathered, gpu_ms, equal))

    def flush(self) -> list[FrameStats]:
        """Wait for every issued frame and return all statistics (after the loop)."""
        self._take(self.stats_ring.collect(wait=True))
        return self.history

    def read_slots(self) -> np.ndarray:
        """(H, W) visible slots of the last frame (waits for the GPU)."""
        return self.vis.read()[:, :, 0].copy()

    def read_ids(self) -> np.ndarray:
        return ids_for(self.store, self.read_slots())

    def read_image(self) -> np.ndarray:
        return self.shading.read()

    def release(self) -> None:
        for sync in self._in_flight:
            self.glc.gl.delete_sync(sync)
        self._in_flight.clear()
        parts = [self.stats_ring, self.raster, self.budget, self.prepare, self.shading, self.vis]
        if self._own_scene:
            parts.append(self.scene)
        if self.compare is not None:
            parts.append(self.compare)
        for obj in parts:
            obj.release()
