"""Upload: the ring of persistently mapped staging slots beside the copy fallback (the
same context as a driver without GL_ARB_buffer_storage offers it), in one run. For the
bundled sample tiled to each size: seconds and points/s of bench.synthetic.load (tiles
made, packed, distributed, glFinish), of Scene.add_batch alone and of the GPU side
alone (packed records staged and distributed again), and the pieces that went
through the ring or were copied; then the time to the first image of `progressive
view` (headless) with each, fresh processes with warm caches (as bench/startup.py's
"Mesa + program cache").

    python -m bench.upload [--points 2000000,10000000] [--repeats 3] [--startup-repeats 5]

writes bench/results/<machine>/upload.{md,json}."""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
WARM = "Mesa + program cache"


def staged(glc, staging: str):
    from progressive.passes.distribute import Staging, without_buffer_storage

    return glc if Staging(staging) is Staging.RING else without_buffer_storage(glc)


def child(staging: str, path: str, width: int, height: int) -> dict:
    """One `progressive view` start (headless) with the given staging, to glFinish after
    the first image; the context is made here (the session is handed it)."""
    from bench.startup import frame_until_first_image  # imports no progressive module: not timed below

    t0 = time.perf_counter()
    from progressive.context import create_context
    from progressive.session import Session, SessionOptions

    imported = time.perf_counter()
    glc = create_context()
    context = time.perf_counter()
    with Session([path], SessionOptions(width=width, height=height), glc=staged(glc, staging)) as s:
        frame_until_first_image(s, s.auto_camera(), path)
        s.glc.ctx.finish()
        done = time.perf_counter()
        used = s.status().staging.value
        out = {"import": imported - t0, **s.startup, "context": context - imported, "in_process": done - t0,
               "staging": used, "epoch_done": time.time(), "device": s.glc.caps.as_dict()}
    glc.release()
    return out


def start(staging: str, path: Path, size: tuple[int, int], env: dict[str, str]) -> dict:
    from bench.startup import spawn

    return spawn("bench.upload", staging, path, size, env)


def uploads(sizes: list[int], repeats: int) -> tuple[list[dict], object]:
    """Each size, ring and copy alternating `repeats` times (so drift hits both alike)."""
    from bench.synthetic import SAMPLE, load, tiled
    from progressive.context import create_context
    from progressive.frame_loop import ProgressiveOptions
    from progressive.passes.distribute import Staging

    glc = create_context()
    rows = []
    for points in sizes:
        cloud = tiled(str(SAMPLE), points)
        records = loader_pieces(list(cloud.batches()))
        runs = {s: [] for s in Staging}
        for _ in range(repeats):
            for s in Staging:
                scene, seconds = load(staged(glc, s.value), cloud, records=ProgressiveOptions().records)
                d = scene.distribute
                assert d.staging is s
                runs[s].append({"seconds": seconds, "add_batch": scene.upload_seconds,
                                "ring": d.stats.ring, "copied": d.stats.copied,
                                "distribute": distribute_seconds(scene, records),
                                "scatter": distribute_seconds(scene, records, stage=False)})
                scene.release()
        ratio = statistics.median(r["add_batch"] / c["add_batch"] for r, c in zip(runs[Staging.RING], runs[Staging.COPY]))
        for s in Staging:
            med = {k: statistics.median(r[k] for r in runs[s]) for k in ("seconds", "add_batch", "distribute", "scatter")}
            best = {k: min(r[k] for r in runs[s]) for k in ("seconds", "add_batch", "distribute", "scatter")}
            rows.append({"points": points, "staging": s.value, "runs": runs[s], "median": med, "best": best,
                         "ring_over_copy": ratio, "ring": runs[s][-1]["ring"], "copied": runs[s][-1]["copied"]})
    caps = glc.caps
    glc.release()
    return rows, caps


def loader_pieces(tiles: list[tuple[int, object]]) -> list[tuple[int, object]]:
    """Consecutive tiles' records joined into pieces of about a loader batch
    (loaders.types.BATCH_POINTS), as the loader hands its batches to the GPU, so that the
    GPU side is timed with the loader's dispatches, not one a tile."""
    import numpy as np

    from progressive.loaders.types import BATCH_POINTS

    pieces, run, held = [], [], 0
    for start, rec in tiles:
        if run and (held >= BATCH_POINTS or run[0][0] + held != start):
            pieces.append((run[0][0], np.concatenate([r for _, r in run])))
            run, held = [], 0
        run.append((start, rec))
        held += rec.shape[0]
    if run:
        pieces.append((run[0][0], np.concatenate([r for _, r in run])))
    return pieces


def distribute_seconds(scene, records, stage: bool = True) -> float:
    """The GPU side of loading alone: every batch's records, packed already, staged and
    distributed again (its frames are set: the same words), to glFinish. Without
    `stage` nothing is copied into the staging memory (the scatter reads whatever it
    held, and the store gets that: time it last), so the scatter's share alone."""
    scene.glc.ctx.finish()
    t0 = time.perf_counter()
    for start, rec in records:
        if stage:
            scene.distribute.upload(rec, start)
        else:
            scene.distribute.upload_packed(_unstaged, rec.shape[0], start)
    scene.glc.ctx.finish()
    return time.perf_counter() - t0


def _unstaged(out, lo: int, hi: int) -> int:
    """A fill that writes nothing (distribute_seconds without staging)."""
    return 0


