"""GPU rendering against the float64 render contract, on real files."""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from conftest import SAMPLE, shared_file
from progressive.attributes import default_attribute
from progressive.camera import Camera, auto_camera
from progressive.loaders import CloudLoader
from progressive.loaders.records import pack_records
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


def file_xyz(path):
    las = laspy.read(path)
    return np.stack([las.x, las.y, las.z], axis=1)


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
    slots = r.store.permutation.forward(np.arange(info.points)).astype(np.int64)
    for cam in cameras(info):
        frame = r.render(cam, W, H, r.style())
        gl.check()
        ref = reference_ids(xyz, cam, W, H, tie_key=slots)
        assert (ref != EMPTY).sum() > 200, "camera sees too little to test"
        assert np.mean(frame.ids == ref) >= 0.999
    r.release()


def test_chunked_store_renders_the_same(gl):
    single, info = load(gl, SAMPLE)
    chunked, _ = load(gl, SAMPLE, chunk_points=25_000)
    assert len(chunked.store.buffers) == 5
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    a = single.render(cam, W, H, single.style())
    b = chunked.render(cam, W, H, chunked.style())
    assert np.array_equal(a.ids, b.ids)
    assert np.array_equal(a.image, b.image)
    single.release()
    chunked.release()


def test_distribute_writes_permuted_records(gl):
    r, info = load(gl, SAMPLE, chunk_points=30_000)
    with CloudLoader([SAMPLE]) as loader:
        loader.start()
        batches = sorted(loader, key=lambda b: b.start)
    records = np.concatenate([pack_records(b, r.attribute, float(info.origin[2])) for b in batches])
    expected = np.full((r.store.capacity, 4), EMPTY_WORD, dtype=np.uint32)     # the layout's padding stays empty
    expected[r.store.permutation.forward(np.arange(info.points))] = records
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
    slots = r.store.permutation.forward(np.arange(40_000)).astype(np.int64)
    assert np.mean(frame.ids == reference_ids(xyz, cam, W, H, tie_key=slots)) >= 0.999
    r.release()


def test_points_baseline_agrees_with_compute(gl):
    compute, info = load(gl, SAMPLE)
    points, _ = load(gl, SAMPLE, Raster.POINTS, chunk_points=50_000)
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


@pytest.mark.parametrize("name, color_by, hide", [("lone-star.copc.laz", "intensity", False),
                                                   ("lone-star.copc.laz", "gps_time", True),
                                                   ("autzen_trim.las", "intensity", True)])
def test_a_session_colouring_by_one_attribute_reads_only_it(gl, name, color_by, hide):
    """With color_by and not switchable the loader keeps the shown attribute (and the
    class and returns where filters need them); the image and ids equal those of a
    session that reads every attribute."""
    from progressive.session import Method, Session, SessionOptions

    path = SAMPLE if name == "autzen_trim.las" else shared_file(name)
    shown = {}
    for switchable in (False, True):
        options = SessionOptions(width=W, height=H, color_by=color_by, switchable=switchable, class_filter=hide,
                                 method=Method.BRUTE)
        with Session([str(path)], options, glc=gl) as s:
            wanted = {color_by, *(("classification", "return_number", "number_of_returns") if hide else ())}
            assert (set(s.loader.attributes) <= wanted) != switchable
            s.frame(s.auto_camera(), hidden=frozenset({2}) if hide else frozenset())
            shown[switchable] = (s.ids().copy(), s.image().copy())
    assert np.array_equal(shown[False][0], shown[True][0]) and (shown[False][0] != EMPTY).any()
    assert np.array_equal(shown[False][1], shown[True][1])
