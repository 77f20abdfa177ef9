"""The viewer: a glfw window over a Session. Input maps to float64 navigation, each
loop runs one progressive frame and presents it; files dropped in open (or add) in
a new session, and any bad input ends as a message in the window, never a crash."""

from __future__ import annotations

import enum
import math
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, replace
from pathlib import Path

import glfw
import numpy as np

from progressive.budget import BudgetParams
from progressive.camera import NO_CLIP, Camera, CameraError, Clip, Returns, Section
from progressive.colors import Colormap
from progressive.context import Backend, GLContext, create_context
from progressive.effects import Effects, EyeDome
from progressive.errors import ProgressiveError
from progressive.loaders.types import AttributeKind
from progressive.measure import Measurement
from progressive.output import write_png
from progressive.passes.present import PresentPass
from progressive.session import Session, SessionOptions
from progressive.viewer import clipbox, defaults
from progressive.viewer.controls import (
    PANEL_EDGE_GRAB,
    SECTION_WIDTH_SHARE,
    VIEW_ACTIONS,
    Action,
    BudgetMode,
    ViewSettings,
    cycle,
    docked_width,
)
from progressive.viewer.navigation import Navigator, Orbit

DOUBLE_CLICK_SECONDS = 0.35
DOUBLE_CLICK_PIXELS = 4.0
MESSAGE_SECONDS = 12.0         # how long a note stays in the panel
CURSOR_SEARCH = 7              # pixels around the cursor searched for a point (zoom, focus)
IDLE_WAIT_SECONDS = 0.05       # idle (Session.idle) and no input: wait for events instead of spinning
READ_WAIT_SECONDS = 0.05
"""How long a click waits on the window's thread for its point read back from the file:
a local file's read is done by then; a slower one (a COPC node over HTTP) finishes on
the reader thread while the window keeps drawing."""
HISTOGRAM_BINS = 64
SCALE_BAR_PIXELS = 160         # the scale bar is the longest 1, 2 or 5 x 10^k file units shorter than this
UNIT_SYMBOLS = {"metre": "m", "foot": "ft", "US survey foot": "ftUS", "kilometre": "km"}

GLFW_KEYS: dict[int, Action] = {
    glfw.KEY_R: Action.RESET, glfw.KEY_P: Action.SCREENSHOT, glfw.KEY_EQUAL: Action.POINT_BIGGER,
    glfw.KEY_KP_ADD: Action.POINT_BIGGER, glfw.KEY_MINUS: Action.POINT_SMALLER, glfw.KEY_KP_SUBTRACT: Action.POINT_SMALLER,
    glfw.KEY_LEFT_BRACKET: Action.PREVIOUS_ATTRIBUTE, glfw.KEY_RIGHT_BRACKET: Action.NEXT_ATTRIBUTE,
    glfw.KEY_E: Action.EYE_DOME, glfw.KEY_H: Action.HELP, glfw.KEY_TAB: Action.PANEL, glfw.KEY_F: Action.FLY,
    glfw.KEY_ESCAPE: Action.QUIT, glfw.KEY_Q: Action.QUIT, glfw.KEY_O: Action.PROJECTION,
    glfw.KEY_1: Action.VIEW_TOP, glfw.KEY_2: Action.VIEW_FRONT, glfw.KEY_3: Action.VIEW_SIDE, glfw.KEY_4: Action.VIEW_ISO,
}
CTRL_KEYS: dict[int, Action] = {glfw.KEY_C: Action.COPY_CAMERA, glfw.KEY_V: Action.PASTE_CAMERA}
FLY_KEYS: dict[int, tuple[float, float, float]] = {
    glfw.KEY_W: (1, 0, 0), glfw.KEY_S: (-1, 0, 0), glfw.KEY_D: (0, 1, 0), glfw.KEY_A: (0, -1, 0),
    glfw.KEY_SPACE: (0, 0, 1), glfw.KEY_Z: (0, 0, -1),
}


@dataclass(frozen=True)
class ViewerOptions:
    session: SessionOptions = SessionOptions()   # size, colouring, loading, memory (size: the window's first)
    point_size: int | None = None       # the first point size; None: viewer/defaults.py chooses
    eye_dome: bool | None = None        # eye-dome lighting on or off; None: viewer/defaults.py chooses
    eye_dome_params: EyeDome = EyeDome()
    hidden_classes: frozenset[int] = frozenset()
    clip: Clip = NO_CLIP                # the first clip box (file coordinates)
    returns: Returns = Returns.ALL      # the first return filter
    ui: bool = True                    # the Dear ImGui panel
    visible: bool = True               # tests run hidden windows too
    screenshot_dir: Path = Path(".")


def display_refresh_hz(default: float = 60.0) -> float:
    """The primary monitor's refresh rate: the adaptive budget's frame target."""
    monitor = glfw.get_primary_monitor()
    mode = glfw.get_video_mode(monitor) if monitor else None
    return float(mode.refresh_rate) if mode and mode.refresh_rate > 0 else default


