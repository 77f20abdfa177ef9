"""Screenshots of the viewer for the README: real windows on a private Xvfb display,
captured from the back buffer as drawn (panel included). Run: python docs/screenshots.py"""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

from PIL import Image

HERE = Path(__file__).resolve().parent
SAMPLE = HERE.parent / "progressive" / "data" / "autzen_trim.las"
SIZE = (1100, 640)


def start_display() -> subprocess.Popen:
    read, write = os.pipe()
    proc = subprocess.Popen(["Xvfb", "-displayfd", str(write), "-screen", "0", "1920x1080x24", "-nolisten", "tcp"],
                            pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write)
    with os.fdopen(read) as f:
        os.environ["DISPLAY"] = f":{f.readline().strip()}"
    return proc


def shoot(viewer, name: str, **settings) -> None:
    import glfw

    viewer.settings = replace(viewer.settings, **settings)
    for _ in range(400):
        viewer.step()
        viewer.session.stats()
        switch = viewer.session.status().switch
        if viewer.session.converged and (switch is None or switch.done):
            break
    captured = []
    swap = glfw.swap_buffers
    glfw.swap_buffers = lambda w: (captured.append(viewer.capture_window()), swap(w))
    try:
        viewer.step()
    finally:
        glfw.swap_buffers = swap
    Image.fromarray(captured[-1]).save(HERE / name, optimize=True)
    print(f"wrote {HERE / name}")


def main() -> int:
    proc = start_display()
    try:
        from progressive.session import SessionOptions
        from progressive.viewer.app import Viewer, ViewerOptions
        from progressive.viewer.controls import Action

        v = Viewer([str(SAMPLE)], ViewerOptions(SessionOptions(width=SIZE[0], height=SIZE[1])))
        v.orbit = v.navigator.zoom(v.orbit, 1)       # about the cloud's centre, framed beside the panel
        shoot(v, "viewer-rgb.png")
        shoot(v, "viewer-rgb-edl.png", eye_dome=True, point_size=2)
        v.switch_attribute("classification")
        shoot(v, "viewer-classification.png", eye_dome=False, point_size=1)
        v.switch_attribute("elevation")
        v.act(Action.PANEL)
        v.home()                                      # framed in the whole window
        v.orbit = v.navigator.zoom(v.orbit, 1)
        shoot(v, "viewer-elevation-edl.png", eye_dome=True, point_size=2)
        v.close()
    finally:
        proc.terminate()
    return 0


if __name__ == "__main__":
    sys.exit(main())
