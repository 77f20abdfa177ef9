"""Files in different coordinate systems as one cloud in a target CRS (`--reproject`).

The loaders give positions relative to an origin; two files in different CRSs must
not share one (its point would be between two places). So each file is loaded alone,
relative to its own centre, one after the other; each batch's coordinates are taken
in float64 — a LAS file's exactly as laspy computes them, from its integers (the
batch's Grid), other formats' from their float32 positions — transformed with pyproj
in float64, and offset to the cloud's origin. Heights keep their datum: a CRS without
a vertical axis has heights in its horizontal unit (a metre for geographic CRSs), so
they are scaled by the ratio of the units only."""

from __future__ import annotations

import queue
import re
import threading
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from progressive.errors import InputError, ProgressiveError
from progressive.loaders import CloudLoader
from progressive.loaders.crs import epsg_code, file_crs
from progressive.loaders.http import DEFAULTS as HTTP_DEFAULTS
from progressive.loaders.http import HttpOptions
from progressive.loaders.lookup import locate, read_point
from progressive.loaders.pipeline import JOIN_S, WAIT_S, BatchQueue, Hold
from progressive.loaders.types import AttributeInfo, Batch, CloudInfo, FileInfo, ReadyQueue, nonfinite_rows
from progressive.loaders.validate import fail, shown
from progressive.permutation import LAYOUT, Permutation

AUTHORITY_CODE = re.compile(r"[A-Za-z]+:\d+")
DENSIFY = 21
"""Points on each side of a file's bounding box when its bounds are transformed."""
LONLAT = "EPSG:4326"
READY_BATCHES = 2
"""Reprojected batches waiting for the consumer (each file's loader bounds its own)."""
_END = object()


class ReprojectError(ProgressiveError):
    pass


def target_crs(text: str):
    """The pyproj CRS of `--reproject AUTHORITY:CODE` (EPSG:32610, ...)."""
    import pyproj

    if not AUTHORITY_CODE.fullmatch(text.strip()):
        raise ReprojectError(f"--reproject {shown(text)} is not a coordinate system code such as EPSG:32610")
    try:
        return pyproj.CRS.from_user_input(text.strip().upper())
    except pyproj.exceptions.CRSError:
        raise ReprojectError(f"--reproject {shown(text)}: pyproj knows no such coordinate system") from None


def crs_label(crs) -> str:
    """A CRS as messages and picks name it: its name and EPSG code where it has one."""
    code = crs.to_epsg()
    return f"{crs.name} (EPSG:{code})" if code else crs.name


def describe_crs(info: FileInfo) -> dict:
    """`info`'s CRS facts of a file: the name pyproj gives it and its EPSG code (None
    where the file names none, or pyproj finds no code)."""
    crs = file_crs(info)
    return {"crs_name": crs.name if crs is not None else None, "epsg": epsg_code(info, crs)}


def height_unit(crs) -> float:
    """Metres per unit of a CRS's heights: its vertical axis's unit, else its horizontal
    unit where that is a length, else a metre (geographic CRSs)."""
    axes = crs.axis_info
    linear = [a for a in axes if a.unit_name and "degree" not in a.unit_name and "radian" not in a.unit_name]
    vertical = [a for a in axes if a.direction in ("up", "down")]
    pick = vertical[0] if vertical else (linear[0] if linear else None)
    return float(pick.unit_conversion_factor) if pick is not None else 1.0


@dataclass(frozen=True)
class Transform:
    """One file's float64 coordinates to the target CRS."""

    transformer: object         # pyproj.Transformer of the horizontal parts, always x, y order
    z_scale: float

    @classmethod
    def between(cls, source, target) -> Transform:
        import pyproj

        try:
            transformer = pyproj.Transformer.from_crs(source.to_2d(), target.to_2d(), always_xy=True)
        except pyproj.exceptions.ProjError as exc:
            raise ReprojectError(f"no transformation from {crs_label(source)} to {crs_label(target)}: {exc}") from None
        return cls(transformer, height_unit(source) / height_unit(target))

    def apply(self, xyz: np.ndarray) -> np.ndarray:
        """(n, 3) float64 -> (n, 3) float64 in the target CRS."""
        out = np.empty_like(xyz, dtype=np.float64)
        with np.errstate(invalid="ignore", over="ignore"):
            out[:, 0], out[:, 1] = self.transformer.transform(xyz[:, 0], xyz[:, 1])
            out[:, 2] = xyz[:, 2] * self.z_scale
        return out

    def bounds(self, lo, hi) -> tuple[np.ndarray, np.ndarray]:
        """The box around a bounding box's transformed edges (DENSIFY points a side)."""
        import pyproj

        try:
            x0, y0, x1, y1 = self.transformer.transform_bounds(lo[0], lo[1], hi[0], hi[1], densify_pts=DENSIFY)
        except pyproj.exceptions.ProjError:
            x0 = y0 = x1 = y1 = np.nan
        z = sorted((lo[2] * self.z_scale, hi[2] * self.z_scale))
        return np.array([x0, y0, z[0]]), np.array([x1, y1, z[1]])


