"""The Python API: open files, render frames for cameras, get images, ids and
statistics. The CLI, the viewer and the benchmarks all go through it.

    import progressive
    with progressive.open(["tile.laz"], progressive.SessionOptions(width=800, height=600)) as s:
        cam = s.auto_camera()
        while not s.converged:
            s.frame(cam)
        image, ids = s.image(), s.ids()
"""

from __future__ import annotations

import enum
import functools
import os
import time
from dataclasses import dataclass, field, replace

import numpy as np

from progressive import batches, encoding, memory
from progressive.attributes import default_choice, find_attribute
from progressive.batches import BATCH_ORDER, BatchOrder
from progressive.budget import BudgetParams
from progressive.camera import NO_CLIP, Camera, Clip, Returns, auto_camera, view_uniforms
from progressive.colors import DEFAULT_PALETTE, Colormap, ColorStyle, Palette
from progressive.context import GLContext, create_context
from progressive.effects import Effects
from progressive.encoding import Precision
from progressive.errors import ProgressiveError
from progressive.frame_loop import FrameStats, ProgressiveOptions, ProgressiveRenderer
from progressive.loaders import laz_pool
from progressive.loaders.copc import CopcStatus, copc_status
from progressive.loaders.copc_choice import View
from progressive.loaders.copc_residency import batch_cost
from progressive.loaders.copc_stream import NodeReader, may_stream, streamable
from progressive.loaders.crs import file_crs
from progressive.loaders.http import DEFAULTS as HTTP_DEFAULTS
from progressive.loaders.http import HttpOptions
from progressive.loaders.laz_pool import DecoderPool
from progressive.loaders.lookup import read_record
from progressive.loaders.pipeline import CloudLoader
from progressive.loaders.records import attribute_word
from progressive.loaders.types import AttributeInfo, AttributeKind, available_cores
from progressive.passes.distribute import Staging
from progressive.passes.visibility import EMPTY
from progressive.permutation import BATCH_POINTS, BATCH_SLOTS
from progressive.pointstore import CLASS_BYTES, GPUMemoryError
from progressive.renderer import Frame, Raster, Renderer, ids_for
from progressive.reproject import Geography, open_loader, target_crs
from progressive.scene import CLASSIFICATION, AttributeSwitch, Scene
from progressive.streaming import FINEST_PX, PLAN, READS_QUEUED, StoreChange, Streamer, StreamStatus

PICK_RADIUS = 7
"""Pixels around a picked pixel searched for the nearest point shown."""
RESTING_WAIT_S = 0.008
"""Longest a loop whose frames rest (Session.resting) waits for an arrival before it
looks at its input again: half a frame at 60 Hz."""
LATER_WAIT_S = 0.01
"""How often a brute-force frame whose switch waits for the later pass looks for its batches."""
FIRST_HELD = 1
"""Batches the loader parses before the first frame is issued: until then the context,
the renderer's buffers and programs and the first upload have the GIL and the cores to
themselves (at 100 M points on the H200 machine's 16 cores the first frame was issued
in 0.12-0.13 s instead of 0.18-0.33 s: bench/results/nvidia-h200/startup_hold/)."""


class Method(enum.Enum):
    BRUTE = "brute"                # every point, every frame
    PROGRESSIVE = "progressive"    # reproject + budgeted fill + prepare


class Streaming(enum.Enum):
    """Whether a COPC cloud keeps on the GPU the octree nodes each view needs, read in the
    background as the camera moves (progressive/streaming.py), or the nodes the first
    view needs, read once."""

    OFF = "off"
    AUTO = "auto"       # where progressive frames draw files that are all COPC, not reprojected
    ON = "on"           # or refused


@dataclass(frozen=True)
class SwitchStatus:
    """An attribute switch: points streamed of those loaded when it began."""

    streamed: int
    total: int
    rate: float                 # points a second (CPU packing and upload)
    done: bool


@dataclass(frozen=True)
class LaterStatus:
    """The attributes a switchable session reads after those it shows (CloudLoader's
    later pass), while they are read."""

    names: tuple[str, ...]
    read: int                   # points of the loaded ones that carry them
    waiting: str | None         # the attribute a switch waits for (begun once it is read)


@dataclass(frozen=True)
class FrameHost:
    """Where the last progressive frame's wall time went on the host: taking loaded
    batches, updating a streamed cloud's nodes (writes, plans, evictions), issuing the
    GPU work (where a driver whose queue is full blocks). A slow frame says which."""

    pump_s: float = 0.0
    stream_s: float = 0.0
    issue_s: float = 0.0


