"""`progressive.show()`: the viewer in a Jupyter notebook. The kernel renders headless
with a Session (GPU or llvmpipe) and jupyter-rfb carries the frames to the browser and
mouse and keys back; gestures go through the window's navigation
(progressive/viewer/navigation.py) and settings (viewer/controls.py). jupyter-rfb sends
a frame only when the browser has taken the ones in flight, and each frame fills what
the adaptive budget fits in its frame time, so frames follow what the connection takes
and a still view converges in as few of them as the GPU allows. Where widgets are not
available, show() returns the converged frame as PNG."""

from __future__ import annotations

import asyncio
import functools
import io
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from progressive.budget import BudgetParams
from progressive.camera import Camera
from progressive.colors import ASPRS_CLASSES, UNKNOWN_CLASS
from progressive.errors import ProgressiveError
from progressive.session import PICK_RADIUS, Session, SessionOptions
from progressive.viewer.controls import KEYS, VIEW_ACTIONS, Action, ViewSettings, cycle
from progressive.viewer.navigation import Navigator, Orbit

NOTEBOOK_FPS = 30.0
"""The adaptive budget's frame rate: frames travel as JPEG over the kernel's websocket."""
WHEEL_PIXELS_PER_NOTCH = 100.0     # what browsers report for one wheel notch (deltaMode pixels)
STILL_MAX_FRAMES = 2000            # a PNG still gives up converging after this many frames
STATUS_SECONDS = 0.25              # how often the status line is sent while frames run

BROWSER_KEYS: dict[str, Action] = {
    **{name.lower(): action for name, action in KEYS.items() if len(name) == 1},
    **{name: action for name, action in KEYS.items() if len(name) == 1}, "=": Action.POINT_BIGGER,
}
"""Browser key names (jupyter-rfb passes KeyboardEvent.key) onto the window's actions."""
NOTEBOOK_ACTIONS = frozenset({Action.RESET, Action.POINT_BIGGER, Action.POINT_SMALLER, Action.PREVIOUS_ATTRIBUTE,
                              Action.NEXT_ATTRIBUTE, Action.EYE_DOME, Action.PROJECTION, *VIEW_ACTIONS})
"""The window's actions that mean something in a notebook (no panel, files, clipboard or quit)."""


class Button:
    """jupyter-rfb's pointer buttons."""

    LEFT = 1
    RIGHT = 2
    MIDDLE = 3


@dataclass(frozen=True)
class Still:
    """A rendered frame as PNG: what show() gives where widgets are not available."""

    png: bytes

    def _repr_png_(self) -> bytes:
        return self.png

    def save(self, path: str | Path) -> None:
        Path(path).write_bytes(self.png)


def png_bytes(rgba: np.ndarray) -> bytes:
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgba[:, :, :3]), mode="RGB").save(out, format="PNG")
    return out.getvalue()


