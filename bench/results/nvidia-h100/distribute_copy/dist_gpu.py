"""The GPU side of loading (bench.upload's distribute_seconds) taken apart: for each way,
the wall clock to glFinish, the GPU's own time in the scatter dispatches (a timestamp
before and after each), and the pieces that went through the ring or were copied.

Ways: the renderer's; no CPU copy into the ring (the GPU's share); the CPU copy split
over T threads (numpy lets the GIL go); the scatter reading every record from one
device buffer uploaded beforehand (no staging at all: the kernel's own rate).

    PYTHONPATH=. python dist_gpu.py POINTS ROUNDS OUT.json [THREADS ...]
"""
import ctypes
import json
import statistics
import sys
import time

import numpy as np

from bench.synthetic import SAMPLE, load, tiled
from bench.upload import distribute_seconds, loader_pieces
from progressive.bindings import Binding
from progressive.context import create_context
from progressive.frame_loop import ProgressiveOptions
from progressive.glext import GL_QUERY_RESULT, GL_TIMESTAMP
from progressive.gpu import grid
from progressive.passes import distribute as dm


class DispatchClock:
    """A GPU timestamp before and after every compute dispatch while on (the programs'
    run patched): the GPU's own time in the dispatches, and their span, since reset()."""

    def __init__(self, glc, program_class, capacity: int = 8192):
        self.glc, self.cls, self.run = glc, program_class, program_class.run
        self.ids = (ctypes.c_uint * capacity)()
        glc.gl.gen_queries(capacity, self.ids)
        self.used = 0

    def on(self) -> None:
        clock, run = self, self.run

        def stamped(program, *args, **kwargs):
            clock.glc.gl.query_counter(clock.ids[clock.used], GL_TIMESTAMP)
            run(program, *args, **kwargs)
            clock.glc.gl.query_counter(clock.ids[clock.used + 1], GL_TIMESTAMP)
            clock.used += 2
        self.cls.run = stamped

    def off(self) -> None:
        self.cls.run = self.run

    def reset(self) -> None:
        self.used = 0

    def ms(self) -> tuple[float, float]:
        """(ms inside the dispatches, ms from the first to the last stamp)."""
        t = []
        for i in range(self.used):
            v = ctypes.c_uint64(0)
            self.glc.gl.get_query_object_ui64v(self.ids[i], GL_QUERY_RESULT, ctypes.byref(v))
            t.append(v.value)
        return sum(t[i + 1] - t[i] for i in range(0, len(t), 2)) / 1e6, (t[-1] - t[0]) / 1e6



def loaded(points: int):
    """(context, loader-sized pieces, scene, seconds): the sample tiled to `points`, loaded
    into the renderer's store; the scene's scatter program and a DispatchClock on it."""
    glc = create_context()
    cloud = tiled(str(SAMPLE), points)
    pieces = loader_pieces(list(cloud.batches()))
    scene, load_s = load(glc, cloud, records=ProgressiveOptions().records)
    program = scene.distribute._program(False)
    return glc, pieces, scene, load_s, program, DispatchClock(glc, type(program))


def summary(points: int, row: dict) -> dict:
    """A way's medians (wall clock, GPU time in the dispatches) and its runs."""
    wall = statistics.median(row["wall_s"])
    disp = statistics.median(row["gpu_dispatch_ms"])
    return {"wall_Mpoints_s": points / wall / 1e6, "gpu_dispatch_Mpoints_s": points / disp * 1e-3,
            "wall_ms": wall * 1e3, "gpu_dispatch_ms": disp, "runs": row}


