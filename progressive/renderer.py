"""A thin composition of the passes: a cloud in a shuffled GPU buffer, rendered whole
("brute force") with the chosen rasterizer, coloured by one attribute."""

from __future__ import annotations

import enum
import time
from dataclasses import dataclass, field

import numpy as np

from progressive.camera import Camera, view_uniforms
from progressive.colors import ColorStyle, Colormap, robust_range
from progressive.context import GLContext
from progressive.loaders.types import AttributeInfo, AttributeKind, Batch, CloudInfo
from progressive.packing import pack_records
from progressive.passes.distribute import DistributePass
from progressive.passes.raster_compute import ComputeRaster
from progressive.passes.raster_points import PointsRaster
from progressive.passes.resolve import ResolvePass
from progressive.passes.visibility import EMPTY, VisibilityBuffer
from progressive.pointstore import PointStore
from progressive.timing import Timestamps

RANGE_SAMPLE_PER_BATCH = 20_000


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
    def __init__(self, glc: GLContext, info: CloudInfo, attribute: AttributeInfo, *,
                 raster: Raster = Raster.COMPUTE, width: int = 1280, height: int = 720,
                 chunk_points: int | None = None):
        self.glc, self.info, self.attribute = glc, info, attribute
        self.store = PointStore(glc, info.points, chunk_points=chunk_points)
        self.distribute = DistributePass(glc, self.store)
        self.vis = VisibilityBuffer(glc, width, height)
        self.raster_kind = raster
        if raster is Raster.POINTS:
            self.raster = PointsRaster(glc, self.store, self.vis)
        else:
            self.raster = ComputeRaster(glc, self.store, self.vis,
                                        atomic64=raster is Raster.COMPUTE and glc.caps.atomic_int64)
        self.resolve = ResolvePass(glc, self.store, self.vis)
        self.timestamps = Timestamps(glc)
        self.loaded = 0
        self._samples: list[np.ndarray] = []
        self.upload_seconds = 0.0

    @property
    def raster_path(self) -> str:
        if self.raster_kind is Raster.POINTS:
            return "GL_POINTS"
        return "compute 64-bit atomicMin" if self.raster.atomic64 else "compute 32-bit two-pass"

    def add_batch(self, batch: Batch) -> None:
        t0 = time.perf_counter()
        records = pack_records(batch, self.attribute, float(self.info.origin[2]))
        self.distribute.upload(records, batch.start)
        if self.attribute.kind is AttributeKind.SCALAR:
            step = max(1, batch.count // RANGE_SAMPLE_PER_BATCH)
            self._samples.append(records[::step, 3].view(np.float32))
        self.loaded += batch.count
        self.upload_seconds += time.perf_counter() - t0

    def value_range(self) -> tuple[float, float]:
        """Robust (1-99 %) range of the packed scalar values seen so far."""
        if not self._samples:
            return (0.0, 1.0)
        return robust_range(np.concatenate(self._samples))

    def style(self, colormap: Colormap = Colormap.VIRIDIS, background=(0, 0, 0)) -> ColorStyle:
        return ColorStyle.for_attribute(self.attribute, self.value_range(), colormap, background)

    def render(self, camera: Camera, width: int, height: int, style: ColorStyle) -> Frame:
        self.vis.resize(width, height)
        view = view_uniforms(camera, self.info.origin, width, height)
        t = self.timestamps
        t.reset()
        t.stamp("start")
        self.vis.clear()
        t.stamp("clear")
        self.raster.draw(view, 0, self.store.count)
        t.stamp("raster")
        self.resolve.run(style)
        t.stamp("resolve")
        image = self.resolve.read()
        slots = self.vis.read()[:, :, 0].copy()
        return Frame(image=image, slots=slots, ids=self.ids_for(slots), gpu_ms=t.durations_ms())

    def ids_for(self, slots: np.ndarray) -> np.ndarray:
        """File-order indices of shuffled slots (the inverse permutation, exact)."""
        ids = np.full(slots.shape, EMPTY, dtype=np.uint32)
        hit = slots != EMPTY
        ids[hit] = self.store.permutation.inverse(slots[hit]).astype(np.uint32)
        return ids

    def release(self) -> None:
        for obj in (self.raster, self.resolve, self.distribute, self.vis, self.store, self.timestamps):
            obj.release()