@dataclass(frozen=True)
class SessionStatus:
    """What the CLI, the viewer and the benchmarks read of a session, at one moment."""

    points: int                 # the cloud's points, every file
    loaded: int                 # read and distributed to the GPU
    complete: bool
    on_gpu: int                 # points the GPU keeps (a memory limit keeps a subset)
    slots: int                  # the store's slots (a progressive fill covers them all)
    not_drawn: int              # non-finite coordinates or shown values
    raster: str                 # the rasterizer's path, in words
    staging: Staging            # how batches reach the GPU: a mapped ring, or copies where buffer storage is missing
    frames: int                 # progressive frames issued
    loading: bool               # batches still to come from the files or waiting for a frame
    switch: SwitchStatus | None
    copc: tuple[CopcStatus | None, ...] = ()
    """Per file (info.files' order): levels, nodes and points kept and read of a COPC
    file read by its hierarchy; None for other files."""
    stream: StreamStatus | None = None
    """A streamed cloud's nodes (SessionOptions.stream)."""
    later: LaterStatus | None = None


@dataclass(frozen=True)
class SessionOptions:
    width: int = 1280
    height: int = 720
    method: Method = Method.PROGRESSIVE
    raster: Raster = Raster.COMPUTE
    progressive: ProgressiveOptions = field(default_factory=ProgressiveOptions)
    """The progressive renderer's own options (budget, batches a frame, reference); its
    size, rasterizer, capacity and kept data come from the fields here."""
    color_by: str | None = None
    colormap: Colormap = Colormap.VIRIDIS
    background: tuple[int, int, int] = (0, 0, 0)
    partial: bool = False
    chunk_points: int | None = None
    gpu_memory_limit: int | None = None     # bytes; the free memory the driver reports also counts
    switchable: bool = False                # keep every attribute (streamed: of the resident nodes) in host memory
    read_later: bool = True
    """Switchable: read the attributes not shown after every point has loaded, so that
    the cloud is whole as soon as for those shown (False: every attribute at once)."""
    parser_threads: int | None = None
    """Threads that parse loaded batches (None: one a core this process may use; a
    streamed cloud's node readers are one a core); fewer leave cores to the frame loop,
    which packs and uploads every batch on its own."""
    value_range: tuple[float, float] | None = None   # the first attribute's values at the colormap's ends; None: percentiles
    class_filter: bool = False              # keep classification on the GPU (where the cloud has it): any colouring filters
    palette: Palette = DEFAULT_PALETTE      # colours of classification codes
    camera: Camera | None = None
    """The first view: a COPC cloud larger than the GPU memory keeps the octree nodes it
    needs most (loaders/copc_choice.py); None: the auto camera's."""
    precision: Precision = Precision.EXACT
    """The position words a brute-force compute raster reads of each batch
    (progressive/encoding.py): all, or with ADAPTIVE the fewest that keep every point
    within encoding.ADAPTIVE_ERROR_PX of where it projects. Progressive frames read all
    (a point kept from the last frame is reprojected where its exact position lies, so
    coarse fills would leave it where it was not drawn)."""
    batch_order: BatchOrder = BATCH_ORDER
    """Which consecutive points make a store batch: the file's order, or MORTON: each
    loaded batch's whole store batches sorted by Morton code (compacter batches where the
    file's order wanders; progressive/batches.py)."""
    http: HttpOptions = HTTP_DEFAULTS
    """How http(s):// URLs of COPC files are fetched (loaders/http.py): timeout, requests in flight."""
    reproject: str | None = None
    """A CRS code (EPSG:32610): load files in any CRSs as one cloud in it (float64,
    pyproj); None: files whose EPSG codes differ are refused."""
    stream: Streaming = Streaming.OFF
    """COPC files: keep on the GPU the octree nodes each view needs, read in the
    background as the camera moves, within the GPU memory (progressive frames)."""
    stream_detail_px: float = FINEST_PX
    """A streamed cloud that the GPU memory cannot hold whole reads no node whose points
    lie closer than this on screen (0: nodes until the memory is full)."""


def node_view(camera: Camera, width: int, height: int) -> View:
    """What the COPC node choice needs of a camera and its image (loaders/copc_choice.py
    View, plain numbers: the loaders stand below the camera)."""
    forward = tuple(np.subtract(camera.target, camera.position).tolist())
    sides = {"up": tuple(map(float, camera.up)), "aspect": width / height}
    if camera.orthographic:
        return View(tuple(camera.position), forward, height, fov_y_deg=None, ortho_height=camera.height, **sides)
    return View(tuple(camera.position), forward, height, camera.fov_y_deg, **sides)


