"""Z-up navigation in float64, GPU-free: an orbit around a target (yaw, pitch,
distance) that every gesture maps to, and back to a look-at Camera.

Gestures take pixels and the viewport, so speeds follow what the user sees: a pan
keeps the point under the cursor under it, a zoom scales the view about the point
under the cursor, fly speed is a share of the cloud's size per second."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace

import numpy as np

from progressive.camera import Camera, Projection, Section, auto_camera

MAX_PITCH = math.radians(89.5)
ZOOM_STEP = 0.85               # distance factor per wheel notch
ORBIT_RADIANS_PER_PIXEL = 0.005
FLY_EXTENTS_PER_SECOND = 0.25  # share of the cloud's diagonal flown per second
NEAR_OVER_FAR = 1e-6           # depth is linear float32: near costs no precision
PROFILE_MARGIN = 1.1           # a profile view spans this much more than the segment and the cloud's height
FRAME_MARGIN = 0.05            # share of the free area's width and height left around a framed cloud


class View(enum.Enum):
    TOP = "top"
    FRONT = "front"
    SIDE = "side"
    ISO = "iso"


PRESETS: dict[View, tuple[float, float]] = {
    View.TOP: (-math.pi / 2, MAX_PITCH),            # from above, north up
    View.FRONT: (-math.pi / 2, 0.0),                # from the south, looking north
    View.SIDE: (0.0, 0.0),                          # from the east, looking west
    View.ISO: (-math.pi / 4, math.radians(35.0)),   # from the south-east, 35 degrees up
}
"""(yaw, pitch) of each view; yaw is the camera's azimuth seen from the target."""


@dataclass(frozen=True)
class Orbit:
    target: tuple[float, float, float]
    distance: float
    yaw: float                 # azimuth of the camera seen from the target, radians
    pitch: float               # elevation of the camera above the target, radians
    fov_y_deg: float = 60.0
    orthographic: bool = False  # parallel projection spanning what the perspective view spans at the target
    pivot: tuple[float, float, float] | None = None
    """The point orbits turn about where it is not the target: the cloud's centre when it
    is framed off the view's axis (beside a panel), so it stays where it is on screen."""

    @property
    def view_height(self) -> float:
        """The world height the image spans at the target (the orthographic camera's height)."""
        return 2.0 * self.distance * math.tan(math.radians(self.fov_y_deg) / 2.0)

    @property
    def backward(self) -> np.ndarray:
        """Unit vector from the target towards the camera."""
        cp = math.cos(self.pitch)
        return np.array([cp * math.cos(self.yaw), cp * math.sin(self.yaw), math.sin(self.pitch)])

    @property
    def position(self) -> np.ndarray:
        return np.asarray(self.target, dtype=np.float64) + self.distance * self.backward

    def basis(self) -> tuple[np.ndarray, np.ndarray]:
        """(right, up) of the screen, in file coordinates."""
        forward = -self.backward
        right = np.cross(forward, (0.0, 0.0, 1.0))
        right /= np.linalg.norm(right)
        return right, np.cross(right, forward)

    @classmethod
    def from_camera(cls, camera: Camera) -> Orbit:
        back = np.subtract(camera.position, camera.target, dtype=np.float64)
        distance = float(np.linalg.norm(back))
        back /= distance
        pitch = max(-MAX_PITCH, min(MAX_PITCH, math.asin(max(-1.0, min(1.0, back[2])))))
        fov = camera.fov_y_deg
        if camera.orthographic:      # keep the height: the distance that spans it at this field of view
            distance = camera.height / (2.0 * math.tan(math.radians(fov) / 2.0))
        return cls(tuple(float(v) for v in camera.target), distance, math.atan2(back[1], back[0]), pitch,
                   fov, camera.orthographic)


