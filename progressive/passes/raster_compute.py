"""Compute rasterization into the visibility buffer: one 64-bit atomicMin per point
where GL_NV_shader_atomic_int64 exists, else a depth pass and an index pass (over the
depth pass's candidates, shaders/raster_candidates.comp)."""

from __future__ import annotations

import enum
from dataclasses import dataclass

from progressive import shaderlib
from progressive.bindings import Binding
from progressive.camera import ViewUniforms
from progressive.context import GLContext
from progressive.encoding import Precision
from progressive.gpu import dispatch_defines, fill_uvec4s, grid, set_view
from progressive.loaders.records import RECORD_BYTES
from progressive.passes.handles import (
    EMPTY,
    FILL_PIECES,
    WALK_ARGS_WORD,
    Culling,
    FillPieces,
    Meta,
    Reprojection,
    Source,
    StateWord,
    Visibility,
    Winners,
)
from progressive.permutation import SLICE_POINTS
from progressive.pointstore import PointStore

SUBGROUP_EXTENSIONS = ("GL_KHR_shader_subgroup", "GL_NV_shader_subgroup_partitioned")     # as the driver names them
SUBGROUP_PARTITIONED = ("GL_KHR_shader_subgroup_basic", "GL_NV_shader_subgroup_partitioned")   # as GLSL enables them


def subgroup_reduction_available(glc: GLContext) -> bool:
    """The driver has what the subgroup reduction needs (GL_NV_shader_subgroup_partitioned)."""
    return all(e in glc.ctx.extensions for e in SUBGROUP_EXTENSIONS)


PREFETCH = 4
"""Records each invocation of a batch's work group loads before it draws them: enough
reads in flight to hide the memory's latency behind the atomics (the paper's uvec4
prefetch, 2-billion-points §3.4)."""


@dataclass(frozen=True)
class ComputeTuning:
    """How the compute raster walks the store; each choice gives the same image (the
    tests hold it), the bench measures them side by side.

    batch_groups: brute force and fill pieces run one work group per batch of the
    batched layout, walking its slices in the range, instead of one invocation per
    slot: a culled batch costs its group one read, not a read per point.
    subgroup_reduction: where GL_NV_shader_subgroup_partitioned exists, the points of a
    subgroup that hit one pixel are reduced to one atomic (the least key).
    vector_loads: a batch walk on the word store gives each invocation four consecutive
    records and reads each word plane's four words as one 16-byte load (where the
    batch's records are aligned), instead of `prefetch` records a slice apart. None: on
    the 64-bit path only; the 32-bit two-pass path measured slower with it on the H200
    (bench/results/nvidia-h200/raster_100000000.md), where the 64-bit walk gained.
    prefetch: records each invocation of a one-word walk loads before it draws them.
    candidates: the 32-bit path's depth pass lists the points that lowered or met their
    pixel's depth, and the index pass reads that list (16 bytes a candidate, in order)
    instead of loading, decoding and projecting every point again: 1.2-1.4x faster on
    llvmpipe in an overview (bench/results/llvmpipe/index_candidates/), 1.2x on the H100
    at 100 M points (bench/results/nvidia-h100/adaptive_fold/) and 1.9x at 1 B, where
    the appends cost the depth pass 6 % (bench/results/nvidia-h100/candidates_1B/). A
    view with more candidates than room wastes the appends and walks every point again.
    winners: a progressive frame ends with the winners pass over its points, which
    leaves each pixel's record for prepare (Winners), instead of prepare gathering each
    new winner from the store at random. None: for a store of WINNERS_MIN_BYTES or more."""

    batch_groups: bool = True
    subgroup_reduction: bool = False
    vector_loads: bool | None = None
    prefetch: int = PREFETCH
    winners: bool | None = None
    candidates: bool = True


DEFAULT_TUNING = ComputeTuning()
WINNERS_MIN_BYTES = 256 << 20
"""The store size from which the winners pass is the default: on the H200, 400,000
random 16-byte lookups take 0.10 ms within 256 MiB but 6.4 ms over 2 GiB
(../shared/gpu/README.md); on a store of 1 M points llvmpipe gathers for less than the
pass costs (bench/results/llvmpipe/winners/progressive_1000000.md)."""


