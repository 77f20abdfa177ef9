"""Packing points into the 16-byte GPU record: xyz float32 (relative to the origin)
and one 4-byte attribute word whose meaning is set by the attribute's kind."""

from __future__ import annotations

import numpy as np

from progressive.loaders.types import AttributeInfo, AttributeKind, Batch, nonfinite_records, nonfinite_rows

RECORD_BYTES = 16
ELEVATION = "elevation"


def attribute_word(batch: Batch, attr: AttributeInfo, origin_z: float) -> np.ndarray:
    """The uint32 attribute word of every point of a batch.

    RGB packs as little-endian RGBA8 (alpha 255), SCALAR as the float32 bits of
    value - attr.offset, CATEGORY as the integer code. Elevation is the file z,
    derived from the float32 position so it needs no array of its own.
    """
    n = batch.count
    if attr.name == ELEVATION:
        z = batch.positions[:, 2].astype(np.float64) + (origin_z - attr.offset)
        with np.errstate(over="ignore", invalid="ignore"):
            return z.astype(np.float32).view(np.uint32)
    values = batch.attributes[attr.name]
    if attr.kind is AttributeKind.RGB:
        rgb = np.asarray(values, dtype=np.uint32)
        return rgb[:, 0] | (rgb[:, 1] << 8) | (rgb[:, 2] << 16) | np.uint32(0xFF000000)
    if attr.kind is AttributeKind.CATEGORY:
        return np.asarray(values).astype(np.uint32, copy=False).reshape(n)
    with np.errstate(over="ignore", invalid="ignore"):
        scalar = np.asarray(values, dtype=np.float64) - attr.offset
        return scalar.astype(np.float32).view(np.uint32).reshape(n)


NAN_WORD = np.uint32(0xFFFFFFFF)
EXPONENT = np.uint32(0x7F800000)


def pack_records(batch: Batch, attr: AttributeInfo, origin_z: float) -> np.ndarray:
    """(n, 4) uint32 GPU records; fast-format batches come packed already. A point
    whose shown scalar is NaN or infinite gets NaN coordinates: no pass draws it, so
    it neither shows a made-up colour nor hides what is behind it."""
    if batch.records is not None:
        out = batch.records
        if not (attr.kind is AttributeKind.SCALAR and batch.nonfinite_values.get(attr.name)):
            return out
    else:
        out = np.empty((batch.count, 4), dtype=np.uint32)
        out[:, :3] = np.ascontiguousarray(batch.positions, dtype=np.float32).view(np.uint32)
        out[:, 3] = attribute_word(batch, attr, origin_z)
    if attr.kind is AttributeKind.SCALAR:
        bad = (out[:, 3] & EXPONENT) == EXPONENT
        out[bad, :3] = NAN_WORD
    return out



def batch_words(batch: Batch, attr: AttributeInfo, origin_z: float) -> np.ndarray:
    """Every point's attribute word as pack_records gives it, before non-finite values
    hide their points (a fast-format batch's stored word)."""
    return batch.records[:, 3] if batch.records is not None else attribute_word(batch, attr, origin_z)


def pack_into(out: np.ndarray, batch: Batch, attr: AttributeInfo, words: np.ndarray, lo: int, hi: int) -> int:
    """Records [lo, hi) of pack_records(batch, attr, ...) written straight into `out`
    ((hi - lo, 4) uint32, e.g. a mapped staging slot: written once, never read back, as
    reading mapped memory may be slow); `words` from batch_words. Returns how many of
    them have non-finite coordinates (what shaders/common.glsl finite_position skips),
    counted from the batch's own arrays."""
    w = words[lo:hi]
    if batch.records is not None:
        src = batch.records[lo:hi]
        out[...] = src
        hidden = nonfinite_records(src)[0]
        xyz = src[:, :3].view(np.float32)
        hides = bool(batch.nonfinite_values.get(attr.name))
    else:
        xyz = np.ascontiguousarray(batch.positions[lo:hi], dtype=np.float32)
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
