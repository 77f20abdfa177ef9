"""Prepare: the slots visible now become the list the next frame reprojects."""

from __future__ import annotations

import numpy as np

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.context import GLContext
from progressive.gpu import grid_2d
from progressive.passes.visibility import VisibilityBuffer


class SlotList:
    """Visible slots (capacity = pixel count, so it cannot overflow; still checked on
    the GPU) and meta words: count, dispatch args (1-3), draw args (4-7)."""

    DISPATCH_OFFSET = 4
    DRAW_OFFSET = 16

    def __init__(self, glc: GLContext, capacity: int, label: str):
        self.glc = glc
        self.capacity = capacity
        self.slots = glc.ctx.buffer(reserve=max(4, capacity * 4))
        self.slots.label = label
        self.meta = glc.ctx.buffer(reserve=32)
        self.meta.label = f"{label} meta"
        self.reset()

    def reset(self) -> None:
        self.glc.gl.clear_u32(self.meta.glo, 0, total=self.meta.size)

    def bind(self) -> None:
        self.slots.bind_to_storage_buffer(Binding.SLOT_LIST)
        self.meta.bind_to_storage_buffer(Binding.SLOT_LIST_META)

    def read(self) -> np.ndarray:
        """The listed slots (tests only: waits for the GPU)."""
        count = min(int(np.frombuffer(self.meta.read(4), dtype=np.uint32)[0]), self.capacity)
        return np.frombuffer(self.slots.read(count * 4), dtype=np.uint32)

    def release(self) -> None:
        self.slots.release()
        self.meta.release()


class PreparePass:
    def __init__(self, glc: GLContext, vis: VisibilityBuffer):
        self.glc, self.vis = glc, vis
        self.append = shaderlib.compute(glc.ctx, "prepare.comp", {"ARGS": 0}, label="prepare")
        self.args = shaderlib.compute(glc.ctx, "prepare.comp", {"ARGS": 1}, label="prepare args")
        self.lists: list[SlotList] = []
        self.current = 0
        self._allocate()

    def _allocate(self) -> None:
        for lst in self.lists:
            lst.release()
        self.capacity = self.vis.pixels
        self.lists = [SlotList(self.glc, self.capacity, f"visible slots {i}") for i in range(2)]

    @property
    def previous(self) -> SlotList:
        """What the last prepare wrote: this frame's reprojection input."""
        return self.lists[self.current]

    def invalidate(self) -> None:
        """Forget the visible set (new size, or nothing to reproject)."""
        if self.capacity != self.vis.pixels:
            self._allocate()
        for lst in self.lists:
            lst.reset()

    def run(self) -> None:
        out = self.lists[1 - self.current]
        out.reset()
        out.bind()
        self.vis.bind()
        for p in (self.append, self.args):
            p["u_capacity"] = self.capacity
        self.append["u_size"] = (self.vis.width, self.vis.height)
        self.append.run(*grid_2d(self.vis.width, self.vis.height))
        self.glc.ctx.memory_barrier()
        self.args.run(1, 1, 1)
        self.glc.ctx.memory_barrier()
        self.current = 1 - self.current

    def release(self) -> None:
        for obj in (*self.lists, self.append, self.args):
            obj.release()
