"""Where the compute raster's time goes: the store read in plain patterns (the bytes a
brute-force frame must read, no rasterization), and the 64-bit batch walk with its
stages cut off one by one, on the same tiled cloud in one run.

    python -m bench.kernel [--points 100000000] [--size 1920x1080] [--out DIR | --out-root DIR]

Stages are cut by rewriting the raster shader's text here (the renderer's shader has
no switches for them): "load" keeps only the record reads, "+ project" adds the
filters and the projection, "+ read" the read-before-atomicMin, "atomic, no read"
every atomic without the read before it, "full" the whole one-word walk. On the word
store each stage runs at exact and adaptive precision, beside "load, no decode" (the
words loaded, not decoded) and the full walk with 1, 2 or 8 records prefetched instead of
ComputeTuning.prefetch's default, with the subgroup reduction, with the decode not `precise`, with a plain loop (plain_loop), and with four-word loads (ComputeTuning.vector_loads;
its load and projection stages too; and the four-word walk with the projection's two
divisions made one reciprocal, with its four points' pixels read together before their
atomics, and both). A variant the driver does not compile gets a row without times. Beside
them, the "prototype" rows: the paper's walk at its plainest on a synthetic store of its
own (PROTOTYPE_SHADER), what the walk would cost without the renderer's layout. 64-bit only
(llvmpipe lacks the atomics: the section says so and times the reads alone).
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from bench.raster import WARM_SECONDS, clear_and_draw, median_gpu_ms
from bench.report import RunInfo, Table
from bench.synthetic import SAMPLE, load, tiled
from progressive import shaderlib
from progressive.camera import auto_camera, view_uniforms
from progressive.context import GLContext, create_context
from progressive.encoding import Encoding, Precision
from progressive.loaders.records import RECORD_BYTES
from progressive.passes.cull import CullPass
from progressive.passes.raster_compute import ComputeRaster, ComputeTuning
from progressive.permutation import BATCH_SLOTS, SLICE_POINTS, FillOrder
from progressive.pointstore import BLOCK_RECORDS, RecordOrder
from progressive.renderer import Renderer

READS = {
    "linear, a record an invocation":
        "uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * 256u;"
        "if (i >= u_n) return; uvec4 a = p[i];",
    "a group a batch, its records contiguous":
        "uint b = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x; if (b >= u_b) return;"
        "uvec4 a = uvec4(0); for (uint k = 0u; k < ROUNDS; ++k) a ^= p[b * BATCH_SLOTS + k * SLICE_POINTS"
        " + gl_LocalInvocationID.x];",
    "a group a batch, its slices across the store":
        "uint b = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x; if (b >= u_b) return;"
        "uvec4 a = uvec4(0); for (uint k = 0u; k < ROUNDS; ++k) a ^= p[(k * u_b + b) * SLICE_POINTS"
        " + gl_LocalInvocationID.x];",
}
READ_SHADER = """#version 450
layout(local_size_x = 256) in;
layout(std430, binding = 0) readonly buffer P { uvec4 p[]; };
layout(std430, binding = 1) writeonly buffer O { uint o[]; };
uniform uint u_n;
uniform uint u_b;
const uint BATCH_SLOTS = %du, SLICE_POINTS = %du, ROUNDS = BATCH_SLOTS / SLICE_POINTS;
void main() { %s if (a.x == 7u && a.y == 9u) o[0] = a.z; }
"""

DEPTH = "    uint depth_bits = floatBitsToUint(depth);\n"
FIRST_TEST = "#if FILTERING\n"
"""raster()'s first line: where the "load" stage returns."""
STAGES = {
    "load": (FIRST_TEST,
             "    if (record.x == 0x7FC00001u && record.y == 1u) visibility[0] = uint64_t(0);\n    return;\n" + FIRST_TEST),
    "+ project": (DEPTH, DEPTH + "    if (pixel == 0xFFFFFFF0u) visibility[0] = uint64_t(depth_bits);\n    return;\n"),
    "+ read": (DEPTH, DEPTH + "    uint64_t probe = (uint64_t(depth_bits) << 32) | uint64_t(slot);\n"
               "    if (probe < visibility[pixel] && pixel == 0xFFFFFFF0u) visibility[0] = probe;\n    return;\n"),
    "atomic, no read": (DEPTH, DEPTH + "    atomicMin(visibility[pixel], (uint64_t(depth_bits) << 32) | uint64_t(slot));\n"
                        "    return;\n"),
    "full": None,
}
NO_DECODE = ("    if (words.x == HIDDEN_WORD) return uvec3(EMPTY);\n",
             "    if (words.x != 0x7FC00001u) return words ^ uvec3(levels);\n")
