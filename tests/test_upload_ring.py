"""Uploads through the ring of persistently mapped staging slots: the store after a
load equals the packed records (numpy's placement by the permutation) for whole,
partial and memory-limited loads, through the ring and through the copy fallback;
slots are handed out again only once their fence has signalled, and each piece
staged is flushed before its scatter reads it; packing straight
into staging memory equals pack_records, hidden points included."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from progressive import encoding, stagecopy
from progressive.attributes import default_attribute
from progressive.encoding import Encoding
from progressive.glext import GL_ALREADY_SIGNALED, GL_CLIENT_MAPPED_BUFFER_BARRIER_BIT
from progressive.loaders.records import pack_records
from progressive.loaders.types import Batch, nonfinite_records
from progressive.packing import batch_words, pack_into
from progressive.passes.distribute import DistributePass, Staging, StagingRing, without_buffer_storage
from progressive.permutation import BATCH_POINTS
from progressive.pointstore import EMPTY_WORD
from progressive.scene import Scene, point_flags

GL_TIMEOUT_EXPIRED = 0x911B


def expected_store(scene: Scene, batches: list[Batch]) -> np.ndarray:
    """The store in slot order as numpy places pack_records' rows: slot = forward(file index)."""
    out = np.full((scene.store.capacity, 4), EMPTY_WORD, dtype=np.uint32)
    for b in batches:
        rec = pack_records(dataclasses.replace(b, records=None if b.records is None else b.records.copy()),
                           scene.attribute, float(scene.info.origin[2]))
        slots = scene.store.slots_of(np.arange(b.start, b.start + b.count))
        keep = slots < scene.store.capacity
        out[slots[keep]] = rec[keep]
    return out


def expected_flags(scene: Scene, batches: list[Batch]) -> np.ndarray:
    out = np.zeros(scene.store.capacity, dtype=np.uint16)
    for b in batches:
        slots = scene.store.slots_of(np.arange(b.start, b.start + b.count))
        keep = slots < scene.store.capacity
        out[slots[keep]] = point_flags(b)[keep]
    return out


def hidden(scene: Scene, batches: list[Batch]) -> int:
    return sum(nonfinite_records(pack_records(dataclasses.replace(b, records=None if b.records is None
                                                                  else b.records.copy()),
                                              scene.attribute, float(scene.info.origin[2])))[0] for b in batches)


