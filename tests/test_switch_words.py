"""Attribute switching streams words (paper 3.5): progressive/wordpack.py packs exactly
loaders/records.py attribute_word (the reference), and after a switch the attribute
words on the GPU, read back in slot order, are the reference's placed by the numpy
permutation (progressive/permutation.py), for every kind of attribute, on both
encodings: kept batches split across the store's batches and delivered out of order,
runs split over staging pieces, a memory-limited store, switches interrupted by
another, switching while loading, points hidden by non-finite values."""

from __future__ import annotations

import dataclasses
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from progressive.encoding import Encoding
from progressive.loaders.records import attribute_word
from progressive.loaders.types import AttributeInfo, AttributeKind, Batch
from progressive.passes.distribute import DistributePass, Staging, StagingRing, without_buffer_storage
from progressive.permutation import BATCH_POINTS, FillOrder
from progressive.pointstore import EMPTY_WORD
from progressive.scene import Scene
from progressive.wordpack import WordPacker, WordRun, threaded
from tests.test_upload_ring import expected_store, hidden, hostile

NAMES = ("intensity", "gps_time", "rgb", "classification", "elevation")
"""A uint16 scalar, a float64 scalar, RGB packed, a category, and the z-derived scalar."""


def resplit(batches: list[Batch], sizes=(7_001, 13_337, 2_500, 31_000)) -> list[Batch]:
    """The same points in loader batches of other sizes (cutting the store's batches of
    BATCH_POINTS anywhere), delivered out of file order."""
    out, start, k = [], 0, 0
    whole = concat(batches)
    total = whole.count
    while start < total:
        n = min(sizes[k % len(sizes)], total - start)
        out.append(dataclasses.replace(whole.rows(start, start + n), nonfinite_positions=0))
        start, k = start + n, k + 1
    rng = np.random.default_rng(5)
    return [out[i] for i in rng.permutation(len(out))]


def concat(batches: list[Batch]) -> Batch:
    ordered = sorted(batches, key=lambda b: b.start)
    return Batch(start=ordered[0].start, xyz=np.concatenate([b.positions for b in ordered]),
                 attributes={k: np.concatenate([b.attributes[k] for b in ordered]) for k in ordered[0].attributes})


def expected_words(scene: Scene, batches: list[Batch], attribute: AttributeInfo) -> np.ndarray:
    """The attribute plane in slot order as numpy places the reference's words."""
    out = np.full(scene.store.capacity, EMPTY_WORD, dtype=np.uint32)     # slots no point maps to stay empty
    for b in batches:
        slots = scene.store.slots_of(np.arange(b.start, b.start + b.count)).astype(np.int64)
        keep = slots < scene.store.capacity
        out[slots[keep]] = attribute_word(b, attribute, float(scene.info.origin[2]))[keep]
    return out


def switch(scene: Scene, attribute: AttributeInfo, seconds: float = float("inf")) -> None:
    scene.begin_switch(attribute)
    while not scene.stream(seconds=seconds):
        pass


def test_packer_equals_attribute_word_for_every_attribute(sample_batches):
    info, batches = sample_batches
    rng = np.random.default_rng(1)
    origin_z = float(info.origin[2])
    for attribute in info.attributes:
        packer = WordPacker(attribute, origin_z)
        for b in batches[:3]:
            ref = attribute_word(b, attribute, origin_z)
            lo, hi = sorted(rng.integers(0, b.count, 2).tolist())
            out = np.zeros(hi - lo, dtype=np.uint32)
            packer.pack(out, b, lo, hi)
            np.testing.assert_array_equal(out, ref[lo:hi], err_msg=attribute.name)


@pytest.mark.parametrize("dtype", ["float64", "float32", "int16", "uint32", "int64"])
def test_packer_equals_attribute_word_on_hard_values(dtype):
    """Non-finite, huge and negative values, blocks of BLOCK_POINTS crossed."""
    rng = np.random.default_rng(2)
    n = 150_001
    if np.dtype(dtype).kind == "f":
        with np.errstate(over="ignore"):       # float32: some overflow to infinity, as they may
            values = (rng.standard_normal(n) * 10.0 ** rng.integers(-3, 40, n)).astype(dtype)
        values[::97], values[5::101], values[7::103] = np.nan, np.inf, -np.inf
    else:
        info = np.iinfo(dtype)
        values = rng.integers(info.min, info.max, n, dtype=dtype, endpoint=True)
    attribute = AttributeInfo("v", AttributeKind.SCALAR, np.dtype(dtype), offset=12345.678)
    batch = Batch(start=0, xyz=rng.standard_normal((n, 3)).astype(np.float32), attributes={"v": values})
    out = np.zeros(n - 3, dtype=np.uint32)
    WordPacker(attribute, 0.0).pack(out, batch, 3, n)
    np.testing.assert_array_equal(out, attribute_word(batch, attribute, 0.0)[3:])


