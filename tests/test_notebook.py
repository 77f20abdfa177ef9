"""progressive.show() in Jupyter: the PNG still, the widget's event handlers driven
headless against brute-force renders of the cameras navigation.py gives, the example
notebook executed by nbclient, and one real drag in headless Chromium against a
Jupyter server on 127.0.0.1."""

from __future__ import annotations

import asyncio
import base64
import io
import json
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import laspy
import numpy as np
import pytest
from PIL import Image

from progressive.camera import Camera
from progressive.cli import sample_path
from progressive.effects import Effects, EyeDome
from progressive.notebook import NOTEBOOK_FPS, WHEEL_PIXELS_PER_NOTCH, session_options, show
from progressive.session import Method, Session, SessionOptions
from progressive.viewer.controls import cycle
from progressive.viewer.navigation import ZOOM_STEP

pytest.importorskip("jupyter_rfb")

ROOT = Path(__file__).resolve().parents[1]
SIZE = (192, 128)
MAX_FRAMES = 200


def brute(gl, camera: Camera, color_by: str | None = None, effects: Effects = Effects(),
          hidden=frozenset()) -> tuple[np.ndarray, np.ndarray]:
    """(image, ids) of a brute-force render: every point, one frame."""
    options = SessionOptions(width=SIZE[0], height=SIZE[1], method=Method.BRUTE, color_by=color_by, class_filter=True)
    with Session([str(sample_path())], options, glc=gl) as s:
        s.frame(camera, effects=effects, hidden=hidden)
        return s.image(), s.ids()


def pointer(kind: str, x: float, y: float, button: int = 1, modifiers=()) -> dict:
    return {"type": kind, "x": x, "y": y, "button": button, "buttons": (button,), "modifiers": tuple(modifiers)}


def drag(canvas, x0, y0, x1, y1, button: int = 1) -> None:
    canvas.handle_event(pointer("pointer_down", x0, y0, button))
    canvas.handle_event(pointer("pointer_move", x1, y1, button))
    canvas.handle_event(pointer("pointer_up", x1, y1, button))


class Draws:
    """Counts the canvas's draw requests and serves them as jupyter-rfb's loop would."""

    def __init__(self, canvas):
        self.canvas, self.requested = canvas, 1      # a new view asks for its first frame
        canvas.request_draw = self.request

    def request(self) -> None:
        self.requested += 1

    def run(self) -> tuple[np.ndarray, int]:
        """Draw while draws are requested; (last image, frames drawn)."""
        image, n = None, 0
        while self.requested:
            assert n < MAX_FRAMES, "frames did not stop"
            self.requested = 0
            image, n = self.canvas.get_frame(), n + 1
        return image, n


@pytest.fixture
def view(gl):
    """A widget as show() makes it, on the tests' GL context."""
    session = Session([str(sample_path())], session_options(*SIZE, None, NOTEBOOK_FPS), glc=gl)
    v = show(session, widget=True)
    yield v
    v.close()
    session.close()


def test_still_is_the_brute_force_render(gl):
    """Where widgets are not available (here: no kernel), show() gives the converged
    frame as PNG, for the camera given as JSON."""
    with Session([str(sample_path())], session_options(*SIZE, None, NOTEBOOK_FPS), glc=gl) as s:
        camera = s.auto_camera()
        camera = replace(camera, position=tuple(np.add(camera.position, (30.0, -40.0, 20.0))))
        still = show(s, camera=camera.to_json())
    rgb = np.asarray(Image.open(io.BytesIO(still._repr_png_())).convert("RGB"))
    image, ids = brute(gl, camera)
    assert (ids != 0xFFFFFFFF).mean() > 0.05
    np.testing.assert_array_equal(rgb, image[:, :, :3])


def test_orbit_pan_and_zoom_follow_navigation(view, gl):
    canvas, it = view.canvas, view.interaction
    draws = Draws(canvas)
    before, _ = draws.run()
    home = it.orbit
    drag(canvas, 50, 40, 80, 52)
    assert draws.requested
    orbited = it.navigator.orbit(home, 30, 12)
    assert it.orbit == orbited
    image, _ = draws.run()
    assert (image != before).any()
    np.testing.assert_array_equal(image, brute(gl, it.navigator.camera(orbited))[0])

    drag(canvas, 50, 40, 60, 30, button=2)
    assert it.orbit == it.navigator.pan(orbited, 10, -10, SIZE[1])
    draws.run()
    distance = it.orbit.distance
    canvas.handle_event({"type": "wheel", "x": 96, "y": 64, "dx": 0.0, "dy": -2 * WHEEL_PIXELS_PER_NOTCH,
                         "buttons": (), "modifiers": ()})
    assert it.orbit.distance == pytest.approx(distance * ZOOM_STEP**2, rel=1e-12)
    image, _ = draws.run()
    np.testing.assert_array_equal(image, brute(gl, it.camera)[0])