class Interaction:
    """A session, its navigation and settings, and what browser events do to them. No
    widget in here: the canvas and the PNG still share it, and tests drive it headless."""

    def __init__(self, session: Session, camera: Camera | None = None, settings: ViewSettings | None = None):
        self.session = session
        w, h = session.size
        self.navigator = Navigator.for_bounds(session.info.bounds_min, session.info.bounds_max, w / h)
        self.pasted = camera
        self.orbit = Orbit.from_camera(camera) if camera is not None else self.navigator.home
        self.settings = settings or ViewSettings(attribute=session.attribute.name, target_fps=NOTEBOOK_FPS)
        self.logical = (float(w), float(h))     # the canvas's size in CSS pixels (events come in those)
        self._drag: tuple[int, float, float] | None = None
        self.last_passes: tuple[str, ...] | None = None    # the passes of the last frame; None before the first
        self.error: str | None = None

    @property
    def camera(self) -> Camera:
        return self.pasted or self.navigator.camera(self.orbit)

    def _moved(self, orbit: Orbit) -> None:
        self.orbit, self.pasted = orbit, None

    def to_image(self, x: float, y: float) -> tuple[float, float]:
        w, h = self.session.size
        return x * w / max(self.logical[0], 1e-6), y * h / max(self.logical[1], 1e-6)

    # ---- events -----------------------------------------------------------------
    def handle(self, event: dict) -> bool:
        """Apply one jupyter-rfb event; True when the view changed (a frame is due)."""
        kind = event.get("type") or event.get("event_type")
        if kind == "resize":
            return self.resize(event["width"], event["height"])
        if kind == "pointer_down":
            button = event.get("button", 0)
            if button in (Button.LEFT, Button.RIGHT, Button.MIDDLE):
                pan = button != Button.LEFT or "Shift" in event.get("modifiers", ())
                self._drag = (Button.RIGHT if pan else Button.LEFT, event["x"], event["y"])
            return False
        if kind == "pointer_up":
            self._drag = None
            return False
        if kind == "pointer_move":
            return self.drag_to(event["x"], event["y"])
        if kind == "wheel":
            return self.zoom(-event.get("dy", 0.0) / WHEEL_PIXELS_PER_NOTCH, event["x"], event["y"])
        if kind == "double_click":
            return self.focus(event["x"], event["y"])
        if kind == "key_down":
            action = BROWSER_KEYS.get(event.get("key", ""))
            if action is not None and action in NOTEBOOK_ACTIONS and not set(event.get("modifiers", ())) & {"Control", "Meta"}:
                return self.act(action)
        return False

    def resize(self, width: float, height: float) -> bool:
        self.logical = (float(width), float(height))
        size = (max(1, round(width)), max(1, round(height)))
        if size == self.session.size:
            return False
        self.session.resize(*size)
        return True

    def drag_to(self, x: float, y: float) -> bool:
        if self._drag is None:
            return False
        button, x0, y0 = self._drag
        self._drag = (button, x, y)
        (ix, iy), (ix0, iy0) = self.to_image(x, y), self.to_image(x0, y0)
        dx, dy = ix - ix0, iy - iy0
        if dx == 0 and dy == 0:
            return False
        nav = self.navigator
        self._moved(nav.orbit(self.orbit, dx, dy) if button == Button.LEFT else
                    nav.pan(self.orbit, dx, dy, self.session.size[1]))
        return True

    def zoom(self, notches: float, x: float, y: float) -> bool:
        """About the point under the cursor (else about the target's depth), as in the window."""
        if notches == 0:
            return False
        ix, iy = self.to_image(x, y)
        hit = self.session.nearest_shown(ix, iy, PICK_RADIUS)
        depth = hit[1] if hit is not None else self.orbit.distance
        anchor = self.navigator.cursor_point(self.orbit, ix, iy, self.session.size, depth)
        self._moved(self.navigator.zoom(self.orbit, notches, anchor))
        return True

    def focus(self, x: float, y: float) -> bool:
        hit = self.session.nearest_shown(*self.to_image(x, y), PICK_RADIUS)
        if hit is None:
            return False
        self._moved(self.navigator.focus(self.orbit, self.session.point(hit[0])))
        return True

    def act(self, action: Action) -> bool:
        s = self.settings
        if action is Action.RESET:
            self._moved(self.navigator.home)
        elif action is Action.POINT_BIGGER:
            self.settings = s.point_size_by(1)
        elif action is Action.POINT_SMALLER:
            self.settings = s.point_size_by(-1)
        elif action in (Action.NEXT_ATTRIBUTE, Action.PREVIOUS_ATTRIBUTE):
            names = [a.name for a in self.session.info.attributes]
            return self.switch_attribute(cycle(names, s.attribute, 1 if action is Action.NEXT_ATTRIBUTE else -1))
        elif action is Action.EYE_DOME:
            self.settings = replace(s, eye_dome=not s.eye_dome)
        elif action is Action.PROJECTION:
            self._moved(replace(self.orbit, orthographic=not self.orbit.orthographic))
        elif action in VIEW_ACTIONS:
            self._moved(self.navigator.preset(self.orbit, VIEW_ACTIONS[action]))
        return True

    # ---- settings ---------------------------------------------------------------
    def switch_attribute(self, name: str) -> bool:
        if name == self.session.chosen.name:
            return False
        try:
            self.session.switch_attribute(name)
        except ProgressiveError as exc:
            self.error = str(exc)
            return False
        self.error = None
        hidden = self.settings.hidden_classes if self.session.filters_classes else frozenset()
        self.settings = replace(self.settings, attribute=self.session.chosen.name,
                                value_range=None, hidden_classes=hidden)
        return True

    def set_hidden(self, codes) -> bool:
        hidden = frozenset(int(c) for c in codes)
        changed = hidden != self.settings.hidden_classes
        self.settings = replace(self.settings, hidden_classes=hidden)
        return changed

    def set_point_size(self, size: int) -> bool:
        before = self.settings.point_size
        self.settings = self.settings.point_size_by(int(size) - before)
        return self.settings.point_size != before

    def set_eye_dome(self, on: bool) -> bool:
        changed = bool(on) != self.settings.eye_dome
        self.settings = replace(self.settings, eye_dome=bool(on))
        return changed

    def classes(self) -> list[int]:
        """Classification codes present once loaded (for toggles); [] while loading or
        where no classes can be filtered."""
        s = self.session
        if s.status().loading or not (s.filters_classes or s.attribute.name == "classification"):
            return []
        return s.categories()

    # ---- frames -----------------------------------------------------------------
    def frame(self) -> np.ndarray:
        """One progressive frame of the current view; (H, W, 4) uint8, row 0 at the top."""
        s, st = self.session, self.settings
        self.last_passes = s.frame(self.camera, s.style(st.colormap, st.value_range, st.background), st.effects,
                                   st.hidden_classes)
        return s.image()

    @property
    def animating(self) -> bool:
        """Another frame would change the image: the last one ran passes (a progressive
        frame runs none once the view is exact and nothing changed), or points are still
        to load. A brute-force session renders everything in one frame."""
        if self.last_passes is None or not self.session.progressive:
            return self.last_passes is None
        return bool(self.last_passes) or self.session.status().loading

    def still(self, max_frames: int = STILL_MAX_FRAMES) -> np.ndarray:
        """Frames until the view is exact (or `max_frames`), then the image."""
        image = self.frame()
        frames = 1
        while frames < max_frames and self.animating:
            image = self.frame()
            frames += bool(self.last_passes)       # frames that rested while points load do not count
        return image


