"""Batches sorted by Morton code inside each loaded batch (batches.BatchOrder.MORTON):
the order itself against numpy, and renders of real files against the float64 render
contract, whose ties go to the least slot of each file-order point (the store's way
back from its order)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from conftest import SAMPLE, file_xyz, shared_file
from progressive import batches
from progressive.attributes import default_attribute
from progressive.batches import BatchOrder
from progressive.camera import auto_camera
from progressive.loaders import CloudLoader
from progressive.loaders.types import Batch, Grid
from progressive.permutation import BATCH_POINTS
from progressive.reference import EMPTY, reference_ids
from progressive.renderer import Renderer
from progressive.scene import Scene

W, H = 200, 150


def naive_codes(xyz: np.ndarray) -> np.ndarray:
    """Morton codes bit by bit (x in bit 0 of each triple) on the cube grid over the box."""
    lo = xyz.min(axis=0)
    cells = 1 << batches.MORTON_BITS
    q = np.minimum((xyz - lo) * (cells / (xyz.max(axis=0) - lo).max()), cells - 1).astype(np.uint64)
    codes = np.zeros(len(xyz), dtype=np.uint64)
    for bit in range(batches.MORTON_BITS):
        for axis in range(3):
            codes |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return codes


def test_morton_order_equals_the_bit_by_bit_codes_sorted():
    rng = np.random.default_rng(4)
    xyz = rng.uniform(-50, 50, (5000, 3)) * [1, 2, 0.1]
    xyz[100:200] = xyz[50]                      # ties keep file order (stable)
    order = batches.morton_order(xyz.astype(np.float32))
    want = np.argsort(naive_codes(xyz.astype(np.float32).astype(np.float64)), kind="stable")
    np.testing.assert_array_equal(order, want)


def test_points_not_finite_go_last_in_file_order():
    xyz = np.array([[3, 3, 3], [np.nan, 0, 0], [0, 0, 0], [1, np.inf, 1], [1, 1, 1]], dtype=np.float32)
    np.testing.assert_array_equal(batches.morton_order(xyz), [2, 4, 0, 1, 3])
    assert batches.morton_order(np.full((3, 3), np.nan, np.float32)).tolist() == [0, 1, 2]


def test_reordered_moves_every_array_of_a_row_together():
    n = 10
    b = Batch(start=5, xyz=np.arange(3 * n, dtype=np.float32).reshape(n, 3),
              attributes={"intensity": np.arange(n, dtype=np.uint16), "rgb": np.arange(3 * n, dtype=np.uint8).reshape(n, 3)},
              records=np.arange(4 * n, dtype=np.uint32).reshape(n, 4),
              grid=Grid(np.arange(3 * n, dtype=np.int32).reshape(n, 3), (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)))
    order = np.array([3, 0, 2, 1])
    r = b.reordered(2, 6, order)
    rows = [0, 1, 5, 2, 4, 3, 6, 7, 8, 9]
    np.testing.assert_array_equal(r.positions, b.positions[rows])
    np.testing.assert_array_equal(r.records, b.records[rows])
    np.testing.assert_array_equal(r.grid.cells, b.grid.cells[rows])
    for key in b.attributes:
        np.testing.assert_array_equal(r.attributes[key], b.attributes[key][rows])
    assert r.start == b.start and r.count == b.count


def scene_of(gl, parts, info, order: BatchOrder) -> tuple[Scene, Renderer]:
    scene = Scene(gl, info, default_attribute(info), batch_order=order)
    for b in parts:
        scene.add_batch(b)
    return scene, Renderer(gl, info, scene.attribute, width=W, height=H, scene=scene)


def loaded(path, batch_points: int):
    with CloudLoader([path], batch_points=batch_points) as loader:
        info = loader.info
        loader.start()
        return info, sorted(loader, key=lambda b: b.start)


def scrambled(info, parts, seed: int):
    """The file's points in a random order, as one loaded batch: a file whose order
    wanders as far as it can."""
    rng = np.random.default_rng(seed)
    whole = dataclasses.replace(parts[0], xyz=np.concatenate([b.positions for b in parts]), grid=None,
                                attributes={k: np.concatenate([b.attributes[k] for b in parts]) for k in parts[0].attributes},
                                bounds=None)
    perm = rng.permutation(whole.count)
    return whole.reordered(0, whole.count, perm), perm


def box_area(scene: Scene) -> float:
    """The batches' boxes' summed XY area (the store's boxes: min at 0..2, max at 4..6)."""
    boxes = scene.store.boxes
    held = np.isfinite(boxes[:, 0])
    return float(np.prod(boxes[held, 4:6] - boxes[held, 0:2], axis=1).sum())


def test_a_scrambled_file_gets_compact_batches_and_keeps_its_ids(gl):
    """The sample's points in a random order, one loaded batch: sorted, its batches' boxes
    cover under 0.4 of the area the file-ordered ones do, and every id is still the
    reference's, the file-order index of the point shown."""
    info, parts = loaded(SAMPLE, 1 << 20)
    batch, perm = scrambled(info, parts, seed=3)
    xyz = file_xyz(SAMPLE)[perm]                     # the scrambled file's own order
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    area = {}
    for order in BatchOrder:
        scene, r = scene_of(gl, [batch], info, order)
        area[order] = box_area(scene)
        frame = r.render(cam, W, H, r.style())
        ref = reference_ids(xyz, cam, W, H, tie_key=scene.store.slots_of(np.arange(info.points)))
        assert np.mean(frame.ids == ref) >= 0.999
        gl.check()
        r.release()
        scene.release()
    assert area[BatchOrder.MORTON] < 0.4 * area[BatchOrder.FILE]     # 11 batches: each a tenth of the cloud, not all of it


@pytest.mark.parametrize("name", ["autzen_trim.las", "pine_plot.laz", "lone-star.copc.laz"])
def test_morton_batches_meet_the_render_contract(gl, name):
    """Real files loaded in batches of several store batches: the ids of a Morton-ordered
    store are the float64 reference's, ties going to the least slot of each file-order
    point; against the file-ordered store the same pixels are covered."""
    path = SAMPLE if name == "autzen_trim.las" else shared_file(name)
    info, parts = loaded(path, 4 * BATCH_POINTS + 77)
    xyz = file_xyz(path)
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    seen = {}
    for order in BatchOrder:
        scene, r = scene_of(gl, parts, info, order)
        assert (scene.store.file_order is not None) == (order is BatchOrder.MORTON)
        frame = r.render(cam, W, H, r.style())
        ref = reference_ids(xyz, cam, W, H, tie_key=scene.store.slots_of(np.arange(info.points)))
        assert (ref != EMPTY).sum() > 200
        assert np.mean(frame.ids == ref) >= 0.999
        seen[order] = frame.ids != EMPTY
        gl.check()
        r.release()
        scene.release()
    np.testing.assert_array_equal(seen[BatchOrder.FILE], seen[BatchOrder.MORTON])


def test_render_batch_order_morton(tmp_path, capsys):
    """`render --batch-order morton`: the pixels the file order covers, each id a point
    that lies in its pixel as the file order's does (ties aside), and --stats says which
    order; a name it does not know is one line, exit 2."""
    from progressive.cli import main

    ids, stats = {}, {}
    for order in ("file", "morton"):
        out, js = tmp_path / f"{order}.npy", tmp_path / f"{order}.json"
        assert main(["render", "--width", str(W), "--height", str(H), "--batch-order", order, "--ids", str(out),
                     "--stats", str(js), "--method", "brute"]) == 0
        ids[order], stats[order] = np.load(out), json.loads(js.read_text())
    assert stats["morton"]["batch_order"] == "morton" and stats["file"]["batch_order"] == "file"
    np.testing.assert_array_equal(ids["file"] != EMPTY, ids["morton"] != EMPTY)
    assert np.mean(ids["file"] == ids["morton"]) >= 0.999
    capsys.readouterr()
    assert main(["render", "--batch-order", "hilbert", "--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("progressive: error:") and err.count("\n") == 1 and not (tmp_path / "x.png").exists()


def test_progressive_frames_converge_to_the_brute_force_render_of_the_same_order(tmp_path):
    """Progressive frames over Morton-ordered batches end equal to the brute-force render
    of the same store order (`--converge`), loading included."""
    from progressive.cli import main

    ids = {}
    for method in ("brute", "progressive"):
        out = tmp_path / f"{method}.npy"
        extra = ["--converge"] if method == "progressive" else []
        assert main(["render", "--width", str(W), "--height", str(H), "--batch-order", "morton", "--method", method,
                     *extra, "--ids", str(out)]) == 0
        ids[method] = np.load(out)
    assert (ids["brute"] != EMPTY).sum() > 500
    np.testing.assert_array_equal(ids["progressive"], ids["brute"])


def test_a_switch_streams_the_words_of_the_points_the_store_placed(gl):
    """Kept batches are kept as sorted: after a switch each slot's attribute word is the
    new attribute's of the point the store placed there, and the image is the reference's."""
    from progressive.loaders.records import attribute_word

    info, parts = loaded(SAMPLE, 4 * BATCH_POINTS + 77)
    scene = Scene(gl, info, default_attribute(info), keep_batches=True, batch_order=BatchOrder.MORTON)
    for b in parts:
        scene.add_batch(b)
    intensity = info.attribute("intensity")
    scene.begin_switch(intensity)
    while not scene.stream(seconds=float("inf")):
        pass
    cloud = np.arange(info.points)
    words = scene.store.read_words()[scene.store.permutation.forward(cloud).astype(np.int64), 3]
    kept = sorted(scene.batches, key=lambda b: b.start)
    expected = np.concatenate([attribute_word(b, intensity, float(info.origin[2])) for b in kept])
    np.testing.assert_array_equal(words, expected)
    files = scene.store.file_indices(cloud)
    raw = np.concatenate([p.attributes["intensity"] for p in parts])
    np.testing.assert_array_equal(np.concatenate([b.attributes["intensity"] for b in kept]), raw[files])
    gl.check()
    scene.release()


def test_a_memory_limit_keeps_the_same_share_of_every_sorted_batch(gl):
    """Under a memory limit the store keeps a slot prefix: the same share of every batch
    as the store ordered it (one slice at most apart), and the render is the
    reference's over the points kept, ties to their slots."""
    from progressive import memory
    from progressive.reference import subset_reference_ids
    from progressive.session import Method, Session, SessionOptions

    budget = memory.bytes_for(40_000, W * H)
    options = SessionOptions(width=W, height=H, method=Method.BRUTE, batch_order=BatchOrder.MORTON,
                             gpu_memory_limit=budget)
    with Session([str(SAMPLE)], options) as s:
        cam = s.auto_camera()
        s.frame(cam)
        store, n = s.renderer.store, s.info.points
        assert store.file_order is not None and store.capacity < n
        cloud = np.arange(n)
        kept_cloud = cloud[store.permutation.forward(cloud) < store.capacity]
        per_batch = np.bincount(kept_cloud // BATCH_POINTS)
        assert per_batch.max() - per_batch[:-1].min() <= 256
        kept = np.sort(store.file_indices(kept_cloud))
        ref = subset_reference_ids(file_xyz(SAMPLE), kept, cam, W, H, store.slots_of(cloud))
        assert (ref != EMPTY).sum() > 200 and np.mean(s.ids() == ref) >= 0.999


def test_view_takes_the_batch_order_too(tmp_path, monkeypatch, capsys):
    """`view --batch-order morton` without a display writes its PNG, the same image as the
    file order's but for ties between points at one depth."""
    from PIL import Image

    from progressive.cli import main

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    images = {}
    for order in ("file", "morton"):
        out = tmp_path / f"{order}.png"
        assert main(["view", "--width", str(W), "--height", str(H), "--batch-order", order, "--out", str(out)]) == 0
        images[order] = np.asarray(Image.open(out))
    capsys.readouterr()
    same = np.all(images["file"] == images["morton"], axis=-1)
    assert (images["file"][..., :3] > 0).any(axis=-1).sum() > 500 and same.mean() >= 0.99


def test_sorted_rows_are_the_whole_store_batches_of_a_loaded_batch():
    """A loaded batch that starts and ends inside store batches sorts only the whole
    ones between (two or more), each row once."""
    rng = np.random.default_rng(2)
    start = 3 * BATCH_POINTS + 5
    xyz = rng.uniform(0, 10, (5 * BATCH_POINTS, 3)).astype(np.float32)
    lo, order = batches.sorted_rows(start, xyz)
    assert lo == BATCH_POINTS - 5 and order.shape[0] == 4 * BATCH_POINTS
    assert (start + lo) % BATCH_POINTS == 0 and np.array_equal(np.sort(order), np.arange(4 * BATCH_POINTS))
    np.testing.assert_array_equal(order, batches.morton_order(xyz[lo: lo + 4 * BATCH_POINTS]))
    assert batches.sorted_rows(start, xyz[: 3 * BATCH_POINTS - 10]) is None      # one whole batch only


def test_a_placed_store_keeps_its_runs_by_batch(gl):
    """A placed store (a streamed cloud's) takes runs of whole batches with the file-order
    index of their first point (a node's, PointStore.place_run): its file indices follow
    on through each run's batches, a later run over an earlier one where they meet; it
    keeps a start a batch, no index a point, and refuses a run that starts inside a batch
    or rows reordered one by one. A loaded store's map keeps the identity for the batches
    never reordered."""
    from progressive.permutation import BATCH_POINTS
    from progressive.pointstore import PointStore

    count = 6 * BATCH_POINTS
    store = PointStore(gl, count, placed=True)
    try:
        store.place_run(0, 1_000_000, 2 * BATCH_POINTS + 7)            # three batches, the last 7 points
        store.place_run(2 * BATCH_POINTS, 5_000, BATCH_POINTS)          # the first run's last batch, again
        store.place_run(4 * BATCH_POINTS, 77, 10)
        cloud = np.array([0, BATCH_POINTS + 3, 2 * BATCH_POINTS, 2 * BATCH_POINTS + 6, 4 * BATCH_POINTS + 9])
        want = [1_000_000, 1_000_000 + BATCH_POINTS + 3, 5_000, 5_006, 86]
        np.testing.assert_array_equal(store.file_indices(cloud), want)
        np.testing.assert_array_equal(store.file_order[cloud], want)
        assert store._batch_starts.nbytes == 8 * store.permutation.batches
        for bad in (lambda: store.place_run(5, 0, 10), lambda: store.reorder(100, np.array([1], np.uint32))):
            with pytest.raises(ValueError):
                bad()
    finally:
        store.release()
    given = np.array([7, 3, 11], dtype=np.uint32)
    store = PointStore(gl, 5_000)
    try:
        store.reorder(100, given)
        expected = np.arange(5_000, dtype=np.uint32)
        expected[100:103] = given
        np.testing.assert_array_equal(store.file_order, expected)
        np.testing.assert_array_equal(store.file_indices(np.arange(100, 103)), given)
        with pytest.raises(ValueError):
            store.place_run(0, 0, 10)
    finally:
        store.release()
