"""How attribute words become colours: RGB as stored, scalars through a colormap
(from the `cmap` library) over a range, classification through the ASPRS palette."""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from progressive.loaders.types import AttributeInfo, AttributeKind


class ColorMode(enum.IntEnum):
    RGB = 0
    SCALAR = 1
    CATEGORY = 2

    @classmethod
    def for_kind(cls, kind: AttributeKind) -> ColorMode:
        return {AttributeKind.RGB: cls.RGB, AttributeKind.SCALAR: cls.SCALAR, AttributeKind.CATEGORY: cls.CATEGORY}[kind]

    @classmethod
    def glsl_defines(cls) -> dict[str, int]:
        return {f"COLOR_MODE_{m.name}": int(m) for m in cls}


class Colormap(enum.Enum):
    VIRIDIS = "viridis"
    INFERNO = "inferno"
    PLASMA = "plasma"
    SPECTRAL = "spectral"
    RAINBOW = "gnuplot:rainbow"
    TURBO = "turbo"
    GRAYSCALE = "gray"


# ASPRS LAS 1.4 (R15) class names, with Potree's de-facto palette (ASPRS defines no colours).
ASPRS_CLASSES: dict[int, tuple[str, tuple[int, int, int]]] = {
    0: ("created, never classified", (128, 128, 128)),
    1: ("unclassified", (180, 180, 180)),
    2: ("ground", (166, 116, 66)),
    3: ("low vegetation", (0, 160, 60)),
    4: ("medium vegetation", (0, 200, 60)),
    5: ("high vegetation", (40, 255, 40)),
    6: ("building", (255, 140, 30)),
    7: ("low point (noise)", (255, 0, 255)),
    8: ("model key-point (reserved in 1.4)", (255, 255, 0)),
    9: ("water", (30, 110, 255)),
    10: ("rail", (150, 80, 40)),
    11: ("road surface", (90, 90, 90)),
    12: ("overlap (reserved in 1.4)", (255, 255, 150)),
    13: ("wire, guard (shield)", (255, 220, 0)),
    14: ("wire, conductor (phase)", (255, 255, 0)),
    15: ("transmission tower", (200, 0, 0)),
    16: ("wire-structure connector", (255, 90, 90)),
    17: ("bridge deck", (120, 120, 200)),
    18: ("high noise", (200, 0, 200)),
    19: ("overhead structure", (220, 160, 120)),
    20: ("ignored ground", (120, 90, 60)),
    21: ("snow", (240, 250, 255)),
    22: ("temporal exclusion", (100, 100, 100)),
}
UNKNOWN_CLASS = (255, 80, 160)


def rgba8(rgb: np.ndarray) -> np.ndarray:
    """(n, 3|4) uint8-range values -> uint32 RGBA8 words (alpha 255)."""
    c = np.asarray(rgb, dtype=np.uint32)
    return c[:, 0] | (c[:, 1] << 8) | (c[:, 2] << 16) | np.uint32(0xFF000000)


def colormap_lut(colormap: Colormap) -> np.ndarray:
    import cmap

    rgba = cmap.Colormap(colormap.value)(np.linspace(0.0, 1.0, 256))
    return rgba8(np.round(np.asarray(rgba)[:, :3] * 255.0))


def classification_lut() -> np.ndarray:
    colours = np.array([ASPRS_CLASSES.get(c, (None, UNKNOWN_CLASS))[1] for c in range(256)])
    return rgba8(colours)


NO_RANGE = (0.0, 1.0)
"""The range of a style with nothing to range over (no scalar, or no finite value)."""


@dataclass(frozen=True)
class ColorStyle:
    mode: ColorMode
    palette: tuple[int, ...]          # 256 RGBA8 words
    value_range: tuple[float, float]  # scalar values (value - attribute offset) at the palette ends
    background: int                   # RGBA8
    automatic: bool = False           # value_range is the cloud's percentile range, kept current by the renderer

    @classmethod
    def for_attribute(cls, attr: AttributeInfo, value_range: tuple[float, float] = NO_RANGE,
                      colormap: Colormap = Colormap.VIRIDIS, background: tuple[int, int, int] = (0, 0, 0),
                      automatic: bool = False) -> ColorStyle:
        mode = ColorMode.for_kind(attr.kind)
        lut = classification_lut() if mode is ColorMode.CATEGORY else colormap_lut(colormap)
        bg = int(rgba8(np.array([background]))[0])
        return cls(mode, tuple(int(v) for v in lut), (float(value_range[0]), float(value_range[1])), bg, automatic)