@pytest.mark.parametrize("layout", ["contiguous", "strided", "uint16"])
@pytest.mark.parametrize("rows", [(0, 0), (0, 1), (5, 6), (0, 70_001), (3, 70_000)])
def test_packer_equals_attribute_word_on_rgb(layout, rows):
    """Contiguous bytes read as words 3 bytes apart, up to the last point; other
    layouts through the reference."""
    rng = np.random.default_rng(4)
    n = 70_001
    rgb = rng.integers(0, 256, (n, 6), dtype=np.uint8)
    values = {"contiguous": np.ascontiguousarray(rgb[:, :3]), "strided": rgb[:, ::2],
              "uint16": rgb[:, :3].astype(np.uint16)}[layout]
    attribute = AttributeInfo("rgb", AttributeKind.RGB, values.dtype)
    batch = Batch(start=0, xyz=np.zeros((n, 3), dtype=np.float32), attributes={"rgb": values})
    lo, hi = rows
    out = np.zeros(hi - lo, dtype=np.uint32)
    WordPacker(attribute, 0.0).pack(out, batch, lo, hi)
    np.testing.assert_array_equal(out, attribute_word(batch, attribute, 0.0)[lo:hi])


def test_run_fill_in_pieces_and_threads_equals_the_reference(sample_batches):
    info, batches = sample_batches
    attribute = info.attribute("rgb")
    packer = WordPacker(attribute, float(info.origin[2]))
    parts = [(batches[0], 1_000, batches[0].count), (batches[1], 0, batches[1].count), (batches[2], 0, 5_000)]
    run = WordRun(packer, parts)
    ref = np.concatenate([attribute_word(b, attribute, 0.0)[lo:hi] for b, lo, hi in parts])
    assert run.start == batches[0].start + 1_000 and run.count == ref.shape[0]
    out = np.zeros(run.count, dtype=np.uint32)
    cuts = [0, 17, 18_999, 19_000, 25_000, run.count]
    for lo, hi in zip(cuts, cuts[1:]):
        run.fill(out[lo:hi], lo, hi)
    np.testing.assert_array_equal(out, ref)
    with ThreadPoolExecutor(3) as pool:
        split = threaded(run.fill, pool, 3, least=1_000)
        out[:] = 0
        split(out[100:], 100, run.count)
        np.testing.assert_array_equal(out[100:], ref[100:])
    with pytest.raises(ValueError):
        WordRun(packer, [parts[0], parts[2]])
    assert run.rgb_bytes      # the loader's RGB: (n, 3) uint8, handed to the GPU as bytes
    rgb = np.zeros((run.count, 3), dtype=np.uint8)
    for lo, hi in zip(cuts, cuts[1:]):
        run.fill_rgb(rgb[lo:hi], lo, hi)
    np.testing.assert_array_equal(rgb, np.concatenate([b.attributes["rgb"][lo:hi] for b, lo, hi in parts]))
    wide = dataclasses.replace(batches[0], attributes={"rgb": batches[0].attributes["rgb"].astype(np.uint16)})
    assert not WordRun(WordPacker(dataclasses.replace(attribute, dtype=np.uint16), 0.0), [(wide, 0, 10)]).rgb_bytes


