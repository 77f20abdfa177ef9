"""Outputs appear whole or not at all: written to a temporary name, then renamed."""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO

import numpy as np

from progressive.errors import ProgressiveError


def check_writable(path: str | os.PathLike) -> Path:
    """Fail before any work when an output cannot be created."""
    p = Path(path)
    if p.is_dir():
        raise ProgressiveError(f"output {p} is a directory")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise ProgressiveError(f"output folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise ProgressiveError(f"output folder {parent} is not writable")
    return p


def atomic_write(path: str | os.PathLike, write: Callable[[IO[bytes]], None]) -> None:
    p = check_writable(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_png(path: str | os.PathLike, rgba: np.ndarray) -> None:
    from PIL import Image

    image = Image.fromarray(np.ascontiguousarray(rgba[:, :, :3]), mode="RGB")
    atomic_write(path, lambda fh: image.save(fh, format="PNG"))


def write_npy(path: str | os.PathLike, array: np.ndarray) -> None:
    atomic_write(path, lambda fh: np.save(fh, array))


def write_json(path: str | os.PathLike, data: object) -> None:
    atomic_write(path, lambda fh: fh.write((json.dumps(data, indent=2) + "\n").encode()))
