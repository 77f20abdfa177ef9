"""The viewer's first point size and eye-dome lighting, chosen from what the frame
shows and what the effects cost, each with the one line the panel gives for it.
Pure functions (numpy only), so the rules are testable against an independent
rasterization of the file.

Point size: a converged 1-pixel frame is cut into TILE-pixel squares; where the
cloud is (tiles with any point) the median share f of covered pixels gives the
points a pixel gets, lambda = -ln(1 - f), as if points fell at random. A point of
size s covers effects.footprint_pixels(s) pixels, so a share 1 - exp(-lambda * a)
of the image is covered; the size is the smallest whose share reaches COVERAGE,
at most AUTO_POINT_SIZE_MAX.

Eye-dome lighting: it helps where colours carry no shading of their own (any
colouring but RGB, which holds the scene's light), and is on by default there if
its measured GPU time at the window's size is at most EFFECT_SHARE of the frame's
goal; otherwise the frame rate would fall below the target for a look.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from progressive.effects import footprint_pixels

TILE = 16                   # pixels a side of the squares the coverage is taken over
COVERAGE = 0.9              # share of the cloud's pixels the chosen point size aims to cover
AUTO_POINT_SIZE_MAX = 4     # the dilation's cost grows with its area; larger sizes are the user's choice
EFFECT_SHARE = 0.25         # eye-dome lighting is on by default if it takes at most this share of the goal


@dataclass(frozen=True)
class Choice:
    """A default and the line the panel shows for it."""

    value: int | bool
    reason: str


def points_per_pixel(covered: np.ndarray, tile: int = TILE) -> float | None:
    """lambda of the rule above from an (H, W) bool mask of covered pixels; None
    where no whole tile holds a point."""
    h, w = (covered.shape[0] // tile) * tile, (covered.shape[1] // tile) * tile
    if h == 0 or w == 0:
        return None
    share = covered[:h, :w].reshape(h // tile, tile, w // tile, tile).mean(axis=(1, 3))
    share = share[share > 0]
    if share.size == 0:
        return None
    f = min(float(np.median(share)), 1.0 - 0.5 / (tile * tile))   # a full tile: at most "half a pixel" empty
    return -math.log1p(-f)


def point_size(covered: np.ndarray) -> Choice:
    """The smallest size covering COVERAGE of the cloud's pixels (rule above)."""
    lam = points_per_pixel(covered)
    if lam is None:
        return Choice(1, "point size 1: nothing on screen to measure the density from")
    need = -math.log1p(-COVERAGE) / lam            # pixels a point must cover
    size = next((s for s in range(1, AUTO_POINT_SIZE_MAX + 1) if footprint_pixels(s) >= need), AUTO_POINT_SIZE_MAX)
    return Choice(size, f"point size {size}: {lam:.2f} points a pixel where the cloud is; "
                        f"{size} px covers {1.0 - math.exp(-lam * footprint_pixels(size)):.0%} of it "
                        f"(aim {COVERAGE:.0%}, at most {AUTO_POINT_SIZE_MAX} by default)")


def eye_dome(rgb: bool, cost_ms: float | None, goal_ms: float) -> Choice:
    """On for colourings without light of their own, if its cost fits EFFECT_SHARE of the goal."""
    if rgb:
        return Choice(False, "eye-dome lighting off: RGB carries the scene's own shading")
    if cost_ms is None:
        return Choice(False, "eye-dome lighting off until its cost is measured")
    allowed = EFFECT_SHARE * goal_ms
    if cost_ms > allowed:
        return Choice(False, f"eye-dome lighting off: {cost_ms:.1f} ms a frame on this GPU, over "
                             f"{EFFECT_SHARE:.0%} of the {goal_ms:.1f} ms frame goal")
    return Choice(True, f"eye-dome lighting on: it shades a colouring without light of its own; "
                        f"{cost_ms:.1f} ms of the {goal_ms:.1f} ms frame goal")