def main() -> None:
    points, rounds, out_path = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
    threads = [int(v) for v in sys.argv[4:]] or [4, 8, 16]
    glc, pieces, scene, load_s, program, clock = loaded(points)
    d = scene.distribute

    from progressive.stagecopy import StageCopier
    copy_rows = dm._copy
    copiers = {n: StageCopier(n, parts=n) for n in [1] + threads}

    def with_copier(n):
        return lambda data, width, copy: copy_rows(data, width, copiers[n])

    ways = {"renderer": copy_rows, "no CPU copy": lambda data, width, copy: (lambda out, lo, hi: 0)}
    ways.update({f"copy on {n} threads": with_copier(n) for n in [1] + threads})
    results = {w: {"wall_s": [], "gpu_dispatch_ms": [], "gpu_span_ms": [], "ring": [], "copied": []} for w in ways}
    from progressive.passes.distribute import StagingRing
    four = d.ring
    eight = StagingRing(glc, glc.gl.storage, four.slot_bytes, 8)
    ways.update({f"{name}, 8 slots": way for name, way in list(ways.items())})
    results = {w: {"wall_s": [], "gpu_dispatch_ms": [], "gpu_span_ms": [], "ring": [], "copied": []} for w in ways}
    clock.on()
    for k in range(rounds + 1):
        for name, way in ways.items():
            d.ring = eight if name.endswith("8 slots") else four
            dm._copy = way
            clock.reset()
            r0, c0 = d.stats.ring, d.stats.copied
            wall = distribute_seconds(scene, pieces)
            inside, span = clock.ms()
            if k:
                row = results[name]
                row["wall_s"].append(wall)
                row["gpu_dispatch_ms"].append(inside)
                row["gpu_span_ms"].append(span)
                row["ring"].append(d.stats.ring - r0)
                row["copied"].append(d.stats.copied - c0)
    dm._copy = copy_rows
    d.ring = four
    # every record in one device buffer, the scatter reading it piece by piece
    allrec = np.concatenate([rec for _, rec in pieces]).astype(np.uint32, copy=False)
    device = glc.ctx.buffer(allrec.tobytes())
    del allrec
    perm = d.store.permutation
    for name, value in (("u_prime", perm.prime), ("u_rotation", perm.offset), ("u_batches", perm.batches),
                        ("u_capacity", d.store.capacity)):
        if name in program:
            program[name] = value
    dev = {"wall_s": [], "gpu_dispatch_ms": [], "gpu_span_ms": []}
    for k in range(rounds + 1):
        clock.reset()
        glc.ctx.finish()
        t0 = time.perf_counter()
        d.store.bind()
        offset = 0
        for start, rec in pieces:
            n = rec.shape[0]
            device.bind_to_storage_buffer(Binding.DISTRIBUTE, offset=offset, size=n * 16)
            program["u_start"] = start
            program["u_count"] = n
            program.run(*grid(n))
            glc.ctx.memory_barrier()
            offset += n * 16
        glc.ctx.finish()
        wall = time.perf_counter() - t0
        inside, span = clock.ms()
        if k:
            dev["wall_s"].append(wall)
            dev["gpu_dispatch_ms"].append(inside)
            dev["gpu_span_ms"].append(span)
    results["device buffer, no staging"] = dev
    clock.off()
    out = {}
    for name, row in results.items():
        out[name] = dict(summary(points, row), gpu_span_ms=statistics.median(row["gpu_span_ms"]))
    out.update(points=points, pieces=len(pieces), piece_points=statistics.median(r.shape[0] for _, r in pieces),
               load_s=load_s, slot_bytes=d.ring.slot_bytes if d.ring else None,
               gl_renderer=glc.ctx.info["GL_RENDERER"], store=type(d.store).__name__)
    with open(out_path, "w") as f:
        json.dump(out, f, indent=1)
    for name in results:
        o = out[name]
        print(f"{name:36s} wall {o['wall_ms']:8.1f} ms {o['wall_Mpoints_s']:7.0f} M/s   "
              f"GPU dispatches {o['gpu_dispatch_ms']:7.1f} ms {o['gpu_dispatch_Mpoints_s']:7.0f} M/s   "
              f"span {o['gpu_span_ms']:7.1f} ms  ring/copied {o['runs'].get('ring', ['-'])[-1]}/"
              f"{o['runs'].get('copied', ['-'])[-1]}")


if __name__ == "__main__":
    main()
