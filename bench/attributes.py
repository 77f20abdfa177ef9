"""Attribute switch (paper 3.5): points per second when the shown attribute changes.
The scene keeps the loaded struct-of-arrays; a switch packs one 4-byte word a point
from the attribute's own array (1, 3 or more source components) and the distribute
words program scatters it to the permuted slots. Clouds are the bundled sample
repeated to N points (the arrays are shared, so host memory stays small)."""

from __future__ import annotations

import dataclasses
import time

from bench.report import Table
from bench.synthetic import SAMPLE
from progressive.context import GLContext
from progressive.loaders import CloudLoader
from progressive.loaders.records import attribute_word
from progressive.scene import Scene

CASES = (("intensity", "1 (uint16)"), ("gps_time", "1 (float64)"), ("rgb", "3 (uint16 each, packed to RGBA8)"),
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
    scene = Scene(glc, info, info.attribute("elevation"), keep_batches=True)
    for b in batches:
        scene.add_batch(b)
    glc.ctx.finish()
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
        t0 = time.perf_counter()
        for b in batches:
            attribute_word(b, info.attribute(name), float(info.origin[2]))
        packing = time.perf_counter() - t0
        rate = points / best
        table.rows.append((name, components, points, round(best, 4), round(rate / 1e6, 1), round(rate * 4 / 1e9, 2),
                           round(packing, 4)))
        raw.append({"attribute": name, "components": components, "points": points, "seconds": best,
                    "points_per_s": rate, "packing_seconds": packing})
    scene.release()
    table.notes = ["Each switch: pack the word of every point on the CPU (numpy), upload it, scatter it with the "
                   "permutation on the GPU; timed from the switch to glFinish, best of "
                   f"{repeats}. Words of the previous attribute are overwritten in place; no reload."]
    table.raw = {"rows": raw}
    return table
