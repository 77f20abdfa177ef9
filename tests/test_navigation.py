"""Viewer navigation, GPU-free, checked through the float64 render contract
(camera.project): what a gesture promises about the pixels is what happens."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from progressive.camera import Camera, project
from progressive.viewer.navigation import Navigator, Orbit

W, H = 640, 480
UTM = np.array([512_345.678, 5_403_210.987, 120.0])


@pytest.fixture(params=[np.zeros(3), UTM], ids=["local", "utm"])
def nav(request):
    lo = request.param + np.array([-50.0, -30.0, -5.0])
    return Navigator.for_bounds(lo, lo + np.array([100.0, 60.0, 10.0]), W / H)


def pixel_of(camera: Camera, point) -> tuple[float, float]:
    """Sub-pixel (x, y) of a point, the contract's own formula."""
    v = (np.asarray(point, dtype=np.float64) - camera.position) @ camera.rotation().T
    f = camera.focal()
    return (f * H / W * v[0] / -v[2] * 0.5 + 0.5) * W, (0.5 - f * v[1] / -v[2] * 0.5) * H


def test_camera_round_trip(nav):
    cam = nav.camera(nav.home)
    again = nav.camera(Orbit.from_camera(cam))
    np.testing.assert_allclose(again.position, cam.position, rtol=0, atol=1e-7)
    np.testing.assert_allclose(again.target, cam.target, rtol=0, atol=1e-9)


def test_home_view_shows_the_whole_cloud(nav):
    cam = nav.camera(nav.home)
    corners = np.array([[x, y, z] for x in (nav.bounds_min[0], nav.bounds_max[0])
                        for y in (nav.bounds_min[1], nav.bounds_max[1]) for z in (nav.bounds_min[2], nav.bounds_max[2])])
    pixel, _ = project(cam, corners, W, H)
    assert (pixel >= 0).all()


def test_orbit_keeps_target_and_distance(nav):
    o = nav.orbit(nav.home, 120.0, -40.0)
    assert o.target == nav.home.target and o.distance == nav.home.distance
    assert o.yaw != nav.home.yaw and o.pitch != nav.home.pitch
    assert abs(nav.orbit(nav.home, 0.0, 1e6).pitch) < math.pi / 2


@given(dx=st.floats(-300, 300), dy=st.floats(-200, 200))
@settings(max_examples=30, deadline=None)
def test_pan_keeps_the_target_under_the_cursor(dx, dy):
    nav = Navigator.for_bounds(UTM - 50, UTM + 50, W / H)
    before = nav.camera(nav.home)
    after = nav.camera(nav.pan(nav.home, dx, dy, H))
    x0, y0 = pixel_of(before, before.target)
    x1, y1 = pixel_of(after, before.target)
    assert x1 == pytest.approx(x0 + dx, abs=1e-6) and y1 == pytest.approx(y0 + dy, abs=1e-6)


def test_zoom_keeps_the_anchor_under_the_cursor(nav):
    cam = nav.camera(nav.home)
    ray = nav.cursor_ray(nav.home, 100.0, 380.0, (W, H))
    anchor = cam.position + ray * nav.home.distance * 0.8
    x0, y0 = pixel_of(cam, anchor)
    assert (x0, y0) == (pytest.approx(100.0, abs=1e-6), pytest.approx(380.0, abs=1e-6))
    for steps in (3, -2):
        o = nav.zoom(nav.home, steps, anchor)
        x1, y1 = pixel_of(nav.camera(o), anchor)
        assert (x1, y1) == (pytest.approx(x0, abs=1e-6), pytest.approx(y0, abs=1e-6))
        assert o.distance == pytest.approx(nav.home.distance * 0.85 ** steps)


def test_focus_keeps_the_camera_where_it_is(nav):
    point = np.asarray(nav.home.target) + np.array([10.0, -5.0, 2.0])
    o = nav.focus(nav.home, point)
    np.testing.assert_allclose(o.position, nav.home.position, atol=1e-7)
    assert o.target == tuple(point.tolist())


def test_fly_moves_by_a_share_of_the_cloud_and_look_turns_in_place(nav):
    o = nav.fly(nav.home, 1.0, 0.0, 0.0, 1.0)
    moved = np.linalg.norm(o.position - nav.home.position)
    assert moved == pytest.approx(0.25 * nav.diagonal)
    turned = nav.look(o, 50.0, 20.0)
    np.testing.assert_allclose(turned.position, o.position, atol=1e-7)
    assert turned.target != o.target


def test_far_plane_reaches_the_cloud_from_far_away(nav):
    o = nav.zoom(nav.home, -40)
    cam = nav.camera(o)
    pixel, depth = project(cam, np.array([nav.centre]), W, H)
    assert pixel[0] >= 0 and cam.near < depth[0] < cam.far


def test_presets_and_orthographic_orbit():
    """Presets keep target and distance; the orthographic camera spans at the target
    what the perspective one does, and round-trips through Orbit.from_camera."""
    from progressive.viewer.navigation import PRESETS, View

    nav = Navigator.for_bounds((0.0, 0.0, 0.0), (100.0, 60.0, 20.0), 4 / 3)
    home = nav.home
    for view in View:
        o = nav.preset(home, view)
        assert (o.yaw, o.pitch) == PRESETS[view] and o.target == home.target and o.distance == home.distance
    top = nav.preset(home, View.TOP)
    cam = nav.camera(top)
    north = np.array([[top.target[0], top.target[1] + 1.0, top.target[2]]])
    south = np.array([[top.target[0], top.target[1] - 1.0, top.target[2]]])
    (pn,), _ = project(cam, north, 400, 300)
    (ps,), _ = project(cam, south, 400, 300)
    assert pn // 400 < ps // 400               # north is higher in the image
    ortho = replace(top, orthographic=True)
    ocam = nav.camera(ortho)
    assert ocam.orthographic and math.isclose(ocam.height, top.view_height)
    back = Orbit.from_camera(ocam)
    assert back.orthographic and math.isclose(back.distance, ortho.distance, rel_tol=1e-9)
    edge = np.array([[top.target[0], top.target[1] + 0.999 * top.view_height / 2, top.target[2]]])
    (pixel,), _ = project(ocam, edge, 400, 300)
    assert 0 <= pixel < 400                    # in the top row: the image's top edge is half the height away
    point = nav.cursor_point(ortho, 0.5, 0.5, (400, 300), ortho.distance)
    (corner,), _ = project(ocam, point[None], 400, 300)
    assert corner == 0
