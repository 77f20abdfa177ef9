"""Brute-force rasterization of every point: compute 64-bit (where the GPU has
GL_NV_shader_atomic_int64), compute 32-bit two-pass and GL_POINTS, on the same cloud
and camera, with the store in file order, Morton order, terrestrial scan order
(FillOrder.FILE, so slots follow that order), shuffled over the whole cloud (the
paper's layout) and batched (the renderer's own layout: shuffled inside batches of
consecutive points, of file or scan order), its positions as 30-bit words relative to
the batch (exact or adaptive precision) or as float records. Bytes read per second are
set against a buffer-to-buffer copy measured in the same run, the GPU's practical
ceiling for streaming the store."""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.report import RunInfo, Table, index_pass_label
from bench.synthetic import SAMPLE, Order, TiledCloud, load, tiled
from progressive import batches, encoding, shaderlib
from progressive.batches import BatchOrder
from progressive.bindings import Binding
from progressive.camera import Camera, auto_camera, view_uniforms
from progressive.context import GLContext, create_context
from progressive.encoding import Encoding, Precision
from progressive.gpu import grid
from progressive.loaders.records import RECORD_BYTES
from progressive.passes.raster_compute import DEFAULT_TUNING, ComputeTuning, subgroup_reduction_available
from progressive.permutation import FillOrder
from progressive.pointstore import RecordOrder
from progressive.renderer import Raster, Renderer
from progressive.timing import Timestamps


@dataclass(frozen=True)
class Layout:
    """How points sit in the GPU buffer the rasterizer streams."""

    label: str
    order: Order
    fill: FillOrder
    records: RecordOrder = RecordOrder.BATCHES
    encoding: Encoding = Encoding.WORDS
    batch_order: BatchOrder = BatchOrder.FILE


LAYOUTS = (Layout("file order", Order.FILE, FillOrder.FILE), Layout("Morton order", Order.MORTON, FillOrder.FILE),
           Layout("scan order", Order.SCAN, FillOrder.FILE), Layout("shuffled", Order.FILE, FillOrder.SHUFFLED),
           Layout("batched", Order.FILE, FillOrder.BATCHED),
           Layout("batched, float records", Order.FILE, FillOrder.BATCHED, encoding=Encoding.FLOAT),
           Layout("batched, records in slot order", Order.FILE, FillOrder.BATCHED, RecordOrder.SLOTS),
           Layout("batched, scan order", Order.SCAN, FillOrder.BATCHED),
           Layout("batched, scan order, Morton in loaded batches", Order.SCAN, FillOrder.BATCHED,
                  batch_order=BatchOrder.MORTON))


WARM_SECONDS = 0.5
"""Work kept up before a timed set, so that the GPU's clocks are those of a busy frame
loop: on the H100 bench.kernel timed its dispatches, each a few ms between readbacks,
while the SM clock sat at its idle 345 MHz of 1980 (bench/results/nvidia-h100/kernel_clocks/)."""


def sustain(glc: GLContext, run, seconds: float = WARM_SECONDS) -> None:
    """run() back to back for `seconds` of wall time (a glFinish every few)."""
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for _ in range(4):
            run()
        glc.ctx.finish()


def median_gpu_ms(glc: GLContext, run, repeats: int, warm_s: float = WARM_SECONDS) -> float:
    """Median GPU milliseconds (timestamps) of `run()` over `repeats` runs after `warm_s`
    seconds of it (sustain) and one warm-up."""
    sustain(glc, run, warm_s)
    t = Timestamps(glc)
    ms = []
    for _ in range(repeats + 1):
        t.reset()
        t.stamp("start")
        run()
        t.stamp("end")
        ms.append(t.durations_ms()["end"])
    t.release()
    return statistics.median(ms[1:])


