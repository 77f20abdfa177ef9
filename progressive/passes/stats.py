"""Per-frame statistics without stalling: the GPU copies a frame's counters and
timestamps into a ring of small slots and sets a fence; the CPU reads a slot only
once its fence has signalled, a few frames later. Each slot is a buffer of its own:
on the NVIDIA driver, reading one range of a buffer that later frames' copies still
write waited for them (profiled on the H200 machine while loading, the one buffer's
reads took a large share of every frame; with a buffer a slot they no longer showed)."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from progressive.context import GLContext
from progressive.passes.handles import TIMESTAMP_SLOTS, Meta, StateWord

TS_WORD = StateWord.WORDS + StateWord.WORDS % 2          # a slot: the fill state, then (8-byte aligned)
VISIBLE_WORD = TS_WORD + 2 * TIMESTAMP_SLOTS                # the timestamps, the visible count,
EQUAL_WORD = VISIBLE_WORD + 1                               # the equal pixels
GATHER_WORD = VISIBLE_WORD + 2                              # and the gathers
SLOT_WORDS = GATHER_WORD + 1


@dataclass(frozen=True)
class Pending:
    slot: int
    fence: int
    tag: object              # what the CPU knew about the frame


@dataclass(frozen=True)
class GPURecord:
    tag: object
    state: np.ndarray        # StateWord words
    stamps: np.ndarray       # Stamp-indexed uint64 nanoseconds
    visible: int
    equal: int
    gathered: int


class StatsRing:
    def __init__(self, glc: GLContext, slots: int = 8):
        self.glc = glc
        self.slots = slots
        self.buffers = [glc.ctx.buffer(reserve=SLOT_WORDS * 4) for _ in range(slots)]
        for k, buffer in enumerate(self.buffers):
            buffer.label = f"frame stats {k}"
        self.pending: deque[Pending] = deque()
        self.next_slot = 0
        self.dropped = 0

    def record(self, tag, state_buf, stamps_buf, stamps_offset: int, visible_meta_buf, equal_buf) -> None:
        """Queue GPU copies of this frame's counters; drops the frame if every slot is in flight."""
        if len(self.pending) >= self.slots:
            self.dropped += 1
            return
        copy = self.glc.gl.copy_named_buffer_sub_data
        slot = self.buffers[self.next_slot].glo
        self.glc.ctx.memory_barrier()
        copy(state_buf.glo, slot, 0, 0, StateWord.WORDS * 4)
        copy(stamps_buf.glo, slot, stamps_offset, TS_WORD * 4, TIMESTAMP_SLOTS * 8)
        copy(visible_meta_buf.glo, slot, Meta.COUNT * 4, VISIBLE_WORD * 4, 4)
        copy(visible_meta_buf.glo, slot, Meta.GATHERS * 4, GATHER_WORD * 4, 4)
        if equal_buf is not None:
            copy(equal_buf.glo, slot, 0, EQUAL_WORD * 4, 4)
        self.pending.append(Pending(self.next_slot, self.glc.gl.fence(), tag))
        self.next_slot = (self.next_slot + 1) % self.slots

    def collect(self, wait: bool = False) -> list[GPURecord]:
        """Records whose fence has signalled (all of them, waiting, when `wait`)."""
        out = []
        if wait and self.pending:
            self.glc.ctx.finish()
        while self.pending:
            head = self.pending[0]
            if not wait and not self.glc.gl.signaled(head.fence):
                break
            self.pending.popleft()
            self.glc.gl.delete_sync(head.fence)
            words = np.frombuffer(self.buffers[head.slot].read(), dtype=np.uint32)
            out.append(GPURecord(head.tag, words[:StateWord.WORDS].copy(),
                                 words[TS_WORD:TS_WORD + 2 * TIMESTAMP_SLOTS].view(np.uint64).copy(),
                                 int(words[VISIBLE_WORD]), int(words[EQUAL_WORD]), int(words[GATHER_WORD])))
        return out

    def release(self) -> None:
        for p in self.pending:
            self.glc.gl.delete_sync(p.fence)
        self.pending.clear()
        for buffer in self.buffers:
            buffer.release()
