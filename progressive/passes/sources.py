"""Where a raster pass takes its slots from (shaders/sources.glsl)."""

from __future__ import annotations

import enum


class Source(enum.IntEnum):
    RANGE = 0     # a uniform range: the whole cloud, brute force
    PIECE = 1     # a fill piece placed by the budget pass
    LIST = 2      # the slots visible last frame (reprojection)

    @classmethod
    def defines(cls, source: Source) -> dict[str, int]:
        d = {f"SOURCE_{s.name}": int(s) for s in cls}
        d["SOURCE"] = int(source)
        return d
