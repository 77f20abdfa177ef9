"""Cameras in float64 file coordinates; only camera-relative float32 reaches the GPU.

A look-at camera (position, target, up, vertical field of view, near, far) looks down
its view-space -z axis; depth is the distance along the viewing direction."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass

import numpy as np

from progressive.errors import ProgressiveError

Vec3 = tuple[float, float, float]
AUTO_AZIMUTH_OFFSET_DEG = 25.0
AUTO_ELEVATION_DEG = 35.0


class CameraError(ProgressiveError):
    pass


@dataclass(frozen=True)
class Camera:
    position: Vec3
    target: Vec3
    up: Vec3 = (0.0, 0.0, 1.0)
    fov_y_deg: float = 60.0
    near: float = 0.1
    far: float = 10_000.0

    def __post_init__(self) -> None:
        values = (*self.position, *self.target, *self.up, self.fov_y_deg, self.near, self.far)
        if not all(math.isfinite(v) for v in values):
            raise CameraError("camera values must be finite numbers")
        if not 0.0 < self.fov_y_deg < 180.0:
            raise CameraError(f"camera fov_y_deg must be in (0, 180), got {self.fov_y_deg}")
        if not 0.0 < self.near < self.far:
            raise CameraError(f"camera needs 0 < near < far, got near={self.near} far={self.far}")
        forward = np.subtract(self.target, self.position, dtype=np.float64)
        if not np.linalg.norm(forward) > 0.0:
            raise CameraError("camera position and target coincide")
        if not np.linalg.norm(np.cross(forward, self.up)) > 1e-12 * np.linalg.norm(forward) * np.linalg.norm(self.up):
            raise CameraError("camera up is parallel to the viewing direction (or zero)")

    def rotation(self) -> np.ndarray:
        """Rows: right, up, backward (float64), so view = R @ (x - position)."""
        forward = np.subtract(self.target, self.position, dtype=np.float64)
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, np.asarray(self.up, dtype=np.float64))
        right /= np.linalg.norm(right)
        true_up = np.cross(right, forward)
        return np.stack([right, true_up, -forward])

    def focal(self) -> float:
        return 1.0 / math.tan(math.radians(self.fov_y_deg) / 2.0)

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)

    @classmethod
    def from_dict(cls, data: object) -> Camera:
        if not isinstance(data, dict):
            raise CameraError("camera JSON must be an object")
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise CameraError(f"unknown camera field(s): {', '.join(sorted(unknown))}")
        missing = {"position", "target"} - set(data)
        if missing:
            raise CameraError(f"camera JSON lacks {', '.join(sorted(missing))}")
        kwargs = {}
        for key, value in data.items():
            if key in ("position", "target", "up"):
                if not (isinstance(value, list) and len(value) == 3 and all(_is_number(v) for v in value)):
                    raise CameraError(f"camera {key} must be a list of 3 numbers")
                kwargs[key] = tuple(float(v) for v in value)
            else:
                if not _is_number(value):
                    raise CameraError(f"camera {key} must be a number")
                kwargs[key] = float(value)
        return cls(**kwargs)

    @classmethod
    def from_json(cls, text: str) -> Camera:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise CameraError(f"camera is not valid JSON ({exc.msg} at line {exc.lineno})") from None
        return cls.from_dict(data)


def _is_number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


@dataclass(frozen=True)
class ViewUniforms:
    """What the shaders get: float32, relative to the cloud origin."""

    rotation: np.ndarray      # (3, 3) float32
    translation: np.ndarray   # (3,) float32 = R @ (origin - position), in float64 first
    projection: np.ndarray    # (4,) float32: f/aspect, f, near, far
    size: tuple[int, int]
    hidden: np.ndarray        # (8,) uint32: bit c set = category code c not drawn


def hidden_mask(hidden: frozenset[int]) -> np.ndarray:
    """The 256-bit mask of category codes (0..255) left out of the raster."""
    mask = np.zeros(8, dtype=np.uint32)
    for code in hidden:
        if not 0 <= code <= 255:
            raise ValueError(f"category code {code} outside 0..255")
        mask[code >> 5] |= np.uint32(1 << (code & 31))
    return mask


def view_uniforms(camera: Camera, origin: np.ndarray, width: int, height: int,
                  hidden: frozenset[int] = frozenset()) -> ViewUniforms:
    r = camera.rotation()
    t = r @ (np.asarray(origin, dtype=np.float64) - np.asarray(camera.position, dtype=np.float64))
    f = camera.focal()
    proj = np.array([f * height / width, f, camera.near, camera.far], dtype=np.float64)
    return ViewUniforms(r.astype(np.float32), t.astype(np.float32), proj.astype(np.float32), (width, height),
                        hidden_mask(hidden))


def auto_camera(bounds_min: np.ndarray, bounds_max: np.ndarray, aspect: float, fov_y_deg: float = 60.0) -> Camera:
    """Frame the bounding box from an oblique view across its longer horizontal side
    (so strips fill the width): the nearest distance at which all 8 corners fit."""
    lo = np.asarray(bounds_min, dtype=np.float64)
    hi = np.asarray(bounds_max, dtype=np.float64)
    centre = (lo + hi) / 2.0
    half = np.maximum((hi - lo) / 2.0, 1e-3)
    side = -90.0 if half[0] >= half[1] else 180.0
    az, el = math.radians(side + AUTO_AZIMUTH_OFFSET_DEG), math.radians(AUTO_ELEVATION_DEG)
    back = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    right = np.cross(-back, (0.0, 0.0, 1.0))
    right /= np.linalg.norm(right)
    up = np.cross(right, -back)
    tan_y = math.tan(math.radians(fov_y_deg) / 2.0)
    tan_x = tan_y * aspect
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    toward = corners @ back
    distance = 1.05 * float(np.max(np.maximum(toward + np.abs(corners @ right) / tan_x,
                                              toward + np.abs(corners @ up) / tan_y)))
    radius = float(np.linalg.norm(half))
    near = max(distance - radius, radius * 1e-3) * 0.5
    return Camera(tuple((centre + distance * back).tolist()), tuple(centre.tolist()), (0.0, 0.0, 1.0),
                  fov_y_deg, near, (distance + radius) * 1.5)


def project(camera: Camera, xyz: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """The render contract in float64: (pixel index or -1, depth) for file coordinates."""
    v = (np.asarray(xyz, dtype=np.float64) - np.asarray(camera.position)) @ camera.rotation().T
    depth = -v[:, 2]
    f = camera.focal()
    with np.errstate(divide="ignore", invalid="ignore"):
        fx = (f * height / width * v[:, 0] / depth * 0.5 + 0.5) * width
        fy = (0.5 - f * v[:, 1] / depth * 0.5) * height
    ok = (depth >= camera.near) & (depth <= camera.far) & (fx >= 0) & (fx < width) & (fy >= 0) & (fy < height)
    pixel = np.full(depth.shape, -1, dtype=np.int64)
    pixel[ok] = np.floor(fy[ok]).astype(np.int64) * width + np.floor(fx[ok]).astype(np.int64)
    return pixel, depth
