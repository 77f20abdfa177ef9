"""Where the batched layout's records live (pointstore.StoreLayout and its GLSL twin in
shaders/records.glsl): each batch's records together, slice after slice, for a store
that keeps the whole cloud or any slot prefix of it; renders equal those of a store in
slot order, for every rasterizer."""

from __future__ import annotations

import numpy as np
import pytest

from progressive import encoding
from progressive.attributes import find_attribute
from progressive.camera import auto_camera
from progressive.loaders.records import pack_records
from progressive.permutation import BATCH_POINTS, BATCH_SLOTS, SLICE_POINTS, FillOrder, Permutation
from progressive.pointstore import EMPTY_WORD, RecordOrder, StoreLayout
from progressive.renderer import Raster, Renderer
from progressive.scene import Scene

W, H = 160, 120


@pytest.mark.parametrize("n", [1, 300, BATCH_POINTS, 3 * BATCH_POINTS + 5, 40 * BATCH_POINTS - 1])
@pytest.mark.parametrize("share", [1.0, 0.5, 0.013, 0.0])
def test_each_batch_keeps_its_records_together(n, share):
    perm = Permutation.for_count(n, order=FillOrder.BATCHED)
    capacity = int(perm.slots * share)
    layout = StoreLayout.of(perm, capacity, RecordOrder.BATCHES)
    slots = np.arange(capacity)
    records = layout.record_index(slots)
    assert np.array_equal(np.sort(records), slots), "not a bijection onto [0, capacity)"
    batch = (slots // SLICE_POINTS) % perm.batches
    starts = layout.batch_record(np.arange(perm.batches + 1))
    for b in range(perm.batches):
        mine = records[batch == b]
        assert np.array_equal(mine, np.arange(starts[b], starts[b] + mine.size)), f"batch {b} not contiguous, in slot order"
    assert StoreLayout.of(perm, capacity, RecordOrder.SLOTS).record_index(slots).tolist() == slots.tolist()


@pytest.fixture(scope="module")
def cloud(sample_batches):
    return sample_batches


def render_ids(gl, info, batches, raster, records, capacity, cam):
    scene = Scene(gl, info, find_attribute(info, "elevation"), capacity=capacity, records=records)
    r = Renderer(gl, info, scene.attribute, raster=raster, width=W, height=H, scene=scene)
    try:
        for b in batches:
            scene.add_batch(b)
        return r.render(cam, W, H, r.style()).ids, scene.store
    finally:
        r.release()


@pytest.mark.parametrize("raster", [Raster.COMPUTE, Raster.COMPUTE32, Raster.POINTS])
@pytest.mark.parametrize("share", [1.0, 0.37])
def test_records_batch_after_batch_render_as_in_slot_order(gl, cloud, raster, share):
    info, batches = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    capacity = int(Permutation.for_count(info.points, order=FillOrder.BATCHED).slots * share)
    together, store = render_ids(gl, info, batches, raster, RecordOrder.BATCHES, capacity, cam)
    in_order, _ = render_ids(gl, info, batches, raster, RecordOrder.SLOTS, capacity, cam)
    assert (together != 0xFFFFFFFF).sum() > 1000
    assert np.array_equal(together, in_order)
    gl.check()


def test_the_gpu_writes_each_record_where_the_twin_says(gl, cloud):
    """The raw buffers, in record order: batch b's block holds exactly the kept points of
    file batch b, each record (its words, as the encoding twin gives them) where
    StoreLayout.record_index puts its slot."""
    info, batches = cloud
    perm = Permutation.for_count(info.points, order=FillOrder.BATCHED)
    capacity = int(perm.slots * 0.61)
    attribute = find_attribute(info, "elevation")
    scene = Scene(gl, info, attribute, capacity=capacity)
    try:
        for b in batches:
            scene.add_batch(b)
        store = scene.store
        raw = store.raw_words()
        expected = np.concatenate([pack_records(b, attribute, float(info.origin[2])) for b in batches])
        ids = np.arange(info.points)
        slots = perm.forward(ids).astype(np.int64)
        kept = slots < capacity
        where = store.layout.record_index(slots[kept])
        assert np.array_equal(raw[where, 3], expected[kept, 3])
        b = ids[kept] // BATCH_POINTS
        integers = np.concatenate([part.grid.cells for part in batches])[kept].astype(np.int64)
        assert store.integer[b].all()       # a LAS file: its integers, moved up the batch's shift
        cells = (integers - store.least_cells[b]) << store.cell_shifts[b]
        assert np.array_equal(raw[where, :3], encoding.pack_words(cells))
        starts = store.layout.batch_record(np.arange(perm.batches + 1))
        file_batch = ids[kept] // BATCH_POINTS
        assert np.all((where >= starts[file_batch]) & (where < starts[file_batch + 1]))
        gl.check()
    finally:
        scene.release()


@pytest.mark.parametrize("records", list(RecordOrder))
def test_clearing_batches_empties_their_records_alone(gl, cloud, records):
    """What a streamed cloud's evictions rely on: clear_batches leaves EMPTY_WORD in every
    word of the emptied batches' records, wherever the order keeps them, and no other."""
    info, batches = cloud
    scene = Scene(gl, info, find_attribute(info, "elevation"), records=records)
    try:
        for b in batches:
            scene.add_batch(b)
        store = scene.store
        before = store.raw_words().copy()
        emptied = [1, 2, 4]
        store.clear_batches(emptied)
        after = store.raw_words()
        slots = np.arange(store.capacity)
        gone = np.zeros(store.capacity, bool)
        gone[store.layout.record_index(slots[np.isin(store.permutation.slot_batch(slots), emptied)])] = True
        assert gone.sum() == len(emptied) * BATCH_SLOTS
        assert (after[gone] == EMPTY_WORD).all()
        assert np.array_equal(after[~gone], before[~gone])
        assert (before[gone] != EMPTY_WORD).any()
        gl.check()
    finally:
        scene.release()
