"""The GPU side of loading, more ways: the ring with the copy on 2..8 threads; the
driver's own copy (glBufferSubData of each piece from the records array, into an
orphaned buffer, or into K device buffers in turn); the ring's slot copied to a device
buffer before the scatter. Wall clock and the GPU's time in the scatter dispatches.

    PYTHONPATH=. python dist_ways.py POINTS ROUNDS OUT.json
"""
import json
import sys
import time

from dist_gpu import loaded, summary

from bench.upload import distribute_seconds
from progressive.bindings import Binding
from progressive.gpu import grid
from progressive.passes import distribute as dm
from progressive.passes.distribute import StagingRing
from progressive.stagecopy import StageCopier


def main() -> None:
    points, rounds, out_path = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
    glc, pieces, scene, _, program, clock = loaded(points)
    d = scene.distribute

    copy_rows = dm._copy
    step = d.piece_items(4)

    def set_uniforms():
        perm = d.store.permutation
        for name, value in (("u_prime", perm.prime), ("u_rotation", perm.offset), ("u_batches", perm.batches),
                            ("u_capacity", d.store.capacity)):
            if name in program:
                program[name] = value
        d.store.bind()

    def own_loop(stage_piece):
        def go():
            glc.ctx.finish()
            t0 = time.perf_counter()
            set_uniforms()
            for start, rec in pieces:
                n = rec.shape[0]
                for lo in range(0, n, step):
                    hi = min(n, lo + step)
                    stage_piece(rec[lo:hi])
                    program["u_start"] = start + lo
                    program["u_count"] = hi - lo
                    program.run(*grid(hi - lo))
                    glc.ctx.memory_barrier()
            glc.ctx.finish()
            return time.perf_counter() - t0
        return go

    orphaned = glc.ctx.buffer(reserve=step * 16)

    def orphan_write(rows):
        orphaned.orphan()
        orphaned.write(rows)
        orphaned.bind_to_storage_buffer(Binding.DISTRIBUTE)

    devices = [glc.ctx.buffer(reserve=step * 16) for _ in range(4)]
    turn = [0]

    def device_write(rows):
        b = devices[turn[0] % 4]
        turn[0] += 1
        b.write(rows)
        b.bind_to_storage_buffer(Binding.DISTRIBUTE)

    def ring_way(n, device_first=False):
        copier = StageCopier(n, parts=n)
        bind = StagingRing.bind
        dev = [glc.ctx.buffer(reserve=d.ring.slot_bytes) for _ in range(2)]

        def copied_bind(self, slot, size):
            b = dev[turn[0] % 2]
            turn[0] += 1
            glc.ctx.copy_buffer(b, self.buffer, size=size, read_offset=slot * self.slot_bytes, write_offset=0)
            b.bind_to_storage_buffer(Binding.DISTRIBUTE, offset=0, size=size)

        def go():
            dm._copy = lambda data, width, copy: copy_rows(data, width, copier)
            if device_first:
                StagingRing.bind = copied_bind
            try:
                return distribute_seconds(scene, pieces)
            finally:
                dm._copy = copy_rows
                StagingRing.bind = bind
        return go

    ways = {f"ring, copy on {n} threads": ring_way(n) for n in (1, 2, 4, 6, 8)}
    ways["ring, copy on 4 threads, slot copied to the GPU first"] = ring_way(4, True)
    ways["driver copy: orphaned buffer, glBufferSubData"] = own_loop(orphan_write)
    ways["driver copy: 4 device buffers in turn, glBufferSubData"] = own_loop(device_write)
    results = {w: {"wall_s": [], "gpu_dispatch_ms": [], "ring": [], "copied": []} for w in ways}
    clock.on()
    for k in range(rounds + 1):
        for name, way in ways.items():
            clock.reset()
            r0, c0 = d.stats.ring, d.stats.copied
            wall = way()
            inside = clock.ms()[0]
            if k:
                row = results[name]
                row["wall_s"].append(wall)
                row["gpu_dispatch_ms"].append(inside)
                row["ring"].append(d.stats.ring - r0)
                row["copied"].append(d.stats.copied - c0)
    clock.off()
    out = {}
    for name, row in results.items():
        o = out[name] = summary(points, row)
        print(f"{name:56s} wall {o['wall_ms']:7.1f} ms {o['wall_Mpoints_s']:6.0f} M/s  GPU {o['gpu_dispatch_ms']:6.1f} ms "
              f"{o['gpu_dispatch_Mpoints_s']:6.0f} M/s  ring/copied {row['ring'][-1]}/{row['copied'][-1]}")
    out.update(points=points, pieces=len(pieces), step=step, gl_renderer=glc.ctx.info["GL_RENDERER"])
    with open(out_path, "w") as f:
        json.dump(out, f, indent=1)


main()
