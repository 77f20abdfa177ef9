"""The viewer in real windows on a virtual X server (Xvfb, started here): frames,
the app's own capture, scripted input through the handlers glfw's callbacks call,
resizing, attribute switching, and bad files dropped in. Run in a process of their
own by test_viewer.py (a GLX window cannot be made current in a process that
already made an EGL context current, as the rest of the suite does)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import replace

import glfw
import laspy
import numpy as np
import pytest
from PIL import Image

from colour_reference import assert_scalar_colours, las_values, reference_range
from conftest import SAMPLE, shared_file
from progressive.camera import Camera, screen_points
from progressive.reference import EMPTY
from progressive.session import SessionOptions
from progressive.viewer.controls import Action

W, H = 320, 240
EXACT = {"point_size": 1, "eye_dome": False}
"""Chosen as --point-size 1 --no-eye-dome would: 1-pixel images the references compare exactly."""


@pytest.fixture(scope="module")
def display():
    """A private X display for this module's windows."""
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb not installed (scripts/setup.sh installs it)")
    read, write = os.pipe()
    proc = subprocess.Popen(["Xvfb", "-displayfd", str(write), "-screen", "0", "1280x1024x24", "-nolisten", "tcp"],
                            pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write)
    with os.fdopen(read) as f:
        number = f.readline().strip()
    old = os.environ.get("DISPLAY")
    os.environ["DISPLAY"] = f":{number}"
    yield os.environ["DISPLAY"]
    glfw.terminate()
    proc.terminate()
    proc.wait(timeout=10)
    if old is None:
        os.environ.pop("DISPLAY", None)
    else:
        os.environ["DISPLAY"] = old


@pytest.fixture
def viewer(display, tmp_path):
    from progressive.viewer.app import Viewer, ViewerOptions

    v = Viewer([str(SAMPLE)], ViewerOptions(SessionOptions(width=W, height=H), screenshot_dir=tmp_path, **EXACT))
    yield v
    v.close()


def settle(v, limit=200):
    """Steps until the image is exact (every point filled since the last change)."""
    for _ in range(limit):
        v.step()
        v.session.stats()
        if v.session.converged and not v.session.renderer.switching:
            v.step()
            return
    raise AssertionError("viewer did not converge")


def finish_reads(v, limit: float = 10.0):
    """Steps until a click's point, read back from its file on the viewer's reader
    thread, has arrived (a local file's within the click itself, mostly)."""
    t0 = time.perf_counter()
    while v.reading:
        assert time.perf_counter() - t0 < limit, "the picked point was not read back"
        v.step()


def double_click(v, x: float, y: float, apart: float = 0.5, at: float | None = None):
    """Two clicks `apart` DOUBLE_CLICK_SECONDS apart, the first `at` (default now) by the
    clock the viewer is given, however long the first click's read back takes on a loaded
    machine."""
    from progressive.viewer.app import DOUBLE_CLICK_SECONDS

    at = time.perf_counter() if at is None else at
    for t in (at, at + apart * DOUBLE_CLICK_SECONDS):
        v.mouse_button(glfw.MOUSE_BUTTON_LEFT, True, x, y, at=t)
        v.mouse_button(glfw.MOUSE_BUTTON_LEFT, False, x, y)
        finish_reads(v)


def no_gl_error(v):
    assert v.glc.ctx.error == "GL_NO_ERROR"


def test_window_shows_the_cloud_and_p_saves_the_frame(viewer, tmp_path):
    viewer.act(Action.PANEL)            # at the home view: framed again in the whole window
    settle(viewer)
    frame = viewer.session.image()
    covered = (viewer.session.ids() != EMPTY).mean()
    assert 0.1 < covered < 0.95, covered
    viewer.act(Action.SCREENSHOT)
    saved = np.asarray(Image.open(viewer.last_screenshot))
    assert viewer.last_screenshot.parent == tmp_path
    np.testing.assert_array_equal(saved, frame[:, :, :3])
    no_gl_error(viewer)


