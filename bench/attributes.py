"""Attribute switch (paper 3.5): points per second when the shown attribute changes.
The scene keeps the loaded struct-of-arrays; a switch packs one 4-byte word a point
from the attribute's own array (1, 3 or more source components; RGB's 3 bytes are
copied as they are, the GPU makes the words) straight into the upload ring, runs of
consecutive kept batches at a time, and the distribute words program scatters it to
the permuted slots. Clouds are the bundled sample
repeated to N points (the arrays are shared, so host memory stays small)."""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from bench.report import Table
from bench.synthetic import SAMPLE
from progressive.context import GLContext
from progressive.frame_loop import ProgressiveOptions
from progressive.loaders import CloudLoader
from progressive.scene import Scene
from progressive.wordpack import PACK_THREADS, WordPacker, WordRun, threaded

CASES = (("intensity", "1 (uint16)"), ("gps_time", "1 (float64)"),
         ("rgb", "3 (uint8 each, staged as bytes, RGBA8 words made on the GPU)"),
         ("classification", "1 (uint8 code)"))


def cloud(points: int):
    with CloudLoader([SAMPLE]) as loader:
        info = loader.info
        loader.start()
        sample = sorted(loader, key=lambda b: b.start)
    batches, start = [], 0
    while start < points:
        for b in sample:
            if start >= points:
                break
            n = min(b.count, points - start)
            part = b.rows(0, n)
            batches.append(dataclasses.replace(part, start=start))
            start += n
    return dataclasses.replace(info, points=points), batches


def run(glc: GLContext, points: int, repeats: int = 3) -> Table:
    info, batches = cloud(points)
    table = Table("attributes", "Attribute switch: points/s streamed to the shuffled buffer",
                  f"{SAMPLE.name} repeated", f"{points:,}",
                  ("attribute", "source components", "points", "best s (finished on the GPU)", "M points/s",
                   "GB/s of words", "of which packing words on the CPU, s"))
    scene = Scene(glc, info, info.attribute("elevation"), keep_batches=True, records=ProgressiveOptions().records)
    for b in batches:
        scene.add_batch(b)
    glc.ctx.finish()
    words = np.ones(points, dtype=np.uint32)     # written once: the packing timings take no page faults
    raw = []
    for name, components in CASES:
        best = float("inf")
        for _ in range(repeats):
            for attribute in (info.attribute("elevation"), info.attribute(name)):
                t0 = time.perf_counter()
                scene.begin_switch(attribute)
                while not scene.stream(seconds=float("inf")):
                    pass
                glc.ctx.finish()
                seconds = time.perf_counter() - t0
            best = min(best, seconds)
        packing = packing_seconds(scene, info.attribute(name), words, repeats)
        rate = points / best
        table.rows.append((name, components, points, round(best, 4), round(rate / 1e6, 1), round(rate * 4 / 1e9, 2),
                           round(packing, 4)))
        raw.append({"attribute": name, "components": components, "points": points, "seconds": best,
                    "points_per_s": rate, "packing_seconds": packing})
    pieces = scene.distribute.word_piece_items()
    scene.release()
    table.notes = [
        ("Each switch: the kept batches in file order as runs of words, each packed on the CPU (numpy, "
         f"progressive/wordpack.py, {PACK_THREADS} threads) straight into a staging slot of the upload ring "
         f"({pieces:,} words a piece; RGB: its 3 bytes a point copied there, the words made on the GPU), then "
         "scattered by the words program to the batch's records on the GPU "
         f"(the batch's prime shuffle), kept in the progressive renderer's order ({ProgressiveOptions().records.value}); timed from the switch to glFinish, best of {repeats}, each switch from "
         "elevation. Words of the previous attribute are overwritten in place; no reload."),
        ("Packing: the same runs packed by the same threads into host memory (no GPU), best of "
         f"{repeats}. The cloud repeats the sample's arrays, so they are read from the CPU's cache: a real cloud's "
         "packing reads its own memory."),
    ]
    table.raw = {"rows": raw, "piece_words": pieces, "pack_threads": PACK_THREADS}
    return table


def packing_seconds(scene: Scene, attribute, words: np.ndarray, repeats: int) -> float:
    """Seconds to pack the kept batches' words as a switch does, into `words` (RGB: its
    bytes copied into them, 3 a point, as the switch stages them)."""
    packer = WordPacker(attribute, float(scene.info.origin[2]))
    kept = sorted(scene.batches, key=lambda b: b.start)
    run = WordRun(packer, [(b, 0, b.count) for b in kept])
    if run.rgb_bytes:
        fill = threaded(run.fill_rgb, scene.distribute.copy.pool, PACK_THREADS)
        words = words.view(np.uint8)[:3 * run.count].reshape(run.count, 3)
    else:
        fill = threaded(run.fill, scene.distribute.copy.pool, PACK_THREADS)
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        step = scene.distribute.word_piece_items()
        for lo in range(0, run.count, step):
            fill(words[lo: lo + step], lo, min(run.count, lo + step))
        best = min(best, time.perf_counter() - t0)
    return best
