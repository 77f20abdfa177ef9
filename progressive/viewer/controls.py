"""What the viewer's keys and the panel change: actions, and the frozen settings
each action replaces. GPU-free and glfw-free, so the mapping is testable as is."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, replace

from progressive.camera import NO_CLIP, Clip, Returns
from progressive.colors import Colormap
from progressive.effects import MAX_POINT_SIZE, Effects, EyeDome
from progressive.streaming import FINEST_PX
from progressive.viewer.navigation import View


class Action(enum.Enum):
    RESET = "reset view"
    SCREENSHOT = "save a PNG screenshot"
    POINT_BIGGER = "larger points"
    POINT_SMALLER = "smaller points"
    PREVIOUS_ATTRIBUTE = "previous attribute"
    NEXT_ATTRIBUTE = "next attribute"
    EYE_DOME = "eye-dome lighting on/off"
    HELP = "help on/off"
    PANEL = "panel on/off"
    FLY = "fly mode on/off (WASD, Space/Z up/down, drag to look)"
    COPY_CAMERA = "copy the camera as JSON"
    PASTE_CAMERA = "paste a camera JSON"
    PROJECTION = "orthographic/perspective"
    VIEW_TOP = "view from the top"
    VIEW_FRONT = "view from the front (south)"
    VIEW_SIDE = "view from the side (east)"
    VIEW_ISO = "isometric view"
    QUIT = "quit"


KEYS: dict[str, Action] = {
    "R": Action.RESET, "P": Action.SCREENSHOT, "+": Action.POINT_BIGGER, "-": Action.POINT_SMALLER,
    "[": Action.PREVIOUS_ATTRIBUTE, "]": Action.NEXT_ATTRIBUTE, "E": Action.EYE_DOME, "H": Action.HELP,
    "Tab": Action.PANEL, "F": Action.FLY, "Ctrl+C": Action.COPY_CAMERA, "Ctrl+V": Action.PASTE_CAMERA,
    "Esc": Action.QUIT, "Q": Action.QUIT, "O": Action.PROJECTION,
    "1": Action.VIEW_TOP, "2": Action.VIEW_FRONT, "3": Action.VIEW_SIDE, "4": Action.VIEW_ISO,
}
"""Key names as shown in the help; app.py maps glfw key codes onto them."""

VIEW_ACTIONS: dict[Action, View] = {Action.VIEW_TOP: View.TOP, Action.VIEW_FRONT: View.FRONT,
                                    Action.VIEW_SIDE: View.SIDE, Action.VIEW_ISO: View.ISO}

MOUSE_HELP = (
    ("Left drag", "orbit"), ("Right drag / Shift+left drag", "pan"), ("Wheel", "zoom to the cursor"),
    ("Double-click", "focus the point under the cursor"), ("Drop files", "open (Shift: add to the cloud)"),
    ("Left drag a clip handle", "move that face of the clip box"),
    ("Shift+click", "add the point to the measurement (two: a section along them)"),
)
PANEL_WIDTH = 360              # the docked panel's first width in screen units ...
PANEL_MAX_SHARE = 0.42         # ... and at most this share of a narrow window's
PANEL_MIN_WIDTH = 240          # a width dragged (its right edge) is at least this many screen units ...
PANEL_DRAG_MAX_SHARE = 0.6     # ... and at most this share of the window's width (which wins)
PANEL_EDGE_GRAB = 6            # screen units right of the panel's edge that grab it (left of it: its scrollbar)


def docked_width(dragged: float | None, window_width: float) -> float:
    """The docked panel's width in screen units: the first one, or the one dragged
    (None: not dragged), clamped to the window as it is now."""
    if dragged is None:
        return min(PANEL_WIDTH, PANEL_MAX_SHARE * window_width)
    return min(max(dragged, PANEL_MIN_WIDTH), PANEL_DRAG_MAX_SHARE * window_width)


SECTION_WIDTH_SHARE = 0.01
"""A new section's width before the panel sets one: this share of the cloud's
horizontal diagonal (file units differ: metres, feet)."""


class BudgetMode(enum.Enum):
    ADAPTIVE = "adaptive"      # fill what fits in the frame time of the target rate
    FIXED = "fixed"            # fill a fixed number of points a frame


@dataclass(frozen=True)
class ViewSettings:
    attribute: str = ""
    colormap: Colormap = Colormap.VIRIDIS
    value_range: tuple[float, float] | None = None     # in the attribute's units; None: the 1st-99th percentiles
    hidden_classes: frozenset[int] = frozenset()
    clip: Clip = NO_CLIP                                # the box (and section) points must lie in (file coordinates)
    section_width: float | None = None                  # for sections along a line; None: SECTION_WIDTH_SHARE
    returns: Returns = Returns.ALL                      # which returns of each pulse are drawn
    point_size: int = 1
    eye_dome: bool = False
    eye_dome_params: EyeDome = field(default_factory=EyeDome)
    budget_mode: BudgetMode = BudgetMode.ADAPTIVE
    target_fps: float = 60.0
    fixed_budget: int = 1_000_000
    stream_detail_px: float = FINEST_PX                 # a streamed cloud's finest detail (SessionOptions's)
    background: tuple[int, int, int] = (0, 0, 0)
    panel: bool = True
    help: bool = False
    fly: bool = False

    @property
    def effects(self) -> Effects:
        return Effects(self.point_size, self.eye_dome_params if self.eye_dome else None)

    def point_size_by(self, step: int) -> ViewSettings:
        return replace(self, point_size=max(1, min(MAX_POINT_SIZE, self.point_size + step)))


def cycle(names: list[str], current: str, step: int) -> str:
    """The attribute `step` places after `current`, wrapping around."""
    if not names:
        return current
    i = names.index(current) if current in names else -1
    return names[(i + step) % len(names)]