"""points.glsl's position_bits cut after its hidden test: the words are loaded, not decoded."""
FUSED = ("    precise vec3 offset = vec3(point_cells(words, levels)) * step;\n    precise vec3 p = base + offset;\n",
         "    vec3 p = base + vec3(point_cells(words, levels)) * step;\n")
"""position_bits without `precise` (the compiler may fuse the decode; its twin would differ): what exactness costs."""
RECIPROCAL = ("    float w = u_perspective != 0.0 ? depth : 1.0;\n"
              "    float fx = (u_projection.x * v.x / w * 0.5 + 0.5) * float(u_size.x);\n"
              "    float fy = (0.5 - u_projection.y * v.y / w * 0.5) * float(u_size.y);\n",
              "    float r = u_perspective != 0.0 ? 1.0 / depth : 1.0;\n"
              "    vec2 half_size = 0.5 * vec2(u_size);\n"
              "    float fx = (v.x * r) * (u_projection.x * half_size.x) + half_size.x;\n"
              "    float fy = half_size.y - (v.y * r) * (u_projection.y * half_size.y);\n")
"""camera.glsl's project with one reciprocal and the viewport folded into the scales
(rounds differently from the render contract's order of operations)."""
QUAD_CALL = ("            for (uint m = 0u; m < 4u; ++m)\n"
             "                raster_by(slot + m, slot + m, uvec4(position_bits(uvec3(w0[m], w1[m], w2[m]), levels, frame_base, frame_step), at[m]),\n"
             "                          view_m, view_t);\n")


def reads_together() -> tuple[str, str]:
    """The four-word walk's four points projected first, then their four pixels read,
    then the atomics: four reads in flight where raster_by waits for each in turn
    (64-bit brute force only: no filters, hints or marks)."""
    return (QUAD_CALL,
            "            uint pix[4]; uint64_t keys[4], held[4];\n"
            "            for (uint m = 0u; m < 4u; ++m) {\n"
            "                uint pixel; float depth;\n"
            "                uvec4 record = uvec4(position_bits(uvec3(w0[m], w1[m], w2[m]), levels, frame_base, frame_step), at[m]);\n"
            "                bool drawn = project_view(view_m * uintBitsToFloat(record.xyz) + view_t, pixel, depth)"
            " && finite_position(record);\n"
            "                pix[m] = drawn ? pixel : 0u;\n"
            "                keys[m] = drawn ? (uint64_t(floatBitsToUint(depth)) << 32) | uint64_t(slot + m) : ~uint64_t(0);\n"
            "            }\n"
            "            for (uint m = 0u; m < 4u; ++m) held[m] = visibility[pix[m]];\n"
            "            for (uint m = 0u; m < 4u; ++m) if (keys[m] < held[m]) atomicMin(visibility[pix[m]], keys[m]);\n")


def plain_loop() -> tuple[str, str]:
    """The one-word walk's loop (its prefetch arrays, the range's first round computed)
    made the prototype's: every round in turn, a constant count, the range tested per
    point (brute force only: no attribute word, no filters)."""
    text = shaderlib.shader_text("raster_compute.comp")
    start = text.index("    uint k = first > base ?")
    end = text.index("#else\nvoid main() {", start)
    return (text[start:end],
            "    for (uint k = 0u; k < ROUNDS; ++k) {\n"
            "        uint slot = base + k * stride;\n"
            "        uvec3 w = point_words(records + k * record_stride, levels);\n"
            "        if (slot < first || slot > last) continue;\n"
            "        raster_by(slot, slot, uvec4(position_bits(w, levels, frame_base, frame_step), EMPTY), view_m, view_t);\n"
            "    }\n}\n")


