"""Packing batches straight into mapped staging memory, in the GPU record of
loaders/records.py (which the core's upload ring alone needs)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from progressive.loaders.records import EXPONENT, NAN_WORD, attribute_word
from progressive.loaders.types import AttributeInfo, AttributeKind, Batch, nonfinite_records, nonfinite_rows


def batch_words(batch: Batch, attr: AttributeInfo, origin_z: float) -> np.ndarray:
    """Every point's attribute word as pack_records gives it, before non-finite values
    hide their points (a fast-format batch's stored word)."""
    return batch.records[:, 3] if batch.records is not None else attribute_word(batch, attr, origin_z)


def pack_into(out: np.ndarray, batch: Batch, attr: AttributeInfo, words: np.ndarray, lo: int, hi: int,
              copy: Callable[[np.ndarray, np.ndarray], None] = np.copyto) -> int:
    """Records [lo, hi) of pack_records(batch, attr, ...) written straight into `out`
    ((hi - lo, 4) uint32, e.g. a mapped staging slot: written once, never read back, as
    reading mapped memory may be slow); `words` from batch_words; a batch of records
    (the fast format's) is copied by `copy` (stagecopy.StageCopier). Returns how many of
    them have non-finite coordinates (what shaders/common.glsl finite_position skips),
    counted from the batch's own arrays."""
    w = words[lo:hi]
    if batch.records is not None:
        src = batch.records[lo:hi]
        copy(out, src)
        hidden = nonfinite_records(src)[0] if batch.nonfinite_positions else 0     # the loader's count: none
        xyz = src[:, :3].view(np.float32)
        hides = bool(batch.nonfinite_values.get(attr.name))
    else:
        xyz = np.ascontiguousarray(batch.rows(lo, hi).positions, dtype=np.float32)
        out[:, :3] = xyz.view(np.uint32)
        out[:, 3] = w
        hidden = nonfinite_rows(xyz)
        hides = True
    if attr.kind is not AttributeKind.SCALAR or not hides:
        return hidden
    bad = (w & EXPONENT) == EXPONENT
    if not bad.any():
        return hidden
    out[bad, :3] = NAN_WORD
    return int(np.count_nonzero(bad | ~np.isfinite(xyz).all(axis=1))) if hidden else int(np.count_nonzero(bad))
