"""Compute programs built through ctypes, so their binaries can be kept between runs
(GL_ARB_get_program_binary, which moderngl does not wrap: a moderngl ComputeShader
always compiles its source). A program is looked up in the cache directory by a hash
of the renderer, the driver version and the full source text (defines and includes
expanded); a miss compiles, links and writes the binary back (temporary + rename).
An entry the driver refuses (stale, truncated, damaged) costs one warning and a
compile, and is rewritten. ComputeProgram offers the part of moderngl's
ComputeShader the passes use: uniforms by name, run, run_indirect, label, release.

PROGRESSIVE_PROGRAM_CACHE=0 turns the cache off; another value (not 1) names the
directory; by default it is $XDG_CACHE_HOME/progressive/programs (~/.cache where
XDG_CACHE_HOME is unset or not absolute, as the XDG base directory rules say)."""

from __future__ import annotations

import ctypes
import hashlib
import os
import struct
import tempfile
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import moderngl
import numpy as np

from progressive.glext import (
    GL_ACTIVE_UNIFORMS,
    GL_COMPILE_STATUS,
    GL_COMPUTE_SHADER,
    GL_DISPATCH_INDIRECT_BUFFER,
    GL_LINK_STATUS,
    GL_NO_ERROR,
    GL_NUM_PROGRAM_BINARY_FORMATS,
    GL_PROGRAM,
    GL_PROGRAM_BINARY_LENGTH,
    GL_PROGRAM_BINARY_RETRIEVABLE_HINT,
    ProgramFunctions,
)

ENV_VAR = "PROGRESSIVE_PROGRAM_CACHE"
MAGIC = b"PRGBIN\0\1"
_HEADER = struct.Struct("<8sII32s")        # magic, binary format, payload length, sha256 of the payload

_DTYPES = {"f": np.float32, "i": np.int32, "ui": np.uint32}
# GL uniform type -> (base type, components, matrix columns; 0: not a matrix)
_UNIFORM_TYPES = {
    0x1406: ("f", 1, 0), 0x8B50: ("f", 2, 0), 0x8B51: ("f", 3, 0), 0x8B52: ("f", 4, 0),
    0x1404: ("i", 1, 0), 0x8B53: ("i", 2, 0), 0x8B54: ("i", 3, 0), 0x8B55: ("i", 4, 0),
    0x1405: ("ui", 1, 0), 0x8DC6: ("ui", 2, 0), 0x8DC7: ("ui", 3, 0), 0x8DC8: ("ui", 4, 0),
    0x8B56: ("i", 1, 0), 0x8B57: ("i", 2, 0), 0x8B58: ("i", 3, 0), 0x8B59: ("i", 4, 0),
    0x8B5A: ("f", 4, 2), 0x8B5B: ("f", 9, 3), 0x8B5C: ("f", 16, 4),
}
_OPAQUE = ("i", 1, 0)      # samplers and images: a unit number


def cache_directory(env: Mapping[str, str]) -> Path | None:
    """Where binaries are kept, from the environment given; None: no cache."""
    value = env.get(ENV_VAR, "")
    if value == "0":
        return None
    if value not in ("", "1"):
        return Path(value)
    xdg = env.get("XDG_CACHE_HOME", "")
    base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".cache"
    return base / "progressive" / "programs"


class Uniform:
    """One active uniform (arrays by their name without [0]), set as moderngl sets them.
    A value equal to the one last set makes no GL call: a frame sets about 150 uniforms,
    most as they were, and each call gives up the GIL the loader's threads then hold (a
    program's uniforms change only through here)."""

    def __init__(self, calls: ProgramFunctions, program: int, location: int, gl_type: int, size: int):
        self._calls, self._program, self._location = calls, program, location
        self._kind, self._components, self._columns = _UNIFORM_TYPES.get(gl_type, _OPAQUE)
        self.array_length = size
        self._last: bytes | None = None

    def write(self, data: bytes) -> None:
        self._set(np.frombuffer(bytes(data), dtype=_DTYPES[self._kind]))

    @property
    def value(self):
        raise AttributeError("uniforms of a ComputeProgram are write-only")

    @value.setter
    def value(self, value) -> None:
        self._set(np.asarray(value, dtype=_DTYPES[self._kind]).ravel())

    def _set(self, flat: np.ndarray) -> None:
        count = flat.size // self._components
        if count < 1 or count * self._components != flat.size or count > self.array_length:
            raise ValueError(f"{flat.size} values for a uniform of {self._components} x {self.array_length}")
        data = flat.tobytes()
        if data == self._last:
            return
        if self._columns:
            self._calls.matrices[self._columns](self._program, self._location, count, 0, data)
        else:
            self._calls.uniforms[(self._kind, self._components)](self._program, self._location, count, data)
        self._last = data