ONE_WORD = ComputeTuning(vector_loads=False, winners=False)
"""The stages' walk: one word a load, `prefetch` records a slice apart (the four-word
walk, the renderer's 64-bit default, is a variant beside it). No winners pass (on by
default from WINNERS_MIN_BYTES): it is not timed here, and its program would take the
raster's patches, which do not fit it."""
FOUR_WORDS = replace(ONE_WORD, vector_loads=True)
VARIANTS = {
    "load, no decode": (ONE_WORD, {"raster_compute.comp": STAGES["load"], "points.glsl": NO_DECODE}),
    "full, prefetch 1": (replace(ONE_WORD, prefetch=1), {}),
    "full, prefetch 2": (replace(ONE_WORD, prefetch=2), {}),
    "full, prefetch 8": (replace(ONE_WORD, prefetch=8), {}),
    "full, subgroup reduction": (replace(ONE_WORD, subgroup_reduction=True), {}),
    "full, four-word loads": (FOUR_WORDS, {}),
    "full, decode fused": (ONE_WORD, {"points.glsl": FUSED}),
    "full, a plain loop": (ONE_WORD, {"raster_compute.comp": plain_loop()}),
    "load, four-word loads": (FOUR_WORDS, {"raster_compute.comp": STAGES["load"]}),
    "+ project, four-word loads": (FOUR_WORDS, {"raster_compute.comp": STAGES["+ project"]}),
    "full, four-word loads, one reciprocal": (FOUR_WORDS, {"camera.glsl": RECIPROCAL}),
    "full, four-word loads, four reads at once": (FOUR_WORDS, {"raster_compute.comp": reads_together()}),
    "full, four-word loads, one reciprocal, four reads at once":
        (FOUR_WORDS, {"camera.glsl": RECIPROCAL, "raster_compute.comp": reads_together()}),
}
"""Walks beside the stages, on the word store: name -> (tuning, patches)."""


