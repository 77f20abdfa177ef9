"""Small GPU helpers shared by passes: dispatch grids within GL's guaranteed limits,
the camera uniforms of camera.glsl, the fill of shaders/clear.comp."""

from __future__ import annotations

from progressive.bindings import Binding
from progressive.camera import ViewUniforms

GUARANTEED_GROUPS = 65535
RANGE_GROUP = 256          # invocations of a work group over a 1-D range (range_index)


def grid(count: int, local_size: int = RANGE_GROUP) -> tuple[int, int, int]:
    """Groups covering `count` invocations as a 2-D grid (shaders use range_index);
    dispatch_grid() in common.glsl is its twin for indirect arguments written on the
    GPU (there 0 invocations give 0 groups)."""
    groups = max(1, -(-count // local_size))
    gx = min(groups, GUARANTEED_GROUPS)
    gy = -(-groups // gx)
    if gy > GUARANTEED_GROUPS:
        raise ValueError(f"{count} invocations exceed the dispatch grid")
    return gx, gy, 1


def dispatch_defines() -> dict[str, str]:
    """What dispatch_grid() in common.glsl needs."""
    return {"RANGE_GROUP": f"{RANGE_GROUP}u", "GUARANTEED_GROUPS": f"{GUARANTEED_GROUPS}u"}


def fill_uvec4s(program, buffer, first: int, count: int, value: int) -> None:
    """uvec4s [first, first + count) of `buffer` set to `value` by `program`, a
    shaders/clear.comp its pass owns (the caller puts the barrier its readers need)."""
    program["u_first"] = first
    program["u_count"] = count
    program["u_value"] = value
    buffer.bind_to_storage_buffer(Binding.COUNTERS)
    program.run(*grid(count))


def grid_2d(width: int, height: int, tile: int = 16) -> tuple[int, int, int]:
    return -(-width // tile), -(-height // tile), 1


def set_view(program, view: ViewUniforms) -> None:
    """Camera uniforms (camera.glsl); a program may not use all of them."""
    for name, value in (("u_view_rotation", view.rotation.T), ("u_view_translation", view.translation),
                        ("u_projection", view.projection)):
        if name in program:
            program[name].write(value.tobytes())
    if "u_perspective" in program:
        program["u_perspective"] = view.perspective
    if "u_size" in program:
        program["u_size"] = view.size
    if "u_hidden" in program:
        program["u_hidden"].write(view.hidden.tobytes())
    if "u_returns" in program:
        program["u_returns"] = view.returns
    if "u_clip_lo" in program:
        program["u_clip_lo"].write(view.clip_lo.tobytes())
        program["u_clip_hi"].write(view.clip_hi.tobytes())
    if "u_section_line" in program:
        program["u_section_line"].write(view.section_line.tobytes())
        program["u_section_range"].write(view.section_range.tobytes())
