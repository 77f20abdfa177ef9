"""Shader storage binding points: one enum, emitted into every shader as #defines,
so Python and GLSL cannot disagree about where a buffer lives."""

from __future__ import annotations

import enum

MAX_POINT_CHUNKS = 8
"""Shuffled point buffers: each under 2^31 bytes and the GL limit; 8 hold > 1e9 points.
The word store binds plane p's chunk c at POINTS_0 + p·chunks + c (pointstore.py)."""


class Binding(enum.IntEnum):
    POINTS_0 = 0
    POINTS_1 = 1
    POINTS_2 = 2
    POINTS_3 = 3
    POINTS_4 = 4
    POINTS_5 = 5
    POINTS_6 = 6
    POINTS_7 = 7
    DISTRIBUTE = 8
    VISIBILITY = 9
    IMAGE = 10
    PALETTE = 11
    FILL_STATE = 12
    FILL_ARGS = 13
    TIMESTAMPS = 14
    SLOT_LIST = 15          # reprojection input: meta words (count, indirect args, gathers), then slots
    WINNERS = 16            # per pixel: the record and slot of the point the winners pass found there
    REFERENCE = 17
    COUNTERS = 18
    LIST_RECORDS = 19       # reprojection input: record copies
    OUT_SLOTS = 20          # prepare output, laid out as SLOT_LIST
    OUT_RECORDS = 21
    IMPROVED = 22           # per batch: a point of it improved a pixel this frame (passes/raster_compute.py)
    HINT = 23               # per pixel: list index of the reprojected point that last improved it
    PIXEL_WORDS = 24        # per pixel: attribute word of the visible point
    DILATED = 25            # point-size pass output, laid out as VISIBILITY
    DILATED_WORDS = 26      # point-size pass output, laid out as PIXEL_WORDS
    HISTOGRAM = 27          # percentile select counts (passes/percentile.py)
    BATCH_BOXES = 28        # batched layout: each batch's box (progressive/batches.py)
    BATCH_FLAGS = 29        # batched layout: each batch in view this frame (passes/cull.py)
    CLASSES = 30            # per slot, its classification code: a byte each (pointstore.py class filter)
    BATCH_FRAMES = 31       # word store: each batch's base and step (progressive/encoding.py)
    GATHERS = 32            # prepare: the list entries and pixels whose records come from the store
    BATCH_CELLS = 33        # word store: each LAS batch's least integers and shifts (pointstore.py cell_frames)
    CANDIDATES = 34         # 32-bit raster: the points that lowered or met their pixel's depth in its depth pass

    @classmethod
    def points(cls, chunk: int) -> Binding:
        return cls(cls.POINTS_0 + chunk)


class UniformBinding(enum.IntEnum):
    """Uniform block binding points (a namespace of their own in GL)."""

    STORE_LAYOUT = 0        # where each slot's record lives (pointstore.py StoreLayout)


def glsl_defines() -> str:
    return ("".join(f"#define BINDING_{b.name} {int(b)}\n" for b in Binding)
            + "".join(f"#define UNIFORM_{b.name} {int(b)}\n" for b in UniformBinding))
