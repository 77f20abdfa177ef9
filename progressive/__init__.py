"""Progressive real-time rendering of LAS/LAZ point clouds on the GPU."""

from progressive.budget import BudgetParams
from progressive.camera import Camera
from progressive.colors import Colormap
from progressive.effects import Effects, EyeDome
from progressive.frame_loop import ProgressiveOptions
from progressive.renderer import Raster
from progressive.session import Method, Session, SessionOptions, open

__all__ = ["BudgetParams", "Camera", "Colormap", "Effects", "EyeDome", "Method", "ProgressiveOptions", "Raster", "Session",
           "SessionOptions", "open", "show"]


def __getattr__(name: str):
    """`show` is imported on first use: the notebook view's imports (asyncio, the
    viewer's controls) would otherwise delay every command's first image."""
    if name == "show":
        from progressive.notebook import show

        return show
    raise AttributeError(f"module 'progressive' has no attribute {name!r}")
