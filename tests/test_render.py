"""GPU rendering against the float64 render contract, on real files."""

from __future__ import annotations

import dataclasses
import time

import laspy
import numpy as np
import pytest

from conftest import SAMPLE, file_xyz, shared_file
from progressive import encoding
from progressive.attributes import default_attribute
from progressive.batches import BatchOrder
from progressive.camera import Camera, auto_camera
from progressive.loaders import CloudLoader
from progressive.loaders.records import pack_records
from progressive.permutation import BATCH_POINTS
from progressive.pointstore import EMPTY_WORD
from progressive.reference import EMPTY, covered_agreement, reference_ids
from progressive.renderer import Raster, Renderer

W, H = 200, 150
SMALL_REAL = ["vegetation_1_3.las", "fullwave.laz", "pine_plot.laz", "extrabytes.las"]


def real_path(name):
    return SAMPLE if name == "autzen_trim.las" else shared_file(name)


def load(gl, path, raster=Raster.COMPUTE, *, chunk_points=None, batch_points=40_000, limit=None):
    with CloudLoader([path], batch_points=batch_points) as loader:
        info = loader.info
        r = Renderer(gl, info, default_attribute(info), raster=raster, width=W, height=H, chunk_points=chunk_points)
        loader.start()
        for batch in sorted(loader, key=lambda b: b.start):
            if limit is None or batch.start < limit:
                r.add_batch(batch)
    gl.check()
    return r, info


def cameras(info):
    """The automatic view, and a close view from inside the box whose near plane cuts the cloud."""
    auto = auto_camera(info.bounds_min, info.bounds_max, W / H)
    lo, hi = info.bounds_min, info.bounds_max
    size = float(np.linalg.norm(hi - lo))
    inside = Camera(tuple((lo + (hi - lo) * [0.3, 0.2, 0.9]).tolist()), tuple(((lo + hi) / 2).tolist()),
                    fov_y_deg=75.0, near=size * 0.05, far=size * 0.6)
    return [auto, inside]


@pytest.mark.parametrize("name", ["autzen_trim.las", *SMALL_REAL])
def test_compute_matches_float64_reference(gl, name):
    path = real_path(name)
    r, info = load(gl, path)
    xyz = file_xyz(path)
    slots = r.store.slots_of(np.arange(info.points)).astype(np.int64)
    for cam in cameras(info):
        frame = r.render(cam, W, H, r.style())
        gl.check()
        ref = reference_ids(xyz, cam, W, H, tie_key=slots)
        assert (ref != EMPTY).sum() > 200, "camera sees too little to test"
        assert np.mean(frame.ids == ref) >= 0.999
    r.release()


def test_chunked_store_renders_the_same(gl):
    single, info = load(gl, SAMPLE)
    chunked, _ = load(gl, SAMPLE, chunk_points=60_000)
    assert chunked.store.chunks == 2 and len(chunked.store.buffers) == 2    # blocks of the four planes in two buffers
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    a = single.render(cam, W, H, single.style())
    b = chunked.render(cam, W, H, chunked.style())
    assert np.array_equal(a.ids, b.ids)
    assert np.array_equal(a.image, b.image)
    single.release()
    chunked.release()


def load_batches(gl, batches, info, *, chunk_points=None, batch_order=BatchOrder.FILE) -> Renderer:
    r = Renderer(gl, info, default_attribute(info), width=W, height=H, chunk_points=chunk_points,
                 batch_order=batch_order)
    for batch in batches:
        r.add_batch(batch)
    gl.check()
    return r


def sample_parts():
    with CloudLoader([SAMPLE], batch_points=40_000) as loader:
        loader.start()
        return loader.info, sorted(loader, key=lambda b: b.start)


def held_slots(r, info):
    """In the store's order (cloud indices): each point's words as the GPU holds them,
    its batch, the file-order index of the point there, and the padding's words."""
    held = r.store.read_words()
    cloud = np.arange(info.points)
    slots = r.store.permutation.forward(cloud).astype(np.int64)
    empty = np.ones(r.store.capacity, dtype=bool)
    empty[slots] = False
    return held[slots], cloud // BATCH_POINTS, r.store.file_indices(cloud).astype(np.int64), held[empty]


