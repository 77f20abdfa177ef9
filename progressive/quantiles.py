"""Exact percentiles of the float32 values on the GPU by a two-level radix select:
a histogram of the high 16 bits of each value's order key finds the bin holding each
wanted rank, a histogram of the low 16 bits inside those bins finds the value. The
GPU pass (`passes/percentile.py`) only counts; this module is its numpy twin and the
arithmetic around it, so the colour range equals numpy's `percentile` over every
loaded point without keeping a host copy of them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BINS = 1 << 16
MAX_TARGETS = 4                  # two percentiles, each between two order statistics
PERCENTILES = (1.0, 99.0)        # the colour contract's default range
NO_TARGET = 0xFFFFFFFF           # a target bin no key has (keys' high halves are < 2^16)


def order_keys(words: np.ndarray) -> np.ndarray:
    """uint32 keys that order like the float32 values whose bits are `words`
    (shaders/histogram.comp order_key)."""
    w = np.asarray(words, dtype=np.uint32)
    negative = (w >> np.uint32(31)).astype(bool)
    return np.where(negative, ~w, w | np.uint32(0x80000000)).astype(np.uint32)


def key_value(key: int) -> float:
    """The float32 value (as a float) whose order key is `key`."""
    k = np.uint32(key)
    bits = k & np.uint32(0x7FFFFFFF) if k & np.uint32(0x80000000) else ~k
    return float(np.array([bits], dtype=np.uint32).view(np.float32)[0])


def finite_words(words: np.ndarray) -> np.ndarray:
    """The words that are finite float32 values (what the histogram counts)."""
    w = np.asarray(words, dtype=np.uint32)
    return w[(w & np.uint32(0x7F800000)) != np.uint32(0x7F800000)]


@dataclass(frozen=True)
class Position:
    """numpy's linear percentile of n sorted values: v[below] + gamma (v[above] - v[below])."""

    below: int
    above: int
    gamma: float


def positions(n: int, percents=PERCENTILES) -> list[Position]:
    """The order statistics each percentile interpolates, as numpy's default method
    computes them (virtual index (n - 1) q, clipped to the ranks)."""
    out = []
    for p in percents:
        q = np.float64(p) / 100.0
        virtual = (n - 1) * q
        below = int(np.clip(np.floor(virtual), 0, n - 1))
        above = int(np.clip(below + 1, 0, n - 1))
        out.append(Position(below, above, float(virtual - np.floor(virtual))))
    return out


def lerp(a: float, b: float, gamma: float) -> float:
    """numpy's `_lerp`: exact at both ends, the same rounding as np.percentile."""
    a64, b64, g = np.float64(a), np.float64(b), np.float64(gamma)
    diff = b64 - a64
    return float(b64 - diff * (1.0 - g) if g >= 0.5 else a64 + diff * g)


def ranks(n: int, percents=PERCENTILES) -> list[int]:
    """Distinct ranks (0-based, ascending) the percentiles need."""
    return sorted({r for pos in positions(n, percents) for r in (pos.below, pos.above)})


def locate(high_counts: np.ndarray, wanted: list[int]) -> tuple[list[int], list[int]]:
    """For each rank, the high-half bin holding it and its rank inside that bin."""
    cumulative = np.cumsum(high_counts, dtype=np.int64)
    bins = [int(np.searchsorted(cumulative, r, side="right")) for r in wanted]
    inside = [r - (int(cumulative[b - 1]) if b > 0 else 0) for r, b in zip(wanted, bins)]
    return bins, inside


def targets(bins: list[int]) -> list[int]:
    """The distinct bins of the second level, padded to MAX_TARGETS (two percentiles
    need at most four)."""
    distinct = sorted(set(bins))
    if len(distinct) > MAX_TARGETS:
        raise ValueError(f"{len(distinct)} bins to refine; the second level counts at most {MAX_TARGETS}")
    return distinct + [NO_TARGET] * (MAX_TARGETS - len(distinct))


def finish(n: int, bins: list[int], inside: list[int], wanted: list[int], target_list: list[int],
           low_counts: np.ndarray, percents=PERCENTILES) -> tuple[float, ...]:
    """Percentile values from the second level's counts (MAX_TARGETS rows of BINS)."""
    values = {}
    for r, b, k in zip(wanted, bins, inside):
        row = np.cumsum(low_counts[target_list.index(b)], dtype=np.int64)
        low = int(np.searchsorted(row, k, side="right"))
        values[r] = key_value((b << 16) | low)
    return tuple(lerp(values[p.below], values[p.above], p.gamma) for p in positions(n, percents))


def high_histogram(keys: np.ndarray) -> np.ndarray:
    return np.bincount(keys >> np.uint32(16), minlength=BINS)


def low_histograms(keys: np.ndarray, target_list: list[int]) -> np.ndarray:
    out = np.zeros((MAX_TARGETS, BINS), dtype=np.int64)
    high = keys >> np.uint32(16)
    for j, t in enumerate(target_list):
        if t != NO_TARGET:
            out[j] = np.bincount(keys[high == t] & np.uint32(0xFFFF), minlength=BINS)
    return out


def percentiles_of_words(words: np.ndarray, percents=PERCENTILES) -> tuple[float, ...] | None:
    """The reference select in numpy, counting as the GPU pass does; None without finite values."""
    keys = order_keys(finite_words(words))
    n = int(keys.size)
    if n == 0:
        return None
    wanted = ranks(n, percents)
    bins, inside = locate(high_histogram(keys), wanted)
    target_list = targets(bins)
    return finish(n, bins, inside, wanted, target_list, low_histograms(keys, target_list), percents)