def reads(glc: GLContext, points: int, repeats: int) -> list[tuple]:
    batches = -(-points // BATCH_SLOTS)
    slots = batches * BATCH_SLOTS
    buf = glc.ctx.buffer(reserve=slots * RECORD_BYTES)
    glc.gl.clear_u32(buf.glo, 0x3F800000, total=buf.size)
    out = glc.ctx.buffer(reserve=16)
    rows = []
    for name, body in READS.items():
        program = glc.ctx.compute_shader(READ_SHADER % (BATCH_SLOTS, SLICE_POINTS, body))
        for uniform, value in (("u_n", slots), ("u_b", batches)):
            if uniform in program:
                program[uniform] = value
        groups = -(-slots // 256) if name.startswith("linear") else batches
        gx = min(groups, 65535)
        buf.bind_to_storage_buffer(0)
        out.bind_to_storage_buffer(1)
        grid = (gx, -(-groups // gx), 1)
        ms = median_gpu_ms(glc, lambda p=program, g=grid: p.run(*g), repeats)
        rows.append(("read", name, "", "", ms, slots * RECORD_BYTES / (ms / 1e3) / 1e9, slots / (ms / 1e3) / 1e9))
        program.release()
    buf.release()
    out.release()
    return rows


PROTOTYPE_SHADER = """#version 450
#extension GL_ARB_gpu_shader_int64 : require
#extension GL_NV_shader_atomic_int64 : require
layout(local_size_x = 256) in;
layout(std430, binding = 0) readonly buffer W { uint words[]; };
layout(std430, binding = 1) readonly buffer F { vec4 frames[]; };
layout(std430, binding = 2) buffer V { uint64_t vis[]; };
uniform uint u_b;
uniform uint u_rounds;
uniform uvec2 u_size;
uniform vec2 u_scale;
const uint BATCH_SLOTS = %du, SLICE_POINTS = %du, ROUNDS = BATCH_SLOTS / SLICE_POINTS;
void main() {
    uint b = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (b >= u_b) return;
    vec3 base = frames[2u * b].xyz, step = frames[2u * b + 1u].xyz;
    uint acc = 0u;
    for (uint k = 0u; k < %s; ++k) {
        uint i = b * BATCH_SLOTS + k * SLICE_POINTS + gl_LocalInvocationID.x;
        uint w = words[%s];
        %s
    }
    if (acc == 0x7FC00001u) vis[0] = uint64_t(acc);
}
"""
"""The 2-billion-points paper's walk at its plainest, on its own synthetic store: one
work group a batch of BATCH_SLOTS points (random 10-bit cells in a tile of a grid, the
batch's frame folded into no transform), a word a point, a plain loop; each point
projected (perspective, camera above the grid's centre) and drawn with
read-before-atomicMin. What the renderer's walk would cost without its layout's address
arithmetic, buffer switch, ranges and prefetch arrays, on the same GPU in the same run."""
PROTOTYPE_BODIES = {
    "load": "acc ^= w;",
    "full": "vec3 p = base + vec3((uvec3(w) >> uvec3(20u, 10u, 0u)) & 1023u) * step;\n"
            "        vec3 v = p - vec3(0.5, 0.5, 1.2);\n"
            "        float depth = -v.z;\n"
            "        float fx = (u_scale.x * v.x / depth * 0.5 + 0.5) * float(u_size.x);\n"
            "        float fy = (0.5 - u_scale.y * v.y / depth * 0.5) * float(u_size.y);\n"
            "        if (!(fx >= 0.0 && fx < float(u_size.x) && fy >= 0.0 && fy < float(u_size.y))) continue;\n"
            "        uint pixel = uint(fy) * u_size.x + uint(fx);\n"
            "        uint64_t key = (uint64_t(floatBitsToUint(depth)) << 32) | uint64_t(i);\n"
            "        if (key < vis[pixel]) atomicMin(vis[pixel], key);",
}
PROTOTYPE_LOOPS = {"rounds a constant": "ROUNDS", "rounds a uniform": "u_rounds"}
PROTOTYPE_PLACES = {"a word a point": "i",
                    "the word store's blocks": f"(i / {BLOCK_RECORDS}u * 4u) * {BLOCK_RECORDS}u + i % {BLOCK_RECORDS}u"}
"""Where point i's word lies: one plane of words, or the word store's first plane in its
blocks of BLOCK_RECORDS records holding four planes in turn (progressive/pointstore.py;
its address arithmetic and its stride between blocks, on a buffer four times as large,
without the buffer switch, the ranges or the prefetch arrays)."""


def prototype(glc: GLContext, points: int, size: tuple[int, int], repeats: int) -> list[tuple]:
    """PROTOTYPE_SHADER's rows: each body with the loop's count a constant (unrollable)
    and a uniform, over `points` points (whole batches) at `size`."""
    batches = -(-points // BATCH_SLOTS)
    side = math.ceil(math.sqrt(batches * size[0] / size[1]))
    rows_of_tiles = -(-batches // side)
    rng = np.random.default_rng(1)
    words = glc.ctx.buffer(reserve=batches * BATCH_SLOTS * 4 * 4)     # room for the blocks' four planes
    piece = 1 << 24
    for at in range(0, batches * BATCH_SLOTS * 4, piece):
        n = min(piece, batches * BATCH_SLOTS * 4 - at)
        words.write(rng.integers(0, 1 << 30, n, dtype=np.uint32).tobytes(), offset=at * 4)
    b = np.arange(batches)
    tile = np.array([1.0 / side, 1.0 / rows_of_tiles, 0.05])
    frames = np.zeros((batches, 2, 4), np.float32)
    frames[:, 0, 0], frames[:, 0, 1] = (b % side) * tile[0], (b // side) * tile[1]
    frames[:, 1, :3] = tile / 1024.0
    frame_buf = glc.ctx.buffer(frames.tobytes())
    vis = glc.ctx.buffer(reserve=size[0] * size[1] * 8)
    f = 1.2 / 0.5                   # the grid's half width at the camera's distance fills the image
    rows = []
    for (place_name, place), (loop_name, loop) in itertools.product(PROTOTYPE_PLACES.items(), PROTOTYPE_LOOPS.items()):
        for body_name, body in PROTOTYPE_BODIES.items():
            name = f"{body_name}, {loop_name}"
            try:
                program = glc.ctx.compute_shader(PROTOTYPE_SHADER % (BATCH_SLOTS, SLICE_POINTS, loop, place, body))
            except Exception as error:      # a driver without 64-bit atomics: a row without times
                print(f"bench.kernel: prototype {name}: {error}", file=sys.stderr)
                rows.append(("prototype", name, place_name, "", float("nan"), float("nan"), float("nan")))
                continue
            values = {"u_b": batches, "u_rounds": BATCH_SLOTS // SLICE_POINTS, "u_size": size,
                      "u_scale": (f, f)}
            for uniform, value in values.items():
                if uniform in program:
                    program[uniform] = value
            gx = min(batches, 65535)
            grid = (gx, -(-batches // gx), 1)

            def run(p=program, g=grid) -> None:
                glc.gl.clear_u32(vis.glo, 0xFFFFFFFF, total=vis.size)
                words.bind_to_storage_buffer(0)
                frame_buf.bind_to_storage_buffer(1)
                vis.bind_to_storage_buffer(2)
                p.run(*g)
            ms = median_gpu_ms(glc, run, repeats)
            n = batches * BATCH_SLOTS
            rows.append(("prototype", name, place_name, "10-bit", ms, n * RECORD_BYTES / (ms / 1e3) / 1e9,
                         n / (ms / 1e3) / 1e9))
            program.release()
    for buf in (words, frame_buf, vis):
        buf.release()
    return rows


STORES = ((RecordOrder.BATCHES, Encoding.WORDS), (RecordOrder.BATCHES, Encoding.FLOAT), (RecordOrder.SLOTS, Encoding.WORDS))
"""Record order and position encoding of each store the stages run on (the word
store's "load" stage includes decoding its words)."""


def compiled_raster(glc: GLContext, store, vis, edit: Callable[[str, str], str], tuning: ComputeTuning,
                    atomic64: bool = True) -> ComputeRaster:
    """A compute raster compiled from the shader texts as edit(name, text) makes them
    (shaderlib's text of each file, included ones too)."""
    original = shaderlib.shader_text
    shaderlib.shader_text = lambda name: edit(name, original(name))
    try:
        return ComputeRaster(glc, store, vis, atomic64=atomic64, culling=CullPass(glc, store), tuning=tuning)
    finally:
        shaderlib.shader_text = original


def patched(patches: dict[str, list[tuple[str, str]]]) -> Callable[[str, str], str]:
    """An edit for compiled_raster: each file's (old, new) replacements, each old text
    required to be there."""
    def edit(name: str, source: str) -> str:
        for old, new in patches.get(name, []):
            if old not in source:
                raise ValueError(f"bench.kernel: the patch of {name} no longer matches its text")
            source = source.replace(old, new, 1)
        return source
    return edit


def _raster(glc: GLContext, store, vis, patches: dict[str, tuple[str, str]], tuning: ComputeTuning) -> ComputeRaster:
    """A 64-bit raster compiled from the shader texts with `patches` (file -> (old, new))."""
    return compiled_raster(glc, store, vis, patched({name: [patch] for name, patch in patches.items()}), tuning)


def word_store_renderer(glc: GLContext, points: int, size: tuple[int, int]):
    """The tiled sample's `points` in a batched word store, each batch's records
    together, and a renderer of it at `size`: (auto camera, scene, renderer, style)."""
    cloud = tiled(str(SAMPLE), points)
    cam = auto_camera(cloud.info.bounds_min, cloud.info.bounds_max, size[0] / size[1])
    scene, _ = load(glc, cloud, fill=FillOrder.BATCHED, records=RecordOrder.BATCHES, position_encoding=Encoding.WORDS)
    r = Renderer(glc, cloud.info, cloud.attribute, width=size[0], height=size[1], scene=scene)
    return cam, scene, r, r.style()


def alternating(r: Renderer, rasters: dict[str, ComputeRaster], cam, size: tuple[int, int], style,
                rounds: int) -> tuple[dict, dict]:
    """Each raster's GPU ms of the raster pass at each precision, `rounds` rounds with
    the rasters in turn (a clock that drifts is shared by all), after a first round that
    keeps each one's slots: ({(name, precision): [ms]}, {(name, precision): slots})."""
    ms = {(name, p): [] for name in rasters for p in Precision}
    slots = {}
    for k in range(rounds + 1):
        for name, raster in rasters.items():
            r.raster = raster
            for p in Precision:
                frame = r.render(cam, *size, style, precision=p)
                if k:
                    ms[name, p].append(frame.gpu_ms["raster"])
                else:
                    slots[name, p] = frame.slots.copy()
    return ms, slots


def stages(glc: GLContext, points: int, size: tuple[int, int], repeats: int) -> list[tuple]:
    """The 64-bit batch walk over the whole store with stages cut, for each of STORES."""
    cloud = tiled(str(SAMPLE), points)
    width, height = size
    cam = auto_camera(cloud.info.bounds_min, cloud.info.bounds_max, width / height)
    rows = []
    for records, encoding in STORES:
        scene, _ = load(glc, cloud, fill=FillOrder.BATCHED, records=records, position_encoding=encoding)
        r = Renderer(glc, cloud.info, cloud.attribute, width=width, height=height, scene=scene)
        style = r.style()
        view = view_uniforms(cam, cloud.info.origin, width, height)
        runs = [(stage, {} if patch is None else {"raster_compute.comp": patch}, ONE_WORD)
                for stage, patch in STAGES.items()]
        if scene.store.words:
            runs += [(name, patches, tuning) for name, (tuning, patches) in VARIANTS.items()]
        precisions = (Precision.EXACT, Precision.ADAPTIVE) if scene.store.words else (Precision.EXACT,)
        for stage, patches, tuning in runs:
            r.raster.release()
            try:
                r.raster = _raster(glc, scene.store, r.vis, patches, tuning)
            except Exception as error:   # a variant this driver does not compile: its row says so, the rest run
                print(f"bench.kernel: {stage}: {error}", file=sys.stderr)
                rows += [("raster", stage, f"{records.value}, {encoding.value}", p.value, float("nan"), float("nan"),
                          float("nan")) for p in precisions]
                r.raster = _raster(glc, scene.store, r.vis, {}, ONE_WORD)
                continue
            for precision in precisions:
                r.render(cam, width, height, style, precision=precision)      # the raster's precision and state
                ms = median_gpu_ms(glc, clear_and_draw(r, view), repeats)
                rows.append(("raster", stage, f"{records.value}, {encoding.value}", precision.value, ms,
                             points * RECORD_BYTES / (ms / 1e3) / 1e9, points / (ms / 1e3) / 1e9))
        r.release()
        scene.release()
    return rows


def run(glc: GLContext, points: int, size: tuple[int, int], repeats: int) -> Table:
    rows = reads(glc, points, repeats)
    notes = []
    if glc.caps.atomic_int64:
        rows += prototype(glc, points, size, repeats)
        rows += stages(glc, points, size, repeats)
    else:
        notes.append("Raster stages: not run, this GPU lacks GL_NV_shader_atomic_int64 (64-bit atomics).")
    table = Table(f"kernel_{points}", "Where the compute raster's time goes", f"{SAMPLE.name} tiled on a grid",
                  f"{points:,}", ("kind", "what", "store", "precision", "ms (median)", "GB/s", "G points/s"), rows)
    table.notes = notes + [
        f"GPU ms from timestamps, median of {repeats} after {WARM_SECONDS:g} s of the same work back to back "
        f"and one warm-up (bench.raster sustain: the GPU's clocks up, as in a busy frame loop). read: {RECORD_BYTES}-byte "
        "records of a "
        f"store of whole batches ({BATCH_SLOTS:,} slots) read in that pattern, nothing drawn. raster: the "
        f"64-bit batch walk at {size[0]}x{size[1]} over the whole cloud, auto camera (a visibility clear and "
        "the raster pass), with its stages cut "
        "(bench/kernel.py's docstring); store = RecordOrder, Encoding (the word store's 'load' decodes its "
        "three words). prototype: PROTOTYPE_SHADER's walk at the same size, its loads alone and its full "
        "raster, each point's word in a plane of its own or where the word store keeps it (store: PROTOTYPE_PLACES), "
        f"its loop of {BATCH_SLOTS // SLICE_POINTS} rounds counted by a constant or by a uniform. GB/s counts {RECORD_BYTES} bytes a point whatever the store reads; G points/s every point."]
    return table


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default="bench/results/local")
    ap.add_argument("--out-root", help="write to OUT_ROOT/<machine> instead of --out")
    args = ap.parse_args(argv)
    glc = create_context()
    size = tuple(int(v) for v in args.size.split("x"))
    table = run(glc, args.points, size, args.repeats)
    info = RunInfo.from_caps(glc.caps, "kernel")
    table.write(Path(args.out_root) / info.machine if args.out_root else Path(args.out), info)
    print(table.markdown(info))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
