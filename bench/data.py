"""Benchmark files, generated once and cached under bench/.cache/ (ignored by git):
the bundled real sample tiled on a grid to N points, written as LAS, LAZ and the fast
format (through `progressive convert`), so load benchmarks read real files of any size.
Tiles are raw-integer copies of the sample shifted by whole tile sizes: every
attribute stays real, only X and Y move."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np

from bench.synthetic import SAMPLE
from progressive import cli

CACHE = Path(__file__).resolve().parent / ".cache"
WRITE_POINTS = 2_000_000
"""Points per write: large writes let lazrs compress chunks in parallel."""
FORMATS = ("LAS", "LAZ", "fast")
"""The formats a cloud is tiled to (ScaledFiles.formats), in that order."""
SHARED = Path(os.environ.get("PROGRESSIVE_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


@dataclass(frozen=True)
class ScaledFiles:
    points: int
    las: Path
    laz: Path
    fast: Path

    def formats(self) -> tuple[tuple[str, Path], ...]:
        return tuple(zip(FORMATS, (self.las, self.laz, self.fast), strict=True))


def scaled(points: int, cache: Path = CACHE, source: Path = SAMPLE, fast: bool = True, laz: bool = True) -> ScaledFiles:
    """`source` tiled to `points` as LAS, (with `laz`) LAZ and (with `fast`) fast
    format, cached by name and size."""
    cache.mkdir(parents=True, exist_ok=True)
    stem = cache / f"{source.stem}_x{points}"
    files = ScaledFiles(points, stem.with_suffix(".las"), stem.with_suffix(".laz"), stem.with_suffix(".prg"))
    for path, compress in ((files.las, False), (files.laz, True)):
        if not path.exists() and (laz or not compress):
            write_tiled(source, path, points, compress)
    if fast and not files.fast.exists():
        tmp = files.fast.with_suffix(".prg.tmp")
        if cli.main(["convert", str(files.las), str(tmp)]) != 0:
            raise RuntimeError(f"progressive convert failed for {files.las}")
        tmp.replace(files.fast)
    return files


def tiled(points: int, compress: bool, cache: Path = CACHE) -> Path:
    """The sample tiled to `points` as LAS or LAZ alone, cached as scaled() names it
    (scaled() makes all three formats: 55 GB at 1 B points)."""
    path = cache / f"{SAMPLE.stem}_x{points}.{'laz' if compress else 'las'}"
    if not path.exists():
        cache.mkdir(parents=True, exist_ok=True)
        write_tiled(SAMPLE, path, points, compress)
    return path


def write_tiled(source: Path, out: Path, points: int, compress: bool) -> None:
    """Write tile after tile (row by row) through laspy, the way a user's tool would."""
    src = laspy.read(source)
    n = len(src.points)
    header = src.header
    step = np.ceil((header.maxs - header.mins) * 1.02 / header.scales).astype(np.int64)
    tiles = math.ceil(points / n)
    gx = math.ceil(math.sqrt(tiles))
    backend = laspy.LazBackend.LazrsParallel if compress else None
    tmp = out.with_suffix(out.suffix + ".tmp")
    with laspy.open(tmp, mode="w", header=laspy.LasHeader(point_format=header.point_format, version=header.version),
                    do_compress=compress, laz_backend=backend) as writer:
        writer.header.scales, writer.header.offsets = header.scales, header.offsets
        per_write = max(1, WRITE_POINTS // n)
        for first in range(0, tiles, per_write):
            parts = []
            for t in range(first, min(tiles, first + per_write)):
                part = src.points.array[: min(n, points - t * n)].copy()
                part["X"] += int(step[0] * (t % gx))
                part["Y"] += int(step[1] * (t // gx))
                parts.append(part)
            array = np.concatenate(parts)
            writer.write_points(laspy.ScaleAwarePointRecord(array, header.point_format, header.scales, header.offsets))
    tmp.replace(out)


def real_files() -> list[Path]:
    """Real files as they are: the bundled sample, and the largest airborne and
    terrestrial files of ../shared/data where present (MANIFEST.md gives licences), with
    the largest of point format 6-10 that is not COPC (its layers decode apart)."""
    shared = [SHARED / name for name in ("wires.laz", "lone-star.copc.laz", "las_with_several_extra_byte_bloc.laz")]
    return [SAMPLE] + [p for p in shared if p.is_file()]


def accuracy_file() -> Path:
    """A real terrestrial scan (high depth complexity, BSD) where present, else the sample."""
    tls = SHARED / "lone-star.copc.laz"
    return tls if tls.is_file() else SAMPLE


def drop_cache(path: Path) -> None:
    """Ask the kernel to drop the file's pages (written pages are synced first, since
    dirty pages cannot be dropped); whether it worked shows in the timings."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    finally:
        os.close(fd)
