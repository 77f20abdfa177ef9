"""Screen-space effects a frame may ask for. The defaults ask for none, and a pass
that is not asked for is neither compiled nor run."""

from __future__ import annotations

import math
from dataclasses import dataclass

MAX_POINT_SIZE = 32


@dataclass(frozen=True)
class EyeDome:
    strength: float = 1.0       # exp(-300 * strength * mean log2-depth step): Potree's scale
    radius: float = 1.4         # pixels to the 8 neighbours

    def __post_init__(self) -> None:
        if not (math.isfinite(self.strength) and self.strength >= 0.0):
            raise ValueError(f"eye-dome strength must be a finite number >= 0, got {self.strength}")
        if not (math.isfinite(self.radius) and 0.5 <= self.radius <= 16.0):
            raise ValueError(f"eye-dome radius must be in [0.5, 16] pixels, got {self.radius}")


@dataclass(frozen=True)
class Effects:
    point_size: int = 1                 # pixels across; above 1 the dilation pass runs
    eye_dome: EyeDome | None = None     # None: no eye-dome lighting pass

    def __post_init__(self) -> None:
        if not 1 <= self.point_size <= MAX_POINT_SIZE:
            raise ValueError(f"point size must be 1..{MAX_POINT_SIZE} pixels, got {self.point_size}")


def footprint(point_size: int) -> tuple[int, float]:
    """(reach, squared radius) of a point's disc: pixel offsets (dx, dy) with
    dx² + dy² <= (size / 2)² are covered; a size of 1 covers its own pixel only."""
    if point_size <= 1:
        return 0, 0.0
    radius2 = (point_size / 2.0) ** 2
    return int(math.floor(math.sqrt(radius2))), radius2


def footprint_pixels(point_size: int) -> int:
    """Pixels a point of this size covers (the disc of footprint())."""
    reach, radius2 = footprint(point_size)
    d = range(-reach, reach + 1)
    return sum(1 for dx in d for dy in d if dx * dx + dy * dy <= radius2)