@pytest.mark.parametrize("order", list(BatchOrder), ids=lambda o: o.value)
def test_las_positions_on_the_gpu_are_the_files_integers(gl, order):
    """A LAS file's batches are kept as its own integers: each point's three words, read
    back from the GPU, are laspy's X, Y, Z less its batch's least, moved up the batch's
    shift (lossless); decoded, every position is within float32 rounding of the file's.
    With batches sorted by Morton code, of the point the store placed there."""
    info, batches = sample_parts()
    r = load_batches(gl, batches, info, chunk_points=60_000, batch_order=order)
    las = laspy.read(SAMPLE)
    words, batch, files, padding = held_slots(r, info)
    assert (r.store.file_order is not None) == (order is BatchOrder.MORTON)
    integers = np.stack([las.X, las.Y, las.Z], axis=1).astype(np.int64)[files]
    assert r.store.words and r.store.integer[: batch[-1] + 1].all()
    starts = np.flatnonzero(np.r_[True, np.diff(batch) > 0])
    assert np.array_equal(r.store.least_cells[: batch[-1] + 1], np.minimum.reduceat(integers, starts, axis=0))
    cells, shift = encoding.unpack_cells(words), r.store.cell_shifts[batch]
    assert np.array_equal(cells >> shift, integers - r.store.least_cells[batch])
    assert not (cells & ((1 << shift) - 1)).any()
    records = np.concatenate([pack_records(b, r.attribute, float(info.origin[2])) for b in batches])[files]
    assert np.array_equal(words[:, 3], records[:, 3])
    assert (padding == EMPTY_WORD).all()     # the layout's padding stays empty
    xyz = (file_xyz(SAMPLE) - info.origin).astype(np.float32)[files]
    frames = r.store.frames[batch]
    decoded = r.store.read_records()[r.store.permutation.forward(np.arange(info.points)).astype(np.int64), :3]
    # float32 decoding (base + q·step): float(q), the product and the sum each round once
    assert (np.abs(decoded.view(np.float32) - xyz) <= 2 * np.spacing(np.abs(frames[:, 0:3]) + np.abs(xyz))).all()
    assert r.store.buffers[0].label == "words[0]"
    r.release()


@pytest.mark.parametrize("order", list(BatchOrder), ids=lambda o: o.value)
def test_float_positions_quantize_to_their_batch_box(gl, order):
    """Positions without a file's integers (here the sample's, dropped) are 30-bit cells
    of their float32 position in the frame of their batch's box (numpy over laspy's
    coordinates), within half a cell; sorted by Morton code, the box of the points the
    store placed in the batch."""
    info, batches = sample_parts()
    r = load_batches(gl, [b.with_positions(b.positions) for b in batches], info, batch_order=order)
    words, batch, files, padding = held_slots(r, info)
    xyz = (file_xyz(SAMPLE) - info.origin).astype(np.float32)[files]
    assert not r.store.integer.any()
    starts = np.flatnonzero(np.r_[True, np.diff(batch) > 0])
    lo, hi = np.minimum.reduceat(xyz, starts, axis=0), np.maximum.reduceat(xyz, starts, axis=0)
    frames = r.store.frames[: batch[-1] + 1]
    assert np.array_equal(frames[:, 0:3], lo)
    assert np.allclose(frames[:, 4:7], (hi.astype(np.float64) - lo) / (encoding.CELLS - 1), rtol=1e-6)
    exact = (xyz.astype(np.float64) - lo[batch]) / frames[batch, 4:7]
    assert np.abs(encoding.unpack_cells(words) - exact).max() <= 0.5 + 1e-6
    assert (padding == EMPTY_WORD).all()
    r.release()


def test_float_records_hold_permuted_records(gl):
    """The float-record store (the baseline) holds each point's float32 record."""
    with CloudLoader([SAMPLE], batch_points=40_000) as loader:
        info = loader.info
        r = Renderer(gl, info, default_attribute(info), width=W, height=H, chunk_points=30_000,
                     position_encoding=encoding.Encoding.FLOAT)
        loader.start()
        batches = sorted(loader, key=lambda b: b.start)
        for b in batches:
            r.add_batch(b)
    records = np.concatenate([pack_records(b, r.attribute, float(info.origin[2])) for b in batches])
    expected = np.full((r.store.capacity, 4), EMPTY_WORD, dtype=np.uint32)     # the layout's padding stays empty
    expected[r.store.slots_of(np.arange(info.points))] = records
    assert np.array_equal(r.store.read_records(), expected)
    assert r.store.buffers[0].label == "points[0]"
    r.release()