class ComputeProgram:
    """A linked compute program (its GL name is `glo`), used as a moderngl ComputeShader."""

    def __init__(self, calls: ProgramFunctions, glo: int):
        self._calls, self._glo, self._label = calls, glo, None
        self._members: dict[str, Uniform] = {}
        name = ctypes.create_string_buffer(256)
        length, size, gl_type = ctypes.c_int(0), ctypes.c_int(0), ctypes.c_uint(0)
        for index in range(calls.program_integer(glo, GL_ACTIVE_UNIFORMS)):
            calls.get_active_uniform(glo, index, len(name), ctypes.byref(length), ctypes.byref(size),
                                     ctypes.byref(gl_type), name)
            location = calls.get_uniform_location(glo, name.value)
            if location >= 0:
                key = name.value.decode().removesuffix("[0]")
                self._members[key] = Uniform(calls, glo, location, gl_type.value, size.value)

    @property
    def glo(self) -> int:
        return self._glo

    def __getitem__(self, key: str) -> Uniform:
        return self._members[key]

    def __setitem__(self, key: str, value) -> None:
        self._members[key].value = value

    def __contains__(self, key: str) -> bool:
        return key in self._members

    def __iter__(self) -> Iterator[str]:
        yield from self._members

    @property
    def label(self) -> str | None:
        return self._label

    @label.setter
    def label(self, value: str | None) -> None:
        self._label = value
        text = (value or "").encode()
        self._calls.object_label(GL_PROGRAM, self._glo, len(text), text)

    def run(self, group_x: int = 1, group_y: int = 1, group_z: int = 1) -> None:
        self._calls.use_program(self._glo)
        self._calls.dispatch_compute(group_x, group_y, group_z)

    def run_indirect(self, buffer: moderngl.Buffer, offset: int = 0) -> None:
        self._calls.use_program(self._glo)
        self._calls.bind_buffer(GL_DISPATCH_INDIRECT_BUFFER, buffer.glo)
        self._calls.dispatch_compute_indirect(offset)
        self._calls.bind_buffer(GL_DISPATCH_INDIRECT_BUFFER, 0)

    def release(self) -> None:
        if self._glo:
            self._calls.delete_program(self._glo)
            self._glo = 0


@dataclass
class ProgramStats:
    hits: int = 0
    misses: int = 0          # compiled (no entry, a refused one, or no cache)
    seconds: float = 0.0     # wall time building programs, loads and compiles together

    def as_dict(self) -> dict:
        return {"hits": self.hits, "misses": self.misses, "seconds": self.seconds}