class ReprojectingLoader(BatchQueue):
    """CloudLoader's interface over files in any CRSs, as one cloud in `target`: one
    loader a file, run in turn (so host memory stays what one loader holds, plus
    READY_BATCHES), reprojected on a thread of its own."""

    def __init__(self, paths, target, *, partial: bool = False, http: HttpOptions = HTTP_DEFAULTS,
                 parser_threads: int | None = None):
        """http: how a URL's COPC file is fetched; parser_threads: each file's loader's."""
        self.target = target
        self._loaders = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._hold = Hold()
        if not paths:
            raise InputError("no input files given")
        try:
            for path in paths:
                self._loaders.append(CloudLoader([path], partial=partial, http=http, check_count=check_addressable,
                                                 parser_threads=parser_threads))
            files = tuple(loader.info.files[0] for loader in self._loaders)
            self.transforms = tuple(self._transform(f) for f in files)
            self.info = self._cloud(files)
            check_addressable(files[-1].path, self.info.points)
        except BaseException:
            self.close()
            raise
        self._starts = np.cumsum([0] + [f.points for f in files])[:-1].tolist()
        self.loaded = 0
        self._results = ReadyQueue(maxsize=READY_BATCHES)
        self._error: BaseException | None = None
        self._finished = False

    def _transform(self, f: FileInfo) -> Transform:
        source = file_crs(f)
        if source is None:
            raise fail(f.path, "has no coordinate system (that pyproj reads) to reproject from")
        return Transform.between(source, self.target)

    def _cloud(self, files: tuple[FileInfo, ...]) -> CloudInfo:
        boxes = [t.bounds(loader.info.bounds_min, loader.info.bounds_max)
                 for t, loader in zip(self.transforms, self._loaders)]
        lo, hi = np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)
        if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
            raise ReprojectError(f"the files' bounds do not transform to {crs_label(self.target)} (outside its area?)")
        origin = (lo + hi) / 2
        return CloudInfo(files=files, points=sum(f.points for f in files), origin=origin, bounds_min=lo,
                         bounds_max=hi, attributes=self._attributes(origin))

    def _attributes(self, origin: np.ndarray) -> tuple[AttributeInfo, ...]:
        """Attributes every file has, in the first file's order, with its offsets but the
        elevation's (the cloud's origin, in the target's heights)."""
        by_file = [{a.name: a for a in loader.info.attributes} for loader in self._loaders]
        return tuple(AttributeInfo(a.name, a.kind, np.result_type(*(f[a.name].dtype for f in by_file)),
                                   float(origin[2]) if a.name == "elevation" else a.offset)
                     for a in self._loaders[0].info.attributes if all(a.name in f for f in by_file))

    @cached_property
    def _names(self) -> frozenset[str]:
        return frozenset(a.name for a in self.info.attributes)

    def file_coordinates(self, k: int, batch: Batch) -> np.ndarray:
        """(n, 3) float64 coordinates of a batch of file k, in its CRS (see the module)."""
        if batch.grid is not None:
            return batch.grid.cells * np.asarray(batch.grid.scale) + np.asarray(batch.grid.offset)
        return batch.positions.astype(np.float64) + self._loaders[k].info.origin

    def _reprojected(self, k: int, batch: Batch) -> Batch:
        world = self.transforms[k].apply(self.file_coordinates(k, batch))
        with np.errstate(invalid="ignore", over="ignore"):
            positions = (world - self.info.origin).astype(np.float32)
        finite = world[np.isfinite(positions).all(axis=1)]
        return batch.with_positions(positions, start=batch.start + self._starts[k],
                                    attributes={n: v for n, v in batch.attributes.items() if n in self._names},
                                    bounds=(finite.min(axis=0), finite.max(axis=0)) if len(finite) else None,
                                    nonfinite_positions=nonfinite_rows(positions))

    @property
    def total(self) -> int:
        return self.info.points

    @property
    def done(self) -> bool:
        """Every batch has been handed to the consumer."""
        return self._finished

    @property
    def warnings(self) -> list[str]:
        return [w for loader in self._loaders for w in loader.warnings]

    def keep_only(self, attributes: tuple[str, ...]) -> None:
        """Before start(): batches carry only these attributes (CloudLoader.keep_only)."""
        if self._thread is not None:
            raise RuntimeError("keep_only() after the loader started")
        for loader in self._loaders:
            loader.keep_only(attributes)

    def start(self, first: int | None = None) -> ReprojectingLoader:
        """The files load in turn on one thread that reprojects as they come (pyproj
        releases the GIL), so a render loop polling batches does not wait for it.
        first: that many batches are reprojected until resume()."""
        if self._thread is None:
            self._hold = Hold(first)
            self._thread = threading.Thread(target=self._run, name="progressive-reproject", daemon=True)
            self._thread.start()
        return self

    def resume(self) -> None:
        self._hold.release()

    def _run(self) -> None:
        try:
            for k, loader in enumerate(self._loaders):
                for batch in loader:
                    if not (self._hold.admit(self._stop) and self._put(self._reprojected(k, batch))):
                        return
                if self._stop.is_set():
                    return
                loader.close()
        except BaseException as exc:
            self._error = exc
        finally:
            self._put(_END)

    def _put(self, item) -> bool:
        while not self._stop.is_set():
            try:
                self._results.put(item, timeout=WAIT_S)
                return True
            except queue.Full:
                pass
        return False

    def _take(self, item, out: list[Batch]) -> None:
        if item is _END:
            self._raise_failure()
            self._finished = True
        else:
            self.loaded += item.count
            out.append(item)

    def _raise_failure(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            self.close()
            raise error

    def close(self) -> None:
        """Stop the thread and every file's loader."""
        self._stop.set()
        for loader in self._loaders:
            loader.close()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(JOIN_S)

    def __enter__(self) -> ReprojectingLoader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def check_addressable(path: str, points: int) -> None:
    """A cloud must fit the point store's uint32 slots: a header declaring 4.29 G points
    (a sparse file of that size holds them) failed deep in the renderer. Checked for a
    LAS/LAZ file once its header is read, before its points are (the loader's
    check_count), and for the cloud once every file is open, before any batch is loaded;
    `path`: the file that made it too large."""
    try:
        Permutation.for_count(points, order=LAYOUT)
    except ValueError as exc:
        raise fail(path, f"makes a cloud of {points:,} points, more than the shuffled buffer can "
                         f"address ({exc})") from None


def open_loader(paths, *, partial: bool = False, reproject=None, point_budget: int | None = None,
                http: HttpOptions = HTTP_DEFAULTS, view=None, parser_threads: int | None = None, on_parsed=None):
    """The loader of a cloud, checked to fit the point store: reprojected into `reproject`
    (a pyproj CRS) where given; point_budget and view: see open_sources (COPC nodes; not
    with reprojection); parser_threads, on_parsed: CloudLoader's (None: the cores
    available; nothing done; a reprojected cloud's batches have no integers to frame)."""
    if reproject is not None:
        return ReprojectingLoader(paths, reproject, partial=partial, http=http, parser_threads=parser_threads)
    loader = CloudLoader(paths, partial=partial, point_budget=point_budget, http=http, view=view,
                         check_count=check_addressable, parser_threads=parser_threads, on_parsed=on_parsed)
    try:
        check_addressable(loader.info.files[-1].path, loader.info.points)
    except BaseException:
        loader.close()
        raise
    return loader


def open_info(paths, *, partial: bool = False, reproject=None, http: HttpOptions = HTTP_DEFAULTS) -> CloudInfo:
    """The cloud's description (headers read, no points loaded)."""
    with open_loader(paths, partial=partial, reproject=reproject, http=http) as loader:
        return loader.info


class Geography:
    """Where a cloud's points are: each file's CRS (or the target's, reprojected), for
    the coordinates a pick reports and its latitude and longitude."""

    def __init__(self, info: CloudInfo, target=None):
        self.info, self.target = info, target
        self._crs: dict[FileInfo, object] = {}
        self._transforms: dict[FileInfo, Transform] = {}
        self._lonlat: dict[FileInfo, object] = {}

    def _source(self, f: FileInfo):
        if f not in self._crs:
            self._crs[f] = file_crs(f)
        return self._crs[f]

    def _to_target(self, f: FileInfo) -> Transform:
        if f not in self._transforms:
            self._transforms[f] = Transform.between(self._source(f), self.target)
        return self._transforms[f]

    def _to_lonlat(self, f: FileInfo):
        """pyproj Transformer from the CRS the cloud shows file f in to longitude and
        latitude; None where there is none (no CRS, or one that places nothing on Earth)."""
        if f not in self._lonlat:
            import pyproj

            crs = self.target if self.target is not None else self._source(f)
            transformer = None
            if crs is not None:
                try:
                    transformer = pyproj.Transformer.from_crs(crs.to_2d(), LONLAT, always_xy=True)
                except pyproj.exceptions.ProjError:
                    transformer = None
            self._lonlat[f] = transformer
        return self._lonlat[f]

    def point(self, index: int) -> np.ndarray:
        """(3,) float64 coordinates of a point in the cloud's CRS (the file's, or the
        target's when reprojected), from its file's float64 ones."""
        xyz = read_point(self.info, index)
        if self.target is None:
            return xyz
        f, _ = locate(self.info, index)
        return self._to_target(f).apply(xyz[None, :])[0]

    def place(self, index: int, record: dict) -> dict:
        """A pick's record with the coordinates in the cloud's CRS (reprojected: the
        file's own under "file_coordinates"), the CRS, and "lat"/"lon" (WGS 84 degrees,
        float64; None where the CRS allows none)."""
        f, _ = locate(self.info, index)
        out = dict(record)
        xyz = read_point(self.info, index)
        if self.target is not None:
            source = self._source(f)
            out["file_coordinates"] = {"x": record["x"], "y": record["y"], "z": record["z"],
                                       "crs": crs_label(source) if source is not None else f.crs}
            xyz = self._to_target(f).apply(xyz[None, :])[0]
            out.update(x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]), crs=crs_label(self.target))
        else:
            source = self._source(f)
            out["crs"] = crs_label(source) if source is not None else f.crs
        lonlat = self._to_lonlat(f)
        lon = lat = None
        if lonlat is not None:
            with np.errstate(invalid="ignore"):
                lon, lat = (float(v) for v in lonlat.transform(xyz[0], xyz[1]))
            lon, lat = (lon, lat) if np.isfinite(lon) and np.isfinite(lat) else (None, None)
        out.update(lat=lat, lon=lon)
        return out


