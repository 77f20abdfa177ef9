"""A thin composition of the passes: a cloud in a shuffled GPU buffer, rendered whole
("brute force") with the chosen rasterizer, coloured by one attribute."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from progressive.batches import BATCH_ORDER, BatchOrder
from progressive.camera import NO_CLIP, Camera, Clip, Returns, view_uniforms
from progressive.colors import Colormap, ColorStyle
from progressive.context import GLContext
from progressive.effects import Effects
from progressive.encoding import Encoding, Precision
from progressive.loaders.types import AttributeInfo, Batch, CloudInfo
from progressive.passes.cull import CullPass
from progressive.passes.raster_compute import DEFAULT_TUNING, ComputeRaster, ComputeTuning
from progressive.passes.raster_points import PointsRaster
from progressive.passes.visibility import EMPTY, VisibilityBuffer
from progressive.pointstore import PointStore
from progressive.scene import Scene
from progressive.shading import Shading
from progressive.timing import Timestamps


class Raster(enum.Enum):
    COMPUTE = "compute"        # 64-bit atomics where the GPU has them, else the 32-bit path
    COMPUTE32 = "compute32"
    POINTS = "points"


@dataclass
class Frame:
    image: np.ndarray           # (H, W, 4) uint8, row 0 at the top
    slots: np.ndarray           # (H, W) uint32 shuffled slots, EMPTY where nothing
    ids: np.ndarray             # (H, W) uint32 file-order indices, EMPTY where nothing
    gpu_ms: dict[str, float] = field(default_factory=dict)


class Renderer:
    """Every loaded point in one frame: the exact image, and the baseline's cost."""

    def __init__(self, glc: GLContext, info: CloudInfo, attribute: AttributeInfo, *,
                 raster: Raster = Raster.COMPUTE, width: int = 1280, height: int = 720,
                 chunk_points: int | None = None, capacity: int | None = None, scene: Scene | None = None,
                 keep_batches: bool = False, tuning: ComputeTuning = DEFAULT_TUNING,
                 class_filter: bool = False, position_encoding: Encoding = Encoding.WORDS,
                 batch_order: BatchOrder = BATCH_ORDER):
        """`scene`: a cloud already on the GPU to render (kept on release)."""
        self.glc, self.info, self.attribute = glc, info, attribute
        self._own_scene = scene is None
        self.scene = scene or Scene(glc, info, attribute, chunk_points=chunk_points, capacity=capacity,
                                    keep_batches=keep_batches, class_filter=class_filter,
                                    position_encoding=position_encoding, batch_order=batch_order)
        self.store = self.scene.store
        self.vis = VisibilityBuffer(glc, width, height)
        self.raster_kind = raster
        self.raster = make_raster(glc, self.store, self.vis, raster, tuning)
        self.shading = Shading(glc, self.store, self.vis)
        self.timestamps = Timestamps(glc)

    @property
    def raster_path(self) -> str:
        return raster_path(self.raster_kind, self.raster)

    @property
    def reads_adaptive(self) -> bool:
        """Whether adaptive precision changes what this renderer reads: a compute raster
        walking the word store batch by batch (GL_POINTS and one invocation a slot read
        every word)."""
        return isinstance(self.raster, ComputeRaster) and self.raster.batch_groups and self.store.words

    @property
    def loaded(self) -> int:
        return self.scene.loaded

    @property
    def upload_seconds(self) -> float:
        return self.scene.upload_seconds

    def add_batch(self, batch: Batch) -> None:
        self.scene.add_batch(batch)

    def style(self, colormap: Colormap = Colormap.VIRIDIS, background=(0, 0, 0)) -> ColorStyle:
        return self.scene.style(colormap, background)

    def switch_attribute(self, attribute: AttributeInfo) -> None:
        """Show another attribute: every kept batch's words are rewritten before returning."""
        self.scene.begin_switch(attribute)
        while not self.scene.stream(seconds=float("inf")):
            pass

    def render(self, camera: Camera, width: int, height: int, style: ColorStyle,
               effects: Effects = Effects(), hidden: frozenset[int] = frozenset(), clip: Clip = NO_CLIP,
               returns: Returns = Returns.ALL, precision: Precision = Precision.EXACT) -> Frame:
        """precision: the position words a compute raster's batch walk reads (GL_POINTS
        and one invocation a slot read all of them)."""
        self.vis.resize(width, height)
        if isinstance(self.raster, ComputeRaster):
            self.raster.precision = precision
        style = self.scene.resolved(style)
        view = view_uniforms(camera, self.info.origin, width, height, self.scene.drawable(hidden), clip,
                             self.scene.drawable_returns(returns))
        t = self.timestamps
        t.reset()
        t.stamp("start")
        self.vis.clear()
        t.stamp("clear")
        self.raster.draw(view, 0, self.store.capacity)
        t.stamp("raster")
        self.shading.run(style, effects)
        t.stamp("resolve")
        image = self.shading.read()
        slots = self.vis.read()[:, :, 0].copy()
        return Frame(image=image, slots=slots, ids=ids_for(self.store, slots), gpu_ms=t.durations_ms())

    def release(self) -> None:
        for obj in (self.raster, self.shading, self.vis, self.timestamps):
            obj.release()
        if self._own_scene:
            self.scene.release()


def make_raster(glc: GLContext, store: PointStore, vis: VisibilityBuffer, raster: Raster,
                tuning: ComputeTuning = DEFAULT_TUNING):
    """tuning: how a compute raster walks the store (GL_POINTS ignores it). A compute
    raster of the batched layout gets a cull pass: batches outside the view are skipped."""
    if raster is Raster.POINTS:
        return PointsRaster(glc, store, vis)
    return ComputeRaster(glc, store, vis, atomic64=raster is Raster.COMPUTE and glc.caps.atomic_int64,
                         culling=CullPass(glc, store) if store.batched else None, tuning=tuning)


def raster_path(kind: Raster, raster) -> str:
    if kind is Raster.POINTS:
        return "GL_POINTS"
    return "compute 64-bit atomicMin" if raster.atomic64 else "compute 32-bit two-pass"


def ids_for(store: PointStore, slots: np.ndarray) -> np.ndarray:
    """File-order indices of shuffled slots (the inverse permutation, exact, then the
    store's way back from reordered batches)."""
    ids = np.full(slots.shape, EMPTY, dtype=np.uint32)
    hit = slots != EMPTY
    ids[hit] = store.file_indices(store.permutation.inverse(slots[hit])).astype(np.uint32)
    return ids