class CandidateMeta(enum.IntEnum):
    """Words before the candidates (shaders/candidates.glsl)."""

    COUNT = 0
    DISPATCH = 1        # 3 words: the candidates pass's dispatch arguments
    FALLBACK = 4        # 3 words a fill piece, then 3 for the list: the index pass over their points
    META = -(-(4 + 3 * (FILL_PIECES + 1)) // 4) * 4     # the words before the first candidate (whole uvec4s)

    @classmethod
    def defines(cls) -> dict[str, int]:
        return {f"CANDIDATE_{m.name}": int(m) for m in cls}


CANDIDATE_BYTES = 16
CANDIDATES_PER_PIXEL = 2
"""Room for the candidates of a frame (progressive/memory.py counts it a pixel): a pixel
reached by k points in random order lowers its depth about ln k + 0.58 times (2.9 for
k = 10), and a frame never has more candidates than points; on llvmpipe 1 M points of
the tiled sample at 1280x720 had 251,026, 4 M 432,484. A frame with more runs the index
pass over every point instead (candidates.glsl)."""


class ComputeRaster:
    """`passes` is 1 (64-bit) or 2 (depth, then index): a frame runs pass 0 over all
    its sources before pass 1, so the index pass sees the final depths, and end_pass
    after each pass over all of them (the index pass over the candidates). A progressive
    frame runs `frame_passes`: those and, with ComputeTuning.winners, the winners pass
    last, over the same sources."""

    def __init__(self, glc: GLContext, store: PointStore, vis: Visibility, *, atomic64: bool,
                 culling: Culling | None = None, tuning: ComputeTuning = DEFAULT_TUNING,
                 precision: Precision = Precision.EXACT):
        """culling: the cull pass (made by the composition, released with the raster)
        whose flags skip batches outside the view in ranges and fill pieces, not in the
        reprojection list, whose points were visible; None draws every batch.
        precision: the position words a batch walk reads (Precision; the cull pass
        chooses them per batch, so without culling or batch groups every word)."""
        if atomic64 and not glc.caps.atomic_int64:
            raise ValueError("64-bit atomics requested but GL_NV_shader_atomic_int64 is missing")
        self.glc, self.store, self.vis = glc, store, vis
        self.atomic64 = atomic64
        self.partitioned = tuning.subgroup_reduction and subgroup_reduction_available(glc)
        self.batch_groups = tuning.batch_groups and store.batched
        vector = atomic64 if tuning.vector_loads is None else tuning.vector_loads
        self.vector_loads = vector and self.batch_groups and store.words
        if tuning.prefetch < 1:
            raise ValueError(f"a walk prefetches at least one record, not {tuning.prefetch}")
        self.prefetch = tuning.prefetch
        self.culling = culling if store.batched else None
        self.passes = 1 if atomic64 else 2
        winners = store.capacity * RECORD_BYTES >= WINNERS_MIN_BYTES if tuning.winners is None else tuning.winners
        self.frame_passes = self.passes + int(winners)
        self.precision = precision
        self._winners: Winners | None = None
        self._clear = shaderlib.compute(glc.ctx, "clear.comp", label="clear winners") if winners else None
        self._improved = None
        if winners and store.batched:
            self._improved = glc.ctx.buffer(reserve=-(-store.permutation.batches // 4) * 16)
            self._improved.label = "improved batches"
            self._clear_improved()
        self._candidates = None
        self._candidate_programs: dict[str, object] = {}
        if tuning.candidates and not atomic64:
            self._candidate_programs = {
                name: shaderlib.compute(glc.ctx, "raster_candidates.comp", defines, label=f"raster32 candidates {name}")
                for name, defines in self._candidate_defines().items()}
        self._programs: dict[tuple[Source, int, bool], object] = {}
        for source in Source:
            for pass_index in range(self.frame_passes):
                self.program(source, pass_index)

    def _candidate_defines(self) -> dict[str, dict]:
        """The arguments' program for brute force, for a frame's fill pieces and for them
        and its list; the index pass over the candidates, with the list's hints or without."""
        common = dict(self.store.defines, **CandidateMeta.defines(), **dispatch_defines(), FILL_PIECES=FILL_PIECES)
        args = dict(common, ARGS=1)
        pieces = dict(args, FALLBACK_PIECES=1)
        index = dict(common, IMPROVED=1) if self._improved is not None else common
        return {"args": args, "args pieces": pieces, "args pieces list": dict(pieces, **Meta.defines(), FALLBACK_LIST=1),
                "index": index, "index with hints": dict(index, HINTS=1)}

    @property
    def candidates(self) -> bool:
        """Whether the index pass reads the depth pass's candidates (ComputeTuning.candidates)."""
        return bool(self._candidate_programs)

    def candidate_capacity(self, pixels: int) -> int:
        """Candidates a frame at `pixels` finds room for: CANDIDATES_PER_PIXEL a pixel, no
        more than the store's points and a reprojection list of a point a pixel (a frame
        that draws new batches beside its pieces may draw more: the count decides), nor
        than a storage buffer may hold."""
        most = (self.glc.caps.max_ssbo_bytes - CandidateMeta.META * 4) // CANDIDATE_BYTES
        return min(self.store.capacity + pixels, CANDIDATES_PER_PIXEL * pixels, most)

    def candidates_found(self) -> int:
        """The last frame's candidates, room or not (a readback, for tests and the bench)."""
        return int.from_bytes(self._candidates.read(4, offset=CandidateMeta.COUNT * 4), "little")

    def _reset_candidates(self) -> None:
        """An empty list, with room for this frame's pixels."""
        capacity = self.candidate_capacity(self.vis.pixels)
        size = CandidateMeta.META * 4 + capacity * CANDIDATE_BYTES
        if self._candidates is None or self._candidates.size != size:
            if self._candidates is not None:
                self._candidates.release()
            self._candidates = self.glc.ctx.buffer(reserve=size)
            self._candidates.label = "raster candidates"
        self.glc.gl.clear_u32(self._candidates.glo, 0, size=CandidateMeta.META * 4, total=size)

    def _bind_candidates(self, program) -> None:
        program["u_candidate_capacity"] = self.candidate_capacity(self.vis.pixels)
        self._candidates.bind_to_storage_buffer(Binding.CANDIDATES)

    @property
    def winners(self) -> Winners | None:
        """The winners pass's records of the last frame (None without the pass)."""
        if self.frame_passes == self.passes:
            return None
        if self._winners is None or self._winners.pixels != self.vis.pixels:
            if self._winners is not None:
                self._winners.buffer.release()
            pixels = self.vis.pixels
            buffer = self.glc.ctx.buffer(reserve=(pixels + -(-pixels // 4)) * RECORD_BYTES)
            buffer.label = "winners"
            self._winners = Winners(buffer, pixels)
            self._clear_winners()
        return self._winners

    def _clear_winners(self) -> None:
        """Every slot word empty (a compute clear: glClearBufferSubData took 0.27 ms for
        a 1080p frame's 8 MB on the H200)."""
        w = self._winners
        fill_uvec4s(self._clear, w.buffer, w.pixels, -(-w.pixels // 4), EMPTY)
        self.glc.ctx.memory_barrier()

    def _clear_improved(self) -> None:
        fill_uvec4s(self._clear, self._improved, 0, self._improved.size // 16, 0)
        self.glc.ctx.memory_barrier()

    def program(self, source: Source, pass_index: int, filtering: bool = False):
        """Those without filters are compiled at construction, so no frame pays for a
        compile; those with (ViewUniforms.filtering) when the first view with a filter
        draws, so a start without one compiles none of them."""
        key = (source, pass_index, filtering)
        if key not in self._programs:
            defines = dict(self.store.defines, **Source.defines(source), **StateWord.defines(), **Meta.defines(),
                           CULL=int(self._culls(source)), BATCH_GROUPS=int(self._walks_batches(source)),
                           PREFETCH=self.prefetch, FILTERING=int(filtering))
            if pass_index == self.passes:
                defines.update(ATOMIC64=0, DEPTH_PASS=0, WINNERS=1)
                ext = ()
                label = f"raster winners {source.name.lower()}"
            elif self.atomic64:
                defines["ATOMIC64"] = 1
                ext = ("GL_ARB_gpu_shader_int64", "GL_NV_shader_atomic_int64")
                label = f"raster64 {source.name.lower()}"
            else:
                defines.update(ATOMIC64=0, DEPTH_PASS=int(pass_index == 0))
                if self.candidates:
                    defines.update(CandidateMeta.defines(), CANDIDATES=1)
                ext = ()
                label = f"raster32 {('depth', 'index')[pass_index]} {source.name.lower()}"
            if self.vector_loads and self._walks_batches(source):
                defines["VECTOR_WORDS"] = 1
            if self._marks(source):
                defines["IMPROVED"] = 1
            defines["PARTITIONED"] = int(self.partitioned)
            ext += SUBGROUP_PARTITIONED if self.partitioned else ()
            label += " filtered" if filtering else ""
            self._programs[key] = shaderlib.compute(self.glc.ctx, "raster_compute.comp", defines, ext, label)
        return self._programs[key]

    @property
    def built(self) -> tuple[str, ...]:
        """The labels of the programs compiled so far."""
        return tuple(str(p.label) for p in (*self._candidate_programs.values(), *self._programs.values()))

    def begin_frame(self, view: ViewUniforms) -> None:
        """Flag the batches in view (the frame loop clears the visibility buffer) and
        forget the last frame's winners."""
        if self.culling is not None:
            self.culling.run(view, self.precision)
        if self._winners is not None:
            self._clear_winners()
        if self._improved is not None:
            self._clear_improved()
        if self.candidates:
            self._reset_candidates()

    def end_pass(self, view: ViewUniforms, pass_index: int, pieces: FillPieces,
                 reprojection: Reprojection | None) -> None:
        """After pass `pass_index` over all of a frame's sources: the candidates' index
        pass once the depth pass is done (reprojection: the frame's list, whose points
        leave hints, or None)."""
        if self.candidates and pass_index == 0:
            self._index_candidates(pieces, reprojection, mark=True)

    def _index_candidates(self, pieces: FillPieces | None, reprojection: Reprojection | None, mark: bool) -> None:
        """The index pass over the candidates, after their count has set its dispatch
        arguments and those of the index pass over the pieces' and the list's points: a
        copy of theirs where the candidates overflowed, else no work group, so a frame
        whose candidates were held dispatches that pass for nothing. mark: flag improved
        batches for the winners pass (not in brute force)."""
        args = self._candidate_programs["args" if pieces is None else
                                        "args pieces" if reprojection is None else "args pieces list"]
        self._bind_candidates(args)
        if pieces is not None:
            args["u_piece_args"] = WALK_ARGS_WORD if self.batch_groups else 0
            pieces.bind_args()
        if reprojection is not None:
            reprojection.meta.bind_to_storage_buffer(Binding.SLOT_LIST)
        args.run(1, 1, 1)
        self.glc.ctx.memory_barrier()
        program = self._candidate_programs["index" if reprojection is None else "index with hints"]
        self._bind_candidates(program)
        if reprojection is not None:
            reprojection.hint.bind_to_storage_buffer(Binding.HINT)
        if self._improved is not None:
            program["u_mark"] = int(mark)
            self._improved.bind_to_storage_buffer(Binding.IMPROVED)
            self.store.bind()
        self.vis.bind()
        program.run_indirect(self._candidates, offset=CandidateMeta.DISPATCH * 4)
        self.glc.ctx.memory_barrier()

    def end_frame(self, view: ViewUniforms) -> None:
        """Nothing to gather: atomics wrote the visibility buffer directly."""

    @property
    def cull(self) -> bool:
        return self.culling is not None

    def _culls(self, source: Source) -> bool:
        return self.cull and source is not Source.LIST

    def _walks_batches(self, source: Source) -> bool:
        return self.batch_groups and source is not Source.LIST

    def _marks(self, source: Source) -> bool:
        """Whether the passes over `source` flag improved batches: the store's slots, not
        the list, whose winners the winners pass finds from the list itself."""
        return self._improved is not None and source is not Source.LIST

    def _prepare(self, source: Source, pass_index: int, view: ViewUniforms):
        program = self.program(source, pass_index, view.filtering)
        set_view(program, view)
        if self._culls(source) or self._walks_batches(source):
            program["u_batches"] = self.store.permutation.batches
        if self._culls(source):
            self.culling.batch_flags.bind()
        if self.candidates and pass_index < self.passes:
            self._bind_candidates(program)
        if pass_index == self.passes:
            program["u_winner_pixels"] = self.vis.pixels
            self.winners.bind()
        if self._marks(source):
            if pass_index == self.passes - 1:       # the pass whose atomics decide (64-bit, or the index pass)
                program["u_mark"] = 1
            self._improved.bind_to_storage_buffer(Binding.IMPROVED)
        self.store.bind()
        self.vis.bind()
        return program

    def draw(self, view: ViewUniforms, first: int, count: int) -> None:
        """All passes over slots [first, first+count) (brute force)."""
        if count <= 0:
            return
        self.begin_frame(view)
        for pass_index in range(self.passes):
            if self._falls_back(pass_index) and count <= self.candidate_capacity(self.vis.pixels):
                continue        # every point's candidate was held
            program = self._prepare(Source.RANGE, pass_index, view)
            program["u_first"] = first
            program["u_count"] = count
            if self._marks(Source.RANGE) and pass_index == self.passes - 1:
                program["u_mark"] = 0       # no winners pass follows
            if self.batch_groups:
                program.run(*grid(self.store.permutation.batches, local_size=1))
            else:
                program.run(*grid(count))
            self.glc.ctx.memory_barrier()
            if self.candidates and pass_index == 0:
                self._index_candidates(None, None, mark=False)

    @property
    def draws_batches(self) -> bool:
        """Whether draw_batches can draw whole batches (the batch walk)."""
        return self.batch_groups

    def draw_batches(self, view: ViewUniforms, first: int, count: int, pass_index: int) -> None:
        """Pass `pass_index` over every slot of batches first.. first+count-1 (batches
        written since the last frame): the batch walk from batch `first`'s first slice
        to the store's last slot, one group for each of the `count` batches."""
        program = self._prepare(Source.RANGE, pass_index, view)
        start = first * SLICE_POINTS
        program["u_first"] = start
        program["u_count"] = self.store.capacity - start
        program.run(*grid(count, local_size=1))
        self.glc.ctx.memory_barrier()

    def draw_piece(self, view: ViewUniforms, pieces: FillPieces, piece: int, pass_index: int) -> None:
        program = self._prepare(Source.PIECE, pass_index, view)
        program["u_piece"] = piece
        pieces.bind()
        if self._falls_back(pass_index):
            program.run_indirect(self._candidates, offset=self._fallback_offset(piece))
        else:
            offset = pieces.walk_offset(piece) if self.batch_groups else pieces.dispatch_offset(piece)
            program.run_indirect(pieces.args, offset=offset)
        self.glc.ctx.memory_barrier()

    def _falls_back(self, pass_index: int) -> bool:
        """Whether this pass is the index pass over the points, run only where the frame's
        candidates overflowed (its dispatch arguments set by the candidates' count)."""
        return self.candidates and pass_index == 1

    @staticmethod
    def _fallback_offset(source: int) -> int:
        """Where that pass's dispatch arguments lie: fill piece `source`'s, or the list's
        (source FILL_PIECES), as the candidates' arguments program writes them."""
        return (CandidateMeta.FALLBACK + 3 * source) * 4

    def draw_list(self, view: ViewUniforms, reprojection: Reprojection, pass_index: int) -> None:
        """Reproject the record copies of the points visible last frame."""
        program = self._prepare(Source.LIST, pass_index, view)
        program["u_capacity"] = reprojection.capacity
        reprojection.bind(hint=pass_index < self.passes)
        if self._falls_back(pass_index):
            program.run_indirect(self._candidates, offset=self._fallback_offset(FILL_PIECES))
        else:
            program.run_indirect(reprojection.meta, offset=reprojection.dispatch_offset)
        self.glc.ctx.memory_barrier()

    def release(self) -> None:
        for p in (*self._programs.values(), *self._candidate_programs.values()):
            p.release()
        self._programs = {}
        self._candidate_programs = {}
        if self._winners is not None:
            self._winners.buffer.release()
            self._winners = None
        for obj in (self._clear, self._improved, self._candidates):
            if obj is not None:
                obj.release()
        self._clear = self._improved = self._candidates = None
        if self.culling is not None:
            self.culling.release()
            self.culling = None