def test_present_puts_the_frame_on_the_window(viewer, monkeypatch):
    """The window's back buffer (panel hidden) is the frame, pixel for pixel, above the
    gizmo and scale bar at the bottom."""
    viewer.act(Action.PANEL)
    settle(viewer)
    shots = []
    swap = glfw.swap_buffers
    monkeypatch.setattr(glfw, "swap_buffers", lambda w: (shots.append(viewer.capture_window()), swap(w)))
    viewer.step()
    np.testing.assert_array_equal(shots[-1][: H // 2], viewer.session.image()[: H // 2, :, :3])


def test_panel_draws_over_the_frame(viewer, monkeypatch):
    settle(viewer)
    shots = []
    swap = glfw.swap_buffers
    monkeypatch.setattr(glfw, "swap_buffers", lambda w: (shots.append(viewer.capture_window()), swap(w)))
    viewer.settings = viewer.settings.__class__(**{**viewer.settings.__dict__, "help": True})
    viewer.step()
    differs = (shots[-1] != viewer.session.image()[:, :, :3]).any(axis=2)
    assert differs[:40, :40].mean() > 0.3      # the panel sits in the top-left corner
    no_gl_error(viewer)


def test_switching_attribute_changes_the_image_and_streams_the_words(viewer):
    settle(viewer)
    before = viewer.session.image()
    viewer.act(Action.NEXT_ATTRIBUTE)
    assert viewer.settings.attribute == viewer.attribute_names[1]
    settle(viewer)
    after = viewer.session.image()
    assert not np.array_equal(before, after)
    s = viewer.session
    switch = s.renderer.scene.switch
    assert switch.done and switch.rate > 0
    words = s.renderer.store.read_records()[:, 3]
    from progressive.loaders.records import attribute_word

    expected = np.concatenate([attribute_word(b, s.attribute, float(s.info.origin[2]))
                               for b in sorted(s.renderer.scene.batches, key=lambda b: b.start)])
    slots = s.renderer.store.permutation.forward(np.arange(s.info.points))    # kept batches' rows: in the store's order
    np.testing.assert_array_equal(words[slots], expected)
    no_gl_error(viewer)


def test_colours_follow_the_contract_after_a_switch(viewer):
    """The window's image, switched to elevation, coloured over the whole cloud's
    percentiles (laspy, numpy, matplotlib); a range set in the panel is used as given."""
    settle(viewer)
    viewer.switch_attribute("elevation")
    settle(viewer)
    las = laspy.read(SAMPLE)
    values = las_values(las, "elevation")
    expected = reference_range(values)
    assert viewer.session.color_range() == pytest.approx(expected, abs=1e-4)
    image, ids = viewer.session.image()[:, :, :3].astype(np.int32), viewer.session.ids()
    assert_scalar_colours(image, ids, values, expected)
    viewer.settings = replace(viewer.settings, value_range=(420.0, 460.0))
    viewer.step()
    image = viewer.session.image()[:, :, :3].astype(np.int32)
    assert_scalar_colours(image, ids, values, (420.0, 460.0))
    no_gl_error(viewer)


def test_a_switch_asked_before_the_other_attributes_are_read_waits_for_them(display):
    """The window reads a layered LAZ's shown attribute first and the others afterwards:
    a switch to one of them asked at once is shown in the panel (the combo, a progress
    bar) and begins once they are read; the image is then coloured by it as the
    contract says."""
    path = shared_file("las_with_several_extra_byte_bloc.laz")
    viewer = open_viewer([path])
    try:
        s = viewer.session
        assert "intensity" in s.later and s.loader.attributes == ("rgb", "classification", "return_number",
                                                                   "number_of_returns")
        viewer.switch_attribute("intensity")
        assert viewer.settings.attribute == "intensity" and s.waiting.name == "intensity"
        assert s.status().later.waiting == "intensity" and s.attribute.name == "rgb"
        viewer.step()       # the panel draws the wait
        settle(viewer)
        assert s.attribute.name == "intensity" and s.waiting is None and not s.later
        values = las_values(laspy.read(path), "intensity")
        image, ids = s.image()[:, :, :3].astype(np.int32), s.ids()
        assert_scalar_colours(image, ids, values, reference_range(values))
        no_gl_error(viewer)
    finally:
        viewer.close()


def test_orbit_pan_zoom_and_reset(viewer):
    settle(viewer)
    viewer.act(Action.PANEL)
    home = viewer.orbit
    viewer.mouse_button(glfw.MOUSE_BUTTON_LEFT, True, 100, 100)
    viewer.cursor(160, 90)
    viewer.mouse_button(glfw.MOUSE_BUTTON_LEFT, False, 160, 90)
    finish_reads(viewer)
    # framed at home, it turns about the cloud's centre, which keeps its place on screen
    assert viewer.orbit.pivot == home.pivot and viewer.orbit.distance == pytest.approx(home.distance)
    np.testing.assert_allclose(screen_points(viewer.camera, np.array([home.pivot]), W, H)[0],
                               screen_points(viewer.navigator.camera(home), np.array([home.pivot]), W, H)[0], atol=1e-6)
    assert viewer.orbit.yaw < home.yaw and viewer.orbit.pitch < home.pitch
    orbited = viewer.orbit
    viewer.mouse_button(glfw.MOUSE_BUTTON_RIGHT, True, 100, 100)
    viewer.cursor(130, 100)
    viewer.mouse_button(glfw.MOUSE_BUTTON_RIGHT, False, 130, 100)
    assert viewer.orbit.target != orbited.target and viewer.orbit.yaw == orbited.yaw
    settle(viewer)
    ids = viewer.session.ids()
    ys, xs = np.nonzero(ids != EMPTY)
    k = len(ys) // 2
    x, y = float(xs[k]) + 0.5, float(ys[k]) + 0.5
    anchor_id = int(ids[ys[k], xs[k]])
    distance = viewer.orbit.distance
    viewer.scroll(2, x, y)
    assert viewer.orbit.distance == pytest.approx(distance * 0.85 ** 2)
    settle(viewer)
    # the point under the cursor is still under it after zooming about it
    near = viewer.session.ids()[max(0, ys[k] - 1): ys[k] + 2, max(0, xs[k] - 1): xs[k] + 2]
    assert anchor_id in near
    viewer.act(Action.RESET)
    assert viewer.orbit == home
    no_gl_error(viewer)


def test_double_click_reports_the_files_coordinates(viewer):
    viewer.act(Action.PANEL)
    settle(viewer)
    ids = viewer.session.ids()
    ys, xs = np.nonzero(ids != EMPTY)
    k = len(ys) // 3
    las = laspy.read(SAMPLE)
    pid = int(ids[ys[k], xs[k]])
    at = time.perf_counter()
    double_click(viewer, xs[k] + 0.5, ys[k] + 0.5, apart=1.5, at=at)
    assert viewer.last_focus is None and viewer.picked is not None     # two clicks, too slow for one double-click
    double_click(viewer, xs[k] + 0.5, ys[k] + 0.5, at=at + 10)
    expected = np.array([las.x[pid], las.y[pid], las.z[pid]])
    np.testing.assert_array_equal(viewer.last_focus, expected)
    assert viewer.orbit.target == tuple(expected.tolist())


def test_keys_through_the_glfw_callback(viewer):
    viewer.act(Action.PANEL)
    press = lambda key, mods=0: viewer.on_key(viewer.window, key, 0, glfw.PRESS, mods)  # noqa: E731
    press(glfw.KEY_E)
    press(glfw.KEY_EQUAL)
    press(glfw.KEY_EQUAL)
    assert viewer.settings.eye_dome and viewer.settings.point_size == 3
    viewer.step()
    assert viewer.last_passes[-3:] == ("dilate", "resolve", "eye_dome")
    press(glfw.KEY_MINUS)
    press(glfw.KEY_MINUS)
    press(glfw.KEY_E)
    viewer.step()
    assert "dilate" not in viewer.last_passes and "eye_dome" not in viewer.last_passes
    press(glfw.KEY_Q)
    assert not viewer.running
    no_gl_error(viewer)


def test_camera_copy_and_paste(viewer):
    viewer.act(Action.PANEL)
    viewer.orbit = viewer.navigator.orbit(viewer.orbit, 40, 10)
    viewer.act(Action.COPY_CAMERA)
    text = glfw.get_clipboard_string(None).decode()
    assert Camera.from_json(text) == viewer.camera
    viewer.act(Action.RESET)
    viewer.paste_camera(text)
    assert viewer.camera == Camera.from_json(text)
    viewer.paste_camera("{not json")
    assert "pasted camera" in viewer.error
    viewer.step()


def test_resize_reallocates_per_pixel_buffers(viewer):
    settle(viewer)
    glfw.set_window_size(viewer.window, 400, 180)
    for _ in range(20):
        viewer.step()
        if viewer.framebuffer_size == (400, 180):
            break
    settle(viewer)
    assert viewer.session.size == (400, 180)
    assert viewer.session.image().shape == (180, 400, 4)
    assert viewer.session.renderer.vis.pixels == 400 * 180
    no_gl_error(viewer)


def test_a_bad_file_dropped_in_is_an_error_in_the_window(viewer, tmp_path):
    settle(viewer)
    bad = tmp_path / "bad.las"
    bad.write_bytes(b"LASF" + bytes(50))
    viewer.drop([str(bad)])
    viewer.step()
    assert viewer.error and "bad.las" in viewer.error
    assert viewer.running and viewer.session.info.points == 110_000
    settle(viewer)
    viewer.drop([str(SAMPLE)], add=True)
    viewer.step()
    assert viewer.error is None and viewer.session.info.points == 220_000
    settle(viewer)
    no_gl_error(viewer)


def test_view_without_a_display_renders_a_png(tmp_path):
    out = tmp_path / "view.png"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    r = subprocess.run([sys.executable, "-m", "progressive", "view", "--width", "200", "--height", "120",
                        "--out", str(out)], env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "no display" in r.stderr and str(out) in r.stdout
    assert np.asarray(Image.open(out)).shape[:2] == (120, 200)


def test_first_image_arrives_before_loading_finishes(display, tmp_path):
    """A cloud of several copies of the sample: the window shows points while loading."""
    from progressive.viewer.app import Viewer, ViewerOptions

    v = Viewer([str(SAMPLE)] * 6, ViewerOptions(SessionOptions(width=W, height=H)))
    t0 = time.perf_counter()
    seen = False
    while not v.session.loader.done or v.session.renderer.pending:
        v.step()
        loaded = v.session.renderer.scene.loaded
        if 0 < loaded < v.session.info.points and (v.session.image()[:, :, 3] > 0).any():
            seen = True
        assert time.perf_counter() - t0 < 60
    v.close()
    assert seen


def test_viewer_objects_stay_flat_over_many_steps(viewer):
    """Attribute cycling, effects and class toggles in the window: GPU objects bounded."""
    import gc

    import moderngl

    from progressive.programs import ComputeProgram

    def objects():
        gc.collect()
        kinds = (moderngl.Buffer, moderngl.ComputeShader, ComputeProgram, moderngl.Program, moderngl.VertexArray)
        return sum(isinstance(o, kinds)
                   for o in gc.get_objects())

    def cycle(steps):
        for k in range(steps):
            if k % 10 == 0:
                viewer.act(Action.NEXT_ATTRIBUTE)
            if k % 7 == 0:
                viewer.act(Action.EYE_DOME)
            viewer.act(Action.POINT_BIGGER if k % 4 < 2 else Action.POINT_SMALLER)
            viewer.orbit = viewer.navigator.orbit(viewer.orbit, 3, 0)
            viewer.step()

    cycle(60)
    before = objects()
    cycle(150)
    assert objects() <= before + 2
    assert viewer.settings.target_fps > 0
    no_gl_error(viewer)


def hide_the_commonest_class(viewer) -> tuple[int, np.ndarray]:
    """Toggle the sample's commonest class off (the legend lists every class present):
    none of its points stays visible and the image changes. (code, image before)."""
    classes = np.asarray(laspy.read(SAMPLE).classification)
    assert viewer.categories() == sorted(set(classes.tolist()))
    common = int(np.bincount(classes).argmax())
    before = viewer.session.image()
    viewer.toggle_class(common)
    settle(viewer)
    ids = viewer.session.ids()
    assert not np.any(classes[ids[ids != EMPTY]] == common)
    assert not np.array_equal(before, viewer.session.image())
    return common, before


def test_class_toggles_in_the_window(viewer):
    """Colour by classification, hide the commonest class from the legend: none of its
    points stays visible, and the image changes."""
    viewer.act(Action.PANEL)
    viewer.switch_attribute("classification")
    settle(viewer)
    common, before = hide_the_commonest_class(viewer)
    viewer.toggle_class(common)
    settle(viewer)
    np.testing.assert_array_equal(viewer.session.image(), before)
    no_gl_error(viewer)


def test_clip_box_in_the_window(viewer):
    """A clip slab set in the viewer's settings (what the panel's numbers edit): no point
    outside it stays visible, and clearing it brings the image back."""
    from progressive.camera import NO_CLIP, Clip

    settle(viewer)
    before = viewer.session.image()
    las = laspy.read(SAMPLE)
    z = np.asarray(las.z)
    low, high = np.percentile(z, [20, 40])
    viewer.settings = replace(viewer.settings, clip=Clip((-np.inf, -np.inf, low), (np.inf, np.inf, high)))
    settle(viewer)
    ids = viewer.session.ids()
    shown = z[ids[ids != EMPTY]]
    assert shown.size and shown.min() >= low - 0.01 and shown.max() <= high + 0.01
    viewer.settings = replace(viewer.settings, clip=NO_CLIP)
    settle(viewer)
    np.testing.assert_array_equal(viewer.session.image(), before)
    no_gl_error(viewer)


def test_views_and_projection_keys(viewer):
    """1-4 give the standard views, O the orthographic projection; each changes the image
    and the camera copied out is the contract's orthographic JSON."""
    settle(viewer)
    images = [viewer.session.image()]
    for key in (glfw.KEY_1, glfw.KEY_2, glfw.KEY_4):
        viewer.on_key(viewer.window, key, 0, glfw.PRESS, 0)
        settle(viewer)
        images.append(viewer.session.image())
    viewer.on_key(viewer.window, glfw.KEY_O, 0, glfw.PRESS, 0)
    settle(viewer)
    assert viewer.camera.orthographic and Camera.from_json(viewer.camera.to_json()) == viewer.camera
    images.append(viewer.session.image())
    assert all(not np.array_equal(a, b) for a, b in zip(images, images[1:]))
    no_gl_error(viewer)


def test_click_picks_the_point_and_the_panel_shows_it(viewer):
    """A click (press and release in place) picks the point shown there: its record equals
    laspy's, and the next frame draws the panel's section and marker for it."""
    settle(viewer)
    ids = viewer.session.ids()
    rows, cols = np.nonzero(ids != EMPTY)
    x, y = float(cols[len(cols) // 2]) + 0.5, float(rows[len(rows) // 2]) + 0.5
    viewer.mouse_button(glfw.MOUSE_BUTTON_LEFT, True, x, y)
    viewer.mouse_button(glfw.MOUSE_BUTTON_LEFT, False, x, y)
    finish_reads(viewer)
    p = viewer.picked
    assert p is not None and p["index"] == int(ids[int(y), int(x)])
    las = laspy.read(SAMPLE)
    assert p["x"] == round(float(las.x[p["index"]]), 2) and p["attributes"]["intensity"] == int(las.intensity[p["index"]])
    viewer.step()
    no_gl_error(viewer)


def test_a_pick_over_a_slow_network_leaves_the_window_drawing(display, tmp_path):
    """A COPC file over HTTP whose server answers each request a second late: a click
    finds its point on the GPU at once, the window keeps drawing while the point's node
    is fetched, and the record that then arrives is laspy's. (The answers are also held
    back until the window has drawn its frames, so that on a slow machine the node cannot
    arrive first.)"""
    from range_server import RangeServer

    from progressive.cli import main
    from progressive.viewer.app import Viewer, ViewerOptions

    copc = tmp_path / "sample.copc.laz"
    assert main(["convert", str(SAMPLE), str(copc)]) == 0
    held = threading.Event()
    with RangeServer({copc.name: copc}) as server:
        v = Viewer([server.url(copc.name)], ViewerOptions(SessionOptions(width=W, height=H), **EXACT))
        try:
            settle(v)
            ids = v.session.ids()
            rows, cols = np.nonzero(ids != EMPTY)
            x, y = float(cols[len(cols) // 2]) + 0.5, float(rows[len(rows) // 2]) + 0.5
            server.faults.pause, server.faults.hold = 1.0, held
            t0 = time.perf_counter()
            v.mouse_button(glfw.MOUSE_BUTTON_LEFT, True, x, y)
            v.mouse_button(glfw.MOUSE_BUTTON_LEFT, False, x, y)
            assert v.reading and v.picked is None       # the click did not wait for the node ...
            assert time.perf_counter() - t0 < server.faults.pause       # ... nor as long as an answer takes
            frames, t0 = v.frames, time.perf_counter()
            while v.frames - frames < 5 and time.perf_counter() - t0 < 5 * server.faults.pause:
                v.step()
            assert v.reading and v.frames - frames >= 5      # drawn while the node is on its way, faster than it came
            held.set()
            finish_reads(v, limit=30)
            p = v.picked
            assert p is not None and p["index"] == int(ids[int(y), int(x)]) and v.error is None
            las = laspy.read(copc)
            assert p["x"] == round(float(las.x[p["index"]]), 2) and p["attributes"]["intensity"] == int(
                las.intensity[p["index"]])
            no_gl_error(v)
        finally:
            held.set()
            v.close()


def test_shift_clicks_measure_between_picked_points(viewer):
    """Shift+clicks add the picked points to the measurement, in the file's coordinates
    (laspy's), and the next frame draws the line and the panel's numbers."""
    settle(viewer)
    ids = viewer.session.ids()
    rows, cols = np.nonzero(ids != EMPTY)
    chosen = [len(cols) // 4, len(cols) // 2, 3 * len(cols) // 4]
    for k in chosen:
        x, y = float(cols[k]) + 0.5, float(rows[k]) + 0.5
        viewer.mouse_button(glfw.MOUSE_BUTTON_LEFT, True, x, y, shift=True)
        viewer.mouse_button(glfw.MOUSE_BUTTON_LEFT, False, x, y, shift=True)
        finish_reads(viewer)
    las = laspy.read(SAMPLE)
    xyz = np.stack([las.x, las.y, las.z], axis=1)[[int(ids[rows[k], cols[k]]) for k in chosen]]
    m = viewer.measurement
    np.testing.assert_allclose(np.asarray(m.points), np.round(xyz, 2), atol=1e-9)
    assert m.length == pytest.approx(float(np.linalg.norm(np.diff(xyz, axis=0), axis=1).sum()), abs=0.05)
    viewer.step()
    no_gl_error(viewer)


def test_class_toggles_apply_to_any_colouring(viewer):
    """Colouring by elevation, the panel's Classes toggles still hide a class: the GPU
    keeps every point's class beside the shown attribute."""
    viewer.switch_attribute("elevation")
    settle(viewer)
    hide_the_commonest_class(viewer)
    no_gl_error(viewer)


def test_return_filter_in_the_window(viewer):
    """Last returns only (the panel's radio buttons set this): every point shown is the
    last return of its pulse."""
    from progressive.camera import Returns

    settle(viewer)
    viewer.settings = replace(viewer.settings, returns=Returns.LAST)
    settle(viewer)
    las = laspy.read(SAMPLE)
    ids = viewer.session.ids()
    shown = ids[ids != EMPTY]
    assert shown.size and np.all(np.asarray(las.return_number)[shown] == np.asarray(las.number_of_returns)[shown])
    no_gl_error(viewer)


@pytest.mark.parametrize("argv", [["missing.las"], ["NOT_LAS"], [str(SAMPLE), "--color-by", "no_such_attribute"]])
def test_view_with_a_display_checks_before_opening_a_window(display, tmp_path, argv):
    """With a display, a bad path, a file that is not a point cloud or an unknown
    attribute is one line and exit 2, and no window opens (the viewer is never built)."""
    if argv == ["NOT_LAS"]:
        bad = tmp_path / "notes.las"
        bad.write_text("not a point cloud\n")
        argv = [str(bad)]
    proc = subprocess.run([sys.executable, "-m", "progressive", "view", *argv], capture_output=True, text=True,
                          timeout=120, env={**os.environ, "DISPLAY": display})
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith("progressive: error: ") and proc.stderr.count("\n") == 1


def test_messages_expire(viewer, tmp_path):
    """Notes (a saved screenshot) show for a while, then leave the panel."""
    from progressive.viewer.app import MESSAGE_SECONDS

    settle(viewer)
    viewer.act(Action.SCREENSHOT)
    assert any(m.startswith("saved ") for m in viewer.messages)
    viewer.expire_messages(time.perf_counter() + MESSAGE_SECONDS / 2)
    assert any(m.startswith("saved ") for m in viewer.messages)
    viewer.expire_messages(time.perf_counter() + MESSAGE_SECONDS + 1)
    assert not viewer.messages
    viewer.step()
    no_gl_error(viewer)


def test_colour_bar_for_scalars_only(viewer):
    """A scalar colouring draws the colour bar over its range; RGB draws none."""
    settle(viewer)
    assert viewer.settings.attribute == "rgb" and viewer.panel.colour_bar is None
    viewer.switch_attribute("elevation")
    settle(viewer)
    name, lo, hi = viewer.panel.colour_bar
    assert name == "elevation" and (lo, hi) == pytest.approx(viewer.session.color_range())
    no_gl_error(viewer)


def test_escape_closes_an_open_popup_before_quitting(viewer, monkeypatch):
    """Esc with a panel popup open (a dropdown, the colour picker) leaves the viewer
    running; with none open it quits."""
    settle(viewer)
    monkeypatch.undo()
    assert viewer.panel.popup_open() is False          # the real query, with nothing open
    monkeypatch.setattr(viewer.panel, "popup_open", lambda: True)
    viewer.on_key(viewer.window, glfw.KEY_ESCAPE, 0, glfw.PRESS, 0)
    assert viewer.running
    monkeypatch.setattr(viewer.panel, "popup_open", lambda: False)
    viewer.on_key(viewer.window, glfw.KEY_ESCAPE, 0, glfw.PRESS, 0)
    assert not viewer.running


def brute_ids(viewer) -> np.ndarray:
    """The brute-force render of the viewer's view, settings and clip over the same
    points on the GPU (a renderer sharing the session's scene)."""
    from progressive.renderer import Renderer

    s = viewer.session
    scene = s.renderer.scene
    w, h = s.size
    brute = Renderer(viewer.glc, s.info, scene.attribute, width=w, height=h, scene=scene)
    try:
        return brute.render(viewer.camera, w, h, brute.style(), hidden=viewer.settings.hidden_classes,
                            clip=viewer.settings.clip, returns=viewer.settings.returns).ids
    finally:
        brute.release()


def clipped_reference(viewer, clip) -> np.ndarray:
    """The float64 contract over laspy's coordinates inside `clip` (its float64 test)."""
    from progressive.reference import clipped_reference_ids

    las = laspy.read(SAMPLE)
    xyz = np.stack([las.x, las.y, las.z], axis=1).astype(np.float64)
    slots = viewer.session.renderer.store.slots_of(np.arange(len(xyz))).astype(np.int64)
    return clipped_reference_ids(xyz, clip, viewer.camera, *viewer.session.size, slots)


def test_dragging_a_clip_face_moves_it_and_the_image_is_the_clipped_render(viewer):
    """With the clip box on (the cloud's bounds), the window shows its 12 edges and 6
    handles; a press on the max-x face's handle dragged along that face's normal on
    screen moves the face so it stays under the cursor (float64 bound, panel fields
    follow), the other sides stay, and the still view converges to the brute-force
    render of the clipped cloud, which is the float64 reference of the points inside."""
    from progressive.camera import Clip, screen_points
    from progressive.viewer import clipbox

    viewer.act(Action.RESET)
    s = viewer.session
    viewer.settings = replace(viewer.settings, clip=Clip(tuple(s.info.bounds_min), tuple(s.info.bounds_max)))
    settle(viewer)
    assert viewer.panel.clip_overlay == (12, 6)
    lo, hi = viewer.shown_clip_box()
    size = viewer.framebuffer_size
    face = clipbox.Face(0, 1)
    handles = clipbox.face_handles(viewer.camera, lo, hi, size)
    start = handles[face]
    centre_xy = screen_points(viewer.camera, ((lo + hi) / 2)[None], *size)[0][0]
    end = start + 0.4 * (centre_xy - start)          # along the face's normal on screen, towards the middle
    ww, wh = glfw.get_window_size(viewer.window)
    to_window = lambda p: (float(p[0]) * ww / size[0], float(p[1]) * wh / size[1])  # noqa: E731
    viewer.mouse_button(glfw.MOUSE_BUTTON_LEFT, True, *to_window(start))
    assert viewer.dragged_face() == face
    for k in range(1, 6):
        viewer.cursor(*to_window(start + (end - start) * k / 5))
        viewer.step()
    viewer.mouse_button(glfw.MOUSE_BUTTON_LEFT, False, *to_window(end))
    finish_reads(viewer)
    clip = viewer.settings.clip
    assert viewer.picked is None and viewer.dragged_face() is None
    assert lo[0] < clip.hi[0] < hi[0]
    assert clip.lo == tuple(lo.tolist()) and clip.hi[1:] == tuple(hi[1:].tolist())
    moved = clipbox.face_centre(*viewer.shown_clip_box(), face)
    np.testing.assert_allclose(screen_points(viewer.camera, moved[None], *size)[0][0], end, atol=0.05)
    settle(viewer)
    ids = viewer.session.ids()
    np.testing.assert_array_equal(ids, brute_ids(viewer))
    assert np.mean(ids == clipped_reference(viewer, clip)) >= 0.999
    las = laspy.read(SAMPLE)
    shown = ids[ids != EMPTY]
    assert shown.size and np.asarray(las.x)[shown].max() <= clip.hi[0] + 0.01
    no_gl_error(viewer)


def test_section_along_the_measured_line_and_its_profile_view(viewer):
    """Two Shift+clicked points and "Section along line" clip to a slab of the panel's
    width along them: the still view converges to the brute-force render, the float64
    reference of the points within the segment's rectangle; the profile view looks
    along the section's normal, orthographic, and shows the section."""
    from progressive.camera import Clip

    viewer.act(Action.RESET)
    settle(viewer)
    assert not viewer.section_along_line() and "two measured points" in viewer.error
    viewer.error = None
    ids = viewer.session.ids()
    rows, cols = np.nonzero(ids != EMPTY)
    order = np.argsort(cols)
    for k in (order[len(order) // 5], order[4 * len(order) // 5]):
        x, y = float(cols[k]) + 0.5, float(rows[k]) + 0.5
        viewer.mouse_button(glfw.MOUSE_BUTTON_LEFT, True, x, y, shift=True)
        viewer.mouse_button(glfw.MOUSE_BUTTON_LEFT, False, x, y, shift=True)
        finish_reads(viewer)
    a, b = viewer.measurement.points[-2:]
    width = 0.02 * float(np.hypot(b[0] - a[0], b[1] - a[1]))
    viewer.set_section_width(width)
    assert viewer.section_along_line()
    section = viewer.settings.clip.section
    assert section.start == (a[0], a[1]) and section.end == (b[0], b[1]) and section.width == width
    settle(viewer)
    ids = viewer.session.ids()
    np.testing.assert_array_equal(ids, brute_ids(viewer))
    assert np.mean(ids == clipped_reference(viewer, viewer.settings.clip)) >= 0.999
    las = laspy.read(SAMPLE)
    xy = np.stack([las.x, las.y], axis=1)[ids[ids != EMPTY]] - np.asarray(a[:2])
    axis = np.subtract(b[:2], a[:2]) / section.length
    assert xy.shape[0] and np.abs(xy[:, 1] * axis[0] - xy[:, 0] * axis[1]).max() <= width / 2 + 0.01
    viewer.profile_view()
    settle(viewer)
    cam = viewer.camera
    forward = np.subtract(cam.target, cam.position)
    forward /= np.linalg.norm(forward)
    assert cam.orthographic
    np.testing.assert_allclose(forward, [-axis[1], axis[0], 0.0], atol=1e-9)
    profile = viewer.session.ids()
    assert np.array_equal(profile, brute_ids(viewer))
    # framed in the free area: the segment spans most of its width, nothing under the panel
    x0, _, x1, _ = viewer.free_area
    cols = np.nonzero((profile != EMPTY).any(axis=0))[0]
    assert cols.min() >= x0 and cols.max() - cols.min() >= 0.6 * (x1 - x0)
    assert np.mean(profile == clipped_reference(viewer, viewer.settings.clip)) >= 0.999
    viewer.clear_section()
    assert viewer.settings.clip == Clip()
    no_gl_error(viewer)


def open_viewer(paths, width=W, height=H, automatic=False, **session):
    """automatic: the point size and eye-dome lighting rules choose (the cases that
    compare exact 1-pixel images choose 1 pixel and no lighting)."""
    from progressive.viewer.app import Viewer, ViewerOptions

    return Viewer([str(p) for p in paths], ViewerOptions(SessionOptions(width=width, height=height, **session),
                                                         **({} if automatic else EXACT)))


def corners(lo, hi) -> np.ndarray:
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


@pytest.mark.parametrize("width", [640, 1280])
def test_the_cloud_is_framed_in_the_area_the_docked_panel_leaves(display, width):
    """The panel docks at the left with its own width; the bounding box's corners (float64
    projection of the camera) and every point drawn lie right of it, and the box fills
    most of the free width; Tab at the home view frames it in the whole window."""
    v = open_viewer([SAMPLE], width, 360)
    try:
        settle(v)
        x0, _, x1, y1 = v.free_area
        assert 0 < x0 < 0.5 * width and (x1, y1) == (width, 360)
        scale = v.framebuffer_size[0] / glfw.get_window_size(v.window)[0]
        assert v.panel.docked[0] == 0 and v.panel.docked[1] * scale == pytest.approx(x0, abs=1)
        xy, depth = screen_points(v.camera, corners(v.session.info.bounds_min, v.session.info.bounds_max), width, 360)
        assert (depth > 0).all() and xy[:, 0].min() >= x0 and xy[:, 0].max() <= x1
        assert xy[:, 1].min() >= 0 and xy[:, 1].max() <= 360
        assert xy[:, 0].max() - xy[:, 0].min() >= 0.85 * (x1 - x0) or xy[:, 1].max() - xy[:, 1].min() >= 0.85 * 360
        cols = np.nonzero((v.session.ids() != EMPTY).any(axis=0))[0]
        assert cols.min() >= x0
        v.act(Action.PANEL)
        assert v.free_area[0] == 0
        xy, _ = screen_points(v.camera, corners(v.session.info.bounds_min, v.session.info.bounds_max), width, 360)
        assert xy[:, 0].min() < x0 and xy[:, 0].max() <= width
        no_gl_error(v)
    finally:
        v.close()


def test_axes_gizmo_and_scale_bar(viewer, monkeypatch):
    """The gizmo's axes point where the camera projects the file's X, Y, Z at the target;
    the scale bar's pixels are its length across the view at the target's depth (the
    camera's float64 projection), labelled in the file's unit (pyproj's of its CRS)."""
    viewer.orbit = viewer.navigator.orbit(viewer.orbit, 35, -20)
    shots = []
    swap = glfw.swap_buffers
    monkeypatch.setattr(glfw, "swap_buffers", lambda w: (shots.append(viewer.capture_window()), swap(w)))
    settle(viewer)
    cam, p = viewer.camera, viewer.panel
    target = np.array(cam.target)
    eps = 1e-4 * viewer.navigator.diagonal
    base = screen_points(cam, target[None], W, H)[0][0]
    for k, name in enumerate("XYZ"):
        moved = screen_points(cam, (target + eps * np.eye(3)[k])[None], W, H)[0][0] - base
        drawn = np.subtract(p.gizmo[name], p.gizmo_centre)
        assert np.linalg.norm(drawn) > 5
        np.testing.assert_allclose(drawn / np.linalg.norm(drawn), moved / np.linalg.norm(moved), atol=2e-3)
    length, pixels, label = p.scale_bar
    right = cam.rotation()[0]
    a, b = screen_points(cam, np.stack([target, target + length * right]), W, H)[0]
    assert np.hypot(*(b - a)) == pytest.approx(pixels, rel=1e-9)
    assert 0.2 * 160 <= pixels <= 160
    leading = float(f"{length:e}".split("e")[0])
    assert leading in (1.0, 2.0, 5.0)
    unit = laspy.open(SAMPLE).header.parse_crs().axis_info[0].unit_name
    assert unit == "foot" and label == f"{length:g} ft"
    # drawn: the window differs from the image around the gizmo
    gx, gy = (int(c) for c in p.gizmo_centre)
    region = (slice(gy - 20, gy + 20), slice(gx - 20, gx + 20))
    assert (shots[-1][region] != viewer.session.image()[:, :, :3][region]).any()
    no_gl_error(viewer)


@pytest.mark.parametrize("name", ["elevation", "intensity"])
def test_histogram_under_the_colour_range(viewer, name):
    """The histogram the panel draws under the colour bar: numpy's counts over laspy's
    values as the contract stores them (float32 of the value less the attribute's
    offset), in equal bins over the colour range; it follows a range set in the panel."""
    from progressive.viewer.app import HISTOGRAM_BINS

    viewer.switch_attribute(name)
    settle(viewer)
    s = viewer.session
    stored = np.float32(las_values(laspy.read(SAMPLE), name) - s.attribute.offset).astype(np.float64) + s.attribute.offset
    lo, hi = s.color_range()
    expected = np.histogram(stored, HISTOGRAM_BINS, (lo, hi))[0]
    np.testing.assert_array_equal(viewer.panel.histogram, expected)
    assert expected.sum() > 0.9 * stored.size
    narrow = (lo + 0.25 * (hi - lo), lo + 0.5 * (hi - lo))
    viewer.settings = replace(viewer.settings, value_range=narrow)
    viewer.step()
    np.testing.assert_array_equal(viewer.panel.histogram, np.histogram(stored, HISTOGRAM_BINS, narrow)[0])
    no_gl_error(viewer)


def test_colormap_is_remembered_per_attribute(viewer):
    """A colormap chosen for elevation comes back with elevation after another attribute
    was shown with its own, and the image is coloured through it (matplotlib's)."""
    from progressive.colors import Colormap

    viewer.switch_attribute("elevation")
    viewer.set_colormap(Colormap.INFERNO)
    viewer.switch_attribute("intensity")
    assert viewer.settings.colormap is Colormap.VIRIDIS
    viewer.set_colormap(Colormap.PLASMA)
    viewer.switch_attribute("elevation")
    assert viewer.settings.colormap is Colormap.INFERNO
    settle(viewer)
    values = las_values(laspy.read(SAMPLE), "elevation")
    image, ids = viewer.session.image()[:, :, :3].astype(np.int32), viewer.session.ids()
    assert_scalar_colours(image, ids, values, viewer.session.color_range(), "inferno")
    viewer.switch_attribute("intensity")
    assert viewer.settings.colormap is Colormap.PLASMA
    no_gl_error(viewer)


def click_a_point(viewer, share=0.5) -> int:
    ids = viewer.session.ids()
    rows, cols = np.nonzero(ids != EMPTY)
    k = int(len(rows) * share)
    x, y = float(cols[k]) + 0.5, float(rows[k]) + 0.5
    viewer.mouse_button(glfw.MOUSE_BUTTON_LEFT, True, x, y)
    viewer.mouse_button(glfw.MOUSE_BUTTON_LEFT, False, x, y)
    finish_reads(viewer)
    viewer.step()
    return int(ids[rows[k], cols[k]])


def test_pick_panel_shows_crs_and_latitude_longitude(viewer):
    """The picked point's section lists its CRS (pyproj's name of the file's) and its
    latitude and longitude (pyproj's WGS 84 transform of laspy's coordinates)."""
    import pyproj

    settle(viewer)
    index = click_a_point(viewer)
    las = laspy.read(SAMPLE)
    crs = las.header.parse_crs()
    lon, lat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(las.x[index], las.y[index])
    lines = viewer.panel.picked_lines
    assert viewer.picked["index"] == index
    assert f"CRS: {crs.name}" in lines
    assert f"lat {lat:.8f}  lon {lon:.8f}" in lines
    assert f"intensity: {int(las.intensity[index])}" in lines
    no_gl_error(viewer)


def test_legend_colours_come_from_the_palette_file(display, tmp_path):
    """--palette overrides show in the classification legend and in the image: the
    listed colours are the file's for its codes, ASPRS names beside them."""
    import json

    from progressive.colors import Palette

    path = tmp_path / "palette.json"
    path.write_text(json.dumps({"1": [10, 20, 30], "2": "#c86432"}))
    v = open_viewer([SAMPLE], palette=Palette.from_json(str(path)), color_by="classification")
    try:
        settle(v)
        legend = {code: (name, rgb) for code, name, rgb in v.panel.legend}
        assert legend == {1: ("unclassified", (10, 20, 30)), 2: ("ground", (200, 100, 50))}
        classes = np.asarray(laspy.read(SAMPLE).classification)
        image, ids = v.session.image()[:, :, :3], v.session.ids()
        shown = ids != EMPTY
        for code, (_, rgb) in legend.items():
            mine = shown.copy()
            mine[shown] = classes[ids[shown]] == code
            assert mine.any() and (image[mine] == rgb).all()
        no_gl_error(v)
    finally:
        v.close()


def test_copy_paste_and_fly_mode_say_so(viewer):
    """Ctrl+C and Ctrl+V leave a note over the image, F shows the fly mode indicator."""
    viewer.act(Action.COPY_CAMERA)
    viewer.act(Action.PASTE_CAMERA)
    viewer.act(Action.FLY)
    viewer.step()
    assert any("copied" in n for n in viewer.panel.notes) and any("pasted" in n for n in viewer.panel.notes)
    assert viewer.panel.fly_shown
    viewer.act(Action.FLY)
    viewer.step()
    assert not viewer.panel.fly_shown
    no_gl_error(viewer)


UTM = "EPSG:32610"


@pytest.fixture(scope="module")
def two_crs_files(tmp_path_factory):
    """The sample written in UTM 10N (EPSG:32610, metres) and in Oregon's Lambert grid
    (EPSG:2992, feet), the second 500 ft east: pyproj's float64 transforms of laspy's
    coordinates, heights in each CRS's unit."""
    import pyproj

    src = laspy.read(SAMPLE)
    source = src.header.parse_crs()
    out = []
    for code, shift in (("EPSG:32610", 0.0), ("EPSG:2992", 500.0)):
        crs = pyproj.CRS.from_user_input(code)
        x, y = pyproj.Transformer.from_crs(source, crs, always_xy=True).transform(src.x, src.y)
        header = laspy.LasHeader(point_format=3, version="1.2")
        header.scales = [0.001] * 3
        header.offsets = [float(np.floor(x.min())), float(np.floor(y.min())), 0.0]
        header.add_crs(crs)
        las = laspy.LasData(header)
        las.x, las.y, las.z = x + shift, y, src.z * (0.3048 / crs.axis_info[0].unit_conversion_factor)
        for dim in ("intensity", "classification", "red", "green", "blue"):
            setattr(las, dim, getattr(src, dim))
        path = tmp_path_factory.mktemp("crs") / f"autzen_{code.split(':')[1]}.las"
        las.write(path)
        out.append(path)
    return out


def test_files_in_two_crs_refused_then_reprojected(display, two_crs_files):
    """Without --reproject the window shows the refusal naming both CRSs and no cloud;
    with it both files are one cloud in the target CRS: both drawn side by side, and a
    double-click orbits about the point's pyproj coordinates, not the file's."""
    import pyproj

    refused = open_viewer(two_crs_files)
    try:
        assert refused.session is None and "2992" in refused.error and "32610" in refused.error
        refused.step()
    finally:
        refused.close()
    v = open_viewer(two_crs_files, reproject=UTM)
    try:
        v.act(Action.PANEL)
        settle(v)
        ids = v.session.ids()
        shown = ids[ids != EMPTY]
        n = laspy.open(two_crs_files[0]).header.point_count
        assert (shown < n).any() and (shown >= n).any()
        rows, cols = np.nonzero((ids >= n) & (ids != EMPTY))
        k = len(rows) // 2
        double_click(v, cols[k] + 0.5, rows[k] + 0.5)
        index = int(ids[rows[k], cols[k]]) - n
        las = laspy.read(two_crs_files[1])
        x, y = pyproj.Transformer.from_crs("EPSG:2992", UTM, always_xy=True).transform(las.x[index], las.y[index])
        feet = pyproj.CRS.from_user_input("EPSG:2992").axis_info[0].unit_conversion_factor
        np.testing.assert_allclose(v.last_focus, [x, y, las.z[index] * feet], rtol=0, atol=1e-6)
        assert abs(v.last_focus[0] - las.x[index]) > 1e-3 or abs(v.last_focus[1] - las.y[index]) > 1e-3
        assert v.orbit.target == tuple(v.last_focus.tolist())
        v.act(Action.PANEL)
        click_a_point(v, 0.7)
        p = v.picked
        assert "32610" in p["crs"] and p["file_coordinates"] is not None
        lines = v.panel.picked_lines
        assert any(line.startswith("in the file: ") for line in lines) and f"CRS: {p['crs']}" in lines
        no_gl_error(v)
    finally:
        v.close()


def projected_coverage(v) -> np.ndarray:
    """(H, W) bool: pixels a laspy point of the sample projects into (float64, the
    camera's own projection), the independent 1-pixel coverage of the view."""
    las = laspy.read(SAMPLE)
    w, h = v.session.size
    xy, depth = screen_points(v.camera, np.stack([las.x, las.y, las.z], axis=1), w, h)
    ok = (depth > 0) & np.isfinite(xy).all(axis=1)
    col, row = np.floor(xy[ok]).astype(np.int64).T
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    mask = np.zeros((h, w), bool)
    mask[row[inside], col[inside]] = True
    return mask


def test_default_point_size_and_lighting_follow_their_rules_and_say_why(display):
    """With nothing asked for, the converged sample gets the point size viewer/defaults.py
    derives from the laspy points' coverage of the view, eye-dome lighting off for RGB
    and, coloured by elevation, on exactly when its measured cost fits its share of the
    frame goal; the panel gives each reason. A key press makes it the user's choice,
    which a new view keeps; the panel's button gives it back to the rules."""
    from progressive.viewer import defaults

    v = open_viewer([SAMPLE], 640, 360, automatic=True)
    try:
        settle(v)
        v.step()
        reference = projected_coverage(v)
        covered = v.session.covered()
        assert (covered != reference).mean() < 0.002          # the GPU's coverage is the view's
        expected = defaults.point_size(reference)
        assert v.settings.point_size == expected.value == defaults.point_size(covered).value
        assert 1 < v.settings.point_size <= defaults.AUTO_POINT_SIZE_MAX  # the sample is sparse at 1 px
        assert not v.settings.eye_dome and v.eye_dome_cost is None
        assert v.panel.effect_lines[0] == v.point_size_choice.reason and f"point size {expected.value}:" in \
            v.panel.effect_lines[0]
        assert "RGB" in v.panel.effect_lines[1]
        v.switch_attribute("elevation")
        settle(v)
        v.step()
        (size, cost) = v.eye_dome_cost
        assert size == (640, 360) and cost > 0
        goal = v.goal_ms
        assert goal == pytest.approx(1e3 / v.settings.target_fps * (1024 - 154) / 1024, rel=1e-6)
        assert v.settings.eye_dome == (cost <= defaults.EFFECT_SHARE * goal)
        assert f"{cost:.1f} ms" in v.panel.effect_lines[1]
        # the user's choice stays through a new view
        was = v.settings.eye_dome
        v.act(Action.EYE_DOME)
        v.act(Action.POINT_BIGGER)
        chosen = v.settings.point_size
        v.orbit = v.navigator.orbit(v.orbit, 30, -10)
        settle(v)
        v.step()
        assert v.settings.eye_dome == (not was) and v.settings.point_size == chosen
        assert v.panel.effect_lines[0].startswith(f"point size {chosen}: your choice")
        assert v.panel.effect_lines[1].startswith("eye-dome lighting " + ("off" if was else "on") + ": your choice")
        v.automatic_effects()
        settle(v)
        v.step()
        assert v.settings.point_size == defaults.point_size(projected_coverage(v)).value
        assert v.settings.eye_dome == was
        no_gl_error(v)
    finally:
        v.close()


def test_options_given_are_not_overridden(display):
    """--point-size 3 and --eye-dome (ViewerOptions) stay what they are."""
    from progressive.viewer.app import Viewer, ViewerOptions

    v = Viewer([str(SAMPLE)], ViewerOptions(SessionOptions(width=W, height=H), point_size=3, eye_dome=True))
    try:
        settle(v)
        v.step()
        assert (v.settings.point_size, v.settings.eye_dome) == (3, True)
        assert "your choice" in v.panel.effect_lines[0] and "your choice" in v.panel.effect_lines[1]
    finally:
        v.close()


@pytest.mark.parametrize("flags", [[], ["--point-size", "1", "--no-eye-dome"]])
def test_point_size_1_and_no_eye_dome_on_the_command_line_stay(display, monkeypatch, flags):
    """`view --point-size 1 --no-eye-dome` keeps 1 pixel and no lighting after the view
    converges, where the rules (as the same view without the flags shows) choose a larger
    size from laspy's coverage and, at a frame goal its measured cost fits, lighting."""
    from progressive.cli import main
    from progressive.effects import Effects
    from progressive.viewer import app, defaults
    from progressive.viewer.controls import BudgetMode

    seen = {}

    def run(self):
        try:
            self.set_budget(BudgetMode.ADAPTIVE, target_fps=2.0)   # a goal eye-dome lighting's cost fits
            settle(self)
            self.step()
            cost = self.session.effect_cost_ms(Effects(1, self.settings.eye_dome_params))["eye_dome"]
            seen.update(settings=self.settings, lines=self.panel.effect_lines,
                        size=defaults.point_size(projected_coverage(self)).value,
                        edl=defaults.eye_dome(False, cost, self.goal_ms).value)
        finally:
            self.close()

    monkeypatch.setattr(app.Viewer, "run", run)
    assert main(["view", str(SAMPLE), "--width", "640", "--height", "360", "--color-by", "elevation", *flags]) == 0
    s, lines = seen["settings"], seen["lines"]
    assert seen["size"] > 1 and seen["edl"] is True
    if flags:
        assert (s.point_size, s.eye_dome) == (1, False)
        assert lines[0].startswith("point size 1: your choice") and lines[1].startswith("eye-dome lighting off: your choice")
    else:
        assert (s.point_size, s.eye_dome) == (seen["size"], True)
        assert "your choice" not in lines[0] + lines[1]


def box_on_screen(v) -> np.ndarray:
    """Screen columns and rows of the cloud's bounding box corners (float64 projection)."""
    xy, depth = screen_points(v.camera, corners(v.session.info.bounds_min, v.session.info.bounds_max),
                              *v.framebuffer_size)
    assert (depth > 0).all()
    return xy


def test_dragging_the_panel_edge_sets_its_width_within_the_clamp(display):
    """A left drag from just right of the panel's edge moves the edge with the cursor,
    clamped to PANEL_MIN_WIDTH .. PANEL_DRAG_MAX_SHARE of the window; at the home view the
    camera frames the box in the area left free after each move, a view the user chose
    stays; the width is kept through Tab and a new file, and imgui docks at it."""
    from progressive.viewer.controls import PANEL_DRAG_MAX_SHARE, PANEL_MIN_WIDTH

    v = open_viewer([SAMPLE], 640, 360)
    try:
        settle(v)
        ww = glfw.get_window_size(v.window)[0]
        scale = v.framebuffer_size[0] / ww
        start = v.panel_units
        assert start > 0 and v.at_home() and not v.on_panel_edge(start - 1) and v.on_panel_edge(start + 2)
        v.on_cursor(v.window, start + 2, 100)           # glfw's callback: the resize cursor over the edge
        assert v._cursor_shown is not None and v._cursor_shown is v._resize_cursor
        v.on_cursor(v.window, start + 40, 100)
        assert v._cursor_shown is None
        v.mouse_button(glfw.MOUSE_BUTTON_LEFT, True, start + 2, 100)
        for dx, expected in ((80, start + 80), (1000, PANEL_DRAG_MAX_SHARE * ww), (-1000, PANEL_MIN_WIDTH),
                             (50, start + 50)):
            v.cursor(start + 2 + dx, 120)
            assert v.panel_units == pytest.approx(expected)
            assert v.at_home() and box_on_screen(v)[:, 0].min() >= v.free_area[0]
        v.mouse_button(glfw.MOUSE_BUTTON_LEFT, False, start + 52, 120)
        finish_reads(v)
        assert v.picked is None and v.dragged_panel == pytest.approx(start + 50)
        settle(v)
        x0, _, x1, y1 = v.free_area
        assert x0 == round((start + 50) * scale) and v.panel.docked[1] * scale == pytest.approx(x0, abs=1)
        xy = box_on_screen(v)
        assert xy[:, 0].min() >= x0 and xy[:, 0].max() <= x1 and xy[:, 1].min() >= 0 and xy[:, 1].max() <= y1
        assert xy[:, 0].max() - xy[:, 0].min() >= 0.85 * (x1 - x0) or xy[:, 1].max() - xy[:, 1].min() >= 0.85 * y1
        assert np.nonzero((v.session.ids() != EMPTY).any(axis=0))[0].min() >= x0
        v.act(Action.PANEL)
        assert v.free_area[0] == 0 and not v.on_panel_edge(start + 52)
        v.act(Action.PANEL)
        assert v.free_area[0] == x0
        v.open([str(SAMPLE)])
        assert v.free_area[0] == x0
        # a view the user chose stays where it is while the edge moves
        v.orbit = v.navigator.orbit(v.orbit, 30, -10)
        chosen = v.orbit
        edge = v.panel_units
        v.mouse_button(glfw.MOUSE_BUTTON_LEFT, True, edge + 1, 100)
        v.cursor(edge + 41, 100)
        v.mouse_button(glfw.MOUSE_BUTTON_LEFT, False, edge + 41, 100)
        finish_reads(v)
        assert v.panel_units == pytest.approx(edge + 40) and v.orbit == chosen
        v.step()
        no_gl_error(v)
    finally:
        v.close()


def test_a_copc_file_streams_in_the_window_and_a_node_that_fails_is_said(display, tmp_path):
    """The window streams a COPC file (view's default): its nodes come as the frames go,
    the still view is the reference over every node that can be read, and the node that
    does not decode is a note in the panel once its read fails, not only at opening."""
    from test_copc import damaged_copc
    from test_copc_stream import assert_exact, las_xyz

    from progressive.session import Streaming

    path, bad, node = damaged_copc(tmp_path)
    _, xyz = las_xyz(path)
    v = open_viewer([bad], stream=Streaming.AUTO)
    try:
        assert v.session.streamed
        v.act(Action.PANEL)
        settle(v)
        assert any("could not be read" in m and f"{node.key.level}-{node.key.x}-{node.key.y}-{node.key.z}" in m
                   for m in v.messages)
        assert_exact(v.session, v.camera, xyz)
        assert v.categories() == v.session.categories()
        no_gl_error(v)
    finally:
        v.close()


def test_the_panel_sets_a_streamed_clouds_finest_detail(display, tmp_path):
    """The finest detail set in the window (the panel's control calls set_stream_detail)
    reaches the session's plan: the still view reads only nodes whose points lie that far
    apart (but for the reads asked for before the setting: those stay), exactly; back at 0 it reads on until the memory is full; a cloud opened next
    starts with the detail set."""
    from test_copc_stream import assert_exact, las_xyz

    from progressive import memory
    from progressive.cli import main
    from progressive.loaders.copc_residency import Status
    from progressive.session import Streaming, node_view

    copc = tmp_path / "sample.copc.laz"
    assert main(["convert", str(SAMPLE), str(copc)]) == 0
    _, xyz = las_xyz(copc)
    v = open_viewer([copc], stream=Streaming.AUTO, gpu_memory_limit=memory.bytes_for(len(xyz) // 2, W * H))
    try:
        v.act(Action.PANEL)
        state = v.session.streamer.state
        asked = set(np.nonzero(state.status != Status.ABSENT)[0].tolist())
        v.set_stream_detail(2.0)
        settle(v)
        rows = np.nonzero(state.status == Status.RESIDENT)[0]
        later = np.array(sorted(set(rows.tolist()) - asked), dtype=np.int64)
        errors = state.nodes.errors(node_view(v.camera, *v.session.size))
        assert rows.size > 0 and (errors[later][state.nodes.level[later] > 0] >= 2.0).all()
        assert_exact(v.session, v.camera, xyz)
        v.set_stream_detail(float("inf"))       # typed in the panel: nothing changes
        assert v.settings.stream_detail_px == 2.0
        v.set_stream_detail(-1.0)       # as 0
        settle(v)
        assert v.settings.stream_detail_px == 0.0
        assert np.count_nonzero(state.status == Status.RESIDENT) > rows.size
        assert_exact(v.session, v.camera, xyz)
        v.set_stream_detail(2.0)
        assert v.open([str(copc)]) and v.session.streamer.state.finest_px == 2.0
        no_gl_error(v)
    finally:
        v.close()
