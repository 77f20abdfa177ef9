"""Batch boxes and culling: boxes hold their points (against numpy per batch), the
frustum test never drops a batch with a point in view (against the float64 render
contract), and the GPU's culled render has the ids of the unculled one for views
inside, at the edge of and outside the cloud."""

from __future__ import annotations

import numpy as np
import pytest

from progressive import batches
from progressive.attributes import find_attribute
from progressive.camera import Camera, auto_camera, project, view_uniforms
from progressive.passes.cull import CullPass
from progressive.passes.raster_compute import ComputeRaster, ComputeTuning
from progressive.passes.visibility import EMPTY
from progressive.permutation import BATCH_POINTS, BATCH_SLOTS, SLICE_POINTS
from progressive.pointstore import RecordOrder
from progressive.renderer import Renderer
from progressive.scene import Scene

W, H = 160, 120


def numpy_boxes(p: np.ndarray) -> np.ndarray:
    """Per batch of BATCH_POINTS file points: min and max of the finite rows."""
    out = batches.empty_boxes(-(-p.shape[0] // BATCH_POINTS))
    for b in range(out.shape[0]):
        part = p[b * BATCH_POINTS:(b + 1) * BATCH_POINTS]
        part = part[np.isfinite(part).all(axis=1)]
        if part.size:
            out[b, 0:3], out[b, 4:7] = part.min(axis=0), part.max(axis=0)
    return out


@pytest.mark.parametrize("finite", [False, True], ids=["nonfinite", "finite"])
@pytest.mark.parametrize("cuts", [[], [1], [BATCH_POINTS], [5000, 5001, 30_000], [BATCH_POINTS * 2 - 1]])
def test_boxes_of_any_split_equal_numpy(cuts, finite):
    rng = np.random.default_rng(len(cuts))
    n = 3 * BATCH_POINTS + 77
    p = rng.normal(0, 100, (n, 3)).astype(np.float32)
    if not finite:
        p[rng.integers(0, n, 50)] = np.nan
        p[rng.integers(0, n, 30), 1] = np.nan               # one coordinate: the whole point never draws
        p[rng.integers(0, n, 30), 0] = rng.choice([np.inf, -np.inf], 30)
        p[BATCH_POINTS:2 * BATCH_POINTS] = np.nan          # a batch of points that never draw stays empty
    boxes = batches.empty_boxes(4)
    edges = [0, *cuts, n]
    for a, b in zip(edges[:-1], edges[1:]):
        first, new = batches.boxes_of(p[a:b], a)
        batches.merge(boxes, first, new)
    assert np.array_equal(boxes, numpy_boxes(p))
    assert (boxes[1, 0:3] <= boxes[1, 4:7]).all() == finite


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_all_finite_sees_any_nonfinite_value(bad):
    p = np.random.default_rng(3).normal(0, 1e30, (1000, 3)).astype(np.float32)
    assert batches.all_finite(p) and batches.all_finite(p[:0])
    p[617, 2] = bad
    assert not batches.all_finite(p)


def cameras(info) -> dict[str, Camera]:
    lo, hi = info.bounds_min, info.bounds_max
    base = auto_camera(lo, hi, W / H)
    centre, size = (lo + hi) / 2, hi - lo
    low = np.array([centre[0], centre[1], lo[2] + 0.3 * size[2]])
    return {
        "overview": base,
        "inside": Camera(position=tuple(low), target=tuple(low + [size[0], 0.2 * size[1], 0]), near=0.5, far=1e4),
        "zoomed corner": Camera(position=tuple(lo + [0.1 * size[0], 0.1 * size[1], 0.3 * size[0]]),
                                target=tuple(lo + [0.1 * size[0], 0.1 * size[1], 0.0]), up=(0, 1, 0), near=1.0, far=1e4),
        "edge": Camera(position=tuple(low - [0.6 * size[0], 0, 0]), target=tuple(low - [0.5 * size[0], 0, 0]),
                       near=1.0, far=1e5),
        "behind near plane": Camera(position=base.position, target=base.target, near=0.9 * np.linalg.norm(
            np.subtract(base.position, base.target)), far=1e5),
        "outside": Camera(position=tuple(low - [2 * size[0], 0, 0]), target=tuple(low - [3 * size[0], 0, 0]),
                          near=1.0, far=1e5),
    }


@pytest.fixture(scope="module")
def sample(sample_batches):
    info, parts = sample_batches
    positions = np.concatenate([b.positions for b in parts])
    xyz = positions.astype(np.float64) + info.origin
    return info, parts, positions, xyz


@pytest.mark.parametrize("name", ["overview", "inside", "zoomed corner", "edge", "behind near plane", "outside"])
def test_culled_batches_have_no_point_in_view(sample, name):
    info, _, positions, xyz = sample
    cam = cameras(info)[name]
    boxes = numpy_boxes(positions)
    kept = batches.in_view(boxes, view_uniforms(cam, info.origin, W, H))
    pixel, _ = project(cam, xyz, W, H)
    seen = np.unique(np.nonzero(pixel >= 0)[0] // BATCH_POINTS)
    assert kept[seen].all(), f"batches {seen[~kept[seen]]} culled with points in view"
    if name in ("zoomed corner", "outside"):
        assert not kept.all()


@pytest.mark.parametrize("name", ["overview", "inside", "zoomed corner", "edge", "behind near plane", "outside"])
def test_culling_keeps_every_visible_point_on_the_gpu(gl, sample, name):
    info, parts, _, _ = sample
    cam = cameras(info)[name]
    scene = Scene(gl, info, find_attribute(info, "elevation"))
    r = Renderer(gl, info, scene.attribute, width=W, height=H, scene=scene)
    try:
        for b in parts:
            scene.add_batch(b)
        culled = r.render(cam, W, H, r.style())
        assert r.raster.cull
        plain = ComputeRaster(gl, scene.store, r.vis, atomic64=r.raster.atomic64)
        r.raster.release()
        r.raster = plain
        unculled = r.render(cam, W, H, r.style())
        assert np.array_equal(culled.ids, unculled.ids)
        assert gl.ctx.error == "GL_NO_ERROR"
    finally:
        r.release()
        scene.release()


def test_store_boxes_hold_the_loaded_points(gl, sample):
    info, parts, positions, _ = sample
    scene = Scene(gl, info, find_attribute(info, "elevation"))
    try:
        for b in parts[::-1]:
            scene.add_batch(b)
        expected = numpy_boxes(positions)
        assert np.array_equal(scene.store.boxes, expected)
        gpu = np.frombuffer(scene.store.box_buffer.read(), dtype=np.float32).reshape(-1, batches.BOX_FLOATS)
        assert np.array_equal(gpu[:, [0, 1, 2, 4, 5, 6]], expected[:, [0, 1, 2, 4, 5, 6]])
    finally:
        scene.release()



def test_stats_report_batches_culled(tmp_path, sample):
    import json

    from progressive.cli import main

    info = sample[0]
    counts = {}
    for name in ("overview", "zoomed corner", "outside"):
        stats = tmp_path / f"{name}.json"
        camera = json.dumps(cameras(info)[name].to_dict())
        assert main(["render", "--width", str(W), "--height", str(H), "--camera", camera, "--stats", str(stats)]) == 0
        counts[name] = json.loads(stats.read_text())["batches"]
    total = -(-info.points // BATCH_POINTS)
    exact = {"10": 0, "20": 0}
    assert counts["overview"] == {"total": total, "drawn": total, "culled": 0, "bits": dict(exact, **{"30": total})}
    assert 0 < counts["zoomed corner"]["culled"] < total
    assert counts["zoomed corner"]["bits"]["30"] == counts["zoomed corner"]["drawn"]
    assert counts["outside"] == {"total": total, "drawn": 0, "culled": total, "bits": dict(exact, **{"30": 0})}


TUNINGS = [ComputeTuning(vector_loads=False, prefetch=k) for k in (1, 3)] + [
    ComputeTuning(batch_groups=g, vector_loads=v, subgroup_reduction=s)
    for g, v in ((True, True), (True, False), (False, False)) for s in (True, False)] + [
    ComputeTuning(batch_groups=False, vector_loads=False, candidates=False)]
"""Every way the compute raster walks the store; the last (one invocation a slot, an
atomic a point, the 32-bit index pass over every point) is the plain reference the
others must equal."""


def slots_of_range(gl, r: Renderer, cam: Camera, first: int, count: int) -> np.ndarray:
    """The visibility buffer's slots after drawing slots [first, first+count) alone."""
    r.vis.resize(W, H)
    r.vis.clear()
    r.raster.draw(view_uniforms(cam, r.info.origin, W, H), first, count)
    return r.vis.read()[:, :, 0].copy()


def assert_same_slots(ranges: list[tuple[int, int]], got: list[np.ndarray], want: list[np.ndarray], label: str) -> None:
    """Each range's slots equal the reference's, which shows points."""
    assert (want[0] != EMPTY).any()
    for span, a, b in zip(ranges, got, want, strict=True):
        assert np.array_equal(a, b), f"{label}: slots {span}"


def store_shape(info, shape: str) -> dict:
    """Scene arguments: the whole cloud in one buffer; two buffers, split inside a batch
    (the word store's blocks round the split up to whole blocks, so a batch's records
    lie in both); a memory limit whose last batch's records start off a multiple of 4
    (its quads fall back to one word a load)."""
    slots = -(-info.points // BATCH_POINTS) * BATCH_SLOTS
    return {"whole": {}, "two buffers": {"chunk_points": slots // 2 + 2 * SLICE_POINTS + 4},
            "memory limit": {"capacity": int(slots * 0.6) + 3}}[shape]


@pytest.mark.parametrize("atomic64", [True, False], ids=["64-bit", "32-bit"])
@pytest.mark.parametrize("name", ["overview", "zoomed corner"])
@pytest.mark.parametrize("shape", ["whole", "two buffers", "memory limit"])
@pytest.mark.parametrize("records", list(RecordOrder))
def test_every_tuning_keeps_the_ids(gl, sample, atomic64, name, shape, records):
    """One work group a batch, its four-word loads and the subgroup reduction (where the
    GPU has GL_NV_shader_subgroup_partitioned) give the ids of one invocation and one
    atomic per point, for the whole store and for ranges that start and end inside
    slices, with the store in one or two buffers and under a memory limit, its records
    batch after batch or in slot order."""
    if atomic64 and not gl.caps.atomic_int64:
        pytest.skip("no GL_NV_shader_atomic_int64")
    info, parts, _, _ = sample
    scene = Scene(gl, info, find_attribute(info, "elevation"), records=records, **store_shape(info, shape))
    assert scene.store.chunks == (2 if shape.startswith("two") else 1)
    r = Renderer(gl, info, scene.attribute, width=W, height=H, scene=scene)
    cam = cameras(info)[name]
    round_slots = scene.store.permutation.batches * SLICE_POINTS
    ranges = [(0, scene.store.capacity), (round_slots + 3 * SLICE_POINTS + 17, 2 * round_slots + 5),
              (5, 40), (scene.store.capacity - 300, 300)]
    try:
        for b in parts:
            scene.add_batch(b)
        seen = {}
        for tuning in TUNINGS:
            r.raster.release()
            r.raster = ComputeRaster(gl, scene.store, r.vis, atomic64=atomic64, culling=CullPass(gl, scene.store),
                                     tuning=tuning)
            if tuning.subgroup_reduction and not r.raster.partitioned:
                continue
            assert r.raster.batch_groups == tuning.batch_groups
            assert r.raster.vector_loads == bool(tuning.vector_loads and tuning.batch_groups and scene.store.words)
            seen[tuning] = [slots_of_range(gl, r, cam, *span) for span in ranges]
        reference = seen.pop(TUNINGS[-1])
        assert len(seen) >= 1
        for tuning, slots in seen.items():
            assert_same_slots(ranges, slots, reference, str(tuning))
        assert gl.ctx.error == "GL_NO_ERROR"
    finally:
        r.release()
        scene.release()


@pytest.mark.parametrize("room", ["enough", "too little", "none"])
@pytest.mark.parametrize("name", ["overview", "zoomed corner"])
def test_the_32_bit_index_pass_over_candidates_keeps_the_ids(gl, sample, monkeypatch, room, name):
    """The 32-bit index pass over the depth pass's candidates gives the ids of the index
    pass over every point; a frame with more candidates than room runs that pass instead,
    with the same ids. The count says the list was used, and that it is shorter than the
    points drawn."""
    info, parts, _, _ = sample
    scene = Scene(gl, info, find_attribute(info, "elevation"))
    r = Renderer(gl, info, scene.attribute, width=W, height=H, scene=scene)
    cam = cameras(info)[name]
    ranges = [(0, scene.store.capacity), (5, 4000)]
    try:
        for b in parts:
            scene.add_batch(b)
        seen = {}
        for tuning in (ComputeTuning(candidates=False), ComputeTuning(candidates=True)):
            with monkeypatch.context() as m:
                if room != "enough":
                    m.setattr(ComputeRaster, "candidate_capacity", lambda self, pixels: {"too little": 50, "none": 0}[room])
                r.raster.release()
                r.raster = ComputeRaster(gl, scene.store, r.vis, atomic64=False, culling=CullPass(gl, scene.store),
                                         tuning=tuning)
                assert r.raster.candidates == tuning.candidates
                seen[tuning] = []
                for span in ranges:
                    seen[tuning].append(slots_of_range(gl, r, cam, *span))
                    if tuning.candidates:
                        count = r.raster.candidates_found()
                        capacity = r.raster.candidate_capacity(r.vis.pixels)
                        assert 0 < count < span[1]
                        assert (count <= capacity) == (room == "enough")
        want, got = seen.values()
        assert_same_slots(ranges, got, want, room)
        assert gl.ctx.error == "GL_NO_ERROR"
    finally:
        r.release()
        scene.release()


@pytest.mark.parametrize("kind", ["none", "hidden", "returns", "clip box", "clip z", "section"])
def test_filtering_whenever_a_filter_can_leave_a_point_out(sample, kind):
    """The raster skips the filter tests when view.filtering is false: it must be true for
    every filter that can leave a point out, and false with none."""
    from progressive.camera import Clip, Returns, Section

    info = sample[0]
    lo, hi = info.bounds_min, info.bounds_max
    options = {"none": {}, "hidden": {"hidden": frozenset({2})}, "returns": {"returns": Returns.FIRST},
               "clip box": {"clip": Clip(lo=tuple(lo), hi=tuple((lo + hi) / 2))},
               "clip z": {"clip": Clip(lo=(-np.inf, -np.inf, lo[2]), hi=(np.inf, np.inf, hi[2]))},
               "section": {"clip": Clip(section=Section(start=(lo[0], lo[1]), end=(hi[0], hi[1]), width=1.0))}}[kind]
    view = view_uniforms(cameras(info)["overview"], info.origin, W, H, **options)
    assert view.filtering == (kind != "none")


@pytest.mark.parametrize("name", ["autzen_trim.las", "vegetation_1_3.las", "extrabytes.las", "pine_plot.laz",
                                  "fullwave.laz", "las_with_several_extra_byte_bloc.laz"])
def test_boxes_from_a_las_files_integers_are_the_boxes_of_its_positions(name):
    """encoding.cell_boxes scales each batch's least and most integers as the loader
    scales coordinates: exactly the float32 boxes that boxes_of finds over the positions
    of real files, batch by batch (loader batches cut store batches anywhere); so are
    scene.part_boxes of a part of a batch, with its parser's runs or without them."""
    from conftest import SAMPLE, shared_file
    from progressive import encoding
    from progressive.loaders import CloudLoader
    from progressive.scene import part_boxes

    with CloudLoader([SAMPLE if name == "autzen_trim.las" else shared_file(name)], batch_points=37_001,
                     on_parsed=encoding.with_runs) as loader:
        origin = loader.info.origin
        for b in loader:
            at, least, most = encoding.cell_range(b.grid, b.start)
            boxes = encoding.cell_boxes(least, most, b.grid.scale, b.grid.offset, origin)
            first, expected = batches.boxes_of(b.positions, b.start)
            assert at == first
            np.testing.assert_array_equal(boxes, expected)
            for part in (b, b.rows(3, b.count - 5)):
                assert b.xyz is None and (part.grid.runs is not None) == (part is b)
                got, want = part_boxes(part), batches.boxes_of(part.positions, part.start)
                assert got[0] == want[0]
                np.testing.assert_array_equal(got[1], want[1])


def test_boxes_from_integers_with_a_negative_scale_or_out_of_float32_reach():
    """A negative scale turns least and most around; a bound that float32 cannot hold
    gives None (frame_parts then takes the boxes of the positions)."""
    from progressive import encoding

    least, most = np.array([[-5, 0, 10]]), np.array([[7, 3, 10]])
    boxes = encoding.cell_boxes(least, most, (-0.5, 0.01, 1.0), (100.0, 0.0, 0.0), np.zeros(3))
    lo, hi = np.float32([96.5, 0.0, 10.0]), np.float32([102.5, 0.03, 10.0])
    np.testing.assert_array_equal(boxes[0, 0:3], lo)
    np.testing.assert_array_equal(boxes[0, 4:7], hi)
    assert encoding.cell_boxes(least, most, (1e38, 1.0, 1.0), (0.0, 0.0, 0.0), np.zeros(3)) is None


def test_cell_runs_of_rows_are_those_of_their_cells():
    """Runs.rows keeps the runs of rows that end at the batch's ends or at runs'
    ends, equal to cell_runs of those rows' cells; rows that cut a run short get None."""
    from progressive.loaders.types import cell_runs

    rng = np.random.default_rng(7)
    points, start = 1_000, 12_345
    cells = rng.integers(-2**30, 2**30, size=(7_777, 3)).astype(np.int32)
    runs = cell_runs(cells, start, points)
    n = cells.shape[0]
    ends = sorted({0, n, *(np.arange(-(-start // points) * points, start + n, points) - start).tolist()})
    for lo in ends:
        for hi in ends:
            if hi <= lo:
                continue
            part, expected = runs.rows(lo, hi), cell_runs(cells[lo:hi], start + lo, points)
            assert part is not None and part.first == expected.first
            assert part.of(start + lo, hi - lo, points) and not part.of(start + lo + 1, hi - lo, points)
            np.testing.assert_array_equal(part.least, expected.least)
            np.testing.assert_array_equal(part.most, expected.most)
    assert runs.rows(1, n) is None and runs.rows(0, n - 1) is None
    assert runs.rows(ends[1], ends[2] + 1) is None


def test_runs_moved_to_a_runs_start_are_those_found_there():
    """Runs.moved: a streamed node's runs, found as if it began at 0, equal cell_runs of
    its cells where it is written (a run's start); from or to another start, None."""
    from progressive.loaders.types import cell_runs

    rng = np.random.default_rng(8)
    points = 1_000
    cells = rng.integers(-2**30, 2**30, size=(2_345, 3)).astype(np.int32)
    found = cell_runs(cells, 0, points)
    for at in (0, 7 * points):
        moved, expected = found.moved(at), cell_runs(cells, at, points)
        assert moved.of(at, cells.shape[0], points) and moved.first == expected.first
        np.testing.assert_array_equal(moved.least, expected.least)
        np.testing.assert_array_equal(moved.most, expected.most)
    assert found.moved(points + 1) is None and cell_runs(cells, 5, points).moved(0) is None


def test_runs_found_by_the_parsers_frame_the_store_as_the_frame_loop_did(gl, monkeypatch):
    """A loader whose parser threads find each batch's runs (the session's on_parsed,
    encoding.with_runs) gives the word store the same frames, least integers,
    shifts, boxes and words as batches framed from their cells by the frame loop, which
    then finds none itself (the parts the store's batches are framed from keep them)."""
    from conftest import SAMPLE
    from progressive import encoding
    from progressive.attributes import default_attribute
    from progressive.loaders import CloudLoader
    from progressive.loaders.types import cell_runs
    from progressive.scene import Scene

    stores = []
    for on_parsed in (None, encoding.with_runs):
        with CloudLoader([SAMPLE], batch_points=37_001, on_parsed=on_parsed) as loader:
            info = loader.info
            loader.start()
            loaded = sorted(loader, key=lambda b: b.start)
        assert all((b.grid.runs is not None) == (on_parsed is not None) for b in loaded)
        scene = Scene(gl, info, default_attribute(info))
        found: list = []
        monkeypatch.setattr(encoding, "cell_runs", lambda *args, found=found: found.append(args) or cell_runs(*args))
        for b in loaded:
            scene.add_batch(b)
        monkeypatch.undo()
        assert (len(found) == 0) == (on_parsed is not None)
        s = scene.store
        stores.append((s.frames.copy(), s.least_cells.copy(), s.cell_shifts.copy(), s.boxes.copy(), s.integer.copy(),
                       s.read_words()))
        scene.release()
    assert stores[1][4].all()
    for before, after in zip(*stores):
        np.testing.assert_array_equal(before, after)


def test_box_runs_of_rows_are_those_of_their_positions():
    """box_runs of a fast-format batch's positions, cut to rows, equal boxes_of of those
    rows (a run of only non-finite points stays empty); a batch whose start moved keeps
    no runs of another's rows."""
    from dataclasses import replace

    from progressive.loaders.types import Batch

    rng = np.random.default_rng(11)
    start, n = 3 * BATCH_POINTS - 777, 4 * BATCH_POINTS + 321
    xyz = rng.normal(size=(n, 3)).astype(np.float32) * 100
    xyz[:BATCH_POINTS // 2, 1] = np.nan            # the first run: every point hidden
    xyz[2 * BATCH_POINTS, 0] = np.inf
    runs = batches.box_runs(xyz, start)
    assert not np.isfinite(runs.least[0]).any()
    ends = [0, n, *(np.arange(-(-start // BATCH_POINTS) * BATCH_POINTS, start + n, BATCH_POINTS) - start).tolist()]
    for lo in ends:
        for hi in ends:
            if hi <= lo:
                continue
            part = runs.rows(lo, hi)
            first, expected = batches.boxes_of(xyz[lo:hi], start + lo)
            assert part.first == first
            np.testing.assert_array_equal(batches.boxes_from_runs(part), expected)
    records = np.zeros((n, 4), dtype=np.uint32)
    records[:, :3] = xyz.view(np.uint32)
    batch = Batch(start=start, xyz=records[:, :3].view(np.float32), records=records, boxes=runs)
    moved = replace(batch, start=start + 5)
    assert batch.rows(0, n).boxes.of(start, n, BATCH_POINTS) and not moved.boxes.of(moved.start, n, BATCH_POINTS)


def _fast_scene(gl, monkeypatch, path, on_parsed, batch_points: int, **scene_options):
    """A Scene of a fast-format file loaded with `on_parsed`, its loaded batches, and the
    calls its frame loop made to batches.boxes_of while they were added."""
    from progressive.attributes import default_attribute
    from progressive.loaders import CloudLoader
    from progressive.scene import Scene

    with CloudLoader([path], batch_points=batch_points, on_parsed=on_parsed) as loader:
        info = loader.info
        loader.start()
        loaded = sorted(loader, key=lambda b: b.start)
    scene = Scene(gl, info, default_attribute(info), **scene_options)
    found: list = []
    monkeypatch.setattr(batches, "boxes_of", lambda *args, boxes_of=batches.boxes_of: found.append(args) or boxes_of(*args))
    for b in loaded:
        scene.add_batch(b)
    monkeypatch.undo()
    return scene, loaded, found


def test_fast_format_boxes_found_by_the_parsers_frame_the_store_as_the_frame_loop_did(gl, monkeypatch, fast_sample):
    """A fast-format file loaded with its boxes found by the parser threads
    (encoding.with_runs) gives the word store the same frames, boxes and words as batches
    framed from their positions by the frame loop, which then reads no positions for
    boxes (only the cut runs of the assembler's held parts, none here: the batches end
    on store batches)."""
    from progressive import encoding

    stores = []
    for on_parsed in (None, encoding.with_runs):
        scene, loaded, found = _fast_scene(gl, monkeypatch, fast_sample, on_parsed, 3 * BATCH_POINTS)
        assert all((b.boxes is not None) == (on_parsed is not None) and b.grid is None for b in loaded)
        assert (len(found) == 0) == (on_parsed is not None)
        s = scene.store
        stores.append((s.frames.copy(), s.boxes.copy(), s.read_words()))
        scene.release()
    for before, after in zip(*stores):
        np.testing.assert_array_equal(before, after)


def test_float_record_store_takes_the_parsers_boxes(gl, monkeypatch, fast_sample):
    """The float record store's batch boxes from a fast-format file's parser-found boxes
    equal those from its positions, and the frame loop then reads no positions for them."""
    from progressive import encoding

    boxes = []
    for on_parsed in (None, encoding.with_runs):
        scene, _, found = _fast_scene(gl, monkeypatch, fast_sample, on_parsed, 2 * BATCH_POINTS + 99,
                                      position_encoding=encoding.Encoding.FLOAT)
        assert scene.store.batched and (len(found) == 0) == (on_parsed is not None)
        boxes.append(scene.store.boxes.copy())
        scene.release()
    assert np.isfinite(boxes[0]).any()
    np.testing.assert_array_equal(boxes[0], boxes[1])
