"""Progressive rendering on a real cloud: exact convergence, reprojection under
motion, rendering while loading, and a frame loop that never waits for the GPU."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import RECORDS, SAMPLE
from progressive.attributes import default_attribute
from progressive.budget import BudgetParams
from progressive.camera import Camera, auto_camera
from progressive.frame_loop import COLD_TIMES, ProgressiveOptions, ProgressiveRenderer
from progressive.passes.raster_compute import DEFAULT_TUNING, ComputeTuning
from progressive.permutation import LAYOUT, Permutation
from progressive.reference import EMPTY
from progressive.renderer import Raster, Renderer

W, H = 200, 150
B = 12_000


@pytest.fixture(scope="module")
def cloud(sample_batches):
    return sample_batches


@pytest.fixture(scope="module")
def brute(gl, cloud):
    info, batches = cloud
    r = Renderer(gl, info, default_attribute(info), width=W, height=H)
    for b in batches:
        r.add_batch(b)
    yield lambda cam: r.render(cam, W, H, r.style()).ids
    r.release()


def make(gl, cloud, *, budget=BudgetParams(fixed=B), batches_per_frame=100, reference=False, load=True,
         tuning=DEFAULT_TUNING, prepare_ballot=None):
    info, batches = cloud
    pr = ProgressiveRenderer(gl, info, default_attribute(info),
                             ProgressiveOptions(W, H, budget=budget, batches_per_frame=batches_per_frame, reference=reference,
                                                tuning=tuning, prepare_ballot=prepare_ballot))
    if load:
        for b in batches:
            pr.add_batch(b)
    return pr


def orbit(cam: Camera, degrees: float) -> Camera:
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    rel = np.subtract(cam.position, cam.target)
    rotated = np.array([c * rel[0] - s * rel[1], s * rel[0] + c * rel[1], rel[2]]) + cam.target
    return Camera(tuple(rotated.tolist()), cam.target, cam.up, cam.fov_y_deg, cam.near, cam.far)


def frames_until_equal(gl, pr, cam, style, expected, limit):
    for k in range(1, limit + 1):
        pr.frame(cam, style)
        gl.check()
        if np.array_equal(pr.read_ids(), expected):
            return k
    return None


def test_still_camera_converges_exactly_when_every_point_was_filled(gl, cloud, brute):
    info, _ = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    expected = brute(cam)
    pr = make(gl, cloud)
    need = math.ceil(info.points / B)
    k = frames_until_equal(gl, pr, cam, pr.scene.style(), expected, need + 1)
    assert k is not None, "did not converge"
    assert k >= need, f"equal at frame {k}, before every point could be filled ({need})"
    pr.release()


@RECORDS
def test_converges_while_loading(gl, cloud, brute, winners):
    info, batches = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    pr = make(gl, cloud, batches_per_frame=1, tuning=ComputeTuning(winners=winners))
    style = pr.scene.style()
    first = pr.frame(cam, style)
    assert "distribute" in first and pr.scene.loaded == batches[0].count
    shown = pr.read_ids()
    assert (shown != EMPTY).any() and shown[shown != EMPTY].max() < batches[0].count
    limit = len(batches) + math.ceil(info.points / B) + 1
    k = frames_until_equal(gl, pr, cam, style, brute(cam), limit)
    assert k is not None and pr.scene.complete
    pr.release()


@RECORDS
def test_motion_keeps_most_of_the_image_and_converges_again(gl, cloud, brute, winners):
    info, _ = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    pr = make(gl, cloud, tuning=ComputeTuning(winners=winners))
    style = pr.scene.style()
    need = math.ceil(info.points / B)
    assert frames_until_equal(gl, pr, cam, style, brute(cam), need + 1)
    moved = orbit(cam, 3.0)
    expected = brute(moved)
    passes = pr.frame(moved, style)
    assert "reproject" in passes
    covered = np.count_nonzero(pr.read_ids() != EMPTY)
    assert covered >= 0.8 * np.count_nonzero(expected != EMPTY)
    assert frames_until_equal(gl, pr, moved, style, expected, need + 1)
    pr.release()


def test_only_needed_passes_run(gl, cloud):
    info, _ = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    slots = Permutation.for_count(info.points, order=LAYOUT).slots     # the layout's padding is filled too
    pr = make(gl, cloud, budget=BudgetParams(fixed=slots // 2 + 1), batches_per_frame=100)
    style = pr.scene.style()
    first = pr.frame(cam, style)
    assert "reproject" not in first and "distribute" in first and "fill" in first
    second = pr.frame(cam, style)
    assert "distribute" not in second and "reproject" in second and "fill" in second
    pr.flush()
    assert pr.converged
    assert pr.frame(cam, style) == ()
    assert pr.frame(cam, pr.scene.style(background=(9, 9, 9))) == ("resolve",)
    assert "fill" in pr.frame(orbit(cam, 1.0), style)
    pr.release()


def test_frames_rest_while_loading_once_what_has_loaded_is_drawn(gl, cloud, brute):
    """While a cloud loads, a frame whose points are all drawn (the GPU said so) and that
    has no batch to distribute runs no pass, its image the brute-force render of the
    points loaded; the next batch sets frames going again, and the whole cloud converges
    to its own brute-force render."""
    info, batches = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    slots = Permutation.for_count(info.points, order=LAYOUT).slots
    pr = make(gl, cloud, budget=BudgetParams(fixed=slots), load=False)
    style = pr.scene.style()
    pr.add_batch(batches[0])
    assert "fill" in pr.frame(cam, style) and not pr.resting
    pr.flush()
    assert pr.resting and not pr.converged and not pr.scene.complete
    assert pr.frame(cam, style) == ()
    first = Renderer(gl, info, default_attribute(info), width=W, height=H)
    first.add_batch(batches[0])
    assert np.array_equal(pr.read_ids(), first.render(cam, W, H, first.style()).ids)
    first.release()
    for b in batches[1:]:
        pr.add_batch(b)
    assert "distribute" in pr.frame(cam, style) and not pr.resting
    pr.flush()
    assert pr.converged
    assert np.array_equal(pr.read_ids(), brute(cam))
    pr.release()


def test_history_keeps_the_last_frames_in_frame_order(gl, cloud):
    """Frames with fill are recorded when the GPU reports them, idle ones as issued: the
    history holds the last history_frames of them by frame number."""
    info, batches = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    pr = ProgressiveRenderer(gl, info, default_attribute(info),
                             ProgressiveOptions(W, H, budget=BudgetParams(fixed=B), batches_per_frame=100,
                                                history_frames=6))
    for b in batches:
        pr.add_batch(b)
    style = pr.scene.style()
    for k in range(9):
        pr.frame(orbit(cam, k), style)
    assert [s.frame for s in pr.flush()] == list(range(3, 9))
    while not pr.converged:
        pr.frame(cam, style)
        pr.flush()
    for _ in range(4):
        assert pr.frame(cam, style) == ()
    frames = [s.frame for s in pr.flush()]
    assert frames == list(range(pr.frame_index - 6, pr.frame_index))
    assert [s.passes for s in pr.history[-4:]] == [()] * 4
    pr.release()


def test_frame_loop_never_waits_for_the_gpu(gl, cloud, monkeypatch):
    """A GPU that never finishes: frames still go on, read nothing and never sync."""
    import moderngl

    info, _ = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    pr = make(gl, cloud, budget=BudgetParams(), batches_per_frame=1)
    reads = []
    monkeypatch.setattr(moderngl.Buffer, "read", lambda self, *a, **k: reads.append(self.label))
    monkeypatch.setattr(type(gl.ctx), "finish", lambda self: pytest.fail("finish() in the frame loop"))
    monkeypatch.setattr(type(gl.gl), "signaled", lambda self, sync: False)
    for k in range(12):
        pr.frame(orbit(cam, k), pr.scene.style())
    assert reads == []
    assert pr.stats_ring.dropped > 0, "stats are dropped rather than waited for"
    monkeypatch.undo()
    pr.release()


def test_adaptive_budget_fills_beyond_the_first_fill(gl, cloud):
    info, _ = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    params = BudgetParams(target_ns=200_000_000, first_fill=2000)
    pr = make(gl, cloud, budget=params)
    style = pr.scene.style()
    for _ in range(4):
        pr.frame(cam, style)
    stats = [s for s in pr.flush() if s.gpu_ms]
    assert all(s.first_fill == 2000 for s in stats)
    assert max(s.budget for s in stats) > 2000
    assert all(s.gpu_ms["frame"] > 0 and s.gpu_ms["fill"] > 0 for s in stats)
    pr.release()


def test_a_cold_frame_times_its_stages_and_every_frame_its_passes(gl, cloud):
    """The first frame knows no rate: its first pass's parts (first fill, adaptive part,
    both growth stages) are timed and add up to that pass, and with the later passes to
    the fill; frames after it time only their two parts of the fill."""
    info, _ = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    pr = make(gl, cloud, budget=BudgetParams(target_ns=200_000_000, first_fill=2000))
    style = pr.scene.style()
    for k in range(3):
        pr.frame(orbit(cam, k), style)
    stats = [s for s in pr.flush() if s.gpu_ms]
    assert [set(COLD_TIMES) <= set(s.gpu_ms) for s in stats] == [True] + [False] * (len(stats) - 1)
    for s in stats:
        ms = s.gpu_ms
        assert ms["fill first pass"] > 0 and ms["fill later passes"] >= 0
        assert ms["fill first pass"] + ms["fill later passes"] == pytest.approx(ms["fill"], abs=1e-6)
    cold = stats[0].gpu_ms
    assert all(cold[k] >= 0 for k in COLD_TIMES)
    assert sum(cold[k] for k in COLD_TIMES) == pytest.approx(cold["fill first pass"], abs=1e-6)
    pr.release()


def test_gpu_equal_fraction_matches_cpu(gl, cloud, brute):
    info, _ = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    pr = make(gl, cloud, reference=True)
    style = pr.scene.style()
    expected = brute(cam)
    fractions = []
    for _ in range(3):
        pr.frame(cam, style)
        fractions.append(float(np.mean(pr.read_ids() == expected)))
    stats = pr.flush()
    assert [s.equal_fraction for s in stats[:3]] == pytest.approx(fractions)
    pr.release()


@pytest.mark.parametrize("ballot", [True, False], ids=["ballot", "barriers"])
@pytest.mark.parametrize("winners", [True, False], ids=["winners pass", "hints"])
def test_reprojection_list_holds_record_copies_and_avoids_gathers(gl, cloud, winners, ballot):
    """Prepare copies visible records into the list (read sequentially by reprojection)
    and each covered pixel's attribute word into the pixel words, whether a subgroup's
    pixels take their entries by ballot or a work group's after a barrier. With the
    winners pass, every record comes from it: none is gathered from the store. With
    hints, the first frame gathers every record and, with a still camera, winners that
    were reprojected come from the list, not the store."""
    if ballot and not gl.caps.shader_ballot:
        pytest.skip("no GL_ARB_shader_ballot")
    info, _ = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    pr = make(gl, cloud, budget=BudgetParams(fixed=2000), tuning=ComputeTuning(winners=winners), prepare_ballot=ballot)
    assert (pr.raster.winners is not None) == winners and pr.prepare.ballot == ballot
    style = pr.scene.style()
    for _ in range(6):
        pr.frame(cam, style)
    slots, records = pr.prepare.previous.read()
    shown = pr.read_slots()
    assert slots.size == np.count_nonzero(shown != EMPTY)
    assert np.array_equal(np.sort(slots), np.sort(shown[shown != EMPTY]))
    store = pr.store.read_records()
    assert np.array_equal(records, store[slots])
    words = np.frombuffer(pr.prepare.pixel_words.read(), dtype=np.uint32).reshape(shown.shape)
    assert np.array_equal(words[shown != EMPTY], store[shown[shown != EMPTY], 3])
    stats = [s for s in pr.flush() if s.gpu_ms]
    if winners:
        assert [s.gathered for s in stats] == [0] * len(stats) and stats[0].covered_pixels > 0
        pr.release()
        return
    assert stats[0].gathered == stats[0].covered_pixels, "first frame: every record comes from the store"
    later = stats[-1]
    assert later.gathered < 0.2 * later.covered_pixels, (later.gathered, later.covered_pixels)
    pr.release()


def test_winners_follow_a_resize(gl, cloud):
    """The winners pass's records are per pixel: after the frame grows and shrinks, the
    pass writes every visible record at the new size (none gathered) and the image
    converges to brute force at that size."""
    info, batches = cloud
    pr = make(gl, cloud, tuning=ComputeTuning(winners=True))
    r = Renderer(gl, info, default_attribute(info), width=W, height=H)
    for b in batches:
        r.add_batch(b)
    style = pr.scene.style()
    for width, height in ((W, H), (W + 37, H + 11), (W // 2, H // 3)):
        pr.resize(width, height)
        cam = auto_camera(info.bounds_min, info.bounds_max, width / height)
        expected = r.render(cam, width, height, r.style()).ids
        assert frames_until_equal(gl, pr, cam, style, expected, math.ceil(info.points / B) + 1) is not None
        assert pr.raster.winners.pixels == width * height
    stats = [s for s in pr.flush() if s.gpu_ms]
    assert stats and all(s.gathered == 0 for s in stats)
    r.release()
    pr.release()


def test_eight_chunk_store_converges(gl, cloud, brute):
    """The largest store (8 buffers: four word planes of two) must fit every pass within
    16 storage blocks."""
    info, batches = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    pr = ProgressiveRenderer(gl, info, default_attribute(info),
                             ProgressiveOptions(W, H, budget=BudgetParams(fixed=B), batches_per_frame=100,
                                                chunk_points=-(-Permutation.for_count(info.points, order=LAYOUT).slots // 2)))
    assert len(pr.store.buffers) == 2 and pr.store.chunks == 2
    for b in batches:
        pr.add_batch(b)
    assert frames_until_equal(gl, pr, cam, pr.scene.style(), brute(cam), math.ceil(pr.store.capacity / B) + 1)
    pr.release()


def test_points_baseline_progressive_converges(gl, cloud, brute):
    """The GL_POINTS baseline renders progressive frames too (vertex pulling, indirect draws)."""
    from progressive.renderer import Raster

    info, batches = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    pr = ProgressiveRenderer(gl, info, default_attribute(info),
                             ProgressiveOptions(W, H, Raster.POINTS, BudgetParams(fixed=B), batches_per_frame=100))
    for b in batches:
        pr.add_batch(b)
    style = pr.scene.style()
    expected = brute(cam)
    pr.frame(cam, style)
    first = pr.read_ids()
    assert (first != EMPTY).sum() > 100 and np.mean(first == expected) < 1.0
    for _ in range(math.ceil(info.points / B)):
        pr.frame(cam, style)
    covered = (pr.read_ids() != EMPTY) | (expected != EMPTY)
    assert np.mean(pr.read_ids()[covered] == expected[covered]) >= 0.99
    assert "reproject" in pr.frame(orbit(cam, 2.0), style)
    gl.check()
    pr.release()


def test_file_fill_order_stores_file_order_and_converges(gl, cloud):
    """FillOrder.FILE (the paper's unshuffled baseline): slot = file index, and the first
    fill is the first points of the file; frames still converge to brute force."""
    from progressive.permutation import FillOrder
    from progressive.scene import Scene

    info, batches = cloud
    scene = Scene(gl, info, default_attribute(info), order=FillOrder.FILE)
    for b in batches:
        scene.add_batch(b)
    assert np.array_equal(scene.store.read_records()[:, :3].view(np.float32)[:1000],
                          np.concatenate([b.positions for b in batches])[:1000])
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    r = Renderer(gl, info, scene.attribute, width=W, height=H, scene=scene)
    expected = r.render(cam, W, H, r.style()).ids
    pr = ProgressiveRenderer(gl, info, scene.attribute, ProgressiveOptions(W, H, budget=BudgetParams(fixed=B)), scene=scene)
    pr.frame(cam, scene.style())
    shown = pr.read_ids()
    assert shown[shown != EMPTY].max() < B
    assert frames_until_equal(gl, pr, cam, scene.style(), expected, math.ceil(info.points / B) + 1) is not None
    for obj in (pr, r, scene):
        obj.release()


@RECORDS
@pytest.mark.parametrize("room", ["enough", "too little"])
def test_the_32_bit_index_pass_over_candidates_keeps_every_frames_ids(gl, cloud, brute, monkeypatch, winners, room):
    """Frames drawn with the 32-bit index pass over the depth pass's candidates (batches
    arriving, the reprojection list's hints, fill pieces, improved batches for the
    winners pass, motion) have the ids of frames drawn with the index pass over every
    point; with too little room a frame that may have more candidates walks its points
    too, with the same ids; both converge to brute force."""
    from progressive.passes.raster_compute import ComputeRaster

    info, batches = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    path = [cam] * 3 + [orbit(cam, 2.0 * k) for k in range(1, 4)] + [orbit(cam, 6.0)] * (math.ceil(info.points / B) + 1)
    runs = {}
    for candidates in (False, True):
        with monkeypatch.context() as m:
            if room == "too little":
                m.setattr(ComputeRaster, "candidate_capacity", lambda self, pixels: 50)
            pr = ProgressiveRenderer(gl, info, default_attribute(info), ProgressiveOptions(
                W, H, raster=Raster.COMPUTE32, budget=BudgetParams(fixed=B), batches_per_frame=2,
                tuning=ComputeTuning(winners=winners, candidates=candidates)))
            assert pr.raster.candidates == candidates
            style = pr.scene.style()
            pending = list(batches)
            runs[candidates] = []
            for camera in path:
                for _ in range(2):
                    if pending:
                        pr.add_batch(pending.pop(0))
                pr.frame(camera, style)
                runs[candidates].append(pr.read_ids())
            gl.check()
            pr.release()
    assert not pending
    assert all(np.array_equal(a, b) for a, b in zip(runs[True], runs[False]))
    assert np.array_equal(runs[True][-1], brute(orbit(cam, 6.0)))


@pytest.mark.parametrize("view", ["overview", "corner"])
def test_fill_pieces_walk_batches_frame_for_frame(gl, cloud, brute, view):
    """Fill pieces walked by one work group a batch (culled batches skipped whole), with
    one word a load or four, and records from the winners pass or gathered after hints,
    give every frame the ids of one invocation a slot (and, on the 32-bit path, an index
    pass over every point, not over the depth pass's candidates), and converge to brute force."""
    from progressive.batches import in_view as batches_in_view
    from progressive.camera import view_uniforms

    info, batches = cloud
    lo, hi = info.bounds_min, info.bounds_max
    cam = auto_camera(lo, hi, W / H) if view == "overview" else Camera(
        position=tuple(lo + (hi - lo) * [0.15, 0.15, 0.0] + [0, 0, 0.4 * (hi - lo)[0]]),
        target=tuple(lo + (hi - lo) * [0.15, 0.15, 0.0]), up=(0, 1, 0), near=1.0, far=1e4)
    runs = {}
    for tuning in (ComputeTuning(vector_loads=True), ComputeTuning(vector_loads=False), ComputeTuning(winners=False),
                   ComputeTuning(batch_groups=False, candidates=False)):
        pr = ProgressiveRenderer(gl, info, default_attribute(info), ProgressiveOptions(
            W, H, budget=BudgetParams(fixed=B), batches_per_frame=100, tuning=tuning))
        for b in batches:
            pr.add_batch(b)
        assert pr.raster.batch_groups == tuning.batch_groups
        vector = pr.raster.atomic64 if tuning.vector_loads is None else tuning.vector_loads
        assert pr.raster.vector_loads == bool(vector and tuning.batch_groups and pr.store.words)
        style = pr.scene.style()
        runs[tuning] = []
        for _ in range(math.ceil(info.points / B) + 1):
            pr.frame(cam, style)
            runs[tuning].append(pr.read_ids())
        shown = batches_in_view(pr.store.boxes, view_uniforms(cam, info.origin, W, H))
        assert shown.any() and (shown.all() == (view == "overview"))
        gl.check()
        pr.release()
    reference = runs.pop(ComputeTuning(batch_groups=False, candidates=False))
    for frames in runs.values():
        assert all(np.array_equal(a, b) for a, b in zip(frames, reference))
    assert not np.array_equal(reference[0], reference[-1])
    assert np.array_equal(reference[-1], brute(cam))


@RECORDS
def test_batches_written_into_a_still_view_are_drawn_whole(gl, brute, winners):
    """A streamed store (progressive/streaming.py) whose nodes arrive while the camera
    holds still: batches written into empty ones are drawn whole in the next frame and
    the fill goes on, so a view whose fill had gone round is exact in that frame. Told
    nothing of which batches (as before), the fill starts again and its image is exact
    only frames later. Both converge to brute force. Frames count until the image read
    back is exact: the converged flag comes frames late where the GPU runs ahead (the
    H200 told it a frame later than llvmpipe)."""
    from progressive.loaders import CloudLoader
    from progressive.permutation import BATCH_POINTS
    from progressive.scene import Scene

    with CloudLoader([SAMPLE], batch_points=BATCH_POINTS) as loader:
        info = loader.info
        loader.start()
        parts = sorted(loader, key=lambda b: b.start)
    assert [p.start for p in parts] == [b * BATCH_POINTS for b in range(len(parts))]
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    expected = brute(cam)
    half = len(parts) // 2
    frames = {}
    for told in (True, False):
        scene = Scene(gl, info, default_attribute(info), streamed=True)
        pr = ProgressiveRenderer(gl, info, scene.attribute, ProgressiveOptions(
            W, H, budget=BudgetParams(fixed=B), tuning=ComputeTuning(winners=winners)), scene=scene)
        style = pr.scene.style()
        try:
            for b in range(half):
                scene.write_store_batches(parts[b], b)
            pr.nodes_changed(False, range(half))
            scene.settled = True            # what the streamer says once nothing more is on its way
            converge(pr, cam, style)
            for b in range(half, len(parts)):
                scene.write_store_batches(parts[b], b)
            pr.nodes_changed(False, range(half, len(parts)) if told else ())
            frames[told] = frames_until_equal(gl, pr, cam, style, expected, 200)
            converge(pr, cam, style)
            gl.check()
            assert np.array_equal(pr.read_ids(), expected)
        finally:
            pr.release()
            scene.release()
    assert frames[True] == 1 and frames[False] is not None and frames[False] > 2, frames


def converge(pr: ProgressiveRenderer, cam: Camera, style, limit: int = 200) -> int:
    """Frames until the still view is exact."""
    for k in range(1, limit + 1):
        pr.frame(cam, style)
        if pr.converged:
            return k
    raise AssertionError("did not converge")