class Owner:
    """The thread that made the view, whose GL context is current there, and its event
    loop. ipykernel 7 may deliver widget messages on a subshell's thread; GL work they
    ask for is handed to this loop, in order."""

    def __init__(self):
        self.thread = threading.get_ident()
        try:
            self.loop: asyncio.AbstractEventLoop | None = asyncio.get_running_loop()
        except RuntimeError:
            self.loop = None

    @property
    def here(self) -> bool:
        return self.loop is None or threading.get_ident() == self.thread

    def run(self, fn, *args) -> None:
        if self.here:
            fn(*args)
        else:
            self.loop.call_soon_threadsafe(fn, *args)


def widgets_available() -> bool:
    """A Jupyter kernel (a front end may show widgets) with jupyter-rfb installed."""
    try:
        import jupyter_rfb  # noqa: F401
        from IPython import get_ipython
    except ImportError:
        return False
    shell = get_ipython()
    return shell is not None and getattr(shell, "kernel", None) is not None


def open_session(source, width: int, height: int, color_by: str | None, target_fps: float) -> tuple[Session, bool]:
    """(session, owned): a Session as given (its budget set to the notebook's rate), or one
    opened on a path or paths (the bundled sample by default), switchable and with classes."""
    if isinstance(source, Session):
        source.set_budget(BudgetParams(target_ns=int(1e9 / target_fps)))
        if color_by:
            source.switch_attribute(color_by)
        return source, False
    if source is None:
        from progressive.cli import sample_path

        paths = [str(sample_path())]
    elif isinstance(source, str | Path):
        paths = [str(source)]
    else:
        paths = [str(p) for p in source]
    return Session(paths, session_options(width, height, color_by, target_fps)), True


def session_options(width: int, height: int, color_by: str | None, target_fps: float) -> SessionOptions:
    """What show() opens files with: attributes kept to switch, classes kept to toggle, and
    the adaptive budget at `target_fps`."""
    options = SessionOptions(width=width, height=height, color_by=color_by, switchable=True, class_filter=True)
    return replace(options, progressive=replace(options.progressive, budget=BudgetParams(target_ns=int(1e9 / target_fps))))


