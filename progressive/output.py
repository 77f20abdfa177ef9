"""Outputs appear whole or not at all, and never in place of something else.

A run's outputs form one transaction: each is written to a temporary name beside it,
and all are renamed into place only when every one is completely written; on any
failure every temporary is removed and nothing is replaced. Temporaries are created
with mode 0666, so the umask gives the files the usual permissions."""

from __future__ import annotations

import json
import os
import secrets
import stat
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import IO

import numpy as np

from progressive.errors import ProgressiveError

NAME_MAX = 255
"""Bytes in one file name (Linux, macOS): a longer temporary name gets a short one."""


def _stat(path: Path) -> os.stat_result | None:
    try:
        return os.stat(path)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise ProgressiveError(f"output {path}: {exc.strerror}") from None
    except ValueError as exc:                # a NUL byte in the name
        raise ProgressiveError(f"output {os.fspath(path)!r}: {exc}") from None


def check_writable(path: str | os.PathLike, inputs: Iterable[str | os.PathLike] = ()) -> Path:
    """Fail before any work when an output cannot be created or would replace what it
    must not: a directory, a device or other non-regular file, or one of the inputs."""
    p = Path(path)
    if not p.name or p.name in (".", "..") or os.fspath(path).endswith(os.sep):
        raise ProgressiveError(f"output {os.fspath(path)} is not a file name")
    st = _stat(p)
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise ProgressiveError(f"output {p} is a directory")
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise ProgressiveError(f"output {p} exists and is not a regular file")
    parent = p.parent
    if not parent.is_dir():
        raise ProgressiveError(f"output folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ProgressiveError(f"output folder {parent} is not writable")
    if st is not None:
        for source in inputs:
            if _same_file(st, source):
                raise ProgressiveError(f"output {p} is the input {source}")
    return p


def _same_file(st: os.stat_result, other: str | os.PathLike) -> bool:
    try:
        o = os.stat(other)
    except OSError:
        return False
    return (st.st_dev, st.st_ino) == (o.st_dev, o.st_ino)


def check_outputs(paths: Iterable[str | os.PathLike | None], inputs: Iterable[str | os.PathLike] = ()) -> list[Path]:
    """check_writable for each given output, and no two naming the same file."""
    inputs = list(inputs)
    checked: list[Path] = []
    for path in paths:
        if path is None:
            continue
        p = check_writable(path, inputs)
        for q in checked:
            if _same_path(p, q):
                raise ProgressiveError(f"outputs {q} and {p} are the same file")
        checked.append(p)
    return checked


def _same_path(a: Path, b: Path) -> bool:
    if a.name != b.name:
        return False
    try:
        return os.path.samefile(a.parent, b.parent)
    except OSError:
        return a.resolve() == b.resolve()


def temp_name(path: Path) -> Path:
    """`.NAME.XXXXXXXX.tmp` beside path, or `.progressive.XXXXXXXX.tmp` where that
    name would be too long for the file system."""
    tag = secrets.token_hex(4)
    name = f".{path.name}.{tag}.tmp"
    if len(os.fsencode(name)) > NAME_MAX:
        name = f".progressive.{tag}.tmp"
    return path.with_name(name)


class Outputs:
    """One run's outputs, committed together:

        with Outputs() as out:
            out.write(png, lambda fh: ...)
            out.write(ids, lambda fh: ...)
            out.commit()          # renames them all; leaving without it removes every temporary
    """

    def __init__(self) -> None:
        self._pending: list[list] = []      # [temporary, final, mode]

    def reserve(self, path: str | os.PathLike) -> Path:
        """A new empty temporary for path, to be filled by the caller (by any means
        that leaves a regular file at that name)."""
        final = Path(path)
        while True:
            tmp = temp_name(final)
            entry = [tmp, final, 0o666]
            self._pending.append(entry)        # first, so a signal right after the open still removes it
            try:
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666)
            except FileExistsError:
                self._pending.remove(entry)
                continue
            break
        try:
            entry[2] = stat.S_IMODE(os.fstat(fd).st_mode)
        finally:
            os.close(fd)
        return tmp

    def write(self, path: str | os.PathLike, write: Callable[[IO[bytes]], None]) -> None:
        tmp = self.reserve(path)
        with open(tmp, "wb") as fh:
            write(fh)

    def commit(self) -> None:
        """Rename every temporary into place (the mode a caller's own writer may have
        set is brought back to 0666 less the umask, as the reserved file had)."""
        for tmp, _, mode in self._pending:
            if stat.S_IMODE(os.stat(tmp).st_mode) != mode:
                os.chmod(tmp, mode)
        try:
            for tmp, final, _ in self._pending:
                os.replace(tmp, final)
        except BaseException as exc:
            if not isinstance(exc, Exception):      # a signal mid-way: finish, so the outputs stay one set
                for tmp, final, _ in self._pending:
                    if os.path.lexists(tmp):
                        os.replace(tmp, final)
            raise
        self._pending.clear()

    def abort(self) -> None:
        for tmp, _, _ in self._pending:
            tmp.unlink(missing_ok=True)
        self._pending.clear()

    def __enter__(self) -> Outputs:
        return self

    def __exit__(self, *exc) -> None:
        self.abort()


def atomic_write(path: str | os.PathLike, write: Callable[[IO[bytes]], None]) -> None:
    """One output on its own: written to a temporary, renamed into place."""
    check_writable(path)
    with Outputs() as out:
        out.write(path, write)
        out.commit()


def png_writer(rgba: np.ndarray) -> Callable[[IO[bytes]], None]:
    from PIL import Image

    image = Image.fromarray(np.ascontiguousarray(rgba[:, :, :3]), mode="RGB")
    return lambda fh: image.save(fh, format="PNG")


def npy_writer(array: np.ndarray) -> Callable[[IO[bytes]], None]:
    return lambda fh: np.save(fh, array)


def json_text(data: object) -> str:
    """The JSON the outputs write (a file, or standard output for `--stats -`)."""
    return json.dumps(data, indent=2)


def json_writer(data: object) -> Callable[[IO[bytes]], None]:
    text = (json_text(data) + "\n").encode()
    return lambda fh: fh.write(text)


def write_png(path: str | os.PathLike, rgba: np.ndarray) -> None:
    atomic_write(path, png_writer(rgba))


def write_npy(path: str | os.PathLike, array: np.ndarray) -> None:
    atomic_write(path, npy_writer(array))


def write_json(path: str | os.PathLike, data: object) -> None:
    atomic_write(path, json_writer(data))
