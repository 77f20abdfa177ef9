"""Positions as 30-bit integers relative to their batch (the 2-billion-points paper,
§3.4), GPU-free: the twin of shaders/points.glsl's decoding and of what distribute
uploads.

Each batch has a frame: a base (its box's least corner, float32 relative to the
cloud origin, exactly what the GPU adds) and a step per axis (its extent over
2^30 - 1 cells). A point is q = round((p - base) / step) in [0, 2^30) per axis,
stored as three words of 10+10+10 bits: word 0 holds the top 10 bits of x, y and z,
word 1 the middle ones, word 2 the low ones. So a pass can read 1, 2 or 3 words of a
point (10-, 20- or 30-bit precision): a distant batch is drawn from one 4-byte word a
point. The words of a point never drawn (non-finite coordinates or shown value) are
HIDDEN_WORD, which no position has (bits 30 and 31 are always clear). Distribute
encodes on the GPU, in float64, from the float records staged as for the float store."""

from __future__ import annotations

import enum
from dataclasses import replace

import numpy as np

from progressive import batches as batch_boxes
from progressive.loaders.types import Batch, cell_runs
from progressive.permutation import BATCH_POINTS

LEVEL_BITS = 10
"""Bits of each axis in one word."""
LEVELS = 3
"""Words a position takes; reading k of them gives 10·k-bit precision."""
BITS = LEVEL_BITS * LEVELS
CELLS = 1 << BITS
HIDDEN_WORD = 0xFFFFFFFF
FRAME_FLOATS = 8
"""A frame on the GPU: base xyz, a pad, step xyz, a pad (two std430 vec4)."""
POSITION_WORDS = LEVELS
PLANES = POSITION_WORDS + 1
"""The planes of the word store: the position words, then the attribute word."""


class Encoding(enum.Enum):
    """How the store keeps a point's position (16 bytes a point either way). WORDS:
    30-bit integers relative to the batch, one buffer per word, so a pass reads only
    the words it needs; FLOAT: float32 xyz relative to the cloud origin beside the
    attribute word in one record (the layouts without batches, and the bench's baseline)."""

    WORDS = "30-bit words relative to the batch"
    FLOAT = "float32 records"


class Precision(enum.Enum):
    """How many words of each batch a render reads. EXACT: all three (the render
    contract's ids). ADAPTIVE: the fewest whose position error, projected, stays
    under ADAPTIVE_ERROR_PX of a pixel for every point of the batch."""

    EXACT = "exact"
    ADAPTIVE = "adaptive"


ADAPTIVE_ERROR_PX = 0.5
"""The adaptive precision's bound: no point drawn further than this from where its
exact position projects, in pixels."""


def empty_frames(batches: int) -> np.ndarray:
    """(batches, FRAME_FLOATS) float32 frames of batches not yet encoded."""
    return np.zeros((batches, FRAME_FLOATS), dtype=np.float32)


