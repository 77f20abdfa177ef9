"""The GPU side of loading (bench.upload's distribute_seconds), four ways in turn:
one memory barrier a piece (the renderer's), two, each staging-ring slot copied into a
device buffer (glCopyBufferSubData) before the scatter reads it instead of reading the
mapped slot in host memory, and the pieces not copied into the ring by the CPU at all
(the scatter reads what the slot held: the GPU's share alone). Prints medians as JSON.

    PYTHONPATH=. python bench/results/nvidia-h100/distribute_copy/dist_ab.py POINTS ROUNDS
"""
import json
import statistics
import sys

from bench.synthetic import SAMPLE, load, tiled
from bench.upload import distribute_seconds, loader_pieces
from progressive.bindings import Binding
from progressive.context import create_context
from progressive.frame_loop import ProgressiveOptions
from progressive.passes import distribute as distribute_module
from progressive.passes.distribute import StagingRing

MODES = ("one barrier", "a barrier a piece", "ring copied to the GPU first", "no CPU copy into the ring")


def main() -> None:
    points, rounds = int(sys.argv[1]), int(sys.argv[2])
    glc = create_context()
    cloud = tiled(str(SAMPLE), points)
    records = loader_pieces(list(cloud.batches()))
    scene, _ = load(glc, cloud, records=ProgressiveOptions().records)
    program = scene.distribute._program(False)
    run, bind = type(program).run, StagingRing.bind
    ring = scene.distribute.ring
    devices = [glc.ctx.buffer(reserve=ring.slot_bytes) for _ in range(2)] if ring is not None else []
    turn = [0]

    def copied_bind(self, slot, size):
        device = devices[turn[0] % 2]
        turn[0] += 1
        glc.ctx.copy_buffer(device, self.buffer, size=size, read_offset=slot * self.slot_bytes, write_offset=0)
        device.bind_to_storage_buffer(Binding.DISTRIBUTE, offset=0, size=size)

    def run_with_barrier(self, *args, **kwargs):
        run(self, *args, **kwargs)
        glc.ctx.memory_barrier()

    copy_rows = distribute_module._copy

    def no_copy(data, width):
        return lambda out, lo, hi: 0

    times = {mode: [] for mode in MODES}
    for k in range(rounds + 1):
        for mode in MODES:
            StagingRing.bind = copied_bind if mode == MODES[2] else bind
            type(program).run = run_with_barrier if mode == MODES[1] else run
            distribute_module._copy = no_copy if mode == MODES[3] else copy_rows
            seconds = distribute_seconds(scene, records)
            if k:
                times[mode].append(seconds)
    type(program).run, StagingRing.bind, distribute_module._copy = run, bind, copy_rows
    out = {m: {"median_s": statistics.median(v), "runs": v, "Mpoints_s": points / statistics.median(v) / 1e6}
           for m, v in times.items()}
    out.update(pieces=len(records), points=points, renderer=glc.ctx.info["GL_RENDERER"])
    print(json.dumps(out, indent=1))


main()
