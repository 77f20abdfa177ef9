"""Prepare: the points visible now become record copies that the next frame
reprojects, and per-pixel attribute words for resolve."""

from __future__ import annotations

import numpy as np

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.context import GLContext
from progressive.gpu import dispatch_defines, grid_2d
from progressive.loaders.records import RECORD_BYTES
from progressive.passes.handles import Meta, Reprojection, Visibility, Winners
from progressive.pointstore import PointStore

GATHER_BYTES = 8
"""A gather: the list entry its record fills and its pixel (two words)."""


class SlotList:
    """Visible points: meta words then slots in one buffer (`meta`), and record copies.
    Capacity is the pixel count, so it cannot overflow (the GPU checks anyway)."""

    META_BYTES = Meta.WORDS * 4

    def __init__(self, glc: GLContext, capacity: int, label: str):
        self.glc = glc
        self.capacity = capacity
        self.meta = glc.ctx.buffer(reserve=self.META_BYTES + max(4, capacity * 4))
        self.meta.label = f"{label} slots"
        self.records = glc.ctx.buffer(reserve=max(16, capacity * RECORD_BYTES))
        self.records.label = f"{label} records"
        self.reset()

    def reset(self) -> None:
        self.glc.gl.clear_u32(self.meta.glo, 0, size=self.META_BYTES, total=self.meta.size)

    def bind_output(self) -> None:
        self.meta.bind_to_storage_buffer(Binding.OUT_SLOTS)
        self.records.bind_to_storage_buffer(Binding.OUT_RECORDS)

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        """The listed slots and records (tests only: waits for the GPU)."""
        count = min(int(np.frombuffer(self.meta.read(4), dtype=np.uint32)[0]), self.capacity)
        slots = np.frombuffer(self.meta.read(count * 4, offset=self.META_BYTES), dtype=np.uint32)
        records = np.frombuffer(self.records.read(count * RECORD_BYTES), dtype=np.uint32).reshape(-1, 4)
        return slots, records

    def release(self) -> None:
        self.meta.release()
        self.records.release()


BALLOT_EXTENSIONS = ("GL_ARB_shader_ballot", "GL_ARB_gpu_shader_int64")


class PreparePass:
    def __init__(self, glc: GLContext, store: PointStore, vis: Visibility, winners: bool = False,
                 ballot: bool | None = None):
        """winners: the raster leaves each pixel's record (Winners, given to each run)
        in place of the hints into the last list. ballot: a subgroup's pixels take their
        list entries together, without a barrier (None: where GL_ARB_shader_ballot is)."""
        self.glc, self.store, self.vis = glc, store, vis
        self.winners = winners
        self.ballot = glc.caps.shader_ballot if ballot is None else ballot
        if self.ballot and not glc.caps.shader_ballot:
            raise ValueError("prepare by ballot needs GL_ARB_shader_ballot")
        defines = dict(Meta.defines(), **dispatch_defines())
        self.append = shaderlib.compute(glc.ctx, "prepare.comp",
                                        dict(defines, ARGS=0, GATHER=0, WINNERS=int(winners), BALLOT=int(self.ballot)),
                                        BALLOT_EXTENSIONS if self.ballot else (), label="prepare")
        self.args = shaderlib.compute(glc.ctx, "prepare.comp", dict(defines, ARGS=1), label="prepare args")
        self.gather = shaderlib.compute(glc.ctx, "prepare.comp", dict(store.defines, **defines, ARGS=0, GATHER=1),
                                        label="prepare gathers")
        self.lists: list[SlotList] = []
        self.hint = self.pixel_words = self.gathers = None
        self.current = 0
        self._allocate()

    def _allocate(self) -> None:
        for obj in (*self.lists, self.hint, self.pixel_words, self.gathers):
            if obj is not None:
                obj.release()
        self.capacity = self.vis.pixels
        self.lists = [SlotList(self.glc, self.capacity, f"visible {i}") for i in range(2)]
        self.hint = self.glc.ctx.buffer(reserve=self.capacity * 4)
        self.hint.label = "reprojection hints"
        self.pixel_words = self.glc.ctx.buffer(reserve=self.capacity * 4)
        self.pixel_words.label = "pixel words"
        self.gathers = self.glc.ctx.buffer(reserve=self.capacity * GATHER_BYTES)
        self.gathers.label = "prepare gathers"

    @property
    def previous(self) -> SlotList:
        """What the last prepare wrote: this frame's reprojection input."""
        return self.lists[self.current]

    @property
    def reprojection(self) -> Reprojection:
        """The handle a rasterizer reprojects this frame's input through."""
        last = self.previous
        return Reprojection(last.meta, last.records, self.hint, self.capacity)

    def invalidate(self) -> None:
        """Forget the visible set (a new size, or records that changed)."""
        if self.capacity != self.vis.pixels:
            self._allocate()
        for lst in self.lists:
            lst.reset()

    def run(self, regather: bool = False, winners: Winners | None = None) -> None:
        """regather: read every visible record from the store (its words were rewritten).
        winners: the raster's records of this frame, where the pass was built for them."""
        if (winners is not None) != self.winners:
            raise ValueError("prepare was built for the winners pass" if self.winners else
                             "prepare was built for hints, not the winners pass")
        out = self.lists[1 - self.current]
        out.reset()
        if winners is not None:
            winners.bind()
            self.append["u_winner_pixels"] = winners.pixels
        else:
            self.reprojection.bind()
        out.bind_output()
        self.vis.bind()
        self.pixel_words.bind_to_storage_buffer(Binding.PIXEL_WORDS)
        self.gathers.bind_to_storage_buffer(Binding.GATHERS)
        for p in (self.append, self.args, self.gather):
            p["u_capacity"] = self.capacity
        self.append["u_size"] = (self.vis.width, self.vis.height)
        self.append["u_regather"] = int(regather)
        self.append.run(*grid_2d(self.vis.width, self.vis.height))
        self.glc.ctx.memory_barrier()
        self.args.run(1, 1, 1)
        self.glc.ctx.memory_barrier()
        self.store.bind()
        self.gather.run_indirect(out.meta, offset=Meta.GATHER_DISPATCH * 4)
        self.glc.ctx.memory_barrier()
        self.current = 1 - self.current

    def release(self) -> None:
        for obj in (*self.lists, self.hint, self.pixel_words, self.gathers, self.append, self.args, self.gather):
            obj.release()