def quantize(positions: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """(n, 3) int64 cells of positions, each in its frame ((n, FRAME_FLOATS), or one
    row for all), rounded to the nearest (even) in float64 as shaders/distribute.comp
    does; -1 rows for non-finite positions."""
    p = np.asarray(positions, dtype=np.float64)
    frames = np.asarray(frames).reshape(-1, FRAME_FLOATS)
    base, step = frames[:, 0:3].astype(np.float64), frames[:, 4:7].astype(np.float64)
    with np.errstate(invalid="ignore"):
        q = np.rint((p - base) / step)
    bad = ~np.isfinite(q).all(axis=1)
    q = np.clip(np.where(np.isfinite(q), q, 0), 0, CELLS - 1).astype(np.int64)
    q[bad] = -1
    return q


def pack_words(q: np.ndarray) -> np.ndarray:
    """(n, 3) uint32 words of (n, 3) cells; rows with a negative cell (a point never
    drawn) get HIDDEN_WORD in every word (shaders/distribute.comp encode_words, the twin)."""
    q = np.asarray(q, dtype=np.int64)
    out = np.empty((q.shape[0], LEVELS), dtype=np.uint32)
    mask = (1 << LEVEL_BITS) - 1
    for level in range(LEVELS):
        part = (q >> (LEVEL_BITS * (LEVELS - 1 - level))) & mask
        out[:, level] = (part[:, 0] << (2 * LEVEL_BITS)) | (part[:, 1] << LEVEL_BITS) | part[:, 2]
    out[(q < 0).any(axis=1)] = HIDDEN_WORD
    return out


def unpack_cells(words: np.ndarray, levels: int = LEVELS) -> np.ndarray:
    """(n, 3) int64 cells the GPU decodes from the first `levels` words: the cell's
    centre at coarser levels (the lowest bits half way), exact at LEVELS."""
    w = np.asarray(words, dtype=np.int64)
    mask = (1 << LEVEL_BITS) - 1
    q = np.zeros((w.shape[0], 3), dtype=np.int64)
    for level in range(levels):
        shift = LEVEL_BITS * (LEVELS - 1 - level)
        for axis in range(3):
            q[:, axis] |= ((w[:, level] >> (LEVEL_BITS * (2 - axis))) & mask) << shift
    if levels < LEVELS:
        q += 1 << (LEVEL_BITS * (LEVELS - levels) - 1)
    return q


def decode_frames(words: np.ndarray, frames: np.ndarray, levels: int = LEVELS) -> np.ndarray:
    """(n, 3) float32 positions relative to the origin as shaders/points.glsl computes
    them from each point's words and its batch's frame ((n, FRAME_FLOATS)): base +
    float(q)·step, each operation rounded to float32 (`precise` there), NaN where
    word 0 is HIDDEN_WORD."""
    q = unpack_cells(words, levels).astype(np.float32)
    frames = np.asarray(frames, dtype=np.float32)
    p = frames[:, 0:3] + q * frames[:, 4:7]
    p[np.asarray(words)[:, 0] == HIDDEN_WORD] = np.nan
    return p


def cell_size(frames: np.ndarray, levels: int) -> np.ndarray:
    """(batches, 3) extent of a cell read from `levels` words."""
    return frames[:, 4:7].astype(np.float64) * float(1 << (LEVEL_BITS * (LEVELS - levels)))


class BatchAssembler:
    """Which points to (re-)encode as loader batches arrive. A batch's frame is of all
    its points, but loader batches end wherever their reads do (and threads deliver
    them in any order): the whole batches of what is added are encoded at once, while
    the parts of a batch shared with a neighbour are kept (under a batch of points a
    boundary) and the batch is encoded again, all its parts so far in one frame, each
    time a part arrives, until it is complete (a batch split into k parts is sent
    about k²/2 parts' worth: loader batches are far larger than batches). So every point loaded is drawn at once,
    and a complete batch ends in the frame of its own points."""

    def __init__(self, points: int, keep=None):
        """keep(part, lo, hi): what to hold of rows lo..hi of a part (a copy, so a held
        part does not keep its whole loader batch alive); None holds the part itself."""
        self.points = points
        self.keep = keep
        self._parts: dict[int, list] = {}
        self._have: dict[int, int] = {}

    def expected(self, b: int) -> int:
        return min(BATCH_POINTS, self.points - b * BATCH_POINTS)

    @property
    def held(self) -> int:
        """Points kept of incomplete batches."""
        return sum(self._have.values())


    def add(self, start: int, count: int, part) -> list:
        """Groups to encode now, each in frames of its own points: [(held, [(start,
        count, [(part, lo, hi), ...]), ...]), ...], runs of consecutive file indices from
        rows lo..hi of the objects added. A group is one run of whole batches (held
        None), or every part kept so far of batch `held` (as its contiguous runs)."""
        groups: list = []
        run_lo = None
        for b in range(start // BATCH_POINTS, -(-(start + count) // BATCH_POINTS) if count else 0):
            lo = max(start, b * BATCH_POINTS) - start
            hi = min(start + count, (b + 1) * BATCH_POINTS) - start
            if hi - lo == self.expected(b):
                run_lo = lo if run_lo is None else run_lo
                continue
            if run_lo is not None:
                groups.append((None, [(start + run_lo, lo - run_lo, [(part, run_lo, lo)])]))
                run_lo = None
            groups.append((b, self._hold(b, start + lo, part, lo, hi)))
        if run_lo is not None:
            groups.append((None, [(start + run_lo, count - run_lo, [(part, run_lo, count)])]))
        return groups

    def _hold(self, b: int, at: int, part, lo: int, hi: int) -> list:
        if self.keep is not None:
            part, lo, hi = self.keep(part, lo, hi), 0, hi - lo
        pieces = self._parts.setdefault(b, [])
        pieces.append((at, part, lo, hi))
        pieces.sort(key=lambda x: x[0])
        self._have[b] = self._have.get(b, 0) + hi - lo
        if self._have[b] >= self.expected(b):
            del self._parts[b], self._have[b]
        runs = [[pieces[0]]]
        for piece in pieces[1:]:
            at, _, lo, hi = runs[-1][-1]
            if piece[0] == at + hi - lo:
                runs[-1].append(piece)
            else:
                runs.append([piece])
        return [(r[0][0], sum(hi - lo for _, _, lo, hi in r), [(part, lo, hi) for _, part, lo, hi in r])
                for r in runs]


def frames_from_boxes(boxes: np.ndarray) -> np.ndarray:
    """(k, FRAME_FLOATS) frames of k batches' boxes (progressive/batches.py, float32):
    base the least corner, step the extent over CELLS - 1 rounded up (so the far corner
    is a cell), 1 on a flat axis (any step encodes q = 0) or an empty box."""
    lo, hi = boxes[:, 0:3], boxes[:, 4:7]
    empty = ~(lo <= hi).all(axis=1)
    lo = np.where(empty[:, None], np.float32(0), lo)
    hi = np.where(empty[:, None], np.float32(0), hi)
    step = ((hi.astype(np.float64) - lo) / (CELLS - 1)).astype(np.float32)
    short = lo.astype(np.float64) + step.astype(np.float64) * (CELLS - 1) < hi
    step = np.where(short, np.nextafter(step, np.float32(np.inf)), step)
    frames = empty_frames(boxes.shape[0])
    frames[:, 0:3], frames[:, 4:7] = lo, np.where(step > 0, step, np.float32(1))
    return frames


def cell_shifts(least: np.ndarray, most: np.ndarray) -> np.ndarray:
    """(k, 3) bits each batch's integers move up so that its extent fills the 30 bits:
    the coarse words then hold the top bits of the batch, not of 2^30 cells."""
    extent = np.asarray(most, dtype=np.int64) - np.asarray(least, dtype=np.int64)
    width = np.where(extent > 0, np.floor(np.log2(np.maximum(extent, 1))).astype(np.int64) + 1, 0)
    return np.clip(BITS - width, 0, BITS)


CELL_FRAME_WORDS = 4
"""A LAS batch's cell frame on the GPU (cell_frames): its least integers and its shifts."""


def cell_frames(least: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """(k, CELL_FRAME_WORDS) uint32 frames from which the distribute pass encodes a LAS
    batch's integers staged as the file has them (shaders/distribute.comp STAGED_CELLS):
    the low 32 bits of its least X, Y, Z (the staged integers less them wrap to the exact
    differences, which are under 2^31) and its three shifts, a byte each."""
    s = np.asarray(shift, dtype=np.uint32)
    frames = np.empty((s.shape[0], CELL_FRAME_WORDS), dtype=np.uint32)
    frames[:, :3] = np.asarray(least, dtype=np.int64) & 0xFFFFFFFF
    frames[:, 3] = s[:, 0] | (s[:, 1] << 8) | (s[:, 2] << 16)
    return frames


def scaled_cells(cells: np.ndarray, scale, offset, origin: np.ndarray) -> np.ndarray:
    """(k, 3) float64 coordinates less the origin of a LAS file's integers, as a LAS
    batch's positions are scaled (Grid.positions): their float32 is exactly those points'
    positions."""
    v = np.asarray(cells, dtype=np.float64) * np.asarray(scale, dtype=np.float64)
    v += np.asarray(offset, dtype=np.float64)
    v -= np.asarray(origin, dtype=np.float64)
    return v


def integer_frames(least: np.ndarray, shift: np.ndarray, scale, offset, origin: np.ndarray) -> np.ndarray:
    """(k, FRAME_FLOATS) frames of k batches kept as a LAS file's own integers, moved up
    `shift` bits (cell = (integer - least) · 2^shift, lossless): base the batch's least
    integer scaled as the loader scales coordinates (scaled_cells, then float32: exactly
    that point's float32 position), step the file's scale over 2^shift (exact in float32)."""
    frames = empty_frames(least.shape[0])
    frames[:, 0:3] = scaled_cells(least, scale, offset, origin)
    frames[:, 4:7] = np.ldexp(np.asarray(scale, dtype=np.float32), -np.asarray(shift, dtype=np.int32))
    return frames


def cell_boxes(least: np.ndarray, most: np.ndarray, scale, offset, origin: np.ndarray) -> np.ndarray | None:
    """(k, BOX_FLOATS) boxes of k batches of a LAS file's integers from their least and
    most cells, scaled as the loader scales coordinates (scaled_cells): the scaling is
    monotonic, so these are the float32 positions' least and greatest, which
    batches.boxes_of would find in two more passes over the points. None where one is
    not finite (boxes_of then leaves such points out)."""
    with np.errstate(over="ignore"):
        lo, hi = (scaled_cells(c, scale, offset, origin).astype(np.float32) for c in (least, most))
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        return None
    boxes = batch_boxes.empty_boxes(lo.shape[0])
    boxes[:, 0:3], boxes[:, 4:7] = np.minimum(lo, hi), np.maximum(lo, hi)     # a negative scale turns them
    return boxes


def with_runs(batch: Batch) -> Batch:
    """A loaded batch with the least and most coordinates of each store batch it
    touches, which frame_parts then takes: a LAS batch's integers (Grid.runs), a
    fast-format batch's float32 positions (Batch.boxes). The loader's parser threads
    find them (CloudLoader's on_parsed), not the frame loop's thread."""
    if batch.count == 0:
        return batch
    if batch.grid is not None:
        return replace(batch, grid=replace(batch.grid, runs=cell_runs(batch.grid.cells, batch.start, BATCH_POINTS)))
    if batch.records is not None:
        return replace(batch, boxes=batch_boxes.box_runs(batch.positions, batch.start, batch.nonfinite_positions == 0))
    return batch


def node_runs(node: Batch) -> Batch:
    """A streamed node with the least and most integers of each store batch it will
    fill: its i-th takes its rows [i·B, (i+1)·B), so they are found as if it began at a
    batch's start (Scene.write_store_batches moves them to where it writes the node),
    on the node's reading thread rather than the frame loop's (frame_parts took 0.20-0.22
    ms a node of the 20 M-point COPC on the 2-core machine, 0.12-0.15 ms with them:
    bench/results/llvmpipe/stream_store_probes/)."""
    if node.count == 0 or node.grid is None:
        return node
    return replace(node, grid=replace(node.grid, runs=cell_runs(node.grid.cells, 0, BATCH_POINTS)))


def cell_range(grid, start: int) -> tuple[int, np.ndarray, np.ndarray]:
    """The first batch that file indices [start, start+n) of a LAS batch's Grid touch
    and the least and most (k, 3) int64 cells of the points in each batch touched
    (progressive/batches.py boxes_of, for its integers): its runs where the parser
    found them for these rows, else from its cells."""
    runs = grid.runs
    if runs is None or not runs.of(start, grid.cells.shape[0], BATCH_POINTS):
        runs = cell_runs(grid.cells, start, BATCH_POINTS)
    return runs.first, runs.least, runs.most


ERROR_SLACK = 1e-3
"""Relative slack on the cell's half diagonal (the bound's own float32 arithmetic)."""
FLOAT_ROUNDING = 2.0**-22
"""Error of float32 decoding relative to the magnitude of the base plus the batch's
extent: float(q), the product and the sum each round once (2^-24 each, and a margin)."""


def glsl_defines() -> str:
    return f"#define ERROR_SLACK {ERROR_SLACK!r}\n#define FLOAT_ROUNDING {FLOAT_ROUNDING!r}\n"


def pixel_scale(view) -> float:
    """Pixels a displacement of one unit may move a drawn point, at depth 1 where
    perspective (ViewUniforms): a point's column moves by W/2·(sx·|dx| + |dz|)/z, its
    row by H/2·(sy·|dy| + |dz|)/z, as |x/z| <= 1/sx inside the image; orthographic
    W/2·sx·|dx| and H/2·sy·|dy|."""
    sx, sy = float(view.projection[0]), float(view.projection[1])
    w, h = view.size
    extra = 1.0 if view.perspective else 0.0
    return float(np.float32(np.hypot(0.5 * w * (sx + extra), 0.5 * h * (sy + extra))))


def levels_needed(frames: np.ndarray, depth_min: np.ndarray, view, bound: float = ADAPTIVE_ERROR_PX) -> np.ndarray:
    """The fewest words (1..LEVELS) of each batch whose position error, projected,
    stays under `bound` pixels (shaders/cull.comp batch_levels, the twin): a cell's half
    diagonal (with ERROR_SLACK) plus float32 decoding's rounding, e, times pixel_scale
    over the least depth the exact point can have: its box's least corner depth, and
    near - e (the drawn point's depth is at least near)."""
    scale = pixel_scale(view)
    near = float(view.projection[2])
    levels = np.full(frames.shape[0], LEVELS, dtype=np.uint32)
    f = frames.astype(np.float64)
    rounding = FLOAT_ROUNDING * (np.linalg.norm(f[:, 0:3], axis=1) + np.linalg.norm(f[:, 4:7], axis=1) * CELLS)
    for k in range(LEVELS - 1, 0, -1):
        e = 0.5 * np.linalg.norm(cell_size(frames, k), axis=1) * (1 + ERROR_SLACK) + rounding
        z = np.maximum(depth_min, near - e) if view.perspective else np.ones_like(e)
        levels = np.where((z > 0) & (e * scale <= bound * z), k, levels)
    return levels
