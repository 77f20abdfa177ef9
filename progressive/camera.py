"""Cameras in float64 file coordinates; only camera-relative float32 reaches the GPU.

A look-at camera (position, target, up, vertical field of view, near, far) looks down
its view-space -z axis; depth is the distance along the viewing direction."""

from __future__ import annotations

import enum
import functools
import json
import math
import os
import re
import stat
from dataclasses import asdict, dataclass, field

import numpy as np

from progressive.errors import ProgressiveError

Vec3 = tuple[float, float, float]
AUTO_AZIMUTH_OFFSET_DEG = 25.0
AUTO_ELEVATION_DEG = 35.0
MAX_COORDINATE = 1e15
"""Largest |x|, |y|, |z| of a camera position, target or up: differences and squares stay
exact enough in float64, and camera-relative values fit float32."""
MIN_EXTENT = 1e-30
"""Smallest near plane, |target - position| and |up|: normal in float32, squares normal in float64."""
MAX_DEPTH = 1e30
"""Largest far plane: representable in float32, its square in float64."""
MIN_FOV_DEG = 1e-6
"""Smallest vertical field of view: the focal length stays far inside float32."""
MAX_JSON_BYTES = 16 * 2**20
"""A camera or camera path (16,384 frames of a few hundred bytes fit easily)."""
MAX_JSON_DEPTH = 8
MAX_NUMBER_CHARS = 64
"""Digits (and sign, point, exponent) of one JSON number: 1e15 to full float64 precision fits."""


class CameraError(ProgressiveError):
    pass


class Projection(enum.Enum):
    PERSPECTIVE = "perspective"
    ORTHOGRAPHIC = "orthographic"     # parallel rays; `height` is the world height the image spans


@dataclass(frozen=True)
class Camera:
    position: Vec3
    target: Vec3
    up: Vec3 = (0.0, 0.0, 1.0)
    fov_y_deg: float = 60.0
    near: float = 0.1
    far: float = 10_000.0
    projection: Projection = Projection.PERSPECTIVE
    height: float | None = None       # orthographic: the world height of the image

    def __post_init__(self) -> None:
        """Every bound the float64 maths and the float32 GPU values need, one message each."""
        if not isinstance(self.projection, Projection):
            raise CameraError("camera projection must be 'perspective' or 'orthographic'")
        if self.projection is Projection.ORTHOGRAPHIC:
            if self.height is None or not _finite(self.height) or not MIN_EXTENT <= self.height <= MAX_DEPTH:
                raise CameraError(f"an orthographic camera needs a height in [{MIN_EXTENT:g}, {MAX_DEPTH:g}]")
        elif self.height is not None:
            raise CameraError("camera height is for orthographic cameras")
        for key in ("position", "target", "up"):
            vec = getattr(self, key)
            if len(vec) != 3 or not all(_finite(v) for v in vec):
                raise CameraError(f"camera {key} must be 3 finite numbers")
            if max(abs(v) for v in vec) > MAX_COORDINATE:
                raise CameraError(f"camera {key} {_show(vec)} is beyond +-{MAX_COORDINATE:g}")
        for key in ("fov_y_deg", "near", "far"):
            if not _finite(getattr(self, key)):
                raise CameraError(f"camera {key} must be a finite number")
        if not MIN_FOV_DEG <= self.fov_y_deg < 180.0:
            raise CameraError(f"camera fov_y_deg must be in [{MIN_FOV_DEG:g}, 180), got {self.fov_y_deg:g}")
        if not MIN_EXTENT <= self.near < self.far <= MAX_DEPTH:
            raise CameraError(f"camera needs {MIN_EXTENT:g} <= near < far <= {MAX_DEPTH:g}, "
                              f"got near={self.near:g} far={self.far:g}")
        forward = np.subtract(self.target, self.position, dtype=np.float64)
        if np.max(np.abs(forward)) < MIN_EXTENT:
            raise CameraError("camera position and target coincide")
        up = np.asarray(self.up, dtype=np.float64)
        if np.max(np.abs(up)) < MIN_EXTENT:
            raise CameraError("camera up is zero")

    def rotation(self) -> np.ndarray:
        """Rows: right, up, backward (float64), so view = R @ (x - position). An up
        parallel to the view (a plan view with Z up) gives way to +Y, or to +X when
        the view is along Y: the same screen orientation every time."""
        forward = _unit(np.subtract(self.target, self.position, dtype=np.float64))
        for up in (np.asarray(self.up, dtype=np.float64), np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])):
            cross = np.cross(forward, _unit(up))
            if np.linalg.norm(cross) > 1e-9:
                break
        right = _unit(cross)
        true_up = np.cross(right, forward)
        return np.stack([right, true_up, -forward])

    @property
    def orthographic(self) -> bool:
        return self.projection is Projection.ORTHOGRAPHIC

    def focal(self) -> float:
        return 1.0 / math.tan(math.radians(self.fov_y_deg) / 2.0)

    def scales(self, width: int, height: int) -> tuple[float, float]:
        """ndc = scale * view x, y (divided by depth when perspective): f/aspect and f,
        or for orthographic 2/(height·aspect) and 2/height."""
        if self.orthographic:
            return 2.0 * height / (self.height * width), 2.0 / self.height
        f = self.focal()
        return f * height / width, f

    def to_dict(self) -> dict:
        """The render contract's JSON; projection and height only for orthographic cameras."""
        out = {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}
        if self.orthographic:
            out["projection"] = self.projection.value
        else:
            del out["projection"], out["height"]
        return out

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
            if key == "projection":
                names = {p.value: p for p in Projection}
                if not isinstance(value, str) or value not in names:
                    raise CameraError("camera projection must be 'perspective' or 'orthographic'")
                kwargs[key] = names[value]
            elif key in ("position", "target", "up"):
                if not (isinstance(value, list) and len(value) == 3 and all(_is_number(v) for v in value)):
                    raise CameraError(f"camera {key} must be a list of 3 numbers")
                kwargs[key] = tuple(_float(key, v) for v in value)
            else:
                if not _is_number(value):
                    raise CameraError(f"camera {key} must be a number")
                kwargs[key] = _float(key, value)
        return cls(**kwargs)

    @classmethod
    def from_json(cls, text: str) -> Camera:
        return cls.from_dict(parse_json(text, "camera"))