def test_switch_changes_colours(view, gl):
    canvas, it = view.canvas, view.interaction
    draws = Draws(canvas)
    before, _ = draws.run()
    first = it.session.attribute.name
    canvas.handle_event({"type": "key_down", "key": "]", "modifiers": ()})
    expected = cycle([a.name for a in it.session.info.attributes], first, 1)
    assert it.session.chosen.name == expected != first      # shown once the later pass has read it
    assert view.attribute.value == expected
    image, _ = draws.run()
    assert (image != before).any()
    np.testing.assert_array_equal(image, brute(gl, it.camera, color_by=expected)[0])


def test_frames_stop_when_converged_and_still(view):
    canvas, it = view.canvas, view.interaction
    draws = Draws(canvas)
    _, n = draws.run()
    assert 1 <= n < MAX_FRAMES and not it.animating
    assert it.session.converged
    canvas.get_frame()               # a draw served late: nothing runs, nothing more is asked for
    assert it.last_passes == () and draws.requested == 0
    canvas.handle_event(pointer("pointer_move", 10, 10))     # no button down: nothing changes
    assert draws.requested == 0
    canvas.handle_event({"type": "key_down", "key": "r", "modifiers": ()})
    assert draws.requested


def test_classes_point_size_and_eye_dome(view, gl):
    canvas, it = view.canvas, view.interaction
    draws = Draws(canvas)
    draws.run()
    codes = view.interaction.classes()
    classification = np.asarray(laspy.read(sample_path()).classification)
    assert codes == sorted(np.unique(classification).tolist())
    assert [b.description.split()[0] for b in view.class_box.children] == [str(c) for c in codes]
    view.class_box.children[codes.index(2)].value = False          # the ground's toggle
    assert it.settings.hidden_classes == {2}
    _, ids = brute(gl, it.camera, hidden=frozenset({2}))
    draws.run()
    shown = it.session.ids()
    np.testing.assert_array_equal(shown, ids)
    drawn = shown[shown != 0xFFFFFFFF]
    assert drawn.size and not (classification[drawn] == 2).any()

    view.hide_classes(())
    canvas.handle_event({"type": "key_down", "key": "+", "modifiers": ()})
    canvas.handle_event({"type": "key_down", "key": "e", "modifiers": ()})
    assert view.point_size.value == 2 and view.eye_dome.value
    image, _ = draws.run()
    np.testing.assert_array_equal(image, brute(gl, it.camera, effects=Effects(2, EyeDome()))[0])


def test_events_on_another_thread_run_on_the_views(gl):
    """ipykernel 7 may deliver widget messages on a subshell's thread: the GL work they
    ask for runs on the thread (and event loop) the view was made on, in order."""

    async def main():
        session = Session([str(sample_path())], session_options(*SIZE, None, NOTEBOOK_FPS), glc=gl)
        v = show(session, widget=True)
        frames, sent = [], []
        frame = v.interaction.frame
        v.interaction.frame = lambda: (frames.append(threading.get_ident()), frame())[1]
        v.canvas.send_frame = sent.append
        home = v.interaction.orbit
        returned = []
        other = threading.Thread(target=lambda: (drag(v.canvas, 50, 40, 80, 52), returned.append(v.canvas.get_frame())))
        other.start()
        other.join()
        for _ in range(100):
            if sent:
                break
            await asyncio.sleep(0.01)
        assert returned == [None] and frames == [threading.get_ident()] and len(sent) == 1
        assert v.interaction.orbit == v.interaction.navigator.orbit(home, 30, 12)
        v.close()
        session.close()

    asyncio.run(main())


def test_example_notebook_runs():
    """docs/notebook.ipynb as CI runs it: every cell, the stills and the accuracy plot."""
    nbformat = pytest.importorskip("nbformat")
    from nbclient import NotebookClient

    path = ROOT / "docs" / "notebook.ipynb"
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=180, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    widgets = [o for o in outputs if "application/vnd.jupyter.widget-view+json" in o.get("data", {})]
    pngs = [Image.open(io.BytesIO(base64.b64decode(o["data"]["image/png"]))) for o in outputs
            if "image/png" in o.get("data", {})]
    assert widgets and len(pngs) == 3
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    assert "shuffled: exact after" in text and "file: exact after" in text
    assert all(np.asarray(p.convert("RGB")).std() > 0 for p in pngs)


# ---- a real browser -------------------------------------------------------------------

