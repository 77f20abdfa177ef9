"""GLSL sources from the installed `progressive.shaders` package, with the binding
enum and per-program defines prepended and `#include "x.glsl"` inlined."""

from __future__ import annotations

import re
from collections.abc import Mapping
from functools import cache
from importlib import resources

import moderngl

from progressive import batches, encoding, permutation
from progressive.bindings import glsl_defines
from progressive.programs import ComputeProgram, Programs

_INCLUDE = re.compile(r'^\s*#include\s+"([^"]+)"\s*$', re.MULTILINE)
Defines = Mapping[str, int | str | bool]


@cache
def shader_text(name: str) -> str:
    return resources.files("progressive.shaders").joinpath(name).read_text(encoding="utf-8")


def _expand(name: str, seen: frozenset[str] = frozenset()) -> str:
    if name in seen:
        raise ValueError(f"recursive #include of {name}")
    return _INCLUDE.sub(lambda m: _expand(m.group(1), seen | {name}), shader_text(name))


def source(name: str, defines: Defines | None = None, extensions: tuple[str, ...] = ()) -> str:
    head = ["#version 450"]
    head += [f"#extension {e} : require" for e in extensions]
    for key, value in (defines or {}).items():
        head.append(f"#define {key} {int(value) if isinstance(value, bool) else value}")
    return "\n".join(head) + "\n" + glsl_defines() + permutation.glsl_defines() + batches.glsl_defines() + encoding.glsl_defines() + "#line 1\n" + _expand(name)


def compute(ctx: moderngl.Context, name: str, defines: Defines | None = None,
            extensions: tuple[str, ...] = (), label: str | None = None) -> ComputeProgram | moderngl.ComputeShader:
    """Through the context's program cache where create_context made it (ctx.extra),
    else moderngl's compiler (a context made elsewhere)."""
    text = source(name, defines, extensions)
    if isinstance(ctx.extra, Programs):
        return ctx.extra.compute(text, label or name)
    program = ctx.compute_shader(text)
    program.label = label or name
    return program
