"""The prime-number shuffle of the paper (section 3.3), exact in uint64.

For P prime with P ≡ 3 (mod 4), x -> x² mod P (or P minus it, for x > P/2) is a
bijection on [0, P). Applying it twice, with a rotation by `offset` in between,
gives a permutation in which any contiguous range of slots is a well-mixed subset
of the file. The rotation breaks the paper's fixed points at the start of the range
(0, 1, 16, 81, ... map from file indices 0, 1, 2, 3): with offset 0 this is the
paper's exact formula. Indices >= P stay where they are.

The batched layout keeps the shuffle local: batch b holds file indices
[b·BATCH_POINTS, (b+1)·BATCH_POINTS), consecutive and so spatially compact, shuffled
inside the batch by the same formula (BATCH_POINTS is the prime; a rotation of its
own per batch), and stored in slices of SLICE_POINTS within BATCH_SLOTS slots: slice
k of every batch comes before slice k+1 of any. A work group of SLICE_POINTS
consecutive slots then sees one compact batch's random points, and any prefix of the
slots holds the same share of every batch.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

GOLDEN = 0.6180339887498949
BATCH_SLOTS = 10_240
"""Slots a batch takes in the batched layout (compute_rasterizer's batch size)."""
BATCH_POINTS = 10_223
"""Points of a batch: the largest prime <= BATCH_SLOTS with P ≡ 3 (mod 4), so the prime
permutation shuffles every point of it (none is left in place); the other 17 slots of
each batch stay empty."""
SLICE_POINTS = 256
"""Consecutive slots of one batch: one raster work group (local_size_x)."""
assert BATCH_SLOTS % SLICE_POINTS == 0 and BATCH_POINTS <= BATCH_SLOTS


class FillOrder(enum.Enum):
    """Which points a range of slots holds. FILE (the identity, prime 0) is the paper's
    unshuffled baseline (Table 4, Figure 5): progressive fills then follow file order."""

    SHUFFLED = "shuffled"
    FILE = "file"
    BATCHED = "batched"


LAYOUT = FillOrder.BATCHED
"""The renderer's layout; the others are baselines for benchmarks and tests."""


@lru_cache(maxsize=256)
def prime_for(n: int) -> int:
    """The largest prime P <= n with P ≡ 3 (mod 4); 0 when there is none (n < 3)."""
    p = n - (n - 3) % 4 if n >= 3 else 0
    while p >= 3 and not is_prime(p):
        p -= 4
    return max(p, 0)


_WITNESSES = (2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37)


def is_prime(n: int) -> bool:
    """Miller-Rabin with the first twelve primes as witnesses: deterministic for every
    n < 3.3·10²⁴, far beyond uint64. Written out because importing sympy for it cost
    0.3 s of every run's time to first image."""
    if n < 2:
        return False
    for q in _WITNESSES:
        if n % q == 0:
            return n == q
    d, r = n - 1, 0
    while d % 2 == 0:
        d, r = d // 2, r + 1
    for a in _WITNESSES:
        x = pow(a, d, n)
        if x in (1, n - 1):
            continue
        for _ in range(r - 1):
            x = x * x % n
            if x == n - 1:
                break
        else:
            return False
    return True


@dataclass(frozen=True)
class Permutation:
    """File-order index -> slot in the shuffled buffer, for a cloud of n points."""

    n: int
    prime: int
    offset: int
    batches: int = 0        # batched layout: the number of batches; 0: one shuffle over the whole cloud

    @classmethod
    def for_count(cls, n: int, *, rotate: bool = True, order: FillOrder = FillOrder.SHUFFLED) -> Permutation:
        limit = (2**32 // BATCH_SLOTS) * BATCH_POINTS if order is FillOrder.BATCHED else 2**32   # slots are uint32
        if not 0 <= n < limit:
            raise ValueError(f"point count {n} outside [0, {limit})")
        if order is FillOrder.FILE:
            return cls(n=n, prime=0, offset=0)
        if order is FillOrder.BATCHED:
            p = BATCH_POINTS
            return cls(n=n, prime=p, offset=int(p * GOLDEN) if rotate else 0, batches=max(1, -(-n // BATCH_POINTS)))
        p = prime_for(n)
        return cls(n=n, prime=p, offset=int(p * GOLDEN) if rotate else 0)

    @property
    def slots(self) -> int:
        """Slots of the layout: the batched one pads the last batch (empty slots never draw)."""
        return self.batches * BATCH_SLOTS if self.batches else self.n

    def kept(self, capacity: int) -> int:
        """File points whose slot is below `capacity` (what a store of that many slots
        holds): each full batch keeps the shuffled positions of whole rounds of slices and
        part of the next (its empty last slots aside), the short last batch is counted."""
        if not self.batches or capacity >= self.slots:
            return min(capacity, self.n)
        rounds, rest = divmod(capacity, self.batches * SLICE_POINTS)
        full = self.n // BATCH_POINTS
        part = np.clip(rest - np.arange(full, dtype=np.int64) * SLICE_POINTS, 0, SLICE_POINTS)
        whole = min(rounds * SLICE_POINTS, BATCH_POINTS)
        total = full * whole + int(np.minimum(part, max(0, BATCH_POINTS - rounds * SLICE_POINTS)).sum())
        last = np.arange(full * BATCH_POINTS, self.n, dtype=np.uint64)
        return total + int(np.count_nonzero(self.forward(last) < np.uint64(capacity)))

    def batch_offsets(self, batch: np.ndarray) -> np.ndarray:
        """The rotation of each batch's shuffle: offset·(b+1) mod P, so batches differ."""
        p = np.uint64(self.prime)
        return ((np.asarray(batch, dtype=np.uint64) + np.uint64(1)) % p) * np.uint64(self.offset) % p

    def slot_batch(self, slot: np.ndarray | int) -> np.ndarray:
        """The batch whose slice holds each slot (batched layout; shaders/records.glsl)."""
        s = np.asarray(slot, dtype=np.int64)
        return (s % (self.batches * SLICE_POINTS)) // SLICE_POINTS

    def forward(self, index: np.ndarray | int) -> np.ndarray:
        """Slot of each file-order index (vectorised, exact)."""
        i = np.asarray(index, dtype=np.uint64)
        if self.prime == 0:
            return i.copy()
        if not self.batches:
            return _shuffle(i, np.uint64(self.prime), np.uint64(self.offset))
        b, local = np.divmod(i, np.uint64(BATCH_POINTS))
        shuffled = _shuffle(local, np.uint64(self.prime), self.batch_offsets(b))
        piece, within = np.divmod(shuffled, np.uint64(SLICE_POINTS))
        return piece * np.uint64(self.batches * SLICE_POINTS) + b * np.uint64(SLICE_POINTS) + within

    def inverse(self, slot: np.ndarray | int) -> np.ndarray:
        """File-order index stored at each slot (vectorised, exact)."""
        s = np.asarray(slot, dtype=np.uint64)
        if self.prime == 0:
            return s.copy()
        if not self.batches:
            return _unshuffle(s, np.uint64(self.prime), np.uint64(self.offset))
        piece, rest = np.divmod(s, np.uint64(self.batches * SLICE_POINTS))
        b, within = np.divmod(rest, np.uint64(SLICE_POINTS))
        local = _unshuffle(piece * np.uint64(SLICE_POINTS) + within, np.uint64(self.prime), self.batch_offsets(b))
        return b * np.uint64(BATCH_POINTS) + local


def glsl_defines() -> str:
    """The layout's constants for every shader (shaders/common.glsl slot_of)."""
    return (f"#define BATCH_POINTS {BATCH_POINTS}u\n#define BATCH_SLOTS {BATCH_SLOTS}u\n"
            f"#define SLICE_POINTS {SLICE_POINTS}u\n")


def _shuffle(i: np.ndarray, p: np.uint64, offset) -> np.ndarray:
    """The double quadratic residue with a rotation between; indices >= p stay."""
    inside = i < p
    x = np.where(inside, i, np.uint64(0))
    x = _qpr(x, p)
    x = (x + offset) % p
    x = _qpr(x, p)
    return np.where(inside, x, i)


def _unshuffle(s: np.ndarray, p: np.uint64, offset) -> np.ndarray:
    inside = s < p
    x = np.where(inside, s, np.uint64(0))
    x = _qpr_inverse(x, p)
    x = (x + p - offset % p) % p
    x = _qpr_inverse(x, p)
    return np.where(inside, x, s)


def _mulmod(a: np.ndarray, b: np.ndarray, p: np.uint64) -> np.ndarray:
    """a·b mod p for a, b < p < 2^32: the product fits in uint64."""
    return (a * b) % p


def _qpr(x: np.ndarray, p: np.uint64) -> np.ndarray:
    r = _mulmod(x, x, p)
    return np.where(x <= p // np.uint64(2), r, p - r)


def _powmod(base: np.ndarray, exponent: int, p: np.uint64) -> np.ndarray:
    result = np.ones_like(base)
    b = base % p
    e = exponent
    while e:
        if e & 1:
            result = _mulmod(result, b, p)
        b = _mulmod(b, b, p)
        e >>= 1
    return result


def _qpr_inverse(y: np.ndarray, p: np.uint64) -> np.ndarray:
    """Undo _qpr: y is a residue (x <= P/2) or minus one (x > P/2), never both,
    because -1 is a non-residue when P ≡ 3 (mod 4); square roots are a^((P+1)/4)."""
    exponent = (int(p) + 1) // 4
    half = p // np.uint64(2)
    root = _powmod(y, exponent, p)
    is_residue = _mulmod(root, root, p) == y % p
    small = np.where(root <= half, root, p - root)
    neg = (p - y) % p
    root_neg = _powmod(neg, exponent, p)
    large = np.where(root_neg > half, root_neg, p - root_neg)
    large = np.where(neg == 0, np.uint64(0), large)
    return np.where(is_residue, small, large)