def test_unloaded_slots_never_render(gl):
    r, info = load(gl, SAMPLE, limit=40_000)
    assert r.loaded == 40_000
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    frame = r.render(cam, W, H, r.style())
    shown = frame.ids[frame.ids != EMPTY]
    assert shown.size > 100 and shown.max() < 40_000
    xyz = file_xyz(SAMPLE)[:40_000]
    slots = r.store.slots_of(np.arange(40_000)).astype(np.int64)
    assert np.mean(frame.ids == reference_ids(xyz, cam, W, H, tie_key=slots)) >= 0.999
    r.release()


def test_points_baseline_agrees_with_compute(gl):
    compute, info = load(gl, SAMPLE)
    points, _ = load(gl, SAMPLE, Raster.POINTS, chunk_points=60_000)
    for cam in cameras(info):
        a = compute.render(cam, W, H, compute.style())
        b = points.render(cam, W, H, points.style())
        gl.check()
        assert covered_agreement(a.ids, b.ids) >= 0.99
    compute.release()
    points.release()


def test_64_and_32_bit_paths_agree(gl):
    if not gl.caps.atomic_int64:
        pytest.skip("GL_NV_shader_atomic_int64 not available (llvmpipe)")
    a64, info = load(gl, SAMPLE, Raster.COMPUTE)
    a32, _ = load(gl, SAMPLE, Raster.COMPUTE32)
    assert a64.raster.atomic64 and not a32.raster.atomic64
    for cam in cameras(info):
        assert np.array_equal(a64.render(cam, W, H, a64.style()).ids, a32.render(cam, W, H, a32.style()).ids)
    a64.release()
    a32.release()


def test_resolve_colours_rgb_from_the_file(gl):
    r, info = load(gl, SAMPLE)
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    frame = r.render(cam, W, H, r.style(background=(1, 2, 3)))
    las = laspy.read(SAMPLE)
    rgb = np.stack([las.red, las.green, las.blue], axis=1)
    rgb8 = (rgb >> 8) if rgb.max() > 255 else rgb
    hit = frame.ids != EMPTY
    assert np.array_equal(frame.image[hit][:, :3], rgb8[frame.ids[hit]].astype(np.uint8))
    assert np.all(frame.image[~hit][:, :3] == (1, 2, 3))
    r.release()


@pytest.mark.parametrize("name, color_by, hide, default", [("lone-star.copc.laz", "intensity", False, None),
                                                            ("lone-star.copc.laz", "gps_time", True, None),
                                                            ("autzen_trim.las", "intensity", True, None),
                                                            ("autzen_trim.las", None, False, "rgb"),
                                                            ("TLSSparseCloud_xyzOnly.laz", None, True, "elevation"),
                                                            ("wires.laz", None, False, "elevation")])
def test_a_session_colouring_by_one_attribute_reads_only_it(gl, name, color_by, hide, default):
    """Not switchable, the loader keeps the shown attribute (and the class and returns
    where filters need them): the one asked for, else the default, chosen before any
    batch loads (TLSSparseCloud's RGB is all zero, wires.laz has none: MANIFEST); the
    image and ids equal those of a session that reads every attribute."""
    from progressive.session import Method, Session, SessionOptions

    path = SAMPLE if name == "autzen_trim.las" else shared_file(name)
    shown = {}
    for switchable in (False, True):
        options = SessionOptions(width=W, height=H, color_by=color_by, switchable=switchable, class_filter=hide,
                                 method=Method.BRUTE)
        with Session([str(path)], options, glc=gl) as s:
            assert s.attribute.name == (color_by or default)
            wanted = {s.attribute.name, *(("classification", "return_number", "number_of_returns") if hide else ())}
            if switchable and s.loader.layered:       # the others in the later pass
                assert set(s.loader.attributes) <= wanted and s.loader.later
            else:
                assert (set(s.loader.attributes) <= wanted) != switchable and not s.loader.later
            s.frame(s.auto_camera(), hidden=frozenset({2}) if hide else frozenset())
            shown[switchable] = (s.ids().copy(), s.image().copy())
    assert np.array_equal(shown[False][0], shown[True][0]) and (shown[False][0] != EMPTY).any()
    assert np.array_equal(shown[False][1], shown[True][1])


def full_attributes(path) -> dict[str, np.ndarray]:
    with CloudLoader([path]) as loader:
        batches = sorted(loader, key=lambda b: b.start)
    return {n: np.concatenate([b.attributes[n] for b in batches]) for n in batches[0].attributes}


def assert_kept_carry_every_attribute(s, path) -> None:
    kept = sorted(s.renderer.scene.batches, key=lambda b: b.start)
    for name, values in full_attributes(path).items():
        np.testing.assert_array_equal(np.concatenate([b.attributes[name] for b in kept]), values, err_msg=name)