BROWSER_SECONDS = 120          # the whole browser test gives up after this
BROWSER_NOTEBOOK = {
    "cells": [{"cell_type": "code", "execution_count": None, "id": "view", "metadata": {}, "outputs": [],
               "source": "import progressive\nview = progressive.show(width=320, height=240)\nview"}],
    "metadata": {"kernelspec": {"name": "python3", "display_name": "Python 3", "language": "python"}},
    "nbformat": 4, "nbformat_minor": 5,
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def until(what, deadline: float, message: str, step: float = 0.25):
    while True:
        value = what()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(message)
        time.sleep(step)


@pytest.fixture
def jupyter_server(tmp_path):
    """JupyterLab on 127.0.0.1 with a one-cell notebook; its own config and runtime dirs."""
    port, token = free_port(), "progressive-test"
    (tmp_path / "view.ipynb").write_text(json.dumps(BROWSER_NOTEBOOK))
    env = {**os.environ, "JUPYTER_CONFIG_DIR": str(tmp_path / "config"), "JUPYTER_RUNTIME_DIR": str(tmp_path / "runtime"),
           "IPYTHONDIR": str(tmp_path / "ipython")}
    log = (tmp_path / "server.log").open("w")
    server = subprocess.Popen(
        [sys.executable, "-m", "jupyterlab", "--no-browser", "--allow-root", "--ServerApp.ip=127.0.0.1",
         f"--ServerApp.port={port}", "--ServerApp.port_retries=0", f"--IdentityProvider.token={token}",
         f"--ServerApp.root_dir={tmp_path}", "--LabApp.expose_app_in_browser=True",
         "--LabApp.news_url=", "--LabApp.check_for_updates_class=jupyterlab.NeverCheckForUpdate"],
        cwd=tmp_path, env=env, stdout=log, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 60
        until(lambda: server.poll() is not None or _listening(port), deadline, "the Jupyter server did not start")
        assert server.poll() is None, (tmp_path / "server.log").read_text()
        yield f"http://127.0.0.1:{port}/lab/tree/view.ipynb?token={token}"
    finally:
        server.terminate()
        try:
            server.wait(10)
        except subprocess.TimeoutExpired:
            server.kill()
        log.close()


def _listening(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def canvas_image(element) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(element.screenshot_as_png)).convert("RGB")).astype(np.int16)


@pytest.mark.skipif(not (shutil.which("chromium") and shutil.which("chromedriver")),
                    reason="Debian's chromium and chromium-driver (scripts/setup.sh installs them)")
def test_drag_in_a_real_browser(jupyter_server, tmp_path):
    """Headless Chromium opens the notebook in JupyterLab and runs it: the canvas shows
    the cloud, and a left drag on it changes what it shows."""
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    deadline = time.monotonic() + BROWSER_SECONDS
    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium")
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1200,900",
                f"--user-data-dir={tmp_path / 'chromium'}"):
        options.add_argument(arg)
    driver = webdriver.Chrome(options=options, service=webdriver.ChromeService(shutil.which("chromedriver")))
    try:
        driver.set_script_timeout(60)
        driver.get(jupyter_server)
        until(lambda: driver.execute_script(
            "const a = window.jupyterapp; const w = a && a.shell.currentWidget;"
            "return !!(w && w.sessionContext && w.sessionContext.session && w.sessionContext.session.kernel"
            " && w.sessionContext.session.kernel.status === 'idle');"), deadline, "the notebook's kernel did not start")
        driver.execute_script("window.jupyterapp.commands.execute('notebook:run-all-cells');")
        canvas = until(lambda: driver.find_elements(By.CSS_SELECTOR, "img.renderview-view"), deadline,
                       "no canvas appeared")[0]

        def lit(image: np.ndarray) -> float:
            return float((image.max(axis=2) > 40).mean())

        until(lambda: lit(canvas_image(canvas)) > 0.05, deadline, "the canvas does not show the cloud")
        shots = [canvas_image(canvas)]

        def steady() -> bool:        # converged, and jupyter-rfb's lossless frame arrived: two shots alike
            time.sleep(0.5)
            shots.append(canvas_image(canvas))
            return np.array_equal(shots[-1], shots[-2])

        until(steady, deadline, "the canvas never came to rest", step=0)
        before = shots[-1]
        ActionChains(driver).move_to_element(canvas).click_and_hold().move_by_offset(60, 25).move_by_offset(40, 10) \
            .release().perform()
        until(lambda: np.abs(canvas_image(canvas) - before).max(axis=2).mean() > 5, deadline,
              "the drag did not change the canvas")
        after = canvas_image(canvas)
        assert lit(after) > 0.05
        if os.environ.get("PROGRESSIVE_BROWSER_SHOTS"):
            for name, image in (("before", before), ("after", after)):
                Image.fromarray(image.astype(np.uint8)).save(Path(os.environ["PROGRESSIVE_BROWSER_SHOTS"]) / f"{name}.png")
            driver.save_screenshot(str(Path(os.environ["PROGRESSIVE_BROWSER_SHOTS"]) / "page.png"))
    finally:
        driver.quit()
