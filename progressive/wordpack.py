"""Attribute words packed straight into staging memory (attribute switching, paper
3.5), GPU-free: bit for bit loaders/records.py attribute_word, the reference, written
into the slot it goes to by one numpy call a kind (no temporaries of a batch's size);
a run of kept batches is packed by several threads (numpy releases the GIL), so
packing keeps up with the GPU's scatter. RGB held as bytes is not packed: its bytes are
copied (WordRun.fill_rgb) and the scatter makes the words."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor

import numpy as np

from progressive.loaders.records import ELEVATION, attribute_word
from progressive.loaders.types import AttributeInfo, AttributeKind, Batch, available_cores

BLOCK_POINTS = 1 << 16
"""Points packed at a time by the reference, for RGB not stored as contiguous bytes."""
PACK_THREADS = min(8, available_cores())
"""Threads that pack a run of words (each a part of it): the cores this process may use
(as the loader's parser threads), at most 8."""
THREAD_POINTS = 1 << 18
"""Fewest points a packing thread is handed: below it, threads cost more than they save."""


class WordPacker:
    """The words of one attribute, as attribute_word(batch, attribute, origin_z) gives
    them, packed piece by piece."""

    def __init__(self, attribute: AttributeInfo, origin_z: float):
        self.attribute, self.origin_z = attribute, origin_z

    def pack(self, out: np.ndarray, batch: Batch, lo: int, hi: int) -> None:
        """out[...] = the words of rows [lo, hi) of `batch` (out: (hi - lo,) uint32,
        maybe mapped memory: written, never read). Each kind is one numpy call over the
        rows where it can be (its loop buffers in cache and releases the GIL)."""
        attr = self.attribute
        floats = out.view(np.float32)
        with np.errstate(over="ignore", invalid="ignore"):
            if attr.name == ELEVATION:      # float32(float64(z) + (origin_z - offset))
                np.add(batch.rows(lo, hi).z(), self.origin_z - attr.offset, out=floats, dtype=np.float64,
                       casting="same_kind")
                return
            values = batch.attributes[attr.name][lo:hi]
            if attr.kind is AttributeKind.CATEGORY:
                np.copyto(out, values.reshape(hi - lo), casting="unsafe")
            elif attr.kind is AttributeKind.RGB:
                self._rgb(out, batch, values, lo, hi)
            else:                           # float32(float64(value) - offset)
                np.subtract(values.reshape(hi - lo), attr.offset, out=floats, dtype=np.float64, casting="same_kind")

    def _rgb(self, out: np.ndarray, batch: Batch, values: np.ndarray, lo: int, hi: int) -> None:
        """R | G << 8 | B << 16 | 0xFF000000: the contiguous RGB bytes read as
        little-endian words 3 bytes apart (the fourth byte, the next point's red, is
        then set by the alpha), the last point on its own (its word would read past)."""
        n = hi - lo
        if values.dtype != np.uint8 or not values.flags.c_contiguous or n == 0:
            for a in range(0, n, BLOCK_POINTS):
                b = min(n, a + BLOCK_POINTS)
                out[a:b] = attribute_word(batch.rows(lo + a, lo + b), self.attribute, self.origin_z)
            return
        words = np.ndarray((n - 1,), dtype="<u4", buffer=values.reshape(-1), strides=(3,))
        np.bitwise_or(words, np.uint32(0xFF000000), out=out[: n - 1])
        r, g, b = (int(c) for c in values[-1])
        out[n - 1] = r | g << 8 | b << 16 | 0xFF000000


class WordRun:
    """Rows of kept batches that follow each other in file order, packed as one run of
    words: parts[k] = (batch, lo, hi) holds file indices start + edges[k] ...
    start + edges[k + 1]."""

    def __init__(self, packer: WordPacker, parts: Sequence[tuple[Batch, int, int]]):
        self.packer = packer
        self.parts = list(parts)
        self.start = self.parts[0][0].start + self.parts[0][1]
        self.edges = np.concatenate([[0], np.cumsum([hi - lo for _, lo, hi in self.parts])]).astype(np.int64)
        at = self.start
        for batch, lo, hi in self.parts:
            if batch.start + lo != at:
                raise ValueError("a run's parts must follow each other in file order")
            at += hi - lo

    @property
    def count(self) -> int:
        return int(self.edges[-1])

    def fill(self, out: np.ndarray, lo: int, hi: int) -> int:
        """Words [lo, hi) of the run into `out` ((hi - lo, 1) or (hi - lo,) uint32);
        nothing is hidden by a word alone, so 0 (distribute's Fill)."""
        flat = out.reshape(hi - lo)
        for batch, first, at, end in self._pieces(lo, hi):
            self.packer.pack(flat[at:end], batch, first, first + end - at)
        return 0

    @property
    def rgb_bytes(self) -> bool:
        """Whether the run's attribute is RGB held as (n, 3) uint8 in every part, so
        fill_rgb can hand its bytes to the GPU as they are (DistributePass.upload_rgb)."""
        name = self.packer.attribute.name
        return self.packer.attribute.kind is AttributeKind.RGB and all(
            b.attributes[name].dtype == np.uint8 and b.attributes[name].shape[1:] == (3,) for b, _, _ in self.parts)

    def fill_rgb(self, out: np.ndarray, lo: int, hi: int) -> int:
        """Points [lo, hi)'s R, G, B bytes into `out` ((hi - lo, 3) uint8): a copy, the
        words made on the GPU (rgb_bytes runs only; distribute's Fill)."""
        name = self.packer.attribute.name
        for batch, first, at, end in self._pieces(lo, hi):
            out[at:end] = batch.attributes[name][first:first + end - at]
        return 0

    def _pieces(self, lo: int, hi: int) -> Iterator[tuple[Batch, int, int, int]]:
        """(batch, its first row, out's first row, out's end) of the parts that hold
        run items [lo, hi), out's rows counted from lo."""
        k = int(np.searchsorted(self.edges, lo, side="right")) - 1
        at = lo
        while at < hi:
            batch, row_lo, _ = self.parts[k]
            end = min(hi, int(self.edges[k + 1]))
            yield batch, row_lo + at - int(self.edges[k]), at - lo, end - lo
            at, k = end, k + 1


def threaded(fill: Callable[[np.ndarray, int, int], int], pool: Executor | None, threads: int,
             least: int = THREAD_POINTS):
    """`fill` with pieces of at least 2·`least` items split over `threads` threads, the
    calling one and the pool's (each writes its own rows of `out`); the sum of what the
    parts return."""
    def split(out: np.ndarray, lo: int, hi: int) -> int:
        parts = min(threads, (hi - lo) // least)
        if pool is None or parts < 2:
            return fill(out, lo, hi)
        cuts = np.linspace(lo, hi, parts + 1).astype(np.int64).tolist()
        jobs = [pool.submit(fill, out[a - lo: b - lo], a, b) for a, b in zip(cuts[1:], cuts[2:])]
        here = fill(out[: cuts[1] - lo], lo, cuts[1])
        return here + sum(job.result() for job in jobs)

    return split
