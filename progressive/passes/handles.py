"""What passes hand each other: the layouts of shared buffers and small typed handles
to them, made by the pass that owns the buffers and given to the passes that read
them. A leaf: no pass module imports another pass module, only this one, so a
rasterizer knows a fill piece or a reprojection list by its handle, not by the
attributes of the budget or prepare pass."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import ClassVar, Protocol

import moderngl

from progressive.bindings import Binding
from progressive.budget import GROW_STAGES

EMPTY = 0xFFFFFFFF
"""A visibility pixel (slot and depth bits) that no point has reached."""


class Visibility(Protocol):
    """The per-pixel visibility buffer as its readers see it (passes/visibility.py owns
    it): 8 bytes a pixel, the slot of the nearest point then its depth bits. A live
    object, not a frozen snapshot: it reallocates on resize and readers hold it across
    frames."""

    @property
    def width(self) -> int: ...

    @property
    def height(self) -> int: ...

    @property
    def pixels(self) -> int: ...

    @property
    def buffer(self) -> moderngl.Buffer: ...

    def bind(self) -> None:
        """At Binding.VISIBILITY (shaders/visibility.glsl)."""


class Source(enum.IntEnum):
    """Where a raster pass takes its slots from (shaders/sources.glsl)."""

    RANGE = 0     # a uniform range: the whole cloud, brute force
    PIECE = 1     # a fill piece placed by the budget pass (FillPieces)
    LIST = 2      # the slots visible last frame (Reprojection)

    @classmethod
    def defines(cls, source: Source) -> dict[str, int]:
        d = {f"SOURCE_{s.name}": int(s) for s in cls}
        d["SOURCE"] = int(source)
        return d


class StateWord(enum.IntEnum):
    """Words of the budget pass's fill state."""

    OFFSET = 0
    RATE_POINTS = 1
    RATE_NS = 2
    GAIN = 3
    FILLED = 4          # ring slots filled since the last reset, saturating at the cloud size
    BUDGET = 5          # the adaptive part of this frame
    FIRST = 6           # the fixed first part of this frame
    NEXT_FIRST = 7      # the next frame's first part (adaptive: a share of the goal)
    PIECES = 8          # FILL_PIECES x (first slot, count)
    FRAME_FIRST = 24    # this frame's first part and
    FRAME_POINTS = 25   # ... all the points it fills: the next frame measures its rate from them
    FIXED_NS = 26       # the first part's fixed cost (budget.BudgetState.fixed_ns)
    STAGE_POINTS = 27   # the points of a cold frame's last growth stage (budget.grow)
    WORDS = 28

    @classmethod
    def defines(cls) -> dict[str, int]:
        return {f"STATE_{w.name}": int(w) for w in cls}


class Stamp(enum.IntEnum):
    """GPU timestamps of a frame: their slots in its block of the timestamp buffer."""

    FRAME = 0
    FILL = 1
    FIRST_END = 2
    FILL_END = 3
    PREPARE_END = 4
    END = 5
    GROW_1 = 6          # a cold frame's ends of its adaptive part and of its first growth stage
    GROW_2 = 7
    PASS_END = 8        # the end of the frame's first pass over its points (the fill's later passes follow;
                        # the 32-bit index pass over the candidates comes before it)


GROW_STAMPS = (Stamp.GROW_1, Stamp.GROW_2)
"""The stamp before each growth stage (budget.GROW_STAGES of them)."""


TIMESTAMP_SLOTS = 9        # a frame's block of timestamps (two blocks, alternate frames)
FILL_PIECES = 2 * (2 + GROW_STAGES)   # first fill, adaptive fill, a cold frame's growth stages: each maybe wrapped in two
ARGS_BYTES = 12            # one DispatchIndirectCommand
DRAW_ARGS_WORD = FILL_PIECES * 3
DRAW_ARGS_BYTES = 16       # one DrawArraysIndirectCommand
WALK_ARGS_WORD = DRAW_ARGS_WORD + FILL_PIECES * 4    # the batch walk's dispatch arguments
FILL_ARGS_BYTES = FILL_PIECES * (2 * ARGS_BYTES + DRAW_ARGS_BYTES)