def copy_bandwidth(glc: GLContext, nbytes: int, repeats: int) -> dict[str, float]:
    """Bytes copied per second between two buffers (GPU timestamps; each byte read once
    and written once), by glCopyNamedBufferSubData and by a compute shader that reads
    16 bytes an invocation as the rasterizers do. The larger is the reference."""
    src, dst = glc.ctx.buffer(reserve=nbytes), glc.ctx.buffer(reserve=nbytes)
    glc.gl.clear_u32(src.glo, 0x3F800000, total=nbytes)
    programs = [shaderlib.compute(glc.ctx, "copy.comp", {"READ_ONLY": k}, label=f"bench copy {k}") for k in (0, 1)]
    count = nbytes // 16
    for program in programs:
        program["u_count"] = count
    src.bind_to_storage_buffer(Binding.DISTRIBUTE)
    dst.bind_to_storage_buffer(Binding.COUNTERS)
    methods = {"glCopyNamedBufferSubData": lambda: glc.gl.copy_named_buffer_sub_data(src.glo, dst.glo, 0, 0, nbytes),
               "compute shader": lambda: programs[0].run(*grid(count))}
    rates = {name: nbytes / (median_gpu_ms(glc, copy, repeats) / 1e3) for name, copy in methods.items()}
    read = nbytes / (median_gpu_ms(glc, lambda: programs[1].run(*grid(count)), repeats) / 1e3)
    for obj in (src, dst, *programs):
        obj.release()
    return rates, read


def rasters(glc: GLContext) -> list[Raster]:
    """COMPUTE is the 64-bit path only where the extension exists; elsewhere it would
    silently be the 32-bit path again."""
    return ([Raster.COMPUTE] if glc.caps.atomic_int64 else []) + [Raster.COMPUTE32, Raster.POINTS]


def variants(glc: GLContext, batched: bool, words: bool) -> list[tuple[Raster, ComputeTuning, Precision]]:
    """Each rasterizer; the compute ones on the batched layout also one invocation a slot
    (against one work group a batch) and, where the GPU has it, with the subgroup
    reduction, and on the word store a batch walk with four-word loads and with adaptive
    precision, and the 32-bit path's index pass the other way (over every point or over
    the depth pass's candidates, ComputeTuning.candidates), so each choice is measured
    side by side."""
    reduce = subgroup_reduction_available(glc)
    tunings = [ComputeTuning(batch_groups=g, subgroup_reduction=s, vector_loads=False)
               for g in ((False, True) if batched else (False,)) for s in ((False, True) if reduce else (False,))]
    out = []
    for r in rasters(glc):
        if r is Raster.POINTS:
            out.append((r, ComputeTuning(), Precision.EXACT))
            continue
        out += [(r, t, Precision.EXACT) for t in tunings]
        one, four = ComputeTuning(vector_loads=False), ComputeTuning(vector_loads=True)
        out += [(r, four, Precision.EXACT), (r, one, Precision.ADAPTIVE), (r, four, Precision.ADAPTIVE)] if words else []
        if r is Raster.COMPUTE32:       # the index pass the renderer does not choose here, too
            out.append((r, ComputeTuning(vector_loads=False, candidates=not DEFAULT_TUNING.candidates), Precision.EXACT))
    return out


def bytes_read(store, view, precision: Precision) -> float:
    """Bytes of the store a raster pass reads, from the cull pass's twins: each point of
    a batch in view, 4 bytes a position word read (the word store; the attribute word
    only where a filter needs it) or its 16-byte record; every point where nothing is culled."""
    if not store.batched:
        return float(store.capacity * RECORD_BYTES)
    shown = batches.in_view(store.boxes, view)
    held = store.kept / max(1, store.permutation.batches)       # points a batch holds, on average
    if not store.words:
        return float(np.count_nonzero(shown) * held * RECORD_BYTES)
    levels = np.full(int(np.count_nonzero(shown)), encoding.LEVELS)
    if precision is Precision.ADAPTIVE:
        levels = encoding.levels_needed(store.frames[shown], batches.least_depths(store.boxes[shown], view), view)
    return float(levels.sum() * 4 * held)