def run(sizes: list[int], repeats: int, startup_repeats: int, size: tuple[int, int]):
    from bench.report import Table, cell
    from bench.startup import SAMPLE, environment
    from progressive.frame_loop import ProgressiveOptions
    from progressive.loaders.types import BATCH_POINTS
    from progressive.passes.distribute import RING_SLOTS, Staging

    rows, caps = uploads(sizes, repeats)
    table = Table("upload", "Uploads: a ring of persistently mapped staging slots beside the copy fallback",
                  "autzen_trim.las tiled", ", ".join(f"{n:,}" for n in sizes),
                  ("points", "staging", "load s", "M points/s", "add_batch s (best)", "M points/s (add_batch)",
                   "add_batch ring / copy", "pieces ring / copied", "stage + distribute s (best)",
                   "M points/s (stage + distribute)", "M points/s (distribute, nothing staged)", "first image s (best)",
                   "upload s (first image)"))
    load_before = os.getloadavg()[0]
    warm = {"mesa": tempfile.mkdtemp(prefix="mesa-warm-"), "programs": tempfile.mkdtemp(prefix="programs-warm-")}
    env = environment(WARM, warm)
    start(Staging.RING.value, SAMPLE, size, env)        # fills the warm caches
    starts = {s: [] for s in Staging}
    for _ in range(startup_repeats):
        for s in Staging:
            got = start(s.value, SAMPLE, size, env)
            if got["staging"] != s.value:
                raise RuntimeError(f"asked for {s.value} staging, the session used {got['staging']}")
            starts[s].append(got)
    first = {s: {k: statistics.median(r[k] for r in starts[s]) for k in ("process", "upload")} for s in Staging}
    best = {s: min(r["process"] for r in starts[s]) for s in Staging}
    load_after = os.getloadavg()[0]
    for r in rows:
        s = Staging(r["staging"])
        med = r["median"]
        table.rows.append((r["points"], s.value, med["seconds"], r["points"] / med["seconds"] / 1e6,
                           f"{cell(med['add_batch'])} ({cell(r['best']['add_batch'])})",
                           r["points"] / med["add_batch"] / 1e6, r["ring_over_copy"], f"{r['ring']} / {r['copied']}",
                           f"{cell(med['distribute'])} ({cell(r['best']['distribute'])})",
                           r["points"] / med["distribute"] / 1e6, r["points"] / med["scatter"] / 1e6,
                           f"{cell(first[s]['process'])} ({cell(best[s])})", first[s]["upload"]))
    table.notes = [
        (f"One run, ring and copy alternating, median of {repeats} (best in brackets); add_batch ring / copy: the "
         "median of the ratios of each pair of runs. load s: bench.synthetic.load, the sample's "
         "records moved to each tile (the stand-in for reading and decoding), packed, distributed (into a store "
         f"keeping its records in the progressive renderer's order, {ProgressiveOptions().records.value}), then "
         "glFinish; "
         "add_batch s: Scene.add_batch alone (packing, staging, queuing the scatter). Ring: "
         f"{RING_SLOTS} slots of a batch each in one buffer mapped persistent (glBufferStorage, "
         "glMapNamedBufferRange through ctypes); each piece is packed straight into a free slot and flushed "
         "(glFlushMappedNamedBufferRange, then a client-mapped buffer barrier), a fence per slot "
         "(glClientWaitSync, timeout 0) tells when it is free again, a piece finding its slot busy is copied. "
         "Copy: the same context as a driver without buffer storage offers it, each piece packed into host memory "
         "and copied into an orphaned buffer. stage + distribute s: the GPU side of loading alone, after each load: "
         f"the loaded records, packed already, in pieces of about a loader batch ({BATCH_POINTS:,} points, "
         "consecutive tiles joined, as the loader hands its batches over), copied into the staging memory and distributed again (the word "
         "store encodes them in their frames, set by the load), to glFinish; add_batch's batch boxes, frames and "
         "packing are left out. Distribute, nothing staged: the same with nothing copied into the staging memory "
         "(the scatter reads what the ring's slots, or the copy's fresh buffer, held), the GPU's share alone: on "
         "the H100 the CPU's copy into the ring took about half of stage + distribute "
         "(bench/results/nvidia-h100/distribute_copy/)."),
        (f"first image s: `progressive view` headless on the bundled sample at {size[0]}x{size[1]}, a fresh process "
         f"from spawn to glFinish after the first frame with points, median of {startup_repeats}, caches warm "
         "(Mesa's shader cache and the program binary cache, as bench/startup.py's last state); upload s: the "
         "session's upload phase of that start. Both columns are per staging, the same for each size."),
        (f"Load average (1 min) {load_before:.1f} before the runs, {load_after:.1f} after, on {os.cpu_count()} cores: "
         "other work on the machine shows as spread between repeats."),
    ]
    table.raw = {"uploads": rows, "startup": {s.value: starts[s] for s in Staging}, "size": list(size),
                 "repeats": repeats, "startup_repeats": startup_repeats, "ring_slots": RING_SLOTS}
    return table, caps


def main(argv: list[str] | None = None) -> int:
    from bench.startup import answer_child, child_arguments

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    child_arguments(parser, "STAGING")
    parser.add_argument("--points", default="2000000,10000000", help="comma-separated sizes")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--startup-repeats", type=int, default=5)
    args = parser.parse_args(argv)
    if answer_child(args, child):
        return 0
    sizes = [int(v) for v in args.points.split(",")]
    table, caps = run(sizes, args.repeats, args.startup_repeats, (args.width, args.height))
    from bench.report import RunInfo

    table.publish(RunInfo.from_caps(caps, "upload"), args.out, RESULTS)
    return 0


if __name__ == "__main__":
    sys.exit(main())
