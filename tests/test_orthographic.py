"""Orthographic and plan views: ids of every rasterizer against the float64 render
contract on real files, a plan view with Z up shows north up, progressive frames
converge, culling keeps every visible point, and the camera JSON round-trips."""

from __future__ import annotations

import json

import laspy
import numpy as np
import pytest

from conftest import SAMPLE, shared_file
from progressive.budget import BudgetParams
from progressive.camera import Camera, CameraError, Projection
from progressive.frame_loop import ProgressiveOptions, ProgressiveRenderer
from progressive.loaders import CloudLoader
from progressive.passes.raster_compute import ComputeRaster
from progressive.reference import EMPTY, reference_ids
from progressive.renderer import Raster, Renderer

W, H = 160, 120


def loaded(gl, path, raster=Raster.COMPUTE):
    with CloudLoader([path]) as loader:
        info = loader.info
        r = Renderer(gl, info, info.attributes[0], raster=raster, width=W, height=H)
        loader.start()
        for batch in loader:
            r.add_batch(batch)
    return r, info


def ortho_cameras(info) -> dict[str, Camera]:
    lo, hi = info.bounds_min, info.bounds_max
    centre, size = (lo + hi) / 2, hi - lo
    span = float(max(size[0], size[1]))
    above = centre + [0, 0, 2 * span]
    return {
        "plan": Camera(tuple(above), tuple(centre), (0, 0, 1), near=0.1 * span, far=4 * span,
                       projection=Projection.ORTHOGRAPHIC, height=span),
        "oblique": Camera(tuple(centre + [-span, -0.71 * span, 0.93 * span]), tuple(centre), near=0.1 * span, far=5 * span,
                          projection=Projection.ORTHOGRAPHIC, height=0.5 * span),
        "slab": Camera(tuple(centre + [0, -2 * span, 0]), tuple(centre), near=1.9 * span, far=2.1 * span,
                       projection=Projection.ORTHOGRAPHIC, height=size[2] * 1.2 + 1e-3),
    }


def xyz_of(path) -> np.ndarray:
    las = laspy.read(path)
    return np.stack([las.x, las.y, las.z], axis=1)


@pytest.mark.parametrize("raster", [Raster.COMPUTE, Raster.POINTS])
@pytest.mark.parametrize("name", ["autzen_trim.las", "vegetation_1_3.las", "pine_plot.laz"])
def test_orthographic_ids_equal_the_float64_reference(gl, raster, name):
    path = SAMPLE if name == "autzen_trim.las" else shared_file(name)
    r, info = loaded(gl, path, raster)
    try:
        xyz = xyz_of(path)
        slots = r.store.slots_of(np.arange(info.points)).astype(np.int64)
        for cam in ortho_cameras(info).values():
            ids = r.render(cam, W, H, r.style()).ids
            ref = reference_ids(xyz, cam, W, H, tie_key=slots)
            assert (ref != EMPTY).sum() > 200, "camera sees too little to test"
            assert np.mean(ids == ref) >= 0.999
        assert gl.ctx.error == "GL_NO_ERROR"
    finally:
        r.release()


def test_plan_view_with_z_up_shows_north_up(gl):
    """Up parallel to the view gives way to +Y: larger y is higher in the image."""
    r, info = loaded(gl, SAMPLE)
    try:
        ids = r.render(ortho_cameras(info)["plan"], W, H, r.style()).ids
        y = xyz_of(SAMPLE)[:, 1]
        rows = np.nonzero(ids != EMPTY)[0]
        ys = y[ids[ids != EMPTY]]
        assert np.corrcoef(rows, ys)[0, 1] < -0.9           # row 0 is the top
    finally:
        r.release()


def test_progressive_orthographic_converges_and_culling_keeps_points(gl):
    r, info = loaded(gl, SAMPLE)
    pr = ProgressiveRenderer(gl, info, r.attribute, ProgressiveOptions(W, H, budget=BudgetParams(fixed=30_000)),
                             scene=r.scene)
    try:
        for cam in ortho_cameras(info).values():
            expected = r.render(cam, W, H, r.style()).ids
            for _ in range(r.store.capacity // 30_000 + 3):
                pr.frame(cam, r.scene.style())
            pr.flush()
            assert pr.converged and np.array_equal(pr.read_ids(), expected)
            plain = ComputeRaster(gl, r.store, r.vis, atomic64=r.raster.atomic64)
            culling, r.raster = r.raster, plain
            assert np.array_equal(r.render(cam, W, H, r.style()).ids, expected)
            r.raster, _ = culling, plain.release()
    finally:
        pr.release()
        r.release()


def test_camera_json_round_trips_and_rejects():
    cam = Camera((1.0, 2.0, 30.0), (1.0, 2.0, 0.0), projection=Projection.ORTHOGRAPHIC, height=12.5)
    data = cam.to_dict()
    assert data["projection"] == "orthographic" and data["height"] == 12.5
    assert Camera.from_json(json.dumps(data)) == cam
    perspective = Camera((1.0, 2.0, 30.0), (1.0, 2.0, 0.0))
    assert "projection" not in perspective.to_dict() and Camera.from_dict(perspective.to_dict()) == perspective
    for bad in ({"projection": "orthographic"}, {"height": 3.0}, {"projection": "fisheye"},
                {"projection": "orthographic", "height": -1.0}, {"projection": 1}):
        with pytest.raises(CameraError):
            Camera.from_dict({"position": [0, 0, 1], "target": [0, 0, 0], **bad})