@dataclass(frozen=True)
class Navigator:
    """The cloud's extent (for clipping planes and speeds) and the home view."""

    bounds_min: tuple[float, float, float]
    bounds_max: tuple[float, float, float]
    home: Orbit

    @classmethod
    def for_bounds(cls, bounds_min, bounds_max, aspect: float) -> Navigator:
        lo, hi = (tuple(float(v) for v in b) for b in (bounds_min, bounds_max))
        return cls(lo, hi, Orbit.from_camera(auto_camera(np.array(lo), np.array(hi), aspect)))

    def framed(self, size: tuple[int, int], free: tuple[float, float, float, float],
               yaw: float | None = None, pitch: float | None = None) -> Orbit:
        """The home view's direction (or `yaw`, `pitch`) at the nearest distance at which
        the bounding box's 8 corners project inside `free` (x0, y0, x1, y1 image pixels,
        row 0 at the top, less FRAME_MARGIN), centred in it; it orbits about the box's
        centre. For a fixed direction each corner's constraint is linear in the camera's
        position (right, up, back), so the nearest distance and the sideways shift have a
        closed form."""
        w, h = size
        x0, y0, x1, y1 = free
        mx, my = FRAME_MARGIN * (x1 - x0), FRAME_MARGIN * (y1 - y0)
        x0, x1, y0, y1 = x0 + mx, x1 - mx, y0 + my, y1 - my
        o = replace(self.home, yaw=self.home.yaw if yaw is None else yaw,
                    pitch=self.home.pitch if pitch is None else pitch, pivot=None)
        right, up = o.basis()
        forward = -o.backward
        focal = 1.0 / math.tan(math.radians(o.fov_y_deg) / 2.0)
        half = np.maximum((np.asarray(self.bounds_max) - np.asarray(self.bounds_min)) / 2.0, 1e-3)
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
        depth = corners @ forward
        # ndc bounds of the free area on each axis (y up), the axis' scale and direction
        axes = (((2.0 * x0 / w - 1.0, 2.0 * x1 / w - 1.0), focal * h / w, corners @ right),
                ((1.0 - 2.0 * y1 / h, 1.0 - 2.0 * y0 / h), focal, corners @ up))
        distance = 0.0
        for (lo, hi), scale, across in axes:
            # scale (across - s) within [lo, hi] (depth + distance): s is the shift
            distance = max(distance, float(np.max(scale * across - hi * depth) - np.min(scale * across - lo * depth))
                           / (hi - lo))
        shifts = []
        for (lo, hi), scale, across in axes:
            low = float(np.max(scale * across - hi * (depth + distance))) / scale
            high = float(np.min(scale * across - lo * (depth + distance))) / scale
            shifts.append((low + high) / 2.0)
        centre = self.centre
        target = centre + shifts[0] * right + shifts[1] * up
        return replace(o, target=tuple(target.tolist()), distance=distance, pivot=tuple(centre.tolist()))

    @property
    def centre(self) -> np.ndarray:
        return (np.asarray(self.bounds_min) + np.asarray(self.bounds_max)) / 2.0

    @property
    def diagonal(self) -> float:
        return max(float(np.linalg.norm(np.subtract(self.bounds_max, self.bounds_min))), 1e-3)

    def camera(self, o: Orbit) -> Camera:
        """Far reaches past the whole cloud from wherever the camera is. An orthographic
        eye stands back beyond the cloud (its zoom is the height, not the distance), so
        nothing between the target and the cloud's edge is cut by the near plane."""
        position = o.position
        if o.orthographic:
            position = np.asarray(o.target, dtype=np.float64) + o.backward * (o.distance + self.diagonal)
        far = 1.05 * (float(np.linalg.norm(position - self.centre)) + self.diagonal / 2.0)
        far = max(far, o.distance * 1.05)
        if o.orthographic:
            return Camera(tuple(position.tolist()), o.target, (0.0, 0.0, 1.0), o.fov_y_deg, far * NEAR_OVER_FAR, far,
                          Projection.ORTHOGRAPHIC, o.view_height)
        return Camera(tuple(position.tolist()), o.target, (0.0, 0.0, 1.0), o.fov_y_deg, far * NEAR_OVER_FAR, far)

    def preset(self, o: Orbit, view: View) -> Orbit:
        """A standard view of the target from the same distance and projection."""
        yaw, pitch = PRESETS[view]
        return self.turned(o, yaw, pitch)

    def profile(self, o: Orbit, section: Section, aspect: float) -> Orbit:
        """An orthographic view of a section from the side: looking along its normal
        (its start on the left, its end on the right), level, centred on the segment's
        middle at the cloud's mid-height, spanning the segment and the cloud's height."""
        u = section.axis
        normal = np.array([-u[1], u[0]])           # the viewing direction: right = forward x Z = the axis
        middle = (np.asarray(section.start) + np.asarray(section.end)) / 2.0
        z = (self.bounds_min[2] + self.bounds_max[2]) / 2.0
        height = PROFILE_MARGIN * max(self.bounds_max[2] - self.bounds_min[2], section.length / aspect, 1e-3)
        distance = height / (2.0 * math.tan(math.radians(o.fov_y_deg) / 2.0))
        return Orbit((float(middle[0]), float(middle[1]), float(z)), distance,
                     math.atan2(-normal[1], -normal[0]), 0.0, o.fov_y_deg, True)

    def orbit(self, o: Orbit, dx: float, dy: float) -> Orbit:
        """Drag right turns the cloud right; drag down tilts the view down onto it."""
        pitch = max(-MAX_PITCH, min(MAX_PITCH, o.pitch + dy * ORBIT_RADIANS_PER_PIXEL))
        return self.turned(o, o.yaw - dx * ORBIT_RADIANS_PER_PIXEL, pitch)

    def turned(self, o: Orbit, yaw: float, pitch: float) -> Orbit:
        """The view turned to (yaw, pitch) about the orbit's pivot: the camera moves
        rigidly (about Z, then about its horizontal right axis), so the pivot keeps its
        place on screen; without a pivot the target stays."""
        turned = replace(o, yaw=yaw, pitch=pitch)
        if o.pivot is None:
            return turned
        pivot = np.asarray(o.pivot, dtype=np.float64)
        # the target's offset from the pivot in the old camera's frame, rebuilt in the new one
        offset = np.asarray(o.target) - pivot
        (r0, u0), b0 = o.basis(), o.backward
        (r1, u1), b1 = turned.basis(), turned.backward
        target = pivot + (offset @ r0) * r1 + (offset @ u0) * u1 + (offset @ b0) * b1
        return replace(turned, target=tuple(target.tolist()))

    def pan(self, o: Orbit, dx: float, dy: float, viewport_height: int) -> Orbit:
        """Move the target in the screen plane so the target's depth follows the cursor."""
        per_pixel = 2.0 * o.distance * math.tan(math.radians(o.fov_y_deg) / 2.0) / max(1, viewport_height)
        right, up = o.basis()
        shift = (-dx * right + dy * up) * per_pixel
        pivot = None if o.pivot is None else tuple((np.asarray(o.pivot) + shift).tolist())
        return replace(o, target=tuple((np.asarray(o.target) + shift).tolist()), pivot=pivot)

    def cursor_point(self, o: Orbit, x: float, y: float, size: tuple[int, int], depth: float) -> np.ndarray:
        """The file-coordinate point under window pixel (x, y) at `depth` along the view."""
        forward = -o.backward
        if not o.orthographic:
            ray = self.cursor_ray(o, x, y, size)
            return o.position + ray * depth / max(float(ray @ forward), 1e-6)
        w, h = size
        right, up = o.basis()
        half = o.view_height / 2.0
        eye = np.asarray(self.camera(o).position, dtype=np.float64)
        return eye + forward * depth + right * (2.0 * x / w - 1.0) * half * w / h + up * (1.0 - 2.0 * y / h) * half

    def cursor_ray(self, o: Orbit, x: float, y: float, size: tuple[int, int]) -> np.ndarray:
        """Unit direction through window pixel (x, y), row 0 at the top (camera.project's inverse)."""
        w, h = size
        f = 1.0 / math.tan(math.radians(o.fov_y_deg) / 2.0)
        vx = (2.0 * x / w - 1.0) * w / (h * f)
        vy = (1.0 - 2.0 * y / h) / f
        right, up = o.basis()
        d = -o.backward + vx * right + vy * up
        return d / np.linalg.norm(d)

    def zoom(self, o: Orbit, steps: float, anchor: np.ndarray | None = None) -> Orbit:
        """Scale the view about `anchor` (the point under the cursor, file coordinates):
        it stays under the cursor. Without one, about the pivot (a framed cloud's centre
        stays put), else about the target."""
        factor = ZOOM_STEP ** steps
        if anchor is None and o.pivot is not None:
            anchor = np.asarray(o.pivot, dtype=np.float64)
        if anchor is None:
            return replace(o, distance=o.distance * factor)
        anchor = np.asarray(anchor, dtype=np.float64)
        target = anchor + (np.asarray(o.target) - anchor) * factor
        pivot = None if o.pivot is None else tuple((anchor + (np.asarray(o.pivot) - anchor) * factor).tolist())
        return replace(o, target=tuple(target.tolist()), distance=o.distance * factor, pivot=pivot)

    def focus(self, o: Orbit, point: np.ndarray) -> Orbit:
        """Orbit about `point` from where the camera is now (no jump of the view direction)."""
        point = np.asarray(point, dtype=np.float64)
        back = o.position - point
        distance = float(np.linalg.norm(back))
        if distance <= 0.0:
            return replace(o, target=tuple(point.tolist()), pivot=None)
        back /= distance
        pitch = max(-MAX_PITCH, min(MAX_PITCH, math.asin(max(-1.0, min(1.0, back[2])))))
        return replace(o, target=tuple(point.tolist()), distance=distance, yaw=math.atan2(back[1], back[0]), pitch=pitch,
                       pivot=None)

    def fly(self, o: Orbit, forward: float, right: float, up: float, seconds: float) -> Orbit:
        """Move camera and target together; speed is a share of the cloud's size."""
        step = FLY_EXTENTS_PER_SECOND * self.diagonal * seconds
        r, _ = o.basis()
        move = (-o.backward * forward + r * right + np.array([0.0, 0.0, 1.0]) * up) * step
        return replace(o, target=tuple((np.asarray(o.target) + move).tolist()), pivot=None)

    def look(self, o: Orbit, dx: float, dy: float) -> Orbit:
        """Turn the view about the camera position (fly mode's mouse)."""
        position = o.position
        turned = replace(o, yaw=o.yaw - dx * ORBIT_RADIANS_PER_PIXEL,
                         pitch=max(-MAX_PITCH, min(MAX_PITCH, o.pitch - dy * ORBIT_RADIANS_PER_PIXEL)))
        target = position - turned.distance * turned.backward
        return replace(turned, target=tuple(target.tolist()), pivot=None)