class Programs:
    """One context's compute programs: built from source or loaded from the cache.
    `warnings` holds what went wrong with the cache (one line each, never raised)."""

    def __init__(self, calls: ProgramFunctions, key: str, directory: Path | None):
        """key: what makes a binary valid besides its source (renderer, driver version).
        A driver without binary formats (Mesa with its own shader cache off) gets no cache."""
        self.calls, self.key = calls, key
        self.directory = directory if directory is not None and calls.integer(GL_NUM_PROGRAM_BINARY_FORMATS) > 0 else None
        self.warnings: list[str] = []
        self.stats = ProgramStats()
        self._writable = True

    def entry(self, source: str) -> Path | None:
        if self.directory is None:
            return None
        digest = hashlib.sha256(self.key.encode() + b"\0" + source.encode()).hexdigest()
        return self.directory / f"{digest}.bin"

    def compute(self, source: str, label: str) -> ComputeProgram:
        t0 = time.perf_counter()
        path = self.entry(source)
        glo = self._load(path) if path is not None else 0
        if glo:
            self.stats.hits += 1
        else:
            self.stats.misses += 1
            glo = self._compile(source, label)
            if path is not None:
                self._save(path, glo)
        program = ComputeProgram(self.calls, glo)
        program.label = label
        self.stats.seconds += time.perf_counter() - t0
        return program

    def _load(self, path: Path) -> int:
        """The program from a cache entry; 0 when there is none or the driver refuses it."""
        try:
            data = path.read_bytes()
        except (FileNotFoundError, NotADirectoryError):     # no entry (or no directory: _save says so once)
            return 0
        except OSError as exc:
            return self._refused(path, exc.strerror or str(exc))
        if len(data) < _HEADER.size:
            return self._refused(path, "truncated")
        magic, fmt, length, digest = _HEADER.unpack_from(data)
        payload = data[_HEADER.size:]
        if magic != MAGIC or len(payload) != length or hashlib.sha256(payload).digest() != digest:
            return self._refused(path, "truncated or damaged")
        c = self.calls
        glo = c.create_program()
        c.program_binary(glo, fmt, payload, len(payload))
        if c.program_integer(glo, GL_LINK_STATUS):
            return glo
        c.delete_program(glo)
        while c.get_error() != GL_NO_ERROR:      # an unknown format is GL_INVALID_ENUM: handled here
            pass
        return self._refused(path, "the driver refused it")

    def _refused(self, path: Path, why: str) -> int:
        self.warnings.append(f"program cache entry {path.name} ignored ({why}); compiled again and rewritten")
        return 0

    def _compile(self, source: str, label: str) -> int:
        c = self.calls
        shader = c.create_shader(GL_COMPUTE_SHADER)
        text = ctypes.c_char_p(source.encode())
        c.shader_source(shader, 1, ctypes.byref(text), None)
        c.compile_shader(shader)
        status = ctypes.c_int(0)
        c.get_shaderiv(shader, GL_COMPILE_STATUS, ctypes.byref(status))
        if not status.value:
            log = c.shader_log(shader)
            c.delete_shader(shader)
            raise moderngl.Error(f"GLSL compiler error in {label}:\n{log}")
        glo = c.create_program()
        c.program_parameteri(glo, GL_PROGRAM_BINARY_RETRIEVABLE_HINT, 1)
        c.attach_shader(glo, shader)
        c.link_program(glo)
        c.detach_shader(glo, shader)
        c.delete_shader(shader)
        if not c.program_integer(glo, GL_LINK_STATUS):
            log = c.program_log(glo)
            c.delete_program(glo)
            raise moderngl.Error(f"GLSL linker error in {label}:\n{log}")
        return glo

    def _save(self, path: Path, glo: int) -> None:
        """Write the binary beside its final name and rename it into place, so a reader
        sees a whole entry or none; a directory that cannot be written warns once."""
        if not self._writable:
            return
        c = self.calls
        size = c.program_integer(glo, GL_PROGRAM_BINARY_LENGTH)
        if size <= 0:
            return
        buf = ctypes.create_string_buffer(size)
        length, fmt = ctypes.c_int(0), ctypes.c_uint(0)
        c.get_program_binary(glo, size, ctypes.byref(length), ctypes.byref(fmt), buf)
        payload = buf.raw[:length.value]
        data = _HEADER.pack(MAGIC, fmt.value, len(payload), hashlib.sha256(payload).digest()) + payload
        temporary = None
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, temporary = tempfile.mkstemp(dir=path.parent, prefix=".tmp-")
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.replace(temporary, path)
        except OSError as exc:
            self._writable = False
            if temporary is not None:
                Path(temporary).unlink(missing_ok=True)
            self.warnings.append(f"program cache {self.directory} cannot be written ({exc.strerror or exc}); "
                                 "programs are compiled each run")