def frame_until_read(s, camera, limit_s: float = 60.0) -> None:
    """Frames until the later pass is in and the view converged, pausing between the
    converged ones as a window waits for events (frames in a tight loop keep the GIL
    from the parser threads)."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        s.frame(camera)
        if s.converged and not s.later:
            return
        if s.idle:
            time.sleep(0.01)


LATER = "las_with_several_extra_byte_bloc.laz"
"""A LAZ of point format 8 (layered), whose viewer sessions read the attributes not shown later."""


@pytest.mark.parametrize("name", [LATER, "fullwave.laz", "autzen_trim.las"])
def test_a_switchable_session_reads_the_other_attributes_afterwards(gl, name):
    """A switchable session (the viewer's) of a layered LAZ (point formats 6-10) loads
    the shown attribute and the filters' first, the others in a later pass that joins
    the kept batches; a switch to one of those asked before they are read waits for
    them (status says so). Either way (a LAS reads all at once) the view converges to
    the brute-force render of a session opened colouring by it, and the kept batches
    end up with every attribute a full load gives."""
    from progressive.session import Method, Session, SessionOptions

    path = real_path(name)
    options = SessionOptions(width=W, height=H, switchable=True, class_filter=True)
    with Session([str(path)], options, glc=gl) as s:
        shown = s.attribute.name
        if name == "autzen_trim.las":
            assert not s.later and s.switch_attribute("intensity") is not None
        else:
            assert "intensity" in s.later and shown not in s.later and "classification" not in s.later
            assert s.switch_attribute("intensity") is None
            assert s.waiting.name == "intensity" and s.attribute.name == shown
            status = s.status()
            assert status.later.waiting == "intensity" and status.loading
        camera = s.auto_camera()
        frame_until_read(s, camera)
        assert not s.later and s.waiting is None and s.status().later is None
        assert s.attribute.name == "intensity" and s.converged
        ids, image = s.ids().copy(), s.image().copy()
        assert s.renderer.scene.joined == (0 if name == "autzen_trim.las" else s.info.points)
        assert_kept_carry_every_attribute(s, path)
    with Session([str(path)], SessionOptions(width=W, height=H, color_by="intensity", method=Method.BRUTE),
                 glc=gl) as s:
        s.frame(camera)
        assert np.array_equal(ids, s.ids()) and (ids != EMPTY).any()
        assert np.array_equal(image, s.image())
    gl.check()


def test_a_brute_force_frame_waits_for_the_attribute_its_switch_asked_for(gl):
    """Brute force renders everything in one frame: a switch waiting for the later pass
    is begun within that frame, which equals a session opened colouring by it."""
    from progressive.session import Method, Session, SessionOptions

    brute = SessionOptions(width=W, height=H, method=Method.BRUTE)
    path = str(shared_file(LATER))
    with Session([path], dataclasses.replace(brute, switchable=True), glc=gl) as s:
        assert s.switch_attribute("gps_time") is None
        camera = s.auto_camera()
        s.frame(camera)
        assert s.attribute.name == "gps_time" and s.waiting is None
        image = s.image().copy()
    with Session([path], dataclasses.replace(brute, color_by="gps_time"), glc=gl) as s:
        s.frame(camera)
        assert np.array_equal(image, s.image())


def test_attributes_the_later_pass_left_short_cannot_be_shown(gl, monkeypatch):
    """A salvaged file whose later pass ends sooner than its first (a damaged layer only
    that pass decodes): the switch that waited is dropped, the warnings say which
    attributes, and a switch to one of them is refused in one line; the view goes on."""
    from progressive.errors import ProgressiveError
    from progressive.loaders import pipeline
    from progressive.session import Session, SessionOptions

    poll_later = pipeline.CloudLoader.poll_later
    monkeypatch.setattr(pipeline.CloudLoader, "poll_later",
                        lambda self, max_batches=None: [b for b in poll_later(self, max_batches) if b.start == 0])
    with Session([str(shared_file(LATER))], SessionOptions(width=W, height=H, switchable=True), glc=gl) as s:
        shown = s.attribute.name
        assert s.switch_attribute("intensity") is None
        camera = s.auto_camera()
        frame_until_read(s, camera)
        assert not s.later and s.waiting is None and s.attribute.name == shown and s.converged
        assert any("intensity" in w and "cannot be shown" in w for w in s.warnings)
        with pytest.raises(ProgressiveError, match="gps_time could not be read for every point"):
            s.switch_attribute("gps_time")
        s.frame(camera)
        assert s.attribute.name == shown
    gl.check()


def test_parser_threads_of_a_session_are_the_loaders_and_change_no_pixel(gl):
    """SessionOptions.parser_threads reaches the loader (default: one a core, at most
    PARSER_THREADS); the ids and the image are those of the default's."""
    from progressive.loaders.types import default_parser_threads
    from progressive.session import Method, Session, SessionOptions

    shown = []
    for threads in (None, 1):
        options = SessionOptions(width=W, height=H, method=Method.BRUTE, parser_threads=threads)
        with Session([str(SAMPLE)], options, glc=gl) as s:
            assert s.loader.parser_threads == (threads or default_parser_threads())
            s.frame(s.auto_camera())
            shown.append((s.ids().copy(), s.image().copy()))
    assert np.array_equal(shown[0][0], shown[1][0]) and np.array_equal(shown[0][1], shown[1][1])


def test_a_switch_to_an_attribute_not_read_when_loading_stopped_is_refused(gl):
    """A viewer stops loading when a file fails: the attributes of the later pass never
    come, so a switch waiting for one is dropped and a new one is refused in one line."""
    from progressive.errors import ProgressiveError
    from progressive.session import Session, SessionOptions

    with Session([str(shared_file(LATER))], SessionOptions(width=W, height=H, switchable=True), glc=gl) as s:
        assert s.switch_attribute("intensity") is None
        s.stop_loading()
        assert s.waiting is None and not s.status().loading
        with pytest.raises(ProgressiveError, match="intensity was not read: loading stopped"):
            s.switch_attribute("intensity")
        s.frame(s.auto_camera())
    gl.check()


def test_attributes_read_afterwards_join_kept_batches_that_start_elsewhere(gl, sample_batches):
    """The later pass's batches need not line up with the kept ones: rows of parts that
    straddle kept batches are gathered until each kept batch has all of its rows."""
    from progressive.scene import Scene

    info, batches = sample_batches
    first = ("intensity",)
    scene = Scene(gl, info, next(a for a in info.attributes if a.name == "intensity"), keep_batches=True)
    try:
        for b in batches:
            scene.add_batch(dataclasses.replace(b, attributes={n: b.attributes[n] for n in first}))
        assert scene.joined == 0
        total = sum(b.count for b in batches)
        edges = [0, 7_000, 45_000, 45_001, 90_000, total]
        whole = {n: np.concatenate([b.attributes[n] for b in batches]) for n in batches[0].attributes}
        positions = np.concatenate([b.positions for b in batches])
        for lo, hi in zip(edges, edges[1:]):
            part = dataclasses.replace(batches[0], start=lo, xyz=positions[lo:hi],
                                       attributes={n: v[lo:hi] for n, v in whole.items() if n not in first},
                                       nonfinite_values={}, grid=None, bounds=None)
            scene.add_attributes(part)
            covered = sum(b.count for b in batches if b.start + b.count <= hi)
            assert scene.joined == covered
        for name, values in whole.items():
            np.testing.assert_array_equal(np.concatenate([b.attributes[name] for b in scene.batches]), values,
                                          err_msg=name)
    finally:
        scene.release()
    gl.check()


@pytest.mark.parametrize("color_by", [None, "intensity"])
def test_a_session_holds_its_loader_until_the_first_frame(gl, color_by):
    """Opening a session parses FIRST_HELD batches and no more until its first frame is
    issued (the renderer is built with the GIL to itself); then the rest loads and the
    still view converges to the brute-force render."""
    from progressive.session import FIRST_HELD, Method, Session, SessionOptions

    progressive = SessionOptions(width=W, height=H, color_by=color_by)
    with Session([str(SAMPLE)], progressive, glc=gl) as s:
        assert s.loader.total > FIRST_HELD * 100_000     # more batches than are held
        deadline = time.monotonic() + 0.5
        while time.monotonic() < deadline:
            for b in s.loader.poll():   # what the first frame would take
                s.renderer.add_batch(b)
            time.sleep(0.01)
        assert 0 < s.loader.loaded <= FIRST_HELD * 100_000 and not s.loader.done
        camera = s.auto_camera()
        for _ in range(200):
            s.frame(camera)
            if s.converged:
                break
        assert s.converged and s.renderer.scene.loaded == s.loader.total
        ids = s.ids().copy()
    with Session([str(SAMPLE)], dataclasses.replace(progressive, method=Method.BRUTE), glc=gl) as s:
        s.frame(camera)
        assert np.array_equal(ids, s.ids())
