"""Progressive real-time rendering of LAS/LAZ point clouds on the GPU."""

from progressive.budget import BudgetParams
from progressive.camera import Camera
from progressive.colors import Colormap
from progressive.effects import Effects, EyeDome
from progressive.frame_loop import ProgressiveOptions
from progressive.notebook import show
from progressive.renderer import Raster
from progressive.session import Method, Session, SessionOptions, open

__all__ = ["BudgetParams", "Camera", "Colormap", "Effects", "EyeDome", "Method", "ProgressiveOptions", "Raster", "Session",
           "SessionOptions", "open", "show"]