def close_up(cloud: TiledCloud, aspect: float) -> Camera:
    """A view of one corner tile from above at 45 degrees: most batches are outside."""
    lo = cloud.info.bounds_min
    size = np.asarray(cloud.tile_size, dtype=np.float64)
    target = lo + size * np.array([0.5, 0.5, 0.0])
    position = target + np.array([0.0, -0.6, 0.6]) * size[:2].max()
    return Camera(position=tuple(position), target=tuple(target), near=0.01 * size[:2].max(), far=10 * size[:2].max())


def views(cloud: TiledCloud, aspect: float) -> dict[str, Camera]:
    return {"overview": auto_camera(cloud.info.bounds_min, cloud.info.bounds_max, aspect),
            "close-up": close_up(cloud, aspect)}


def clear_and_draw(r: Renderer, view):
    """A visibility clear and the raster pass over the whole store (as the last render
    left its precision): what a raster row times without the frame around it."""
    def run() -> None:
        r.vis.clear()
        r.raster.draw(view, 0, r.store.capacity)
    return run


def wall_ms(glc: GLContext, r: Renderer, view, repeats: int) -> float:
    """Wall-clock ms of clear_and_draw between two glFinish: a check on the timestamps
    that needs no query."""
    run = clear_and_draw(r, view)
    glc.ctx.finish()
    t0 = time.perf_counter()
    for _ in range(repeats):
        run()
    glc.ctx.finish()
    return (time.perf_counter() - t0) / repeats * 1e3


def measure(glc: GLContext, cloud: TiledCloud, layouts, sizes, repeats: int) -> list[dict]:
    """Every variant of a layout, size and view is timed in turn, round after round
    (after one warm-up round), so a clock or cache that drifts during the run is shared
    by all of them instead of favouring whichever ran last."""
    rows = []
    for layout in layouts:
        scene, upload_s = load(glc, cloud, layout.order, layout.fill, layout.records, layout.encoding, layout.batch_order)
        for width, height in sizes:
            for view, cam in views(cloud, width / height).items():
                uniforms = view_uniforms(cam, cloud.info.origin, width, height)
                culled = (1.0 - float(np.mean(batches.in_view(scene.store.boxes, uniforms)))) if scene.store.batched else 0.0
                variant = [(raster, tuning, precision)
                           for raster, tuning, precision in variants(glc, scene.store.batched, scene.store.words)
                           if raster is not Raster.POINTS or view == "overview"]
                renderers = [Renderer(glc, cloud.info, cloud.attribute, raster=raster, width=width, height=height,
                                      scene=scene, tuning=tuning) for raster, tuning, _ in variant]
                styles = [r.style() for r in renderers]
                times = [[] for _ in renderers]
                for _ in range(repeats + 1):
                    for k, (r, (_, _, precision)) in enumerate(zip(renderers, variant)):
                        times[k].append(r.render(cam, width, height, styles[k], precision=precision).gpu_ms["raster"])
                exact = None
                for r, style, t, (_, tuning, precision) in zip(renderers, styles, times, variant):
                    frame = r.render(cam, width, height, style, precision=precision)
                    wall = wall_ms(glc, r, uniforms, repeats)
                    exact = frame.slots if exact is None else exact
                    ms = statistics.median(t[1:])
                    candidates = getattr(r.raster, "candidates", False)
                    found = (r.raster.candidates_found(), r.raster.candidate_capacity(width * height)) \
                        if candidates else None
                    read = bytes_read(scene.store, uniforms, precision) * (1 if candidates else r.raster.passes)
                    rows.append({"points": cloud.points, "width": width, "height": height, "layout": layout.label,
                                 "view": view, "raster": r.raster_path, "ms": ms, "ms_all": t[1:],
                                 "subgroup_reduction": getattr(r.raster, "partitioned", False),
                                 "batch_groups": getattr(r.raster, "batch_groups", False),
                                 "vector_loads": getattr(r.raster, "vector_loads", False),
                                 "candidates": candidates, "default_index_pass": tuning.candidates == DEFAULT_TUNING.candidates,
                                 "candidates_found": found,
                                 "precision": precision.value, "wall_ms": wall,
                                 "passes": r.raster.passes, "points_per_s": cloud.points / (ms / 1e3),
                                 "bytes_per_point": read / cloud.points, "bytes_per_s": read / (ms / 1e3),
                                 "pixels_differing": int(np.count_nonzero(frame.slots != exact)),
                                 "batches_culled": culled, "covered_pixels": int((frame.slots != 0xFFFFFFFF).sum()),
                                 "upload_s": upload_s})
                for r in renderers:
                    r.release()
        scene.release()
    return rows


