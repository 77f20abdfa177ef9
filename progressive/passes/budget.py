"""The GPU side of the adaptive fill budget: timestamps land in a buffer through
GL_QUERY_BUFFER and a 1x1x1 compute shader turns them into the next fill's range
and indirect dispatch arguments. The CPU never waits for any of it."""

from __future__ import annotations

import ctypes
import enum

import numpy as np

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.budget import (
    FIRST_INITIAL,
    FIRST_MIN,
    FIRST_SHARE,
    GAIN_MAX,
    GAIN_MIN,
    GAIN_ONE,
    GAIN_STEP_MAX,
    GAIN_STEP_MIN,
    GROW_STAGES,
    BudgetParams,
)
from progressive.context import GLContext
from progressive.glext import GL_QUERY_BUFFER, GL_QUERY_RESULT, GL_TIMESTAMP
from progressive.gpu import dispatch_defines
from progressive.passes.handles import (
    DRAW_ARGS_WORD,
    FILL_ARGS_BYTES,
    FILL_PIECES,
    TIMESTAMP_SLOTS,
    WALK_ARGS_WORD,
    FillPieces,
    Stamp,
    StateWord,
)


class Stage(enum.IntEnum):
    """What a run of budget.comp does (the fill state and timestamp layouts it shares
    with the rasterizers and the statistics are in passes/handles.py)."""

    BEGIN = 0
    ADAPT = 1
    GROW = 2


def layout_defines() -> dict[str, int]:
    d = dict(StateWord.defines(), **dispatch_defines())
    d.update({f"TS_{s.name}": int(s) for s in Stamp})
    d.update({f"STAGE_{s.name}": int(s) for s in Stage})
    d["TIMESTAMP_SLOTS"] = TIMESTAMP_SLOTS
    d["FILL_PIECES"] = f"{FILL_PIECES}u"
    d["FIRST_INITIAL"] = f"{FIRST_INITIAL}u"
    d.update({name: f"{value}ul" for name, value in (("GAIN_ONE", GAIN_ONE), ("GAIN_MIN", GAIN_MIN), ("GAIN_MAX", GAIN_MAX),
                                                      ("GAIN_STEP_MIN", GAIN_STEP_MIN), ("GAIN_STEP_MAX", GAIN_STEP_MAX),
                                                      ("FIRST_MIN", FIRST_MIN), ("FIRST_SHARE", FIRST_SHARE))})
    d["DRAW_ARGS_WORD"] = f"{DRAW_ARGS_WORD}u"
    d["WALK_ARGS_WORD"] = f"{WALK_ARGS_WORD}u"
    return d


class BudgetPass:
    def __init__(self, glc: GLContext, points: int, params: BudgetParams, batches: int = 0):
        """batches: the store's batches (batched layout), for the batch walk's dispatch."""
        if not glc.caps.shader_int64:
            raise ValueError("the GPU budget needs GL_ARB_gpu_shader_int64")
        self.glc, self.points, self.params, self.batches = glc, points, params, batches
        ctx = glc.ctx
        initial = np.zeros(StateWord.WORDS, dtype=np.uint32)
        initial[StateWord.GAIN] = GAIN_ONE
        self.state = ctx.buffer(initial.tobytes())
        self.state.label = "fill state"
        self.args = ctx.buffer(reserve=FILL_ARGS_BYTES)
        self.args.label = "fill dispatch args"
        self.pieces = FillPieces(self.state, self.args)
        self.stamps = ctx.buffer(reserve=2 * TIMESTAMP_SLOTS * 8)
        self.stamps.label = "timestamps"
        self.queries = (ctypes.c_uint * (2 * TIMESTAMP_SLOTS))()
        glc.gl.gen_queries(len(self.queries), self.queries)
        self.program = shaderlib.compute(ctx, "budget.comp", layout_defines(), ("GL_ARB_gpu_shader_int64",), "budget")
        self.parity = 0
        self.have_prev = False
        self.timed_frames = 0       # frames with a fill whose timestamps the budget has had

    @property
    def cold(self) -> bool:
        """No frame with a fill yet: this one knows no rate, so it grows (budget.grow)."""
        return self.timed_frames == 0 and self.params.fixed is None

    def bind(self) -> None:
        self.state.bind_to_storage_buffer(Binding.FILL_STATE)
        self.args.bind_to_storage_buffer(Binding.FILL_ARGS)
        self.stamps.bind_to_storage_buffer(Binding.TIMESTAMPS)

    def stamp(self, which: Stamp) -> None:
        """A GPU timestamp written into this frame's block of the timestamp buffer."""
        gl = self.glc.gl
        slot = self.parity * TIMESTAMP_SLOTS + int(which)
        gl.query_counter(self.queries[slot], GL_TIMESTAMP)
        gl.bind_buffer(GL_QUERY_BUFFER, self.stamps.glo)
        gl.query_into_buffer(self.queries[slot], GL_QUERY_RESULT, ctypes.c_void_p(slot * 8))
        gl.bind_buffer(GL_QUERY_BUFFER, 0)

    def _run(self, stage: Stage, reset: bool = False, grow: int = 0) -> None:
        p, params = self.program, self.params
        p["u_stage"] = int(stage)
        p["u_grow"] = grow
        p["u_points"] = self.points
        p["u_first_fill"] = min(params.fixed if params.fixed is not None else params.first_fill, 2**32 - 1)
        p["u_reset"] = reset
        p["u_fixed"] = params.fixed is not None
        p["u_parity"] = self.parity
        p["u_have_prev"] = self.have_prev
        p["u_goal_ns"] = min(params.goal_ns, 2**32 - 1)
        p["u_min_budget"] = params.min_budget
        p["u_max_budget"] = min(params.max_budget, 2**32 - 1)
        p["u_batches"] = self.batches
        self.glc.ctx.memory_barrier()
        self.bind()
        p.run(1, 1, 1)
        self.glc.ctx.memory_barrier()

    def begin(self, reset: bool) -> None:
        """Place the fixed first fill (pieces 0, 1) at the ring offset."""
        self._run(Stage.BEGIN, reset)

    def adapt(self) -> None:
        """From the first fill's timestamps, place what still fits (pieces 2, 3)."""
        self._run(Stage.ADAPT)

    def grow(self, stage: int) -> None:
        """In a cold frame, from the last stage's timestamps, place growth stage `stage`
        (1 .. GROW_STAGES: pieces 2 + 2·stage and the next)."""
        if not 1 <= stage <= GROW_STAGES:
            raise ValueError(f"growth stages are 1 to {GROW_STAGES}")
        self._run(Stage.GROW, grow=stage)

    def end_frame(self, complete: bool) -> None:
        """Flip timestamp blocks; a frame that skipped its passes gives no previous time."""
        self.have_prev = complete
        self.timed_frames += complete
        self.parity ^= 1

    def release(self) -> None:
        self.glc.gl.delete_queries(len(self.queries), self.queries)
        for obj in (self.state, self.args, self.stamps, self.program):
            obj.release()
