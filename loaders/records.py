"""The 16-byte GPU record the loaders hand points over in: xyz float32 (relative to the
origin) and one 4-byte attribute word whose meaning is set by the attribute's kind. It
lives with the loaders because the fast format stores these records as they are."""

from __future__ import annotations

import numpy as np

from progressive.loaders.types import AttributeInfo, AttributeKind, Batch

RECORD_BYTES = 16
ELEVATION = "elevation"
NAN_WORD = np.uint32(0xFFFFFFFF)
EXPONENT = np.uint32(0x7F800000)


def attribute_word(batch: Batch, attr: AttributeInfo, origin_z: float) -> np.ndarray:
    """The uint32 attribute word of every point of a batch.

    RGB packs as little-endian RGBA8 (alpha 255), SCALAR as the float32 bits of
    value - attr.offset, CATEGORY as the integer code. Elevation is the file z,
    derived from the float32 position so it needs no array of its own.
    """
    n = batch.count
    if attr.name == ELEVATION:
        z = batch.z().astype(np.float64) + (origin_z - attr.offset)
        with np.errstate(over="ignore", invalid="ignore"):
            return z.astype(np.float32).view(np.uint32)
    values = batch.attributes[attr.name]
    if attr.kind is AttributeKind.RGB:
        if values.dtype == np.uint8:        # the loaders' 8-bit channels: the bytes of RGBA words, one copy
            rgba = np.empty((n, 4), np.uint8)
            rgba[:, :3] = values
            rgba[:, 3] = 0xFF
            return rgba.view("<u4").reshape(n)
        rgb = np.asarray(values, dtype=np.uint32)
        return rgb[:, 0] | (rgb[:, 1] << 8) | (rgb[:, 2] << 16) | np.uint32(0xFF000000)
    if attr.kind is AttributeKind.CATEGORY:
        return np.asarray(values).astype(np.uint32, copy=False).reshape(n)
    with np.errstate(over="ignore", invalid="ignore"):
        scalar = np.asarray(values, dtype=np.float64) - attr.offset
        return scalar.astype(np.float32).view(np.uint32).reshape(n)


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
