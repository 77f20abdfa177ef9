"""The clip box on screen, GPU-free: its edges clipped to the near plane, a handle at
the centre of each face, and the drag that moves a face along its normal. Geometry is
float64 in file coordinates; screen positions are framebuffer pixels (row 0 at the
top), as camera.screen_points gives them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from progressive.camera import Camera, Clip, pixel_ray, screen_points

HANDLE_PIXELS = 9.0
"""How near (framebuffer pixels) a press must be to a face's handle to drag it."""
MIN_SCREEN_SLOPE = 1e-3
"""A face whose normal is this close to the view direction (the sine of the angle
between them) is not dragged: the cursor would move it arbitrarily far."""


@dataclass(frozen=True)
class Face:
    axis: int      # 0, 1, 2: x, y, z
    side: int      # 0: the min side, 1: the max side


FACES = tuple(Face(axis, side) for axis in range(3) for side in (0, 1))


def shown_box(clip: Clip, bounds_min, bounds_max) -> tuple[np.ndarray, np.ndarray]:
    """The box drawn and dragged: the clip's sides, its infinite ones at the cloud's
    bounds (kept on the right side of a finite opposite side)."""
    lo, hi = np.array(clip.lo, dtype=np.float64), np.array(clip.hi, dtype=np.float64)
    lo = np.where(np.isfinite(lo), lo, np.minimum(np.asarray(bounds_min, dtype=np.float64), hi))
    hi = np.where(np.isfinite(hi), hi, np.maximum(np.asarray(bounds_max, dtype=np.float64), lo))
    return lo, hi


def face_centre(lo: np.ndarray, hi: np.ndarray, face: Face) -> np.ndarray:
    centre = (lo + hi) / 2.0
    centre[face.axis] = (lo, hi)[face.side][face.axis]
    return centre


EDGES = tuple((a, a | 1 << k) for a in range(8) for k in range(3) if not a & 1 << k)
"""The 12 edges of a box as pairs of corner numbers (bit k set: the max side on axis k)."""


def box_edges(camera: Camera, lo: np.ndarray, hi: np.ndarray, size: tuple[int, int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Screen segments of the box's edges, each cut where it crosses the near plane
    (the part behind is not drawn)."""
    corners = np.array([[(hi if c >> k & 1 else lo)[k] for k in range(3)] for c in range(8)])
    _, depth = screen_points(camera, corners, *size)
    out = []
    for a, b in EDGES:
        pa, pb, da, db = corners[a], corners[b], depth[a], depth[b]
        if da < camera.near and db < camera.near:
            continue
        if da < camera.near or db < camera.near:     # move the end behind onto the near plane
            t = (camera.near - da) / (db - da)
            cut = pa + t * (pb - pa)
            pa, pb = (cut, pb) if da < camera.near else (pa, cut)
        xy, _ = screen_points(camera, np.stack([pa, pb]), *size)
        out.append((xy[0], xy[1]))
    return out


def face_handles(camera: Camera, lo: np.ndarray, hi: np.ndarray, size: tuple[int, int]) -> dict[Face, np.ndarray]:
    """Screen positions of the face centres in front of the near plane."""
    centres = np.stack([face_centre(lo, hi, f) for f in FACES])
    xy, depth = screen_points(camera, centres, *size)
    return {f: xy[i] for i, f in enumerate(FACES) if depth[i] >= camera.near and np.isfinite(xy[i]).all()}


def handle_at(camera: Camera, lo: np.ndarray, hi: np.ndarray, size: tuple[int, int], x: float, y: float) -> Face | None:
    """The face whose handle is nearest to (x, y), within HANDLE_PIXELS, that can be dragged."""
    best, best_distance = None, HANDLE_PIXELS
    for face, xy in face_handles(camera, lo, hi, size).items():
        distance = float(np.hypot(xy[0] - x, xy[1] - y))
        if distance <= best_distance and along_axis(camera, face_centre(lo, hi, face), face.axis, size, x, y) is not None:
            best, best_distance = face, distance
    return best


def along_axis(camera: Camera, point: np.ndarray, axis: int, size: tuple[int, int], x: float, y: float) -> float | None:
    """Where the axis line through `point` comes closest to the ray through (x, y): the
    signed distance from `point` along the axis, in file units; None where the axis
    lies (nearly) along the ray."""
    origin, d = pixel_ray(camera, x, y, *size)
    e = np.zeros(3)
    e[axis] = 1.0
    b = float(e @ d)
    denom = 1.0 - b * b
    if denom < MIN_SCREEN_SLOPE ** 2:
        return None
    w = np.asarray(point, dtype=np.float64) - origin
    return (b * float(d @ w) - float(e @ w)) / denom


def dragged(clip: Clip, face: Face, start_bound: float, start_along: float, along: float) -> Clip:
    """The clip with `face` moved from `start_bound` by how far the cursor's point on the
    axis moved (along - start_along), kept on its side of the opposite face."""
    lo, hi = list(clip.lo), list(clip.hi)
    bound = start_bound + (along - start_along)
    if face.side == 0:
        lo[face.axis] = min(bound, hi[face.axis])
    else:
        hi[face.axis] = max(bound, lo[face.axis])
    return Clip(tuple(lo), tuple(hi), clip.section)
