"""Packing attribute words on the CPU (the host side of an attribute switch,
progressive/wordpack.py) at 1, 2, 4, ... threads, without a GPU: where the switch's
CPU time goes and whether more threads help. Unlike bench/attributes.py, whose cloud
repeats the sample's arrays (read from the CPU's cache), every point here has memory
of its own: the sample's attributes tiled to N points, as a loaded cloud holds them."""

from __future__ import annotations

import argparse
import dataclasses
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from bench.attributes import CASES
from bench.report import RunInfo, Table
from bench.synthetic import SAMPLE
from progressive.loaders import CloudLoader
from progressive.loaders.records import attribute_word
from progressive.loaders.types import BATCH_POINTS, available_cores
from progressive.passes.distribute import RECORD_WORDS
from progressive.wordpack import WordPacker, WordRun, threaded

PIECE_WORDS = (BATCH_POINTS * RECORD_WORDS, 1 << 24)
"""Words packed a call: a staging slot's worth, as a switch packs one piece at a time
(passes/distribute.py piece_items), and a larger piece."""


def tiled_batches(points: int):
    """The sample's batches tiled to `points`, each array a copy of its own."""
    with CloudLoader([SAMPLE]) as loader:
        info = loader.info
        loader.start()
        sample = sorted(loader, key=lambda b: b.start)
    whole = sample[0]
    for b in sample[1:]:
        whole = dataclasses.replace(whole, xyz=np.concatenate([whole.positions, b.positions]),
                                    attributes={k: np.concatenate([v, b.attributes[k]]) for k, v in whole.attributes.items()},
                                    records=None, bounds=None, grid=None)
    reps = -(-points // whole.count)
    positions = np.tile(whole.positions, (reps, 1))[:points]
    attributes = {k: np.tile(v, (reps,) + (1,) * (v.ndim - 1))[:points] for k, v in whole.attributes.items()}
    batches = [whole.with_positions(positions[lo:lo + BATCH_POINTS], start=lo, bounds=None,
                                    attributes={k: v[lo:lo + BATCH_POINTS] for k, v in attributes.items()})
               for lo in range(0, points, BATCH_POINTS)]
    return dataclasses.replace(info, points=points), batches


def seconds(fill, words: np.ndarray, piece: int, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for lo in range(0, words.size, piece):
            fill(words[lo: lo + piece], lo, min(words.size, lo + piece))
        best = min(best, time.perf_counter() - t0)
    return best


def check(words: np.ndarray, batches, attribute, origin_z: float) -> None:
    """The words packed last equal the reference's (loaders/records.py attribute_word)."""
    for b in batches:
        if not np.array_equal(words[b.start: b.start + b.count], attribute_word(b, attribute, origin_z)):
            raise AssertionError(f"{attribute.name}: packed words differ from attribute_word at batch {b.start}")


def run(points: int, threads: list[int], pieces: tuple[int, ...], repeats: int) -> Table:
    info, batches = tiled_batches(points)
    words = np.ones(points, dtype=np.uint32)     # written once: no page faults in the timings
    table = Table("packing", "Attribute words packed on the CPU, by threads", f"{SAMPLE.name} tiled, own memory",
                  f"{points:,}", ("attribute", "source components", "words a call", "threads", "best s",
                                  "M points/s", "GB/s of words", "× 1 thread"))
    raw = []
    for name, components in CASES:
        run_ = WordRun(WordPacker(info.attribute(name), float(info.origin[2])), [(b, 0, b.count) for b in batches])
        for piece in pieces:
            one = None
            for k in threads:
                with ThreadPoolExecutor(k) as pool:
                    s = seconds(threaded(run_.fill, pool if k > 1 else None, k), words, piece, repeats)
                one = one or s
                table.rows.append((name, components, piece, k, round(s, 4), round(points / s / 1e6, 1),
                                   round(points * 4 / s / 1e9, 2), round(one / s, 2)))
                raw.append({"attribute": name, "piece_words": piece, "threads": k, "seconds": s,
                            "points_per_s": points / s})
        check(words, batches, info.attribute(name), float(info.origin[2]))
    table.notes = [f"Each attribute's words of every point packed into one host array, a call at a time of the "
                   f"words it names (a switch's staging piece is {PIECE_WORDS[0]:,}), split over the threads "
                   f"(progressive/wordpack.py threaded), best of {repeats}; the words "
                   f"checked against loaders/records.py attribute_word. "
                   f"Cores available to the process: {available_cores()}."]
    table.raw = {"rows": raw, "cores": available_cores()}
    return table


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=20_000_000)
    ap.add_argument("--threads", type=int, nargs="+")
    ap.add_argument("--piece-words", type=int, nargs="+", default=list(PIECE_WORDS))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--machine", default="local", help="the results folder's name (no GPU is asked)")
    ap.add_argument("--out", default="bench/results")
    args = ap.parse_args(argv)
    cores = available_cores()
    threads = args.threads or sorted({1, 2, 4, 8, cores} & set(range(1, cores + 1)))
    table = run(args.points, threads, tuple(args.piece_words), args.repeats)
    table.publish(RunInfo.cpu_only("packing only", args.machine), None, Path(args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