@pytest.mark.parametrize("encoding", list(Encoding), ids=lambda e: e.name.lower())
@pytest.mark.parametrize("name", NAMES)
def test_switched_words_equal_the_reference(gl, sample_batches, encoding, name):
    """Loader batches cutting the store's batches, out of order; runs over several
    staging pieces (a small piece), every kind of attribute, both encodings."""
    info, batches = sample_batches
    loaded = resplit(batches)
    first = info.attribute("classification" if name != "classification" else "intensity")
    scene = Scene(gl, info, first, keep_batches=True, position_encoding=encoding)
    for b in loaded:
        scene.add_batch(b)
    scene.distribute.batch_points = 3_001      # pieces of 12,004 words: runs and batches split over pieces
    scene.distribute.word_piece = 12_004
    before = scene.store.read_words()
    np.testing.assert_array_equal(before[:, 3], expected_words(scene, loaded, first))
    attribute = info.attribute(name)
    stats = scene.distribute.stats
    pieces = stats.ring + stats.copied
    switch(scene, attribute)
    assert stats.ring + stats.copied - pieces >= -(-info.points // 12_004)     # pieces of the word piece at most
    after = scene.store.read_words()
    np.testing.assert_array_equal(after[:, 3], expected_words(scene, loaded, attribute))
    assert not np.array_equal(after[:, 3], before[:, 3])
    np.testing.assert_array_equal(after[:, :3], before[:, :3])     # positions untouched
    assert scene.switch.streamed == info.points and scene.switch.unchanged == 0
    assert scene.skipped == 0
    assert (scene.distribute.rgb_words is not None) == (name == "rgb")      # RGB staged as bytes
    scene.release()


@pytest.mark.parametrize("staging", list(Staging), ids=lambda s: s.name.lower())
@pytest.mark.parametrize("encoding", list(Encoding), ids=lambda e: e.name.lower())
def test_rgb_switch_staged_as_bytes_through_the_ring_and_copied(gl, sample_batches, staging, encoding):
    """RGB switches stage 3 bytes a point and the scatter makes the words: equal to the
    reference through ring slots and through the copy buffer, with pieces whose bytes
    end inside a word (12,003 points: 36,009 bytes)."""
    info, batches = sample_batches
    loaded = resplit(batches)
    scene = Scene(gl if staging is Staging.RING else without_buffer_storage(gl), info, info.attribute("intensity"),
                  keep_batches=True, position_encoding=encoding)
    for b in loaded:
        scene.add_batch(b)
    scene.distribute.word_piece = 12_003
    stats = scene.distribute.stats
    ring, copied = stats.ring, stats.copied
    attribute = info.attribute("rgb")
    switch(scene, attribute)
    np.testing.assert_array_equal(scene.store.read_words()[:, 3], expected_words(scene, loaded, attribute))
    assert scene.distribute.rgb_words is not None
    assert (stats.ring - ring > 0) == (staging is Staging.RING) and (stats.copied - copied > 0) == (staging is Staging.COPY)
    scene.release()


@pytest.mark.parametrize("name", ["gps_time", "rgb"])
def test_a_switch_piece_copied_for_want_of_a_free_slot_may_outgrow_a_records_piece(gl, sample_batches,
                                                                                  monkeypatch, name):
    """A switch's piece of words finding its ring slot busy is copied through the copy
    path's buffer, which holds a piece of records: a piece of more words than that (a
    large cloud's, by default 64 MiB against 8 MB) is copied whole, equal to the reference."""
    info, batches = sample_batches
    loaded = resplit(batches)
    scene = Scene(gl, info, info.attribute("intensity"), keep_batches=True)
    scene.distribute.release()
    scene.distribute = DistributePass(gl, scene.store, batch_points=2_000, word_piece=30_000)
    for b in loaded:
        scene.add_batch(b)
    stage = scene.distribute.stage.size
    acquire = StagingRing.acquire
    monkeypatch.setattr(StagingRing, "acquire",
                        lambda ring: None if ring is scene.distribute.word_ring else acquire(ring))
    copied = scene.distribute.stats.copied
    attribute = info.attribute(name)
    switch(scene, attribute)
    gl.check()
    assert scene.distribute.stats.copied - copied == -(-info.points // 30_000)
    assert scene.distribute.stage.size > stage
    np.testing.assert_array_equal(scene.store.read_words()[:, 3], expected_words(scene, loaded, attribute))
    scene.release()


@pytest.mark.parametrize("encoding", list(Encoding), ids=lambda e: e.name.lower())
def test_interrupted_switches_and_switching_while_loading(gl, sample_batches, encoding):
    """A switch interrupted after one run by another, batches arriving in between, and
    a switch back to the attribute most batches still hold: those are left as they are,
    the words are the reference's throughout."""
    info, batches = sample_batches
    loaded = resplit(batches)
    half = len(loaded) // 2
    a, b, c = (info.attribute(n) for n in ("intensity", "rgb", "gps_time"))
    scene = Scene(gl, info, a, keep_batches=True, position_encoding=encoding)
    for batch in loaded[:half]:
        scene.add_batch(batch)
    scene.distribute.batch_points = 2_000
    scene.distribute.word_piece = 8_000
    scene.begin_switch(b)
    assert not scene.stream(seconds=0.0)         # one run of 8,000 words
    for batch in loaded[half: half + 3]:
        scene.add_batch(batch)                   # packed with b, some encoded again with earlier parts
    scene.begin_switch(c)
    assert not scene.stream(seconds=0.0)
    switch(scene, c)
    for batch in loaded[half + 3:]:
        scene.add_batch(batch)
    np.testing.assert_array_equal(scene.store.read_words()[:, 3], expected_words(scene, loaded, c))
    switch(scene, b)
    scene.begin_switch(c)
    scene.stream(seconds=0.0)
    written = scene.distribute.points_distributed
    switch(scene, b)                               # back: all but one run's batches still hold b
    assert 0 < scene.distribute.points_distributed - written < info.points // 2
    assert scene.switch.unchanged > info.points // 2
    np.testing.assert_array_equal(scene.store.read_words()[:, 3], expected_words(scene, loaded, b))
    scene.release()


@pytest.mark.parametrize("encoding", list(Encoding), ids=lambda e: e.name.lower())
def test_switch_on_a_memory_limited_store(gl, sample_batches, encoding):
    info, batches = sample_batches
    capacity = 3 * BATCH_POINTS + 1_234
    scene = Scene(gl, info, info.attribute("intensity"), keep_batches=True, capacity=capacity,
                  position_encoding=encoding)
    for b in batches:
        scene.add_batch(b)
    attribute = info.attribute("gps_time")
    switch(scene, attribute)
    assert scene.store.capacity == capacity
    np.testing.assert_array_equal(scene.store.read_words()[:, 3], expected_words(scene, batches, attribute))
    scene.release()


@pytest.mark.parametrize("encoding", list(Encoding), ids=lambda e: e.name.lower())
def test_hidden_points_across_switches(gl, sample_batches, encoding):
    """Non-finite intensities hide their points: switching away shows them again (whole
    records), switching back hides them; the store equals pack_records' throughout."""
    info, batches = sample_batches
    bad = hostile(batches, info)
    scene = Scene(gl, info, info.attribute("intensity"), keep_batches=True, position_encoding=encoding)
    for b in bad:
        scene.add_batch(b)
    for name in ("rgb", "intensity", "elevation"):
        switch(scene, info.attribute(name))
        held, expected = scene.store.read_records(), expected_store(scene, bad)
        if encoding is Encoding.FLOAT:
            np.testing.assert_array_equal(held, expected)
        else:
            np.testing.assert_array_equal(held[:, 3], expected[:, 3])
            shown = np.isfinite(expected[:, :3].view(np.float32)).all(axis=1)
            np.testing.assert_array_equal((held[:, :3] == EMPTY_WORD).all(axis=1), ~shown)
        assert scene.skipped == hidden(scene, bad) > 0
        assert scene.switch.records == len(bad)     # each batch's intensities hide points
    scene.release()


def test_parts_encoded_again_during_a_switch_are_rewritten(gl, sample_batches):
    """The word store encodes a batch again, with the attribute shown, when a loader
    batch completes it: a kept batch whose rows it shares then holds a mix, which a
    switch back to its own attribute must still rewrite."""
    info, batches = sample_batches
    whole = concat(batches)
    cut = (5 * BATCH_POINTS + 3_885, 4 * BATCH_POINTS - 892)      # inside batches 5 and 3
    z, x, y = whole.rows(0, cut[1]), whole.rows(cut[1], cut[0]), whole.rows(cut[0], whole.count)
    a, b = info.attribute("intensity"), info.attribute("classification")
    scene = Scene(gl, info, a, keep_batches=True)
    scene.add_batch(z)
    scene.add_batch(x)
    scene.distribute.batch_points = 2_000
    scene.distribute.word_piece = 8_000
    scene.begin_switch(b)
    scene.stream(seconds=0.0)                    # one run, inside z: x still holds a
    scene.add_batch(y)                           # batch 5 encoded again, x's rows of it with b
    assert scene.held[1] is None
    switch(scene, a)
    np.testing.assert_array_equal(scene.store.read_words()[:, 3], expected_words(scene, [z, x, y], a))
    scene.release()


@pytest.mark.parametrize("order", [FillOrder.SHUFFLED, FillOrder.FILE], ids=lambda o: o.name.lower())
def test_switch_on_the_unbatched_baselines(gl, sample_batches, order):
    """The benchmarks' baselines (one shuffle of the whole cloud, file order: float
    records) switch through the general scatter."""
    info, batches = sample_batches
    scene = Scene(gl, info, info.attribute("intensity"), keep_batches=True, order=order)
    for b in resplit(batches):
        scene.add_batch(b)
    attribute = info.attribute("rgb")
    switch(scene, attribute)
    assert not scene.store.batched
    np.testing.assert_array_equal(scene.store.read_words()[:, 3], expected_words(scene, batches, attribute))
    scene.release()