def _is_number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _float(key: str, v: int | float) -> float:
    try:
        return float(v)
    except OverflowError:
        raise CameraError(f"camera {key} is beyond float64") from None


def _finite(v: object) -> bool:
    try:
        return math.isfinite(v)
    except (TypeError, OverflowError):
        return False


def _unit(v: np.ndarray) -> np.ndarray:
    """v / |v| without overflow or underflow: scaled by its largest component first."""
    v = v / np.max(np.abs(v))
    return v / np.linalg.norm(v)


def _show(vec) -> str:
    return "[" + ", ".join(f"{v:g}" for v in vec) + "]"


def _number(text: str) -> float:
    """JSON numbers as float, refused when too long to be a camera value (Python's int
    and float would take thousands of digits, slowly or not at all) or not finite."""
    if len(text) > MAX_NUMBER_CHARS:
        raise CameraError(f"a number of {len(text)} characters (at most {MAX_NUMBER_CHARS})")
    value = float(text)
    if not math.isfinite(value):
        raise CameraError(f"number {text[:24]} is beyond float64")
    return value


def _constant(name: str):
    raise CameraError(f"{name} is not a number JSON allows")


def json_depth(text: str) -> int:
    """Deepest nesting of [ and { outside strings, found without recursion (json.loads
    would raise RecursionError, or exhaust the stack)."""
    code = np.frombuffer(_JSON_STRING.sub("", text).encode("utf-8", "replace"), dtype=np.uint8)
    steps = np.isin(code, _OPEN).astype(np.int64) - np.isin(code, _CLOSE)
    return int(np.cumsum(steps).max(initial=0))


_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)
_OPEN, _CLOSE = np.frombuffer(b"[{", np.uint8), np.frombuffer(b"]}", np.uint8)