def hostile(batches: list[Batch], info, every: int = 97) -> list[Batch]:
    """The batches with some coordinates and intensities NaN or infinite (overlapping)."""
    out = []
    for b in batches:
        pos = b.positions.copy()
        pos[::every, 1] = np.nan
        values = b.attributes["intensity"].astype(np.float64)
        values[3::every // 2] = np.inf
        values[::every * 3] = np.nan
        out.append(b.with_positions(pos, attributes={**b.attributes, "intensity": values},
                                    nonfinite_positions=int(np.count_nonzero(np.isnan(pos[:, 1]))),
                                    nonfinite_values={"intensity": int(np.count_nonzero(~np.isfinite(values)))}))
    return out


def fast(batches: list[Batch], info, attribute) -> list[Batch]:
    """The same points as fast-format batches: records as stored (scalars not yet hidden)."""
    origin_z = float(info.origin[2])
    out = []
    for b in batches:
        rec = np.empty((b.count, 4), dtype=np.uint32)
        rec[:, :3] = b.positions.view(np.uint32)
        rec[:, 3] = batch_words(b, attribute, origin_z)
        out.append(dataclasses.replace(b, attributes={}, records=rec))
    return out


@pytest.mark.parametrize("staging", list(Staging))
@pytest.mark.parametrize("load", ["whole", "partial", "limited"])
def test_store_equals_packed_records(gl, sample_batches, staging, load):
    info, batches = sample_batches
    ctx = gl if staging is Staging.RING else without_buffer_storage(gl)
    capacity = 45_000 if load == "limited" else None
    loaded = batches[:3] if load == "partial" else batches
    scene = Scene(ctx, info, default_attribute(info), capacity=capacity, class_filter=True,
                  position_encoding=Encoding.FLOAT)
    assert scene.distribute.staging is staging
    for b in loaded:
        scene.add_batch(b)
    gl.check()
    assert np.array_equal(scene.store.read_records(), expected_store(scene, loaded))
    flags = np.frombuffer(scene.store.class_buffer.read(), dtype=np.uint16)[: scene.store.capacity]
    assert np.array_equal(flags, expected_flags(scene, loaded))
    assert scene.distribute.class_bytes is not None and scene.distribute.classes is None   # the file's bytes staged
    stats = scene.distribute.stats
    pieces = 2 * len(loaded)        # records and flags, one piece each
    assert (stats.ring, stats.copied) == ((pieces, 0) if staging is Staging.RING else (0, pieces))
    scene.release()


@pytest.mark.parametrize("encoding", list(Encoding), ids=lambda e: e.name.lower())
@pytest.mark.parametrize("staging", list(Staging))
@pytest.mark.parametrize("source", ["las", "fast"])
def test_hidden_points_through_staging(gl, sample_batches, staging, source, encoding):
    """Non-finite coordinates and shown values: the same records (the word store's
    decoded, within its rounding) and the same count of points never drawn as
    pack_records and nonfinite_records give."""
    info, batches = sample_batches
    attribute = info.attribute("intensity")
    bad = hostile(batches, info)
    loaded = fast(bad, info, attribute) if source == "fast" else bad
    scene = Scene(gl if staging is Staging.RING else without_buffer_storage(gl), info, attribute,
                  position_encoding=encoding)
    for b in loaded:
        scene.add_batch(b)
    held, expected = scene.store.read_records(), expected_store(scene, loaded)
    if encoding is Encoding.FLOAT:
        assert np.array_equal(held, expected)
    else:
        assert np.array_equal(held[:, 3], expected[:, 3])
        shown = np.isfinite(expected[:, :3].view(np.float32)).all(axis=1)
        assert np.array_equal((held[:, :3] == EMPTY_WORD).all(axis=1), ~shown)
        assert np.allclose(held[shown, :3].view(np.float32), expected[shown, :3].view(np.float32), rtol=1e-6, atol=1e-4)
    assert scene.skipped == hidden(scene, loaded) > 0
    scene.release()


def nonfinite_values(batches: list[Batch], every: int = 89) -> list[Batch]:
    """The batches with some intensities NaN or infinite, their positions and the file's
    integers (Batch.grid) as read."""
    out = []
    for b in batches:
        values = b.attributes["intensity"].astype(np.float64)
        values[5::every] = np.nan
        values[::every * 2] = -np.inf
        out.append(dataclasses.replace(b, attributes={**b.attributes, "intensity": values},
                                       nonfinite_values={"intensity": int(np.count_nonzero(~np.isfinite(values)))}))
    return out


@pytest.mark.parametrize("source", ["las", "fast"])
def test_flags_from_staged_bytes_or_made_on_the_cpu(gl, sample_batches, source):
    """A LAS batch's class and return bytes are staged as read and the scatter makes the
    flags, in pieces that split them; a batch holding them otherwise (a fast-format file,
    whose one word is the class, no returns) has point_flags make them: both equal the
    reference."""
    info, batches = sample_batches
    attribute = info.attribute("classification")
    loaded = fast(batches, info, attribute) if source == "fast" else batches
    scene = Scene(gl, info, attribute, class_filter=True)
    scene.distribute.release()
    scene.distribute = DistributePass(gl, scene.store, batch_points=7_001)
    for b in loaded:
        scene.add_batch(b)
    gl.check()
    flags = np.frombuffer(scene.store.class_buffer.read(), dtype=np.uint16)[: scene.store.capacity]
    assert np.array_equal(flags, expected_flags(scene, loaded))
    assert (scene.distribute.class_bytes is not None) == (source == "las") == (scene.distribute.classes is None)
    scene.release()


@pytest.mark.parametrize("shown", ["intensity", "rgb"])
@pytest.mark.parametrize("piece", [None, 7_001], ids=["batch a piece", "pieces of 7,001"])
def test_las_integers_staged_as_read(gl, sample_batches, piece, shown):
    """A LAS file's integers staged as read (the distribute pass encodes them in each
    batch's cell frame), with a shown scalar some of whose values are not finite (those
    points are never drawn and counted) or RGB staged as bytes: every other point's words
    hold its integers less its batch's least, moved up its shift, and its attribute word
    as pack_records makes it; in pieces that split batches (and words) too."""
    info, batches = sample_batches
    attribute = info.attribute(shown)
    loaded = nonfinite_values(batches) if shown == "intensity" else batches
    scene = Scene(gl, info, attribute)
    if piece is not None:
        scene.distribute.release()
        scene.distribute = DistributePass(gl, scene.store, batch_points=piece)
    for b in loaded:
        scene.add_batch(b)
    gl.check()
    assert scene.store.integer[: scene.store.permutation.batches].all()
    words = scene.store.read_words()
    expected = expected_store(scene, loaded)
    cloud = np.arange(info.points)
    slots = scene.store.slots_of(cloud)
    drawn = np.isfinite(expected[slots, :3].view(np.float32)).all(axis=1)
    assert drawn.all() == (shown == "rgb")
    held = words[slots]
    assert np.array_equal(held[:, 3], expected[slots, 3])
    assert (held[~drawn, :3] == EMPTY_WORD).all()
    batch = cloud // BATCH_POINTS
    integers = np.concatenate([b.grid.cells for b in batches]).astype(np.int64)
    cells = (integers - scene.store.least_cells[batch]) << scene.store.cell_shifts[batch]
    assert np.array_equal(encoding.unpack_cells(held[drawn, :3]), cells[drawn])
    assert scene.skipped == int(np.count_nonzero(~drawn)) == sum(b.nonfinite_values.get(shown, 0) for b in loaded)
    scene.release()


@pytest.mark.parametrize("source", ["las", "fast"])
def test_pack_into_pieces_equals_pack_records(sample_batches, source):
    info, batches = sample_batches
    attribute = info.attribute("intensity")
    b = hostile(batches, info, every=13)[1]
    b = fast([b], info, attribute)[0] if source == "fast" else b
    reference = pack_records(dataclasses.replace(b, records=None if b.records is None else b.records.copy()),
                             attribute, float(info.origin[2]))
    words = batch_words(b, attribute, float(info.origin[2]))
    out = np.zeros((b.count, 4), dtype=np.uint32)
    edges = [0, 1, 777, 5000, b.count]
    count = sum(pack_into(out[lo:hi], b, attribute, words, lo, hi) for lo, hi in zip(edges, edges[1:]))
    assert np.array_equal(out, reference)
    assert count == nonfinite_records(reference)[0] > 0


class Fences:
    """Fences that signal only when the test says (after glFinish, so the GPU truly is
    done): glClientWaitSync with timeout 0 reports them pending until then."""

    def __init__(self):
        self.made, self.signalled, self.deleted = 0, set(), set()

    def fence_sync(self, condition, flags):
        self.made += 1
        return self.made

    def client_wait_sync(self, sync, flags, timeout):
        assert timeout == 0, "the ring must never block"
        return GL_ALREADY_SIGNALED if sync in self.signalled else GL_TIMEOUT_EXPIRED

    def delete_sync(self, sync):
        self.deleted.add(sync)


def small_ring(ctx, info, attribute, piece: int, slots: int) -> Scene:
    """Float records: each batch goes through in whole pieces (the word store also sends
    again the parts of batches that loader batches split)."""
    scene = Scene(ctx, info, attribute, position_encoding=Encoding.FLOAT)
    scene.distribute.release()
    scene.distribute = DistributePass(ctx, scene.store, batch_points=piece, ring_slots=slots)
    return scene


def test_slots_reused_only_after_their_fence(gl, sample_batches):
    """Many batches through a ring of 3 slots: each piece goes to the next slot in turn
    if that slot's last fence has signalled, else it is copied; never to a busy slot."""
    info, batches = sample_batches
    fences = Fences()
    ctx = dataclasses.replace(gl, gl=dataclasses.replace(gl.gl, fence_sync=fences.fence_sync,
                                                         client_wait_sync=fences.client_wait_sync,
                                                         delete_sync=fences.delete_sync))
    scene = small_ring(ctx, info, default_attribute(info), piece=7_000, slots=3)
    ring = scene.distribute.ring
    written, last, view, read = [], {}, ring.view, ring.read

    def spied_view(slot, count, width):
        assert last.get(slot) in (None, *fences.signalled), f"slot {slot} handed out before its fence signalled"
        written.append(slot)
        return view(slot, count, width)

    def spied_read(slot):
        read(slot)
        last[slot] = ring.fences[slot]

    ring.view, ring.read = spied_view, spied_read
    rng = np.random.default_rng(5)
    pieces = 0
    for b in batches * 3:
        scene.add_batch(b)
        pieces += -(-b.count // 7_000)
        if rng.random() < 0.6:          # the GPU catches up on some batches, not on others
            gl.ctx.finish()
            fences.signalled.update(f for f in ring.fences if f is not None)
    assert written == [k % 3 for k in range(len(written))], "slots are used in turn"
    stats = scene.distribute.stats
    assert stats.ring == len(written) > 3 * 3 and stats.copied > 0 and stats.ring + stats.copied == pieces
    assert fences.deleted == set(range(1, fences.made + 1)) - {f for f in ring.fences if f is not None}
    assert np.array_equal(scene.store.read_records(), expected_store(scene, batches))
    scene.release()


def test_real_fences_free_every_slot(gl, sample_batches):
    """With the GPU's own fences, and the GPU finished between batches, every piece of
    every batch goes through the ring (wrapping around it many times)."""
    info, batches = sample_batches
    scene = small_ring(gl, info, default_attribute(info), piece=8_192, slots=3)
    for b in batches:
        scene.add_batch(b)
        gl.ctx.finish()
    pieces = sum(-(-b.count // 8_192) for b in batches)
    assert scene.distribute.stats.ring == pieces > 3 and scene.distribute.stats.copied == 0
    assert np.array_equal(scene.store.read_records(), expected_store(scene, batches))
    scene.release()


@pytest.mark.parametrize("encoding", list(Encoding), ids=lambda e: e.name.lower())
def test_each_piece_is_flushed_before_its_scatter(gl, sample_batches, monkeypatch, encoding):
    """The ring's mapping is not coherent: every piece staged in a slot, records and a
    switch's words alike, has exactly the bytes it wrote flushed, then a client-mapped
    buffer barrier, before its scatter; and the store is still the reference's."""
    info, batches = sample_batches
    events = []
    storage = dataclasses.replace(gl.gl.storage, flush_mapped_named_buffer_range=lambda glo, offset, size: (
        events.append(("flush", glo, offset, size)), gl.gl.storage.flush_mapped_named_buffer_range(glo, offset, size)))
    ctx = dataclasses.replace(gl, gl=dataclasses.replace(gl.gl, storage=storage))
    barrier = gl.ctx.memory_barrier
    monkeypatch.setattr(gl.ctx, "memory_barrier", lambda *args, **kwargs: (
        events.append(("barrier", *args)), barrier(*args, **kwargs)))
    staged, view, read = {}, StagingRing.view, StagingRing.read

    def spied_view(ring, slot, count, width):
        staged[ring.mapped.glo, slot] = count * width * 4
        return view(ring, slot, count, width)

    def spied_read(ring, slot):     # called once the scatter is issued
        assert events[-2:] == [("flush", ring.mapped.glo, slot * ring.slot_bytes, staged.pop((ring.mapped.glo, slot))),
                               ("barrier", GL_CLIENT_MAPPED_BUFFER_BARRIER_BIT)]
        read(ring, slot)

    monkeypatch.setattr(StagingRing, "view", spied_view)
    monkeypatch.setattr(StagingRing, "read", spied_read)
    scene = Scene(ctx, info, info.attribute("intensity"), keep_batches=True, position_encoding=encoding)
    scene.distribute.word_piece = 9_000
    for b in batches:
        scene.add_batch(b)
    scene.begin_switch(info.attribute("gps_time"))
    while not scene.stream(seconds=float("inf")):
        pass
    stats = scene.distribute.stats
    assert sum(e[0] == "flush" for e in events) == stats.ring > len(batches) and not staged
    assert scene.distribute.word_ring is not None
    held, expected = scene.store.read_records(), expected_store(scene, batches)
    columns = slice(None) if encoding is Encoding.FLOAT else 3        # the word store's positions are quantized
    assert np.array_equal(held[:, columns], expected[:, columns])
    scene.release()


def test_no_ring_slots_is_the_copy_path(gl, sample_batches):
    info, batches = sample_batches
    scene = small_ring(gl, info, default_attribute(info), piece=20_000, slots=0)
    assert scene.distribute.staging is Staging.COPY and scene.distribute.ring is None
    for b in batches:
        scene.add_batch(b)
    assert np.array_equal(scene.store.read_records(), expected_store(scene, batches))
    scene.release()



@pytest.mark.parametrize("encoding", list(Encoding), ids=lambda e: e.name.lower())
@pytest.mark.parametrize("names", [("intensity", "elevation"), ("elevation", "intensity")])
def test_points_never_drawn_are_counted_once_across_a_switch(gl, sample_batches, encoding, names):
    """A switch after the first loader batch, the rest loaded after it: the points never
    drawn are those pack_records gives the new attribute's (the word store encodes the
    batches loader batches split more than once; each point counts once)."""
    info, batches = sample_batches
    bad = hostile(batches, info)
    scene = Scene(gl, info, info.attribute(names[0]), keep_batches=True, position_encoding=encoding)
    scene.add_batch(bad[0])
    scene.begin_switch(info.attribute(names[1]))
    while not scene.stream(seconds=float("inf")):
        pass
    for b in bad[1:]:
        scene.add_batch(b)
    assert scene.skipped == hidden(scene, bad) > 0
    scene.release()


def test_negative_file_integers_are_staged_exactly(gl, sample_batches):
    """A LAS batch's cells are staged in uint32 arithmetic (wrapping subtraction of the
    batch's least integers): exact for integers far below zero too."""
    from progressive.encoding import pack_words
    from progressive.permutation import BATCH_POINTS

    info, batches = sample_batches
    moved = [dataclasses.replace(b, grid=dataclasses.replace(b.grid, cells=b.grid.cells - np.int32(2_000_000_000)))
             for b in batches]
    scene = Scene(gl, info, info.attribute("intensity"))
    for b in moved:
        scene.add_batch(b)
    ids = np.arange(info.points)
    batch = ids // BATCH_POINTS
    store = scene.store
    assert store.integer[batch].all() and (store.least_cells[batch] < -1_000_000_000).all()
    integers = np.concatenate([b.grid.cells for b in moved]).astype(np.int64)
    cells = (integers - store.least_cells[batch]) << store.cell_shifts[batch]
    held = store.read_words()[store.slots_of(ids).astype(np.int64)]
    assert np.array_equal(held[:, :3], pack_words(cells))
    assert store.cell_shifts[batch].max() > 0
    scene.release()


@pytest.mark.parametrize("case", ["rows", "bytes", "strided source", "other dtype", "over the held size",
                                  "split over threads", "split, other dtype", "too small to split"])
def test_stage_copy_equals_numpy_assignment(monkeypatch, case):
    """StageCopier writes what dst[...] = src writes: by its memmove holding the GIL where
    both are contiguous and alike, by numpy where not (a strided source, another dtype, a
    copy over HELD_COPY_BYTES), and by numpy split by rows over three threads where each
    gets THREAD_COPY_BYTES (the calling thread copies a part, the pool the others)."""
    rng = np.random.default_rng(3)
    src = rng.integers(0, 1 << 32, (1000, 4), dtype=np.uint32)
    if case == "bytes":
        src = rng.integers(0, 256, (999, 3), dtype=np.uint8)
    elif case == "strided source":
        src = src[::2]
    elif case in ("other dtype", "split, other dtype"):
        src = src.astype(np.int64)
    if case not in ("rows", "bytes", "strided source", "other dtype"):
        monkeypatch.setattr(stagecopy, "HELD_COPY_BYTES", 64)
    if case.startswith("split"):
        monkeypatch.setattr(stagecopy, "THREAD_COPY_BYTES", 1000)     # 16,000 bytes: three parts
    elif case == "too small to split":
        monkeypatch.setattr(stagecopy, "THREAD_COPY_BYTES", 10_000)   # the calling thread alone
    dst = np.zeros(src.shape, np.uint8 if case == "bytes" else np.uint32)
    want = dst.copy()
    want[...] = src
    moves = []
    memmove = stagecopy._MEMMOVE_HOLDING_GIL
    monkeypatch.setattr(stagecopy, "_MEMMOVE_HOLDING_GIL", lambda *args: moves.append(args) or memmove(*args))
    copier = stagecopy.StageCopier(4, parts=3)
    submitted = []
    if copier.pool is not None:
        submit = copier.pool.submit
        monkeypatch.setattr(copier.pool, "submit", lambda *a: submitted.append(a[1].shape) or submit(*a))
    copier(dst, src)
    copier.close()
    np.testing.assert_array_equal(dst, want)
    assert len(moves) == (case in ("rows", "bytes"))
    assert submitted == ([(333, 4), (334, 4)] if case.startswith("split") else [])
