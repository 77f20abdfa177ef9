"""The prime-number shuffle of the paper (section 3.3), exact in uint64.

For P prime with P ≡ 3 (mod 4), x -> x² mod P (or P minus it, for x > P/2) is a
bijection on [0, P). Applying it twice, with a rotation by `offset` in between,
gives a permutation in which any contiguous range of slots is a well-mixed subset
of the file. The rotation breaks the paper's fixed points at the start of the range
(0, 1, 16, 81, ... map from file indices 0, 1, 2, 3): with offset 0 this is the
paper's exact formula. Indices >= P stay where they are.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import sympy

GOLDEN = 0.6180339887498949


class FillOrder(enum.Enum):
    """Which points a range of slots holds. FILE (the identity, prime 0) is the paper's
    unshuffled baseline (Table 4, Figure 5): progressive fills then follow file order."""

    SHUFFLED = "shuffled"
    FILE = "file"


@lru_cache(maxsize=256)
def prime_for(n: int) -> int:
    """The largest prime P <= n with P ≡ 3 (mod 4); 0 when there is none (n < 3)."""
    if n < 3:
        return 0
    p = sympy.prevprime(n + 1)
    while p % 4 != 3:
        if p <= 3:
            return 0
        p = sympy.prevprime(p)
    return int(p)


@dataclass(frozen=True)
class Permutation:
    """File-order index -> slot in the shuffled buffer, for a cloud of n points."""

    n: int
    prime: int
    offset: int

    @classmethod
    def for_count(cls, n: int, *, rotate: bool = True, order: FillOrder = FillOrder.SHUFFLED) -> Permutation:
        if not 0 <= n < 2**32:
            raise ValueError(f"point count {n} outside [0, 2^32)")
        if order is FillOrder.FILE:
            return cls(n=n, prime=0, offset=0)
        p = prime_for(n)
        return cls(n=n, prime=p, offset=int(p * GOLDEN) if rotate else 0)

    def forward(self, index: np.ndarray | int) -> np.ndarray:
        """Slot of each file-order index (vectorised, exact)."""
        i = np.asarray(index, dtype=np.uint64)
        p = np.uint64(self.prime)
        if self.prime == 0:
            return i.copy()
        inside = i < p
        x = np.where(inside, i, np.uint64(0))
        x = _qpr(x, p)
        x = (x + np.uint64(self.offset)) % p
        x = _qpr(x, p)
        return np.where(inside, x, i)

    def inverse(self, slot: np.ndarray | int) -> np.ndarray:
        """File-order index stored at each slot (vectorised, exact)."""
        s = np.asarray(slot, dtype=np.uint64)
        p = np.uint64(self.prime)
        if self.prime == 0:
            return s.copy()
        inside = s < p
        x = np.where(inside, s, np.uint64(0))
        x = _qpr_inverse(x, p)
        x = (x + p - np.uint64(self.offset) % p) % p
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