def run(glc: GLContext, points: list[int], sizes: list[tuple[int, int]], repeats: int,
        copy_bytes: int, layouts=LAYOUTS) -> Table:
    copies, read_rate = copy_bandwidth(glc, copy_bytes, repeats)
    copy = max(copies.values())
    rows = []
    for n in points:
        rows += measure(glc, tiled(str(SAMPLE), n), layouts, sizes, repeats)
    table = Table(f"raster_{max(points)}", "Brute-force rasterization of every point", f"{SAMPLE.name} tiled on a grid",
                  ", ".join(f"{n:,}" for n in points), (
                      "points", "size", "store order", "view", "rasterizer", "work group", "subgroup reduction",
                      "index pass", "precision", "ms (median)", "wall ms", "Mpoints/s", "B/point read", "GB/s read",
                      "share of copy bandwidth", "share of read bandwidth", "× GL_POINTS", "batches culled", "× overview", "covered pixels",
                      "pixels ≠ first row", "candidates / room"))
    def twin(r: dict, **keys) -> float:
        """ms of the row of the same cloud, size and layout with `keys` changed."""
        want = dict(points=r["points"], width=r["width"], layout=r["layout"], **keys)
        return next(b["ms"] for b in rows if all(b[k] == v for k, v in want.items()))

    for r in rows:
        base = twin(r, view="overview", raster="GL_POINTS")
        overview = twin(r, view="overview", raster=r["raster"], subgroup_reduction=r["subgroup_reduction"],
                        batch_groups=r["batch_groups"], vector_loads=r["vector_loads"], precision=r["precision"],
                        default_index_pass=r["default_index_pass"])
        r["vs_points"] = base / r["ms"] if r["view"] == "overview" else None
        r["vs_overview"] = overview / r["ms"]
        r["share_of_copy"] = r["bytes_per_s"] / copy
        r["share_of_read"] = r["bytes_per_s"] / read_rate
        table.rows.append((r["points"], f"{r['width']}x{r['height']}", r["layout"], r["view"], r["raster"],
                           ("batch, 4-word loads" if r["vector_loads"] else "batch") if r["batch_groups"] else "256 slots", "yes" if r["subgroup_reduction"] else "no",
                           index_pass_label(r["candidates"], r["passes"]), r["precision"], r["ms"], r["wall_ms"], r["points_per_s"] / 1e6, r["bytes_per_point"], r["bytes_per_s"] / 1e9,
                           r["share_of_copy"], r["share_of_read"], r["vs_points"], r["batches_culled"], r["vs_overview"], r["covered_pixels"],
                           r["pixels_differing"],
                           None if r["candidates_found"] is None else "{:,} / {:,}".format(*r["candidates_found"])))
    missing = [] if glc.caps.atomic_int64 else [
        ("Compute 64-bit atomicMin: not run, this GPU lacks GL_NV_shader_atomic_int64 (llvmpipe has no 64-bit "
        "atomics); `--raster compute` falls back to the 32-bit two-pass path here.")]
    table.notes = missing + [
        (f"Same auto camera for every row; GPU time of the raster pass from timestamps, median of {repeats} after "
        f"one warm-up; wall ms = a visibility clear and the raster pass {repeats} times between two glFinish, "
        f"by the CPU's clock, a check on the timestamps. B/point read = bytes of the store a raster reads (from the cull pass's twins: "
        f"{RECORD_BYTES} B a float record, 4 B a position word, for the points of batches in view; × passes, "
        f"the 32-bit path reads twice where its index pass walks every point, once where it walks the depth "
        f"pass's candidates, whose 16 bytes each are not counted) / the cloud's points; GB/s read = those bytes / time. Precision: exact reads "
        f"all three 10-bit words of a position (30 bits), adaptive the fewest that keep each point within "
        f"{encoding.ADAPTIVE_ERROR_PX} px of its exact projection; pixels ≠ first row = pixels whose slot differs "
        f"from the first rasterizer's of the same layout, size and view (exact, so the adaptive rows count what "
        f"coarser words change). Copy bandwidth, measured in this run on {copy_bytes / 2**20:.0f} MiB (each byte read "
        "and written): " + ", ".join(f"{k} {v / 1e9:.1f} GB/s" for k, v in copies.items()) +
        f"; the share is of the faster, {copy / 1e9:.1f} GB/s (a copy counts each byte once though it reads and "
        f"writes it, so a raster may read faster). Read bandwidth: the same shader reading only, "
        f"{read_rate / 1e9:.1f} GB/s. × GL_POINTS = GL_POINTS ms / this ms, "
        "same cloud, size and order. Store order: file/Morton/scan = points in the buffer in that file order "
        "(FillOrder.FILE); shuffled = the paper's permutation of the whole file order; batched = the renderer's "
        "layout (shuffled inside batches of 10,240 consecutive points, slices of 256 interleaved in slot order, each "
        "batch's records stored together, positions as 30-bit words relative to the batch; 'float records' keeps "
        "float32 xyz relative to the origin beside the attribute word; 'records in slot order' stores them slice by "
        "slice as the slots run). Scan order: a scanner station "
        "per tile, vertical scan lines by azimuth (bench/synthetic.py). Views: overview = the auto camera on the "
        "whole cloud; close-up = one corner tile from above at 45° (GL_POINTS not run); batches culled = share of "
        "the store's batches the culling test leaves out (batched layouts only); × overview = overview ms / this "
        "ms, same rasterizer. Work group: batch = one work group walks one batch's slices (ComputeTuning.batch_groups), "
        "256 slots = one invocation a slot. Candidates / room: the last frame's candidates and the room for them "
        "(more than the room: the index pass ran over every point instead). "
        "Index pass (32-bit path): candidates = over the points that lowered or met their "
        "pixel's depth in its depth pass (ComputeTuning.candidates; the default), every point = loading, "
        "decoding and projecting them all again. Mpoints/s and GB/s count every point of the cloud, culled ones "
        "included.")]
    table.raw = {"copy_bytes": copy_bytes, "copy_bytes_per_s": copy, "copy_methods": copies,
                 "read_bytes_per_s": read_rate, "rows": rows}
    return table


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="rasterization section alone (python -m bench runs every section)")
    ap.add_argument("--points", type=int, nargs="+", default=[1_000_000])
    ap.add_argument("--size", nargs="+", default=["1920x1080"])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--layouts", nargs="+", choices=[layout.label for layout in LAYOUTS])
    ap.add_argument("--copy-mib", type=int, default=64, help="bytes for the copy-bandwidth reference")
    ap.add_argument("--out", default="bench/results/local")
    args = ap.parse_args(argv)
    glc = create_context()
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.size]
    layouts = [x for x in LAYOUTS if not args.layouts or x.label in args.layouts]
    table = run(glc, args.points, sizes, args.repeats, args.copy_mib << 20, layouts)
    table.write(Path(args.out), RunInfo.from_caps(glc.caps, "raster only"))
    print(table.markdown(RunInfo.from_caps(glc.caps, "raster only")))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