def parse_json(text: str, what: str) -> object:
    """JSON of bounded size, nesting and number length; every number a finite float."""
    if len(text) > MAX_JSON_BYTES:
        raise CameraError(f"{what} is {len(text):,} characters (at most {MAX_JSON_BYTES:,})")
    if json_depth(text) > MAX_JSON_DEPTH:
        raise CameraError(f"{what} JSON is nested more than {MAX_JSON_DEPTH} deep")
    try:
        return json.loads(text, parse_int=_number, parse_float=_number, parse_constant=_constant)
    except json.JSONDecodeError as exc:
        raise CameraError(f"{what} is not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except CameraError as exc:
        raise CameraError(f"{what} JSON: {exc}") from None
    except RecursionError:
        raise CameraError(f"{what} JSON is nested too deep") from None


def read_json_file(path: str | os.PathLike, what: str) -> object:
    """A JSON file that must be a regular file (a FIFO or device would block or never
    end), read whole up to MAX_JSON_BYTES, UTF-8."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise CameraError(f"{what} {path} not found") from None
    except OSError as exc:
        raise CameraError(f"cannot read {what} {path}: {exc.strerror}") from None
    except ValueError as exc:                # a NUL byte in the name
        raise CameraError(f"cannot read {what} {path!r}: {exc}") from None
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise CameraError(f"{what} {path} is a directory")
        if not stat.S_ISREG(st.st_mode):
            raise CameraError(f"{what} {path} is not a regular file")
        if st.st_size > MAX_JSON_BYTES:
            raise CameraError(f"{what} {path} is {st.st_size:,} bytes (at most {MAX_JSON_BYTES:,})")
        try:
            data = fh.read(MAX_JSON_BYTES + 1)
        except OSError as exc:
            raise CameraError(f"cannot read {what} {path}: {exc.strerror}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise CameraError(f"{what} {path} is not UTF-8 text") from None
    return parse_json(text, f"{what} {path}")


@dataclass(frozen=True)
class Section:
    """A thin vertical slab along a horizontal segment, for profiles: a point is kept
    iff its XY lies within width/2 of the segment's line and between the segment's two
    ends (a rectangle in XY, unbounded in Z), so the slab ends where the picked line
    does. Limited to the segment rather than the infinite plane: a profile between
    two picked points shows that stretch, not every feature the line's extension
    crosses across the cloud."""

    start: tuple[float, float]
    end: tuple[float, float]
    width: float

    def __post_init__(self):
        a, b = np.asarray(self.start, dtype=np.float64), np.asarray(self.end, dtype=np.float64)
        if a.shape != (2,) or b.shape != (2,) or not (np.isfinite(a).all() and np.isfinite(b).all()):
            raise CameraError("a section needs two finite XY points")
        if max(np.abs(a).max(), np.abs(b).max()) > MAX_COORDINATE:
            raise CameraError(f"section ends are beyond +-{MAX_COORDINATE:g}")
        if not (_finite(self.width) and MIN_EXTENT <= self.width <= MAX_DEPTH):
            raise CameraError(f"section width must be in [{MIN_EXTENT:g}, {MAX_DEPTH:g}], got {self.width}")
        if np.hypot(*(b - a)) < MIN_EXTENT:
            raise CameraError("a section's two points coincide in XY (a vertical line has no profile)")

    @property
    def length(self) -> float:
        return float(np.hypot(*np.subtract(self.end, self.start, dtype=np.float64)))

    @property
    def axis(self) -> np.ndarray:
        """Unit XY direction from start to end (float64); the normal is (-y, x)."""
        return _unit(np.subtract(self.end, self.start, dtype=np.float64))

    def uniforms(self, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What the shaders compare (camera.glsl section_keeps): (start - origin, axis)
        and (0, length, width/2), each rounded to float32 once."""
        o = np.asarray(origin, dtype=np.float64)[:2]
        line = np.concatenate([np.asarray(self.start, dtype=np.float64) - o, self.axis]).astype(np.float32)
        return line, np.array([0.0, self.length, self.width / 2.0], dtype=np.float32)

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """The float64 test on file coordinates (the reference)."""
        q = np.asarray(xy, dtype=np.float64)[:, :2] - np.asarray(self.start, dtype=np.float64)
        u = self.axis
        t = q @ u
        d = q[:, 1] * u[0] - q[:, 0] * u[1]
        return (t >= 0.0) & (t <= self.length) & (np.abs(d) <= self.width / 2.0)


NO_SECTION_LINE = np.array([0.0, 0.0, 1.0, 0.0], dtype=np.float32)
"""No section: along +x from the origin, every finite point within an infinite range."""
NO_SECTION_RANGE = np.array([-np.inf, np.inf, np.inf], dtype=np.float32)


def section_keeps(positions: np.ndarray, line: np.ndarray, extent: np.ndarray) -> np.ndarray:
    """The shaders' section test in float32, operation for operation (numpy twin of
    camera.glsl section_keeps, whose products are `precise`: no fused multiply-add)."""
    p = np.asarray(positions, dtype=np.float32)
    qx, qy = p[:, 0] - line[0], p[:, 1] - line[1]
    t = qx * line[2] + qy * line[3]
    d = qy * line[2] - qx * line[3]
    return (t >= extent[0]) & (t <= extent[1]) & (np.abs(d) <= extent[2])


@dataclass(frozen=True)
class Clip:
    """An axis-aligned box in file coordinates that a point must lie in to be drawn
    (sides inclusive); infinite sides make a slab (between two heights) or nothing.
    An optional `section` (a vertical slab along a segment) is intersected with it.
    The test is on the stored positions: float32 relative to the origin, against the
    box's corners rounded to float32 in that frame (`relative`) and the section's
    float32 line (Section.uniforms)."""

    lo: tuple[float, float, float] = (-math.inf, -math.inf, -math.inf)
    hi: tuple[float, float, float] = (math.inf, math.inf, math.inf)
    section: Section | None = None

    def __post_init__(self):
        lo, hi = np.asarray(self.lo, dtype=np.float64), np.asarray(self.hi, dtype=np.float64)
        if lo.shape != (3,) or hi.shape != (3,) or np.isnan(lo).any() or np.isnan(hi).any() or (lo > hi).any():
            raise CameraError(f"clip box {_show(lo)} to {_show(hi)} is not a box (min <= max, no NaN)")
        if self.section is not None and not isinstance(self.section, Section):
            raise CameraError("a clip's section must be a Section")

    @property
    def has_box(self) -> bool:
        """Some side of the box is finite (a box or a slab, not only a section)."""
        return bool(np.isfinite(self.lo).any() or np.isfinite(self.hi).any())

    def intersect(self, other: Clip) -> Clip:
        if self.section is not None and other.section is not None and self.section != other.section:
            raise CameraError("two different sections cannot be combined into one clip")
        return Clip(tuple(np.maximum(self.lo, other.lo).tolist()), tuple(np.minimum(self.hi, other.hi).tolist()),
                    self.section or other.section)

    def relative(self, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The corners as the shaders compare them: float32 of corner - origin (float64 first)."""
        o = np.asarray(origin, dtype=np.float64)
        with np.errstate(over="ignore"):
            return ((np.asarray(self.lo) - o).astype(np.float32), (np.asarray(self.hi) - o).astype(np.float32))

    def section_uniforms(self, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The section's line and range as the shaders take them (none: keeps every finite point)."""
        if self.section is None:
            return NO_SECTION_LINE.copy(), NO_SECTION_RANGE.copy()
        return self.section.uniforms(origin)

    def keeps(self, positions: np.ndarray, origin: np.ndarray) -> np.ndarray:
        """Which float32 positions (relative to origin) the shaders keep (numpy twin of clip_keeps)."""
        lo, hi = self.relative(origin)
        p = np.asarray(positions, dtype=np.float32)
        inside = ((p >= lo) & (p <= hi)).all(axis=1)
        if self.section is not None:
            inside &= section_keeps(p, *self.section.uniforms(origin))
        return inside

    def contains(self, xyz: np.ndarray) -> np.ndarray:
        """The float64 test on file coordinates: the reference the float32 test approximates."""
        p = np.asarray(xyz, dtype=np.float64)
        inside = ((p >= np.asarray(self.lo)) & (p <= np.asarray(self.hi))).all(axis=1)
        if self.section is not None:
            inside &= self.section.contains(p)
        return inside


NO_CLIP = Clip()


class Returns(enum.Enum):
    """Which returns of each pulse are drawn (LAS return number and number of returns;
    needs the store's kept point flags, like class filters)."""

    ALL = 0
    FIRST = 1       # return number 1
    LAST = 2        # return number == number of returns
    SINGLE = 3      # the only return of its pulse


@dataclass(frozen=True)
class ViewUniforms:
    """What the shaders get: float32, relative to the cloud origin."""

    rotation: np.ndarray      # (3, 3) float32
    translation: np.ndarray   # (3,) float32 = R @ (origin - position), in float64 first
    projection: np.ndarray    # (4,) float32: x and y scales (Camera.scales), near, far
    size: tuple[int, int]
    hidden: np.ndarray        # (8,) uint32: bit c set = category code c not drawn
    clip_lo: np.ndarray = field(default_factory=lambda: np.full(3, -np.inf, dtype=np.float32))
    clip_hi: np.ndarray = field(default_factory=lambda: np.full(3, np.inf, dtype=np.float32))
    section_line: np.ndarray = field(default_factory=NO_SECTION_LINE.copy)    # (4,) Section.uniforms
    section_range: np.ndarray = field(default_factory=NO_SECTION_RANGE.copy)  # (3,)
    perspective: float = 1.0  # 0: orthographic (no division by depth)
    returns: int = 0          # Returns value

    @functools.cached_property
    def filtering(self) -> bool:
        """Whether a hidden category, a return filter, a clip box or a section can leave a
        point out: without one the raster draws with programs that have none of those
        tests, so a view without filters pays nothing for them (worked out once a view)."""
        return bool(self.hidden.any() or self.returns or np.isfinite(self.clip_lo).any()
                    or np.isfinite(self.clip_hi).any() or not np.array_equal(self.section_range, NO_SECTION_RANGE))


def hidden_mask(hidden: frozenset[int]) -> np.ndarray:
    """The 256-bit mask of category codes (0..255) left out of the raster."""
    mask = np.zeros(8, dtype=np.uint32)
    for code in hidden:
        if not 0 <= code <= 255:
            raise ValueError(f"category code {code} outside 0..255")
        mask[code >> 5] |= np.uint32(1 << (code & 31))
    return mask


def view_uniforms(camera: Camera, origin: np.ndarray, width: int, height: int,
                  hidden: frozenset[int] = frozenset(), clip: Clip = NO_CLIP,
                  returns: Returns = Returns.ALL) -> ViewUniforms:
    r = camera.rotation()
    t = r @ (np.asarray(origin, dtype=np.float64) - np.asarray(camera.position, dtype=np.float64))
    proj = np.array([*camera.scales(width, height), camera.near, camera.far], dtype=np.float64)
    lo, hi = clip.relative(origin)
    line, extent = clip.section_uniforms(origin)
    return ViewUniforms(r.astype(np.float32), t.astype(np.float32), proj.astype(np.float32), (width, height),
                        hidden_mask(hidden), lo, hi, line, extent, 0.0 if camera.orthographic else 1.0, returns.value)


def auto_camera(bounds_min: np.ndarray, bounds_max: np.ndarray, aspect: float, fov_y_deg: float = 60.0) -> Camera:
    """Frame the bounding box from an oblique view across its longer horizontal side
    (so strips fill the width): the nearest distance at which all 8 corners fit."""
    lo = np.asarray(bounds_min, dtype=np.float64)
    hi = np.asarray(bounds_max, dtype=np.float64)
    if not (np.isfinite(lo).all() and np.isfinite(hi).all() and max(np.abs(lo).max(), np.abs(hi).max()) <= MAX_COORDINATE):
        raise CameraError(f"the cloud's bounds {_show(lo)} to {_show(hi)} are beyond the cameras' +-{MAX_COORDINATE:g}")
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
    sx, sy = camera.scales(width, height)
    w = np.ones_like(depth) if camera.orthographic else depth
    with np.errstate(divide="ignore", invalid="ignore"):
        fx = (sx * v[:, 0] / w * 0.5 + 0.5) * width
        fy = (0.5 - sy * v[:, 1] / w * 0.5) * height
    ok = (depth >= camera.near) & (depth <= camera.far) & (fx >= 0) & (fx < width) & (fy >= 0) & (fy < height)
    pixel = np.full(depth.shape, -1, dtype=np.int64)
    pixel[ok] = np.floor(fy[ok]).astype(np.int64) * width + np.floor(fx[ok]).astype(np.int64)
    return pixel, depth


def screen_points(camera: Camera, xyz: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2) continuous image positions (column, row; row 0 at the top; pixel k spans
    [k, k+1)) and depths of file coordinates, in float64 (project() before the floor).
    Points at or behind the eye plane give non-finite positions."""
    v = (np.asarray(xyz, dtype=np.float64).reshape(-1, 3) - np.asarray(camera.position)) @ camera.rotation().T
    depth = -v[:, 2]
    sx, sy = camera.scales(width, height)
    w = np.ones_like(depth) if camera.orthographic else depth
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = np.stack([(sx * v[:, 0] / w * 0.5 + 0.5) * width, (0.5 - sy * v[:, 1] / w * 0.5) * height], axis=1)
    return xy, depth


def pixel_ray(camera: Camera, x: float, y: float, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(origin, unit direction) in file coordinates of the ray through image position
    (x, y) (screen_points' inverse): from the eye, or for orthographic cameras from the
    eye plane along the view."""
    r = camera.rotation()
    sx, sy = camera.scales(width, height)
    ndc = np.array([2.0 * x / width - 1.0, 1.0 - 2.0 * y / height])
    across = ndc / np.array([sx, sy])
    eye = np.asarray(camera.position, dtype=np.float64)
    if camera.orthographic:
        return eye + r[0] * across[0] + r[1] * across[1], -r[2]
    d = r[0] * across[0] + r[1] * across[1] - r[2]
    return eye, d / np.linalg.norm(d)
