"""Per-frame statistics without stalling: the GPU copies a frame's counters and
timestamps into a ring of small slots and sets a fence; the CPU reads a slot only
once its fence has signalled, a few frames later."""

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
        self.buffer = glc.ctx.buffer(reserve=slots * SLOT_WORDS * 4)
        self.buffer.label = "frame stats"
        self.pending: deque[Pending] = deque()
        self.next_slot = 0
        self.dropped = 0

    def record(self, tag, state_buf, stamps_buf, stamps_offset: int, visible_meta_buf, equal_buf) -> None:
        """Queue GPU copies of this frame's counters; drops the frame if every slot is in flight."""
        if len(self.pending) >= self.slots:
            self.dropped += 1
            return
        copy = self.glc.gl.copy_named_buffer_sub_data
        base = self.next_slot * SLOT_WORDS * 4
        self.glc.ctx.memory_barrier()
        copy(state_buf.glo, self.buffer.glo, 0, base, StateWord.WORDS * 4)
        copy(stamps_buf.glo, self.buffer.glo, stamps_offset, base + TS_WORD * 4, TIMESTAMP_SLOTS * 8)
        copy(visible_meta_buf.glo, self.buffer.glo, Meta.COUNT * 4, base + VISIBLE_WORD * 4, 4)
        copy(visible_meta_buf.glo, self.buffer.glo, Meta.GATHERS * 4, base + GATHER_WORD * 4, 4)
        if equal_buf is not None:
            copy(equal_buf.glo, self.buffer.glo, 0, base + EQUAL_WORD * 4, 4)
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
            words = np.frombuffer(self.buffer.read(SLOT_WORDS * 4, offset=head.slot * SLOT_WORDS * 4), dtype=np.uint32)
            out.append(GPURecord(head.tag, words[:StateWord.WORDS].copy(),
                                 words[TS_WORD:TS_WORD + 2 * TIMESTAMP_SLOTS].view(np.uint64).copy(),
                                 int(words[VISIBLE_WORD]), int(words[EQUAL_WORD]), int(words[GATHER_WORD])))
        return out

    def release(self) -> None:
        for p in self.pending:
            self.glc.gl.delete_sync(p.fence)
        self.pending.clear()
        self.buffer.release()