def describe_reprojected(paths, target_text: str, *, partial: bool = False,
                         http: HttpOptions = HTTP_DEFAULTS) -> tuple[dict, list[dict]]:
    """`info --reproject`: each file described as it is (its own CRS), and the cloud's
    and each file's bounds in the target CRS, from the reprojected float64 points (a
    second pass over the files). Returns the description and the files' own ones."""
    from progressive.loaders import describe

    target = target_crs(target_text)
    own = [describe([p], partial=partial, http=http) for p in paths]
    with ReprojectingLoader(paths, target, partial=partial, http=http) as loader:
        info = loader.info
        ends = np.cumsum([f.points for f in info.files])
        lo = np.full((len(info.files), 3), np.inf)
        hi = np.full((len(info.files), 3), -np.inf)
        for batch in loader:
            if batch.bounds is not None:
                k = int(np.searchsorted(ends, batch.start, side="right"))
                lo[k], hi[k] = np.minimum(lo[k], batch.bounds[0]), np.maximum(hi[k], batch.bounds[1])
        warnings = loader.warnings
    files = []
    for d, f, flo, fhi in zip(own, info.files, lo, hi):
        summary = {**d["files"][0], **describe_crs(f)}
        summary["reprojected_bounds"] = _bounds(flo, fhi)
        files.append(summary)
    desc = {"points": info.points, "crs": crs_label(target), "crs_name": target.name, "epsg": target.to_epsg(),
            "bounds": _bounds(lo.min(axis=0), hi.max(axis=0)),
            "header_bounds": {"min": info.bounds_min.tolist(), "max": info.bounds_max.tolist()},
            "origin": info.origin.tolist(), "files": files, "warnings": warnings}
    return desc, own


def _bounds(lo: np.ndarray, hi: np.ndarray) -> dict:
    seen = bool(np.isfinite(lo).all() and np.isfinite(hi).all())
    return {"min": lo.tolist() if seen else None, "max": hi.tolist() if seen else None}


def format_crs(desc: dict, text: str) -> str:
    """`info`'s text with each file's CRS (name, EPSG code) and, reprojected, the bounds
    in the target CRS."""
    def named(d: dict) -> str:
        return f"{d['crs_name'] or 'none given'}" + (f" (EPSG:{d['epsg']})" if d["epsg"] else "")

    lines = [text, "", "coordinate systems:"]
    lines += [f"  {f['path']}: {named(f)}" for f in desc["files"]]
    if "reprojected_bounds" in desc["files"][0]:
        lines += ["", f"reprojected to {named(desc)}: {desc['points']:,} points"]
        lines += [f"  {f['path']}: bounds {f['reprojected_bounds']['min']} .. {f['reprojected_bounds']['max']}"
                  for f in desc["files"]]
        lines += [f"  cloud: bounds {desc['bounds']['min']} .. {desc['bounds']['max']}"]
    return "\n".join(lines)
