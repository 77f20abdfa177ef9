"""How attribute words become colours: RGB as stored, scalars through a colormap
(from the `cmap` library) over a range, classification codes through a palette
(Potree's and CloudCompare's colours for the ASPRS codes, overridable from JSON)."""

from __future__ import annotations

import enum
import functools
import re
from dataclasses import dataclass

import numpy as np

from progressive.errors import ProgressiveError
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


ASPRS_NAMES: dict[int, str] = {
    0: "created, never classified", 1: "unclassified", 2: "ground", 3: "low vegetation",
    4: "medium vegetation", 5: "high vegetation", 6: "building", 7: "low point (noise)",
    8: "model key-point (reserved in 1.4)", 9: "water", 10: "rail", 11: "road surface",
    12: "overlap (reserved in 1.4)", 13: "wire, guard (shield)", 14: "wire, conductor (phase)",
    15: "transmission tower", 16: "wire-structure connector", 17: "bridge deck", 18: "high noise",
    19: "overhead structure", 20: "ignored ground", 21: "snow", 22: "temporal exclusion",
}
"""ASPRS LAS 1.4 (R15) class names; ASPRS defines no colours, so they come from viewers."""

POTREE_CLASSES: dict[int, tuple[float, float, float]] = {
    0: (0.5, 0.5, 0.5), 1: (0.5, 0.5, 0.5), 2: (0.63, 0.32, 0.18), 3: (0.0, 1.0, 0.0), 4: (0.0, 0.8, 0.0),
    5: (0.0, 0.6, 0.0), 6: (1.0, 0.66, 0.0), 7: (1.0, 0.0, 1.0), 8: (1.0, 0.0, 0.0), 9: (0.0, 0.0, 1.0),
    12: (1.0, 1.0, 0.0),
}
"""Potree's ClassificationScheme.DEFAULT (src/materials/ClassificationScheme.js), as fractions."""

CLOUDCOMPARE_CLASSES: dict[int, tuple[int, int, int]] = {
    10: (85, 85, 0), 11: (128, 128, 128), 13: (191, 231, 205), 14: (193, 230, 125), 15: (0, 0, 128),
    16: (128, 128, 0), 17: (0, 128, 128), 18: (128, 0, 0), 19: (14, 170, 255), 20: (50, 255, 198),
    21: (255, 250, 250), 22: (0, 0, 0),
}
"""CloudCompare's ASPRS_CLASSES colour scale (libs/qCC_db/src/ccColorScalesManager.cpp) for the
codes Potree leaves out; Qt's dark colours are 128 a channel, and its qRgb(270, 170, 255) for 19
keeps the low byte of 270, as Qt draws it."""

UNKNOWN_CLASS = (255, 80, 160)
"""Codes 23-255 (no ASPRS name, no palette entry): a pink that no named class uses."""


def _unorm8(fraction: float) -> int:
    """A [0, 1] colour channel as 8 bits, as GL converts it (round to nearest)."""
    return int(fraction * 255.0 + 0.5)


ASPRS_CLASSES: dict[int, tuple[str, tuple[int, int, int]]] = {
    code: (name, tuple(_unorm8(c) for c in POTREE_CLASSES[code]) if code in POTREE_CLASSES
           else CLOUDCOMPARE_CLASSES[code])
    for code, name in ASPRS_NAMES.items()
}
"""Each ASPRS code's name and default colour (Potree's where it has one, else CloudCompare's)."""


def rgba8(rgb: np.ndarray) -> np.ndarray:
    """(n, 3|4) uint8-range values -> uint32 RGBA8 words (alpha 255)."""
    c = np.asarray(rgb, dtype=np.uint32)
    return c[:, 0] | (c[:, 1] << 8) | (c[:, 2] << 16) | np.uint32(0xFF000000)


@functools.cache
def colormap_lut(colormap: Colormap) -> tuple[int, ...]:
    """The colormap's 256 RGBA8 words, from cmap once per colormap: every frame asks for
    its style, and cmap's lookup (Python per colour) stalled frames while parser threads
    held the GIL (profiled on the H200 machine)."""
    import cmap

    rgba = cmap.Colormap(colormap.value)(np.linspace(0.0, 1.0, 256))
    return tuple(int(v) for v in rgba8(np.round(np.asarray(rgba)[:, :3] * 255.0)))


class PaletteError(ProgressiveError):
    """A --palette file that is not a JSON object of class codes and colours."""


CLASS_CODES = 256
HEX_COLOUR = re.compile(r"#([0-9a-fA-F]{2})([0-9a-fA-F]{2})([0-9a-fA-F]{2})")


@dataclass(frozen=True)
class Palette:
    """The colour of every classification code 0-255 (the legend's too)."""

    colours: tuple[tuple[int, int, int], ...] = tuple(ASPRS_CLASSES.get(c, (None, UNKNOWN_CLASS))[1]
                                                      for c in range(CLASS_CODES))

    def rgb(self, code: int) -> tuple[int, int, int]:
        return self.colours[code]

    @staticmethod
    def name(code: int) -> str:
        return ASPRS_NAMES.get(code, f"class {code}")

    def lut(self) -> np.ndarray:
        return rgba8(np.array(self.colours))

    def overridden(self, entries: dict[int, tuple[int, int, int]]) -> Palette:
        colours = list(self.colours)
        for code, rgb in entries.items():
            colours[code] = rgb
        return Palette(tuple(colours))

    @classmethod
    def from_json(cls, path: str) -> Palette:
        """The default palette with the entries of a JSON file {"code": [r, g, b] or
        "#rrggbb", ...} (codes 0-255 in decimal, channels 0-255) in their place."""
        from progressive.camera import CameraError, read_json_file

        try:
            data = read_json_file(path, "palette file")
        except CameraError as exc:
            raise PaletteError(str(exc)) from None
        if not isinstance(data, dict) or not data:
            raise PaletteError(f"palette file {path} must be a JSON object of class codes and colours, "
                               f'e.g. {{"2": [166, 116, 66], "6": "#ff8c1e"}}')
        return cls().overridden({_code(key, path): _colour(value, key, path) for key, value in data.items()})


def _code(key: str, path: str) -> int:
    if not (key.isascii() and key.isdigit() and str(int(key)) == key and int(key) < CLASS_CODES):
        raise PaletteError(f"palette file {path}: {key[:40]!r} is not a class code 0..255")
    return int(key)


def _colour(value, key: str, path: str) -> tuple[int, int, int]:
    if isinstance(value, str) and (match := HEX_COLOUR.fullmatch(value)):
        return tuple(int(h, 16) for h in match.groups())
    if isinstance(value, list) and len(value) == 3 and all(_channel(v) for v in value):
        return tuple(int(v) for v in value)
    raise PaletteError(f"palette file {path}: class {key}: {str(value)[:40]!r} is not [r, g, b] (0..255) or '#rrggbb'")


def _channel(v) -> bool:
    """A whole number 0..255 (the JSON reader gives numbers as floats)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and float(v).is_integer() and 0 <= v <= 255


DEFAULT_PALETTE = Palette()


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
                      automatic: bool = False, palette: Palette = DEFAULT_PALETTE) -> ColorStyle:
        mode = ColorMode.for_kind(attr.kind)
        lut = tuple(int(v) for v in palette.lut()) if mode is ColorMode.CATEGORY else colormap_lut(colormap)
        bg = int(rgba8(np.array([background]))[0])
        return cls(mode, lut, (float(value_range[0]), float(value_range[1])), bg, automatic)