class DragKind(enum.Enum):
    ORBIT = "orbit"
    PAN = "pan"
    LOOK = "look"      # fly mode: turn about the camera
    CLIP_FACE = "clip face"   # move a face of the clip box along its normal
    PANEL_EDGE = "panel edge"  # set the docked panel's width


@dataclass(frozen=True)
class FaceDrag:
    """What a clip face drag started from: the face, its centre and bound, and where
    the pressed cursor's ray met the face's axis (clipbox.along_axis)."""

    face: clipbox.Face
    centre: tuple[float, float, float]
    bound: float
    along: float


@dataclass(frozen=True)
class PanelDrag:
    """What a drag of the panel's edge started from: its width (screen units), and
    whether the camera was at the home view, which then follows the free area."""

    width: float
    home: bool


@dataclass(frozen=True)
class Drag:
    kind: DragKind
    x: float
    y: float
    face: FaceDrag | None = None
    panel: PanelDrag | None = None


class Viewer:
    def __init__(self, paths: list[str], options: ViewerOptions = ViewerOptions()):
        self.options = options
        self.glc: GLContext = create_context(Backend.WINDOW, size=(options.session.width, options.session.height),
                                             title="progressive", visible=options.visible)
        self.window = self.glc.window
        glfw.swap_interval(1)
        self.present = PresentPass(self.glc)
        size = 1 if options.point_size is None else options.point_size     # the rules start from 1 pixel
        self.settings = ViewSettings(target_fps=display_refresh_hz(), point_size=size,
                                     eye_dome=bool(options.eye_dome), eye_dome_params=options.eye_dome_params,
                                     stream_detail_px=options.session.stream_detail_px)
        # the rules of viewer/defaults.py choose what the options leave as None, until
        # the user changes it (keys, panel); each choice keeps its reason
        self.auto_point_size = options.point_size is None
        self.auto_eye_dome = options.eye_dome is None
        self.point_size_choice: defaults.Choice | None = None
        self.eye_dome_choice: defaults.Choice | None = None
        self.eye_dome_cost: tuple[tuple[int, int], float] | None = None   # (size, ms) measured
        self._applied = (self.settings.point_size, self.settings.eye_dome)
        self._defaults_key: tuple | None = None
        self.session: Session | None = None
        self.paths: list[str] = []
        self.navigator: Navigator | None = None
        self.orbit: Orbit | None = None
        self.pasted: Camera | None = None
        self.messages: list[str] = []
        self._message_times: list[float] = []
        self._said: set[str] = set()       # the session's warnings shown so far
        self.error: str | None = None
        self.running = True
        self.frames = 0
        self.last_passes: tuple[str, ...] = ()
        self.last_focus: np.ndarray | None = None
        self.picked: dict | None = None     # Session.pick's record of the last clicked point
        self._reader: ThreadPoolExecutor | None = None      # reads picked points off the window's thread
        self._reading: tuple[Future, Callable, Session] | None = None   # the read under way, what takes its result
        self.measurement = Measurement(())  # Shift+clicked points
        self.last_screenshot: Path | None = None
        self._drag: Drag | None = None
        self.dragged_panel: float | None = None    # the panel width dragged (screen units), kept while the viewer runs
        self._resize_cursor = glfw.create_standard_cursor(glfw.HRESIZE_CURSOR)
        self._cursor_shown = None
        self._last_click = (0.0, -1e9, -1e9)
        self._dropped: tuple[list[str], bool] | None = None
        self._categories: list[int] | None = None
        self._colormaps: dict[str, Colormap] = {}    # the colormap chosen for each attribute shown before
        self._histogram: tuple[tuple, np.ndarray | None] | None = None
        self._last_time = time.perf_counter()
        self.panel = None
        if options.ui:
            from progressive.viewer.panel import Panel

            self.panel = Panel(self)
        self._install_callbacks()
        self.open(paths)

    # ---- files ---------------------------------------------------------------------
    def open(self, paths: list[str], add: bool = False) -> bool:
        """Open files as the cloud (or add them to it). On failure the current cloud
        stays and the error is shown."""
        paths = [*self.paths, *paths] if add else list(paths)
        width, height = self.framebuffer_size
        try:
            options = self.options.session
            session = Session(paths, replace(options, width=width, height=height, switchable=True, class_filter=True,
                                             progressive=replace(options.progressive, budget=self._budget()),
                                             stream_detail_px=self.settings.stream_detail_px),
                              glc=self.glc)
        except (ProgressiveError, OSError) as exc:
            self.fail(str(exc))
            return False
        if self.session is not None:
            self.session.close()
        self.session, self.paths, self.error = session, paths, None
        self.navigator = Navigator.for_bounds(session.info.bounds_min, session.info.bounds_max, width / height)
        self.orbit, self.pasted = self.navigator.framed((width, height), self.free_area), None
        self._colormaps, self._histogram = {}, None
        self._defaults_key, self.eye_dome_cost = None, None
        self.settings = replace(self.settings, attribute=session.attribute.name, value_range=None,
                                colormap=options.colormap,
                                hidden_classes=self.options.hidden_classes if not add else frozenset(),
                                clip=self.options.clip if not add else self.settings.clip,
                                returns=self.options.returns if not add else self.settings.returns)
        self.messages, self._message_times = [], []
        self._said = set()
        self._say_new_warnings()
        self._categories = None
        return True

    def _say_new_warnings(self) -> None:
        """The session's warnings not shown yet: those of opening, then those that come
        while it runs (a streamed COPC node that cannot be read)."""
        for warning in self.session.warnings:
            if warning not in self._said:
                self._said.add(warning)
                self.say(warning)

    def categories(self) -> list[int]:
        """Category codes present in the shown attribute (for the legend), once loaded (a
        streamed cloud's as its nodes come: they change as the camera moves)."""
        if self.session is not None and (self._categories is None or self.session.streamed) \
                and not self.session.status().loading:
            self._categories = self.session.categories()
        return self._categories or []

    def shown_clip_box(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The clip box as drawn and dragged (infinite sides at the cloud's bounds), or
        None without a box (no clip, or only a section)."""
        clip = self.settings.clip
        if self.session is None or not clip.has_box:
            return None
        return clipbox.shown_box(clip, self.session.info.bounds_min, self.session.info.bounds_max)

    def dragged_face(self) -> clipbox.Face | None:
        d = self._drag
        return d.face.face if d is not None and d.face is not None else None

    @property
    def section_width(self) -> float:
        """The width a new section gets: the panel's, else SECTION_WIDTH_SHARE of the
        cloud's horizontal diagonal."""
        if self.settings.section_width is not None:
            return self.settings.section_width
        size = np.subtract(self.session.info.bounds_max, self.session.info.bounds_min)[:2]
        return max(float(np.hypot(*size)) * SECTION_WIDTH_SHARE, 1e-6)

    def section_along_line(self) -> bool:
        """Clip to a vertical slab of `section_width` along the segment between the last
        two measured points (Shift+click), kept with the box."""
        points = self.measurement.points
        if self.session is None or len(points) < 2:
            self.fail("a section needs two measured points (Shift+click them)")
            return False
        a, b = points[-2], points[-1]
        try:
            section = Section((a[0], a[1]), (b[0], b[1]), self.section_width)
        except CameraError as exc:
            self.fail(f"section: {exc}")
            return False
        clip = self.settings.clip
        self.settings = replace(self.settings, clip=Clip(clip.lo, clip.hi, section))
        return True

    def set_section_width(self, width: float) -> None:
        """The width for sections, applied to the current one too."""
        try:
            section = self.settings.clip.section
            clip = self.settings.clip
            if section is not None:
                clip = Clip(clip.lo, clip.hi, Section(section.start, section.end, width))
            elif not width > 0:
                raise CameraError("section width must be positive")
        except CameraError as exc:
            self.fail(f"section: {exc}")
            return
        self.settings = replace(self.settings, section_width=width, clip=clip)

    def clear_section(self) -> None:
        clip = self.settings.clip
        self.settings = replace(self.settings, clip=Clip(clip.lo, clip.hi))

    def profile_view(self) -> None:
        """Look at the section from the side, orthographic: along its normal, its start
        on the left, the whole segment and the cloud's height in view."""
        section = self.settings.clip.section
        if section is None or self.navigator is None:
            return
        w, h = self.framebuffer_size
        x0, _, x1, _ = self.free_area
        o = self.navigator.profile(self.orbit, section, (x1 - x0) / h)
        middle = o.target            # moved to the free area's centre, and turned about there
        o = self.navigator.pan(o, (x0 + x1) / 2.0 - w / 2.0, 0.0, h)
        self.orbit, self.pasted = replace(o, pivot=middle), None

    def toggle_class(self, code: int) -> None:
        self.settings = replace(self.settings, hidden_classes=self.settings.hidden_classes ^ {code})

    def say(self, message: str) -> None:
        """A note in the panel for MESSAGE_SECONDS (warnings, saves, focus)."""
        self.messages.append(message)
        self._message_times.append(time.perf_counter())

    def expire_messages(self, now: float | None = None) -> None:
        """Drop the notes older than MESSAGE_SECONDS (errors stay until dismissed)."""
        now = time.perf_counter() if now is None else now
        keep = [i for i, t in enumerate(self._message_times) if now - t < MESSAGE_SECONDS]
        self.messages = [self.messages[i] for i in keep]
        self._message_times = [self._message_times[i] for i in keep]

    def fail(self, message: str) -> None:
        self.error = message

    @property
    def attribute_names(self) -> list[str]:
        return [a.name for a in self.session.info.attributes] if self.session else []

    def switch_attribute(self, name: str) -> None:
        if self.session is None or name == self.session.chosen.name:
            return
        try:
            self.session.switch_attribute(name)
        except ProgressiveError as exc:
            self.fail(str(exc))
            return
        self._colormaps[self.settings.attribute] = self.settings.colormap
        colormap = self._colormaps.get(name, self.options.session.colormap)
        self.settings = replace(self.settings, attribute=name, value_range=None, hidden_classes=frozenset(),
                                colormap=colormap)
        self._categories = None

    def set_colormap(self, colormap: Colormap) -> None:
        """The colormap of the attribute shown; it comes back when the attribute does."""
        self.settings = replace(self.settings, colormap=colormap)

    def histogram(self) -> tuple[np.ndarray, tuple[float, float]] | None:
        """(HISTOGRAM_BINS counts, range) of the shown scalar over its colour range, for
        the legend; counted again when the range, the attribute or the loaded points
        change (while loading, each time they have doubled)."""
        s = self.session
        if s is None:
            return None
        value_range = s.color_range(self.settings.value_range)
        if value_range is None or not value_range[0] < value_range[1]:
            return None
        status = s.status()
        loaded = status.loaded
        if self._histogram is not None:
            (name, kept_range, counted), _ = self._histogram
            fresh = counted == loaded or (status.loading and loaded < 2 * counted)
            if name == s.attribute.name and kept_range == value_range and fresh:
                return self._histogram[1], value_range
        counts = s.histogram(HISTOGRAM_BINS, value_range)
        self._histogram = ((s.attribute.name, value_range, loaded), counts)
        return None if counts is None else (counts, value_range)

    # ---- the loop ------------------------------------------------------------------
    @property
    def framebuffer_size(self) -> tuple[int, int]:
        w, h = glfw.get_framebuffer_size(self.window)
        return max(1, w), max(1, h)

    @property
    def panel_units(self) -> float:
        """Screen units the docked panel covers at the window's left (0 when hidden)."""
        if self.panel is None or not self.settings.panel:
            return 0.0
        return docked_width(self.dragged_panel, glfw.get_window_size(self.window)[0])

    @property
    def panel_width(self) -> int:
        """Framebuffer pixels the docked panel covers at the window's left (0 when hidden)."""
        ww, _ = glfw.get_window_size(self.window)
        fw, _ = self.framebuffer_size
        return int(round(self.panel_units * fw / max(1, ww)))

    def on_panel_edge(self, x: float) -> bool:
        """Window position x (screen units) grabs the docked panel's right edge."""
        edge = self.panel_units
        return edge > 0 and edge <= x < edge + PANEL_EDGE_GRAB

    @property
    def free_area(self) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1) framebuffer pixels the panel leaves free: where the camera
        frames the cloud and the overlays go."""
        w, h = self.framebuffer_size
        return self.panel_width, 0, w, h

    def home(self) -> None:
        """Frame the whole cloud in the free area (R)."""
        self.orbit, self.pasted = self.navigator.framed(self.framebuffer_size, self.free_area), None

    def at_home(self) -> bool:
        """The camera is where home() puts it: a change of the free area may frame it again."""
        return self.navigator is not None and self.pasted is None and \
            self.orbit == self.navigator.framed(self.framebuffer_size, self.free_area)

    def scale_bar(self) -> tuple[float, float, str] | None:
        """(length in file units, pixels, label) of a bar measuring lengths across the view
        at the target's depth: the longest 1, 2 or 5 x 10^k units within SCALE_BAR_PIXELS."""
        if self.navigator is None or self.session is None:
            return None
        camera, (_, h) = self.camera, self.framebuffer_size
        if camera.orthographic:
            per_pixel = camera.height / h
        else:
            depth = float(np.linalg.norm(np.subtract(camera.target, camera.position)))
            per_pixel = 2.0 * depth * np.tan(np.radians(camera.fov_y_deg) / 2.0) / h
        most = per_pixel * SCALE_BAR_PIXELS
        power = 10.0 ** np.floor(np.log10(most))
        length = max(k * power for k in (1.0, 2.0, 5.0) if k * power <= most)
        unit = self.session.units
        label = f"{length:g} {UNIT_SYMBOLS.get(unit, unit)}" if unit else f"{length:g} (file units)"
        return float(length), float(length / per_pixel), label

    def axes_gizmo(self) -> dict[str, tuple[float, float]]:
        """The file's X, Y and Z axes as unit-length screen directions (column, row; row
        down) of the camera's view: the gizmo draws them scaled."""
        r = self.camera.rotation()
        return {name: (float(r[0][k]), float(-r[1][k])) for k, name in enumerate("XYZ")}

    @property
    def camera(self) -> Camera:
        return self.pasted or self.navigator.camera(self.orbit)

    def _budget(self) -> BudgetParams:
        s = self.settings
        if s.budget_mode is BudgetMode.FIXED:
            return BudgetParams(fixed=s.fixed_budget)
        return BudgetParams(target_ns=int(1e9 / s.target_fps))

    def step(self) -> None:
        """One iteration: input, one frame, present, panel, swap."""
        now = time.perf_counter()
        seconds, self._last_time = now - self._last_time, now
        idle = (self.session is not None and self.session.idle and self._drag is None and self._dropped is None
                and self._reading is None)
        if idle:
            glfw.wait_events_timeout(IDLE_WAIT_SECONDS)
        else:
            glfw.poll_events()
        if glfw.window_should_close(self.window):
            self.running = False
            return
        if self._dropped is not None:
            (paths, add), self._dropped = self._dropped, None
            self.open(paths, add)
        self._collect()
        self._fly(seconds)
        size = self.framebuffer_size
        if self.session is not None:
            if size != self.session.size:
                self.session.resize(*size)
            self._frame()
            self.choose_defaults()
            self.present.run(self.session.image_buffer, self.session.size, size)
        else:
            self.glc.ctx.screen.use()
            self.glc.ctx.clear(0.0, 0.0, 0.0)
        if self.panel is not None:
            self.panel.draw()
        glfw.swap_buffers(self.window)
        self.frames += 1

    def _frame(self) -> None:
        s = self.session
        try:
            style = s.style(self.settings.colormap, self.settings.value_range, self.settings.background)
            self.last_passes = s.frame(self.camera, style, self.settings.effects, self.settings.hidden_classes,
                                       self.settings.clip, self.settings.returns)
            self._say_new_warnings()
        except ProgressiveError as exc:
            self.fail(f"{exc} (showing the {s.status().loaded:,} points read before)")
            s.stop_loading()

    @property
    def goal_ms(self) -> float:
        """The adaptive budget's frame goal at the target rate (the effects' yardstick)."""
        return BudgetParams(target_ns=int(1e9 / self.settings.target_fps)).goal_ns / 1e6

    def automatic_effects(self) -> None:
        """Point size and eye-dome lighting back to the rules' choices (the panel's button)."""
        self.auto_point_size = self.auto_eye_dome = True
        self._applied, self._defaults_key = (self.settings.point_size, self.settings.eye_dome), None

    def choose_defaults(self) -> None:
        """Once a view has converged, apply the rules of viewer/defaults.py to what the
        user has not changed: point size from the 1-pixel coverage, eye-dome lighting from
        the colouring and its measured cost at this size (measured once a size)."""
        s, v = self.session, self.settings
        if v.point_size != self._applied[0]:
            self.auto_point_size = False
        if v.eye_dome != self._applied[1]:
            self.auto_eye_dome = False
        if s is None or not (self.auto_point_size or self.auto_eye_dome) or not s.converged:
            return
        key = (self.camera, s.size, s.attribute.name, v.clip, v.hidden_classes, v.returns, v.target_fps)
        if key == self._defaults_key:
            return
        self._defaults_key = key
        if self.auto_point_size:
            self.point_size_choice = defaults.point_size(s.covered())
            v = replace(v, point_size=int(self.point_size_choice.value))
        if self.auto_eye_dome:
            rgb = s.attribute.kind is AttributeKind.RGB
            if not rgb and (self.eye_dome_cost is None or self.eye_dome_cost[0] != s.size):
                self.eye_dome_cost = (s.size, s.effect_cost_ms(Effects(1, v.eye_dome_params))["eye_dome"])
            self.eye_dome_choice = defaults.eye_dome(rgb, None if rgb else self.eye_dome_cost[1], self.goal_ms)
            v = replace(v, eye_dome=bool(self.eye_dome_choice.value))
        self.settings, self._applied = v, (v.point_size, v.eye_dome)

    def run(self) -> None:
        while self.running:
            self.step()
        self.close()

    def close(self) -> None:
        if self._reader is not None:
            self._reader.shutdown(wait=False, cancel_futures=True)
            self._reader, self._reading = None, None
        if self.panel is not None:
            self.panel.release()
            self.panel = None
        if self.session is not None:
            self.session.close()
            self.session = None
        if self._resize_cursor is not None:
            glfw.destroy_cursor(self._resize_cursor)
            self._resize_cursor = None
        self.present.release()
        self.glc.release()

    # ---- actions -------------------------------------------------------------------
    def act(self, action: Action) -> None:
        s = self.settings
        if action is Action.QUIT:
            self.running = False
        elif action is Action.RESET and self.navigator is not None:
            self.home()
        elif action is Action.SCREENSHOT:
            self.screenshot()
        elif action is Action.POINT_BIGGER:
            self.settings = s.point_size_by(1)
        elif action is Action.POINT_SMALLER:
            self.settings = s.point_size_by(-1)
        elif action in (Action.NEXT_ATTRIBUTE, Action.PREVIOUS_ATTRIBUTE):
            step = 1 if action is Action.NEXT_ATTRIBUTE else -1
            self.switch_attribute(cycle(self.attribute_names, s.attribute, step))
        elif action is Action.EYE_DOME:
            self.settings = replace(s, eye_dome=not s.eye_dome)
        elif action is Action.HELP:
            self.settings = replace(s, help=not s.help)
        elif action is Action.PANEL:
            at_home = self.at_home()
            self.settings = replace(s, panel=not s.panel)
            if at_home:             # the home view follows the free area; a view the user chose stays
                self.home()
        elif action is Action.FLY:
            self.settings = replace(s, fly=not s.fly)
        elif action is Action.COPY_CAMERA and self.navigator is not None:
            glfw.set_clipboard_string(None, self.camera.to_json())
            self.say("camera copied to the clipboard (Ctrl+V pastes it; render --camera takes it)")
        elif action is Action.PASTE_CAMERA:
            self.paste_camera(glfw.get_clipboard_string(None) or b"")
        elif action is Action.PROJECTION and self.navigator is not None:
            self.orbit, self.pasted = replace(self.orbit, orthographic=not self.orbit.orthographic), None
        elif action in VIEW_ACTIONS and self.navigator is not None:
            self.orbit, self.pasted = self.navigator.preset(self.orbit, VIEW_ACTIONS[action]), None

    def paste_camera(self, text: bytes | str) -> None:
        """Show exactly the render contract's camera given as JSON."""
        try:
            camera = Camera.from_json(text.decode("utf-8", "replace") if isinstance(text, bytes) else text)
        except CameraError as exc:
            self.fail(f"pasted camera: {exc}")
            return
        self.pasted, self.orbit = camera, Orbit.from_camera(camera)
        self.say("camera pasted")

    def set_budget(self, mode: BudgetMode, target_fps: float | None = None, fixed: int | None = None) -> None:
        self.settings = replace(self.settings, budget_mode=mode, target_fps=target_fps or self.settings.target_fps,
                                fixed_budget=fixed or self.settings.fixed_budget)
        if self.session is not None:
            self.session.set_budget(self._budget())

    def set_stream_detail(self, finest_px: float) -> None:
        """A streamed cloud's finest detail (this cloud's and the next's); below 0 counts
        as 0, and one not finite (typed in the panel) changes nothing."""
        if not math.isfinite(finest_px):
            return
        self.settings = replace(self.settings, stream_detail_px=max(0.0, finest_px))
        if self.session is not None:
            self.session.set_stream_detail(self.settings.stream_detail_px)

    def screenshot(self, path: Path | None = None) -> Path | None:
        """The frame as shown, as PNG (P); the path is new each time."""
        if self.session is None:
            return None
        if path is None:
            stamp = time.strftime("%Y%m%d-%H%M%S")
            path = self.options.screenshot_dir / f"progressive-{stamp}.png"
            k = 1
            while path.exists():
                path = self.options.screenshot_dir / f"progressive-{stamp}-{k}.png"
                k += 1
        try:
            write_png(path, self.session.image())
        except (ProgressiveError, OSError) as exc:
            self.fail(f"screenshot: {exc}")
            return None
        self.last_screenshot = path
        self.say(f"saved {path}")
        return path

    def capture_window(self) -> np.ndarray:
        """(H, W, 3) uint8 of the window's back buffer as drawn, panel included, row 0
        at the top (moderngl's screen.read fails on some default framebuffers)."""
        from OpenGL import GL

        w, h = self.framebuffer_size
        self.glc.ctx.screen.use()
        GL.glReadBuffer(GL.GL_BACK)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
        data = GL.glReadPixels(0, 0, w, h, GL.GL_RGB, GL.GL_UNSIGNED_BYTE)
        return np.frombuffer(data, dtype=np.uint8).reshape(h, w, 3)[::-1].copy()

    # ---- picking -------------------------------------------------------------------
    def to_framebuffer(self, x: float, y: float) -> tuple[float, float]:
        """Window (cursor) coordinates to image pixels: on a HiDPI display the
        framebuffer has more pixels than the window has screen units."""
        ww, wh = glfw.get_window_size(self.window)
        fw, fh = self.framebuffer_size
        return x * fw / max(1, ww), y * fh / max(1, wh)

    def pick(self, x: float, y: float) -> tuple[int, float] | None:
        """(file-order index, depth) of the point shown nearest to window position (x, y)."""
        if self.session is None:
            return None
        hit = self.session.nearest_shown(*self.to_framebuffer(x, y), CURSOR_SEARCH)
        return None if hit is None else hit[:2]

    @property
    def reading(self) -> bool:
        """A picked point is being read back from its file."""
        return self._reading is not None

    def _read(self, work: Callable, done: Callable) -> None:
        """Read a picked point back (`work`, a file read) on the reader thread, and hand
        it to `done` on the window's thread: at once where it takes under
        READ_WAIT_SECONDS, else at a later step, the window drawing meanwhile. A newer
        click's read replaces an older one's, whose result is then dropped."""
        if self._reader is None:
            self._reader = ThreadPoolExecutor(1, thread_name_prefix="progressive-pick")
        self._reading = (self._reader.submit(work), done, self.session)
        if not self._collect(READ_WAIT_SECONDS):
            self.say("reading the picked point from its file ...")

    def _collect(self, wait: float = 0.0) -> bool:
        """Hand a finished read to what takes it (an error to the panel); False while it
        is under way."""
        if self._reading is None:
            return True
        future, done, session = self._reading
        try:
            result = future.result(timeout=wait)
        except FutureTimeout:
            return False
        except (OSError, ValueError, ProgressiveError) as exc:
            self._reading = None
            if session is self.session:
                self.fail(f"reading the picked point: {exc}")
            return True
        self._reading = None
        if session is self.session:       # not a cloud dropped in since: its result, or its error
            done(result)
        return True

    def pick_point(self, x: float, y: float, measure: bool = False) -> None:
        """Remember all of the point shown nearest to window position (x, y) (or nothing);
        `measure`: add it to the measurement too. The point is found on the GPU here and
        read back from its file on the reader thread."""
        if self.session is None:
            return
        hit = self.session.nearest_shown(*self.to_framebuffer(x, y), CURSOR_SEARCH)
        if hit is None:
            self.picked = None
            return

        def picked(record: dict) -> None:
            self.picked = record
            if measure:
                self.measurement = self.measurement.add((record["x"], record["y"], record["z"]))
        session = self.session
        self._read(lambda: session.picked_record(hit), picked)

    def focus(self, x: float, y: float) -> None:
        """Orbit about the point under the cursor, at its exact coordinates in the cloud's
        CRS (read back from its file, as a pick is; reprojected with --reproject)."""
        hit = self.pick(x, y)
        if hit is None:
            return

        def focused(point: np.ndarray) -> None:
            self.last_focus = point
            self.orbit, self.pasted = self.navigator.focus(self.orbit, point), None
            self.say("focus " + ", ".join(f"{v:.6f}" for v in point))
        session = self.session
        self._read(lambda: session.point(hit[0]), focused)

    # ---- input ---------------------------------------------------------------------
    def _install_callbacks(self) -> None:
        glfw.set_mouse_button_callback(self.window, self.on_mouse_button)
        glfw.set_cursor_pos_callback(self.window, self.on_cursor)
        glfw.set_scroll_callback(self.window, self.on_scroll)
        glfw.set_key_callback(self.window, self.on_key)
        glfw.set_char_callback(self.window, self.on_char)
        glfw.set_drop_callback(self.window, self.on_drop)

    def _ui_wants_mouse(self) -> bool:
        return self.panel is not None and self.settings.panel and self.panel.wants_mouse()

    def on_mouse_button(self, window, button: int, action: int, mods: int) -> None:
        if self.panel is not None:
            self.panel.renderer.mouse_button_callback(window, button, action, mods)
        x, y = glfw.get_cursor_pos(self.window)
        self.mouse_button(button, action == glfw.PRESS, x, y, bool(mods & glfw.MOD_SHIFT))

    def mouse_button(self, button: int, pressed: bool, x: float, y: float, shift: bool = False,
                     at: float | None = None) -> None:
        """A press starts a drag (orbit, pan, or look in fly mode; on the panel's right
        edge, its width); a release where it was pressed picks the point there (the panel
        shows all of it; with Shift it is also the next point of the measurement); two
        quick presses focus. `at`: when it happened (perf_counter seconds; GLFW's callbacks
        give no time, so None is now)."""
        if not pressed:
            d, self._drag = self._drag, None
            if (d is not None and button == glfw.MOUSE_BUTTON_LEFT and abs(x - d.x) + abs(y - d.y) < DOUBLE_CLICK_PIXELS
                    and d.kind not in (DragKind.CLIP_FACE, DragKind.PANEL_EDGE) and (d.kind is not DragKind.PAN or shift)):
                self.pick_point(x, y, measure=shift)
            return
        if button == glfw.MOUSE_BUTTON_LEFT and self.on_panel_edge(x):
            self._drag = Drag(DragKind.PANEL_EDGE, x, y, panel=PanelDrag(self.panel_units, self.at_home()))
            return
        if self._ui_wants_mouse() or self.navigator is None:
            return
        if button == glfw.MOUSE_BUTTON_LEFT and not shift and self._grab_face(x, y):
            return
        if button == glfw.MOUSE_BUTTON_LEFT:
            t, lx, ly = self._last_click
            now = time.perf_counter() if at is None else at
            if now - t < DOUBLE_CLICK_SECONDS and abs(x - lx) + abs(y - ly) < DOUBLE_CLICK_PIXELS:
                self._last_click = (0.0, -1e9, -1e9)
                self.focus(x, y)
                return
            self._last_click = (now, x, y)
            kind = DragKind.PAN if shift else (DragKind.LOOK if self.settings.fly else DragKind.ORBIT)
        elif button in (glfw.MOUSE_BUTTON_RIGHT, glfw.MOUSE_BUTTON_MIDDLE):
            kind = DragKind.PAN
        else:
            return
        self._drag = Drag(kind, x, y)

    def _grab_face(self, x: float, y: float) -> bool:
        """A press on a clip face's handle starts dragging that face."""
        box = self.shown_clip_box()
        if box is None:
            return False
        camera, size, (fx, fy) = self.camera, self.framebuffer_size, self.to_framebuffer(x, y)
        face = clipbox.handle_at(camera, *box, size, fx, fy)
        if face is None:
            return False
        centre = clipbox.face_centre(*box, face)
        along = clipbox.along_axis(camera, centre, face.axis, size, fx, fy)
        bound = float(box[face.side][face.axis])
        self._drag = Drag(DragKind.CLIP_FACE, x, y, FaceDrag(face, tuple(centre.tolist()), bound, along))
        return True

    def on_cursor(self, window, x: float, y: float) -> None:
        if self.panel is not None:
            self.panel.renderer.mouse_callback(window, x, y)
        self.cursor(x, y)
        d = self._drag
        edge = (d.kind is DragKind.PANEL_EDGE) if d is not None else self.on_panel_edge(x)
        shape = self._resize_cursor if edge else None
        if shape is not self._cursor_shown:
            glfw.set_cursor(self.window, shape)
            self._cursor_shown = shape

    def cursor(self, x: float, y: float) -> None:
        d = self._drag
        if d is not None and d.kind is DragKind.PANEL_EDGE:
            self._drag_panel(d, x)
            return
        if d is None or self.navigator is None:
            return
        if d.kind is DragKind.CLIP_FACE:
            self._drag_face(d.face, x, y)
            return
        dx, dy = x - d.x, y - d.y
        nav, o = self.navigator, self.orbit
        if d.kind is DragKind.ORBIT:
            o = nav.orbit(o, dx, dy)
        elif d.kind is DragKind.LOOK:
            o = nav.look(o, dx, dy)
        else:
            o = nav.pan(o, dx, dy, self.framebuffer_size[1])
        self.orbit, self.pasted = o, None
        self._drag = Drag(d.kind, x, y)

    def _drag_panel(self, d: Drag, x: float) -> None:
        """The edge follows the cursor within the clamp; a camera at the home view frames
        the cloud again in the area left free, a view the user chose stays."""
        self.dragged_panel = docked_width(d.panel.width + x - d.x, glfw.get_window_size(self.window)[0])
        if d.panel.home and self.navigator is not None:
            self.home()

    def _drag_face(self, f: FaceDrag, x: float, y: float) -> None:
        """The face moves to where the cursor's ray meets its axis (the camera stands
        still while dragging); the new bound is float64 file units."""
        along = clipbox.along_axis(self.camera, np.asarray(f.centre), f.face.axis, self.framebuffer_size,
                                   *self.to_framebuffer(x, y))
        if along is None:
            return
        self.settings = replace(self.settings, clip=clipbox.dragged(self.settings.clip, f.face, f.bound, f.along, along))

    def on_scroll(self, window, dx: float, dy: float) -> None:
        if self.panel is not None:
            self.panel.renderer.scroll_callback(window, dx, dy)
        if not self._ui_wants_mouse():
            self.scroll(dy, *glfw.get_cursor_pos(self.window))

    def scroll(self, notches: float, x: float, y: float) -> None:
        """Zoom about the point under the cursor (else about the target's depth)."""
        if self.navigator is None or notches == 0:
            return
        o = self.orbit
        hit = self.pick(x, y)
        depth = hit[1] if hit is not None else o.distance
        anchor = self.navigator.cursor_point(o, *self.to_framebuffer(x, y), self.framebuffer_size, depth)
        self.orbit, self.pasted = self.navigator.zoom(o, notches, anchor), None

    def on_key(self, window, key: int, scancode: int, action: int, mods: int) -> None:
        if self.panel is not None:
            self.panel.renderer.keyboard_callback(window, key, scancode, action, mods)
            if self._ui_keyboard():
                return
        if action != glfw.PRESS:
            return
        if key == glfw.KEY_ESCAPE and self.panel is not None and self.settings.panel and self.panel.popup_open():
            return          # imgui closes the popup; only an Esc with none open quits
        table = CTRL_KEYS if mods & glfw.MOD_CONTROL else GLFW_KEYS
        if key in table:
            self.act(table[key])

    def on_char(self, window, char: int) -> None:
        if self.panel is not None:
            self.panel.renderer.char_callback(window, char)

    def on_drop(self, window, paths: list[str]) -> None:
        shift = glfw.get_key(self.window, glfw.KEY_LEFT_SHIFT) == glfw.PRESS or \
            glfw.get_key(self.window, glfw.KEY_RIGHT_SHIFT) == glfw.PRESS
        self.drop(list(paths), add=shift)

    def drop(self, paths: list[str], add: bool = False) -> None:
        """Opened at the start of the next step, outside glfw's callback."""
        self._dropped = (paths, add)

    def _fly(self, seconds: float) -> None:
        if not self.settings.fly or self.navigator is None or self._ui_keyboard():
            return
        move = np.zeros(3)
        for key, v in FLY_KEYS.items():
            if glfw.get_key(self.window, key) == glfw.PRESS:
                move += v
        if move.any():
            self.orbit, self.pasted = self.navigator.fly(self.orbit, *move, min(seconds, 0.1)), None

    def _ui_keyboard(self) -> bool:
        return self.panel is not None and self.settings.panel and self.panel.wants_keyboard()