class Meta(enum.IntEnum):
    """Words of a slot list's meta buffer (prepare's output, the next reprojection's input)."""

    COUNT = 0
    DISPATCH = 1     # 3 words: the next reprojection's dispatch arguments
    DRAW = 4         # 4 words: the same as draw arguments
    GATHERS = 8      # records that had to come from the shuffled store
    GATHER_DISPATCH = 9     # 3 words: the dispatch arguments of prepare's gathers
    WORDS = 12

    @classmethod
    def defines(cls) -> dict[str, int]:
        return {f"META_{m.name}": int(m) for m in cls}


@dataclass(frozen=True)
class FillPieces:
    """The budget pass's fill pieces of this frame: `state` holds each piece's first
    slot and count (StateWord.PIECES), `args` its indirect dispatch arguments (one
    invocation a slot, and one work group a batch its slices meet) and draw arguments,
    both written on the GPU."""

    state: moderngl.Buffer
    args: moderngl.Buffer
    count: ClassVar[int] = FILL_PIECES

    def bind(self) -> None:
        """What a raster program of Source.PIECE reads (shaders/sources.glsl)."""
        self.state.bind_to_storage_buffer(Binding.FILL_STATE)

    def bind_args(self) -> None:
        """The pieces' arguments as a storage buffer (the 32-bit raster copies them)."""
        self.args.bind_to_storage_buffer(Binding.FILL_ARGS)

    @staticmethod
    def dispatch_offset(piece: int) -> int:
        return piece * ARGS_BYTES

    @staticmethod
    def draw_offset(piece: int) -> int:
        return DRAW_ARGS_WORD * 4 + piece * DRAW_ARGS_BYTES

    @staticmethod
    def walk_offset(piece: int) -> int:
        return WALK_ARGS_WORD * 4 + piece * ARGS_BYTES


@dataclass(frozen=True)
class Reprojection:
    """Prepare's last list, this frame's reprojection input: `meta` (Meta words, then
    the slots), the record copies, the per-pixel hints the raster writes, and the
    list's capacity (the count on the GPU is clamped to it)."""

    meta: moderngl.Buffer
    records: moderngl.Buffer
    hint: moderngl.Buffer
    capacity: int
    dispatch_offset: ClassVar[int] = Meta.DISPATCH * 4
    draw_offset: ClassVar[int] = Meta.DRAW * 4

    def bind(self, hint: bool = True) -> None:
        """What a raster program of Source.LIST, and prepare, read (shaders/sources.glsl);
        hint: also the hints (not for the winners pass, which writes none)."""
        self.meta.bind_to_storage_buffer(Binding.SLOT_LIST)
        self.records.bind_to_storage_buffer(Binding.LIST_RECORDS)
        if hint:
            self.hint.bind_to_storage_buffer(Binding.HINT)


@dataclass(frozen=True)
class Winners:
    """The compute raster's last pass of a frame (its winners pass): each pixel whose
    point was drawn this frame (reprojected from the list or filled from the store)
    holds that point's record at uvec4 `pixel`, and its slot at word `pixel` after them
    (shaders/winners.glsl), so prepare reads new winners in pixel order instead of
    gathering them from the store. Slots are cleared each frame; a pixel whose slot
    differs from its visible one (a record not written) is gathered as before."""

    buffer: moderngl.Buffer
    pixels: int

    def bind(self) -> None:
        self.buffer.bind_to_storage_buffer(Binding.WINNERS)


@dataclass(frozen=True)
class BatchFlags:
    """The cull pass's flag a batch, in view or not, for the frame's last cull run."""

    buffer: moderngl.Buffer

    def bind(self) -> None:
        self.buffer.bind_to_storage_buffer(Binding.BATCH_FLAGS)


class Culling(Protocol):
    """The cull pass as the compute raster uses it (passes/cull.py CullPass): run once a
    frame, then its flags bound for the raster's programs; the raster releases it."""

    batch_flags: BatchFlags

    def run(self, view, precision) -> None: ...

    def release(self) -> None: ...