def show(source=None, width: int = 800, height: int = 450, color_by: str | None = None,
         camera: Camera | str | None = None, target_fps: float = NOTEBOOK_FPS, widget: bool | None = None):
    """An interactive view of a point cloud in Jupyter: `source` is a path, a list of paths
    (one cloud) or an open Session (default: the bundled sample); `camera` a Camera or the
    render contract's JSON (default: the auto camera). Left drag orbits, right (or Shift)
    drag pans, the wheel zooms to the cursor, double-click focuses; keys as in the window
    ([ ] attribute, + - point size, E eye-dome lighting, R reset, 1-4 views, O projection).
    Returns a NotebookView widget, or a Still (PNG of the converged frame) where widgets
    are not available (`widget=False` asks for the still)."""
    if isinstance(camera, str):
        camera = Camera.from_json(camera)
    session, owned = open_session(source, width, height, color_by, target_fps)
    interaction = Interaction(session, camera, ViewSettings(attribute=session.attribute.name, target_fps=target_fps))
    if widget is False or (widget is None and not widgets_available()):
        try:
            return Still(png_bytes(interaction.still()))
        finally:
            if owned:
                session.close()
    return NotebookView(interaction, owned)


@functools.cache
def widget_classes():
    """(Canvas, View): the widget classes, defined where jupyter-rfb is imported (an optional extra)."""
    import ipywidgets
    from jupyter_rfb import RemoteFrameBuffer

    class Canvas(RemoteFrameBuffer):
        """The frame buffer: events change the interaction, each draw runs one frame and
        asks for the next while the image still changes (none once converged and still)."""

        def __init__(self, interaction: Interaction, on_frame, owner: Owner, **kwargs):
            super().__init__(**kwargs)
            self.interaction = interaction
            self.on_frame = on_frame
            self.owner = owner
            self.frames = 0

        def handle_event(self, event: dict) -> None:
            self.owner.run(self._handle, event)

        def _handle(self, event: dict) -> None:
            if self.interaction.handle(event):
                self.request_draw()
            if event.get("type") == "key_down":
                self.on_frame(force=True)

        def get_frame(self) -> np.ndarray | None:
            """The frame, or, asked on another thread than the context's, None now and the
            frame sent from the context's thread (jupyter-rfb's asynchronous draw)."""
            if self.owner.here:
                return self._render()
            self.owner.run(lambda: self.send_frame(self._render()))
            return None

        def _render(self) -> np.ndarray:
            image = self.interaction.frame()
            self.frames += 1
            if self.interaction.animating:
                self.request_draw()
            self.on_frame()
            return image

    class View(ipywidgets.VBox):
        """The canvas, a row of controls (attribute, point size, eye-dome lighting), the
        classification toggles once the cloud has loaded, and a status line."""

        def __init__(self, interaction: Interaction, owned: bool):
            self.interaction = interaction
            self._owned = owned
            w, h = interaction.session.size
            s = interaction.settings
            self.owner = Owner()
            self.canvas = Canvas(interaction, self._sync, self.owner, css_width=f"{w}px", css_height=f"{h}px", resizable=False)
            names = [a.name for a in interaction.session.info.attributes]
            self.attribute = ipywidgets.Dropdown(options=names, value=s.attribute, description="attribute")
            self.point_size = ipywidgets.BoundedIntText(value=s.point_size, min=1, max=32, description="point size",
                                                        layout=ipywidgets.Layout(width="160px"))
            self.eye_dome = ipywidgets.Checkbox(value=s.eye_dome, description="eye-dome lighting", indent=False)
            self.class_box = ipywidgets.HBox(layout=ipywidgets.Layout(flex_flow="row wrap"))
            self.status = ipywidgets.Label()
            self._class_buttons: dict[int, ipywidgets.ToggleButton] = {}
            self._status_time = 0.0
            self._syncing = False
            self.attribute.observe(lambda c: self._control(self.interaction.switch_attribute, c["new"]), names="value")
            self.point_size.observe(lambda c: self._control(self.interaction.set_point_size, c["new"]), names="value")
            self.eye_dome.observe(lambda c: self._control(self.interaction.set_eye_dome, c["new"]), names="value")
            super().__init__([ipywidgets.HBox([self.attribute, self.point_size, self.eye_dome]), self.canvas,
                              self.class_box, self.status])
            self.canvas.request_draw()

        @property
        def session(self) -> Session:
            return self.interaction.session

        def _control(self, change, value) -> None:
            if not self._syncing:
                self.owner.run(self._change, change, value)

        def _change(self, change, value) -> None:
            if change(value):
                self.canvas.request_draw()
            self._sync(force=True)

        def _sync(self, force: bool = False) -> None:
            """Controls follow the settings (keys change them too); the status line and the
            class toggles follow the session, at most every STATUS_SECONDS while frames run."""
            now = time.perf_counter()
            if not force and now - self._status_time < STATUS_SECONDS and self.interaction.animating:
                return
            self._status_time = now
            s, it = self.interaction.settings, self.interaction
            self._syncing = True
            try:
                self.attribute.value, self.point_size.value, self.eye_dome.value = s.attribute, s.point_size, s.eye_dome
                codes = it.classes()
                if codes and list(self._class_buttons) != codes:
                    self._class_buttons = {c: self._class_button(c) for c in codes}
                    self.class_box.children = tuple(self._class_buttons.values())
                for code, button in self._class_buttons.items():
                    button.value = code not in s.hidden_classes
            finally:
                self._syncing = False
            status = self.session.status()
            state = "exact" if not it.animating else ("loading" if status.loading else "converging")
            stats = self.canvas.get_stats()
            self.status.value = (f"{status.loaded:,} of {status.points:,} points · {state} · frame {self.canvas.frames} · "
                                 f"{stats['fps']:.1f} frames/s to the browser · {status.raster}"
                                 + (f" · {it.error}" if it.error else ""))

        def _class_button(self, code: int):
            name, rgb = ASPRS_CLASSES.get(code, (f"class {code}", UNKNOWN_CLASS))
            button = ipywidgets.ToggleButton(value=True, description=f"{code} {name}",
                                             tooltip=f"show or hide class {code}",
                                             layout=ipywidgets.Layout(width="auto"))
            button.style.button_color = "#" + "".join(f"{c:02x}" for c in rgb)
            button.observe(lambda c: self._control(lambda shown: self._toggle(code, shown), c["new"]), names="value")
            return button

        # ---- the Python side of the same controls ---------------------------------
        def switch_attribute(self, name: str) -> None:
            """Colour by another attribute (no reload)."""
            if self.interaction.switch_attribute(name):
                self.canvas.request_draw()
            elif self.interaction.error:
                raise ProgressiveError(self.interaction.error)
            self._sync(force=True)

        def hide_classes(self, codes) -> None:
            if self.interaction.set_hidden(codes):
                self.canvas.request_draw()
            self._sync(force=True)

        def toggle_class(self, code: int) -> None:
            """Show a hidden class, hide a shown one."""
            self.hide_classes(self.interaction.settings.hidden_classes ^ {int(code)})

        def _toggle(self, code: int, shown: bool) -> bool:
            hidden = set(self.interaction.settings.hidden_classes)
            (hidden.discard if shown else hidden.add)(code)
            return self.interaction.set_hidden(hidden)

        def set_camera(self, camera: Camera | str) -> None:
            camera = Camera.from_json(camera) if isinstance(camera, str) else camera
            self.interaction.pasted, self.interaction.orbit = camera, Orbit.from_camera(camera)
            self.canvas.request_draw()

        @property
        def camera(self) -> Camera:
            return self.interaction.camera

        def still(self, max_frames: int = STILL_MAX_FRAMES) -> Still:
            """The current view converged, as PNG (also what a saved notebook keeps)."""
            return Still(png_bytes(self.interaction.still(max_frames)))

        def close(self) -> None:
            self.canvas.close()
            super().close()
            if self._owned:
                self.interaction.session.close()      # closing twice is harmless

    return Canvas, View


def NotebookView(interaction: Interaction, owned: bool = False):  # noqa: N802 (a class, defined on first use)
    """The interactive view widget (an ipywidgets.VBox around a jupyter-rfb canvas)."""
    return widget_classes()[1](interaction, owned)