class Session:
    def __init__(self, paths, options: SessionOptions = SessionOptions(), glc: GLContext | None = None):
        """Not `switchable`, the loader reads only what is shown (`color_by`, else the
        default chosen from the files' probes) and what the filters test, so a LAZ of
        point formats 6-10 decodes only those layers. Switchable, it reads the other
        attributes afterwards (`later`), so that every point is shown as soon; batches
        reordered for culling (BatchOrder.MORTON) are read with all of them at once."""
        if options.precision is not Precision.EXACT and options.method is not Method.BRUTE:
            raise ProgressiveError("adaptive precision is for brute-force renders (--method brute): progressive "
                                   "frames reproject each point at its exact position")
        if options.stream is Streaming.ON and options.method is not Method.PROGRESSIVE:
            raise ProgressiveError("streaming COPC nodes needs progressive frames (--method progressive): a "
                                   "brute-force render draws the nodes its camera needs without it")
        if options.stream is Streaming.ON and options.reproject:
            raise ProgressiveError("streaming COPC nodes does not reproject (yet): leave out --reproject or --stream")
        self.options = options
        self.opened = time.perf_counter()
        self.target = target_crs(options.reproject) if options.reproject else None
        budget = None if options.gpu_memory_limit is None else memory.points_within(
            options.gpu_memory_limit, options.width * options.height, CLASS_BYTES if options.class_filter else 0)
        width, height = options.width, options.height
        view = (node_view(options.camera, width, height) if options.camera is not None
                else lambda lo, hi: node_view(auto_camera(lo, hi, width / height), width, height))
        stream = options.stream is Streaming.ON or (
            options.stream is Streaming.AUTO and options.method is Method.PROGRESSIVE and not options.reproject
            and all(may_stream(p) for p in ([paths] if isinstance(paths, (str, os.PathLike)) else paths)))
        self.loader = open_loader(paths, partial=options.partial, reproject=self.target,
                                  point_budget=None if stream else budget, http=options.http,
                                  view=None if stream else view, parser_threads=options.parser_threads,
                                  on_parsed=encoding.with_runs)
        if stream and options.stream is Streaming.AUTO and not streamable(self.loader.sources):
            self.loader.close()         # a hierarchy that cannot be used: read once, as with streaming off
            stream = False
            self.loader = open_loader(paths, partial=options.partial, point_budget=budget, http=options.http,
                                      view=view, parser_threads=options.parser_threads, on_parsed=encoding.with_runs)
        self.streamer: Streamer | None = None
        self._given_range = options.value_range
        self._notes: list[str] = []
        self.startup: dict[str, float] = {}
        """Seconds of each phase before the first image: read (the headers and the files'
        probes), context, passes (buffers and
        programs), programs (of passes: compiled or loaded), upload and first_frame
        (the frame that showed points first, its distributes included; GPU work queued)."""
        try:
            self.info = self.loader.info
            self.geography = Geography(self.info, self.target)
            if stream and not streamable(self.loader.sources):
                plain = next(f.path for f, s in zip(self.info.files, self.loader.sources) if not streamable((s,)))
                raise ProgressiveError(f"streaming reads COPC files by their octree: {plain} is not one (or its "
                                       "hierarchy cannot be used)")
            if options.color_by:
                self.attribute = find_attribute(self.info, options.color_by)
            else:
                self.attribute, note = default_choice(self.info)
                self._notes += [note] if note else []
            self.later: tuple[str, ...] = ()
            """Attributes the loader reads after the first pass, until they join the kept batches."""
            self._waiting: AttributeInfo | None = None
            self._unread: tuple[str, ...] = ()      # later attributes some points did not get (a salvaged file)
            if not stream:
                needed = self._needed(self.attribute, options.class_filter)
                if not options.switchable:
                    self.loader.keep_only(needed)
                elif options.read_later and isinstance(self.loader, CloudLoader) and self.loader.layered and \
                        options.batch_order is BatchOrder.FILE:
                    self.loader.keep_only(needed, later=tuple(a.name for a in self.info.attributes))
                    self.later = self.loader.later
                self.loader.start(FIRST_HELD)
            t0 = time.perf_counter()
            self.startup["read"] = t0 - self.opened
            self._own_context = glc is None
            self.glc = glc or create_context()
            t1 = time.perf_counter()
            self.startup["context"] = t1 - t0
            programs_before = self.glc.programs.stats.seconds
            self._program_warnings = len(self.glc.programs.warnings)    # a shared context's earlier ones are not ours
            class_filter = options.class_filter and any(a.name == CLASSIFICATION for a in self.info.attributes)
            self._class_filter = class_filter
            if stream:
                self._open_stream(options, class_filter)
            else:
                self._open_renderer(options, class_filter)
        except BaseException:
            if self.streamer is not None:
                self.streamer.close()
            self.loader.close()
            raise
        self.startup["passes"] = time.perf_counter() - t1
        self.startup["programs"] = self.glc.programs.stats.seconds - programs_before
        self.load_seconds: float | None = None
        self.first_image_seconds: float | None = None
        self._last: Frame | None = None
        self.host = FrameHost()
        """The last frame's host seconds by part (progressive frames)."""
        self.size = (options.width, options.height)
        self.loading = not stream

    def _open_stream(self, options: SessionOptions, class_filter: bool) -> None:
        """A store of whole node batches within the GPU memory, and the Streamer that
        fills it as the camera moves."""
        names = tuple(a.name for a in self.info.attributes) if options.switchable else \
            self._needed(self.attribute, class_filter)
        cores = available_cores()
        # nodes are decoded on every core; a URL's range requests (bounded by its file) on as many threads,
        # a file's reads on READS_PER_PROCESS threads a decoder process
        remote = any(source.remote is not None for source in self.loader.sources)
        # as the loader's Decoders.AUTO: on fewer cores, or for fewer points than pay for it (a small
        # COPC), the processes' start costs more than they save
        processes = laz_pool.available() and cores >= laz_pool.MIN_AUTO_PROCESSES \
            and self.info.points >= laz_pool.MIN_PROCESS_POINTS
        threads = max(cores, options.http.in_flight) if remote else cores * (laz_pool.READS_PER_PROCESS if processes else 1)
        decoders = DecoderPool(cores) if processes else None
        reader = NodeReader(self.loader.sources, self.info.origin, names, threads, decoders,
                            on_parsed=encoding.node_runs)
        plan_options = replace(PLAN, max_in_flight=READS_QUEUED * threads)
        scene = None
        try:
            need = int(batch_cost(reader.nodes.points, BATCH_POINTS).sum())     # every node, in whole batches
            self.memory = memory.plan(need * BATCH_SLOTS, self.glc.caps, options.width * options.height,
                                      options.gpu_memory_limit, CLASS_BYTES if class_filter else 0,
                                      default_bytes=memory.stream_bytes(self.glc.caps))
            state = Streamer.residency(reader, self.memory.capacity * BATCH_POINTS // BATCH_SLOTS,
                                       options.stream_detail_px)
            first = None
            if decoders is not None:    # decoded in this process, early reads would hold the GIL through the open
                camera = options.camera if options.camera is not None else auto_camera(
                    self.info.bounds_min, self.info.bounds_max, options.width / options.height)
                first = Streamer.request_first(reader, state, node_view(camera, options.width, options.height),
                                               plan_options, first_in_flight=threads)
            info = replace(self.info, points=state.capacity * BATCH_POINTS)
            scene = Scene(self.glc, info, self.attribute, chunk_points=options.chunk_points,
                          class_filter=class_filter, streamed=True, records=options.progressive.records)
            self.renderer = ProgressiveRenderer(self.glc, info, self.attribute, replace(
                options.progressive, width=options.width, height=options.height, raster=options.raster,
                chunk_points=options.chunk_points, class_filter=class_filter), scene=scene)
        except BaseException:
            reader.close()
            if scene is not None:
                scene.release()
            raise
        self.streamer = Streamer(scene, reader, state, plan_options, keep=options.switchable, first_in_flight=threads,
                                 first=first)

    def _open_renderer(self, options: SessionOptions, class_filter: bool) -> None:
        """The renderer of a cloud loaded in order (a uniform random subset where it does
        not fit the GPU memory)."""
        self.memory = memory.plan(self.info.points, self.glc.caps, options.width * options.height,
                                  options.gpu_memory_limit, CLASS_BYTES if class_filter else 0)
        if self.memory.capacity == 0:
            raise GPUMemoryError(f"no points fit in the GPU memory available ({self.memory.source})")
        capacity = self.memory.capacity
        if options.method is Method.BRUTE:
            self.renderer = Renderer(self.glc, self.info, self.attribute, raster=options.raster,
                                     width=options.width, height=options.height,
                                     chunk_points=options.chunk_points, capacity=capacity,
                                     keep_batches=options.switchable, class_filter=class_filter,
                                     batch_order=options.batch_order)
        else:
            self.renderer = ProgressiveRenderer(self.glc, self.info, self.attribute, replace(
                options.progressive, width=options.width, height=options.height, raster=options.raster,
                chunk_points=options.chunk_points, capacity=capacity, keep_batches=options.switchable,
                class_filter=class_filter, batch_order=options.batch_order))

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _needed(self, attribute: AttributeInfo, class_filter: bool) -> tuple[str, ...]:
        """The attributes batches must carry: the shown one, and the class and return
        numbers where the filters test them."""
        filters = (CLASSIFICATION, "return_number", "number_of_returns") if class_filter else ()
        known = {a.name for a in self.info.attributes}
        return (attribute.name, *(n for n in filters if n in known))

    @property
    def streamed(self) -> bool:
        """COPC nodes stream as the camera moves (SessionOptions.stream)."""
        return self.streamer is not None

    @property
    def progressive(self) -> bool:
        return isinstance(self.renderer, ProgressiveRenderer)

    @property
    def converged(self) -> bool:
        """The still view is exact, and no switch waits for the later pass."""
        return self.idle and self._waiting is None

    @property
    def idle(self) -> bool:
        """Frames change nothing until the camera or the style does, or a switch waiting
        for the later pass can begin: a window may wait for events between them (frames
        in a tight loop keep the GIL from the parser threads)."""
        return self.progressive and self.renderer.converged

    @property
    def resting(self) -> bool:
        """Frames change nothing until a batch or node arrives, or the camera or the style
        changes: everything on the GPU is drawn (frame() then waits a little for one)."""
        return (self.progressive and self.renderer.resting
                and (self.streamer is None or not self.streamer.busy))

    def _rest(self) -> None:
        """Where frames rest, wait at most RESTING_WAIT_S for what would change the next
        one: a loaded batch (or a part of the later pass), a streamed node; at once where
        nothing is on its way. Frames issued back to back that change nothing would take
        the GIL (and, on a CPU GL, the cores) from the loader's threads."""
        if not self.resting:
            return
        if self.streamer is not None:
            self.streamer.wait(RESTING_WAIT_S)
        elif self.loading and (not self.loader.done or self.later):
            self.loader.wait(RESTING_WAIT_S)

    @property
    def warnings(self) -> list[str]:
        if self.streamer is not None:
            subset = [self._stream_note()] if self.memory.subset else []
            subset += self.streamer.warnings
        else:
            subset = [self.memory.message(self.renderer.store.kept)] if self.memory.subset and self.renderer else []
        skipped = self.renderer.scene.skipped if self.renderer is not None else 0
        nonfinite = [f"{skipped:,} points not drawn: non-finite coordinates or {self.attribute.name} values"] if skipped else []
        return subset + self._notes + nonfinite + list(self.loader.warnings) + self.glc.programs.warnings[self._program_warnings:]

    def _stream_note(self) -> str:
        room = self.streamer.state.capacity * BATCH_POINTS
        return (f"the cloud's points do not fit in the GPU memory ({self.memory.source}): streaming the COPC "
                f"octree nodes each view needs, room for {room:,} of {self.info.points:,} points")

    def auto_camera(self) -> Camera:
        return auto_camera(self.info.bounds_min, self.info.bounds_max, self.size[0] / self.size[1])

    def style(self, colormap: Colormap | None = None, value_range: tuple[float, float] | None = None,
              background: tuple[int, int, int] | None = None) -> ColorStyle:
        """The options' colouring, or the one given (a viewer's controls). `value_range`:
        values at the colormap's ends in the attribute's units; None: the given range
        of the options, else the colour contract's percentiles."""
        chosen = value_range or self._given_range
        offset_range = None if chosen is None else (chosen[0] - self.attribute.offset, chosen[1] - self.attribute.offset)
        return self.renderer.scene.style(colormap or self.options.colormap, background or self.options.background,
                                         offset_range, self.options.palette)

    def color_range(self, value_range: tuple[float, float] | None = None) -> tuple[float, float] | None:
        """The scalar values at the colormap's ends, in the attribute's units, for the
        range given (as to `style`); None when the attribute is not a scalar or no
        finite value has loaded."""
        chosen = value_range or self._given_range
        if chosen is not None or self.attribute.kind is not AttributeKind.SCALAR:
            return chosen if self.attribute.kind is AttributeKind.SCALAR else None
        taken = self.renderer.scene.value_range()
        return None if taken is None else (taken[0] + self.attribute.offset, taken[1] + self.attribute.offset)

    def histogram(self, bins: int, value_range: tuple[float, float]) -> np.ndarray | None:
        """Counts of the shown scalar's values in `bins` equal bins over `value_range`
        (attribute units; the last bin closed, as numpy's), over the loaded points the
        colour range is taken over: finite position and value, as stored on the GPU
        (float32 of the value less the attribute's offset). Counted on the host from
        the kept batches (SessionOptions.switchable; streamed: the resident nodes');
        None for other kinds or without them."""
        scene = self.renderer.scene
        kept = self.streamer.kept() if self.streamer is not None and self.streamer.keep else \
            list(scene.batches) if scene.keep_batches else None
        if self.attribute.kind is not AttributeKind.SCALAR or kept is None:
            return None
        lo, hi = value_range
        counts = np.zeros(bins, dtype=np.int64)
        for batch in kept:
            if batch.records is not None:
                words, finite = batch.records[:, 3], np.isfinite(batch.records[:, :3].view(np.float32)).all(axis=1)
            else:
                words = attribute_word(batch, self.attribute, float(self.info.origin[2]))
                finite = np.isfinite(batch.positions).all(axis=1) if batch.nonfinite_positions \
                    else np.ones(batch.count, dtype=bool)
            values = words.view(np.float32)[finite].astype(np.float64) + self.attribute.offset
            counts += np.histogram(values[np.isfinite(values)], bins, (lo, hi))[0]
        return counts

    @functools.cached_property
    def units(self) -> str | None:
        """The horizontal unit of the cloud's CRS as pyproj names it ("metre", "foot"):
        the target's when reprojecting, else the first file's; None without a CRS."""
        crs = self.target if self.target is not None else file_crs(self.info.files[0])
        return None if crs is None or not crs.axis_info else crs.axis_info[0].unit_name

    def switch_attribute(self, name: str) -> AttributeSwitch | None:
        """Colour by another attribute (needs SessionOptions.switchable). Progressive
        frames stream it in; the brute renderer rewrites it here. A streamed cloud writes
        its resident nodes again from their kept points (switchable), else reads them
        again (None: no switch to follow)."""
        attribute = find_attribute(self.info, name)
        if attribute.name in self.later:
            if not self.loading:
                raise ProgressiveError(f"{attribute.name} was not read: loading stopped")
            self._waiting = attribute
            return None
        if attribute.name in self._unread:
            raise ProgressiveError(f"{attribute.name} could not be read for every point (see the warnings)")
        self._waiting = None
        if self.streamer is not None:
            self.renderer.scene.show_streamed(attribute)
            if change := self.streamer.restart(self._needed(attribute, self._class_filter)):
                self.renderer.nodes_changed(StoreChange.EMPTIED in change)
        else:
            self.renderer.switch_attribute(attribute)
        self.attribute = attribute
        self._given_range = None
        return self.renderer.scene.switch

    @property
    def waiting(self) -> AttributeInfo | None:
        """The attribute a switch waits for (switch_attribute before the later pass has read it)."""
        return self._waiting

    @property
    def chosen(self) -> AttributeInfo:
        """The attribute last asked for: the one shown, or the one a switch waits for."""
        return self._waiting or self.attribute

    def batch_counts(self, camera: Camera, clip: Clip = NO_CLIP) -> dict[str, int | dict[str, int]]:
        """Batches of the store, how many the rasterizer's culling test keeps for
        `camera` and `clip` and, of those, how many it reads at 10, 20 and 30 bits
        (the numpy twins of shaders/cull.comp: fewer only where adaptive precision
        reaches the rasterizer); empty batches are culled."""
        store = self.renderer.store
        if not store.batched:
            return {"total": 0, "drawn": 0, "culled": 0, "bits": {}}
        view = view_uniforms(camera, self.info.origin, *self.size, clip=clip)
        shown = batches.in_view(store.boxes, view)
        drawn = int(np.count_nonzero(shown))
        levels = np.full(int(drawn), encoding.LEVELS)
        if self.options.precision is Precision.ADAPTIVE and not self.progressive and self.renderer.reads_adaptive:
            levels = encoding.levels_needed(store.frames[shown], batches.least_depths(store.boxes[shown], view), view)
        bits = {f"{encoding.LEVEL_BITS * k}": int(np.count_nonzero(levels == k)) for k in range(1, encoding.LEVELS + 1)}
        return {"total": store.permutation.batches, "drawn": drawn, "culled": store.permutation.batches - drawn,
                "bits": bits}

    def nearest_shown(self, x: float, y: float, radius: int = PICK_RADIUS) -> tuple[int, float, tuple[int, int]] | None:
        """(file-order index, depth, (column, row)) of the point shown nearest to image
        pixel (x, y) within `radius` pixels (row 0 at the top), from the last image's
        visibility buffer in one read; None where no point is shown there."""
        vis = self.shown_visibility
        w, h = vis.width, vis.height
        px, py = int(x), int(y)
        x0, x1 = max(0, px - radius), min(w, px + radius + 1)
        y0, y1 = max(0, py - radius), min(h, py + radius + 1)
        if x0 >= x1 or y0 >= y1:
            return None
        first, last = y0 * w + x0, (y1 - 1) * w + x1
        span = np.frombuffer(vis.buffer.read(size=(last - first) * 8, offset=first * 8), dtype=np.uint32)
        span = np.concatenate([span, np.zeros(2 * (w - x1 + x0), dtype=np.uint32)])
        block = span.reshape(y1 - y0, w, 2)[:, : x1 - x0]
        ys, xs = np.nonzero(block[:, :, 0] != EMPTY)
        if ys.size == 0:
            return None
        k = int(np.argmin((ys + y0 - py) ** 2 + (xs + x0 - px) ** 2))
        slot, depth = block[ys[k], xs[k]]
        index = ids_for(self.renderer.store, np.array([slot], dtype=np.uint32))[0]
        return int(index), float(np.array(depth, np.uint32).view(np.float32)), (int(xs[k] + x0), int(ys[k] + y0))

    def pick(self, x: float, y: float, radius: int = PICK_RADIUS) -> dict | None:
        """All of the point shown nearest to image pixel (x, y) within `radius`: its file,
        its index there and in the cloud, x, y, z in file coordinates (reprojected: in the
        target CRS, and the file's under "file_coordinates"), the CRS, "lat" and "lon"
        (None where the CRS allows none) and every attribute, read back from its file;
        the pixel and depth it was found at. None: nothing there."""
        hit = self.nearest_shown(x, y, radius)
        return None if hit is None else self.picked_record(hit)

    def picked_record(self, hit: tuple[int, float, tuple[int, int]]) -> dict:
        """pick's record of a point nearest_shown found. It reads the point's file (over
        HTTP, fetches its node), and touches no GPU object, so a window may run it on
        another thread and keep drawing."""
        index, depth, pixel = hit
        record = self.geography.place(index, read_record(self.info, index))
        return {**record, "pixel": list(pixel), "depth": depth}

    def point(self, index: int) -> np.ndarray:
        """(3,) float64 coordinates of the point with cloud index `index`, read back from
        its file, in the cloud's CRS (the target's when reprojecting)."""
        return self.geography.point(index)

    def set_budget(self, params: BudgetParams) -> None:
        """Another fill budget from the next frame on (progressive)."""
        if self.progressive:
            self.renderer.budget.params = params

    def set_stream_detail(self, finest_px: float) -> None:
        """Another finest detail for a streamed cloud (SessionOptions.stream_detail_px),
        from the next frame's plan on; nothing for a cloud not streamed."""
        if self.streamer is not None:
            self.streamer.set_finest(finest_px)

    def stop_loading(self) -> None:
        """Keep what has loaded and read no more (a file failed while the viewer shows it)."""
        self.loading = False
        self._waiting = None
        self.loader.close()
        self.renderer.scene.finished = True

    def resize(self, width: int, height: int) -> None:
        """A new frame size; per-pixel buffers follow (the image starts again)."""
        self.size = (width, height)
        if self.progressive:
            self.renderer.resize(width, height)

    def _pump(self, block: bool) -> None:
        if not self.loading:
            return
        batches = self.loader if block else self.loader.poll(self.renderer.wanted_batches)
        for b in batches:       # one at a time, as many as frames take: host memory stays bounded
            self.renderer.add_batch(b)
        if self.load_seconds is None and self.loader.done:
            self.load_seconds = time.perf_counter() - self.opened
            self.renderer.scene.finished = True
        if self.later and self.loader.done and not (self.progressive and self.renderer.pending):
            self._join_later(block)     # once every kept batch is in the scene

    def _join_later(self, block: bool) -> None:
        """The later pass's batches join the kept ones; once all have, a switch waiting
        for one of its attributes begins (block: wait for them where one does)."""
        while True:
            for part in self.loader.poll_later():
                self.renderer.scene.add_attributes(part)
            if self.loader.later_done:
                break
            if not (block and self._waiting):
                return
            time.sleep(LATER_WAIT_S)
        scene = self.renderer.scene
        if scene.joined < scene.loaded:     # a damaged file salvaged: its later pass ended sooner
            self._unread = self.later
            self._notes.append(f"{', '.join(self.later)}: read for {scene.joined:,} of the {scene.loaded:,} points "
                               "loaded, so they cannot be shown")
        self.later = ()
        if self._waiting is not None:
            waiting, self._waiting = self._waiting, None
            if waiting.name not in self._unread:
                self.switch_attribute(waiting.name)

    def frame(self, camera: Camera, style: ColorStyle | None = None, effects: Effects = Effects(),
              hidden: frozenset[int] = frozenset(), clip: Clip = NO_CLIP,
              returns: Returns = Returns.ALL) -> tuple[str, ...]:
        """Progressive: one frame with whatever has loaded (where everything loaded is
        drawn and the view has not changed, after waiting up to RESTING_WAIT_S for the next
        batch or node). Brute: load all, render.
        `hidden`: category codes not drawn while a category attribute is shown; `clip`:
        the box (file coordinates) points must lie in to be drawn; `returns`: which
        returns of each pulse are drawn (with filters_classes)."""
        t0 = time.perf_counter()
        if not self.progressive:
            self._pump(block=True)
            self._last = self.renderer.render(camera, *self.size, style or self.style(), effects, hidden, clip,
                                              returns, self.options.precision)
            passes = ("distribute", "raster", "resolve")
        else:
            self._rest()
            self._pump(block=False)
            t1 = time.perf_counter()
            if self.streamer is not None and (change := self.streamer.update(node_view(camera, *self.size))):
                self.renderer.nodes_changed(StoreChange.EMPTIED in change, self.streamer.written)
            t2 = time.perf_counter()
            passes = self.renderer.frame(camera, style or self.style(), effects, hidden, clip, returns)
            self.loader.resume()
            self.host = FrameHost(t1 - t0, t2 - t1, time.perf_counter() - t2)
        if self.first_image_seconds is None and self.renderer.scene.loaded > 0:
            now = time.perf_counter()
            self.first_image_seconds = now - self.opened
            self.startup["upload"] = self.renderer.scene.upload_seconds
            self.startup["first_frame"] = now - t0
        return passes

    def status(self) -> SessionStatus:
        r = self.renderer
        scene, sw = r.scene, r.scene.switch
        pending = bool(r.pending) if self.progressive else False
        streamed = None if self.streamer is None else self.streamer.status()
        return SessionStatus(
            points=self.info.points, loaded=scene.loaded, complete=scene.complete,
            on_gpu=scene.loaded if streamed is not None else scene.store.kept,
            slots=scene.store.capacity, not_drawn=scene.skipped, raster=r.raster_path,
            staging=scene.distribute.staging,
            frames=r.frame_index if self.progressive else int(self._last is not None),
            loading=(self.loading and not self.loader.done) or pending or (streamed is not None and not streamed.settled)
            or self._waiting is not None,
            switch=None if sw is None else SwitchStatus(sw.streamed, sw.total, sw.rate, sw.done),
            copc=tuple(copc_status(f) for f in self.info.files), stream=streamed,
            later=LaterStatus(self.later, scene.joined, self._waiting and self._waiting.name) if self.later else None)

    def categories(self) -> list[int]:
        """Category codes present in the shown attribute (kept batches; for a legend)."""
        return self.renderer.scene.categories()

    @property
    def filters_classes(self) -> bool:
        """Hidden classes apply whatever attribute is shown (the GPU keeps the classes)."""
        return self.renderer.store.has_classes

    @property
    def history(self) -> list[FrameStats]:
        """The per-frame statistics the GPU has reported so far (no wait; see stats())."""
        return self.renderer.history if self.progressive else []

    def stats(self) -> list[FrameStats]:
        """Per-frame statistics (progressive; waits for the GPU, so call after the loop)."""
        return self.renderer.flush() if self.progressive else []

    @property
    def image_buffer(self):
        """The GPU buffer of the last image (RGBA8 words, row 0 at the top)."""
        return self.renderer.shading.resolve.image

    @property
    def shown_visibility(self):
        """The visibility buffer behind the last image (after the point-size pass)."""
        return self.renderer.shading.shown

    def image(self) -> np.ndarray:
        return self.renderer.read_image() if self.progressive else self._last.image

    def ids(self) -> np.ndarray:
        return self.renderer.read_ids() if self.progressive else self._last.ids

    def covered(self) -> np.ndarray:
        """(H, W) bool: pixels the last frame drew a point in, before the point-size pass."""
        slots = self.renderer.read_slots() if self.progressive else self._last.slots
        return slots != EMPTY

    def effect_cost_ms(self, effects: Effects, repeats: int = 3) -> dict[str, float]:
        """GPU milliseconds of each screen-space pass `effects` asks for ("dilate",
        "eye_dome") at the current size, on the last frame; the image shown stays. Blocks."""
        words = self.renderer.prepare.pixel_words if self.progressive else None
        return self.renderer.shading.cost_ms(effects, words, repeats)

    @property
    def last_frame(self) -> Frame | None:
        return self._last

    def close(self) -> None:
        self.loader.close()
        streamer = getattr(self, "streamer", None)
        if streamer is not None:
            streamer.close()
        renderer = getattr(self, "renderer", None)
        if renderer is not None:
            renderer.release()
            if streamer is not None:
                renderer.scene.release()
            self.renderer = None
        if getattr(self, "_own_context", False):
            self.glc.release()
            self._own_context = False


def open(paths, options: SessionOptions = SessionOptions(), glc: GLContext | None = None) -> Session:  # noqa: A001
    return Session(paths, options, glc)
