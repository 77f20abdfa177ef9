"""Planning a streamed COPC cloud's residency (loaders/copc_residency.py plan): the
milliseconds one plan takes on the frame thread, by hierarchy size, GPU-free. The
hierarchies are synthetic terrains: every node of a quadtree of `levels` levels (one
z cell), 40,000 points a node; the camera looks down at 30° from inside the box; the
plan runs once the state holds the nodes of earlier plans, made anew and, as after an
arrival, with the view's part of the plan kept (copc_residency.ViewPart)."""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from bench.report import RunInfo, Table
from progressive.loaders.copc_choice import Nodes, View
from progressive.loaders.copc_residency import PlanOptions, Residency, ViewPart, plan

SIDE = 1000.0
NODE_POINTS = 40_000
STORE_BATCH_POINTS = 10_223


def terrain(levels: int) -> Nodes:
    """Every node of a quadtree of `levels` levels over a SIDE-wide square."""
    rows = [(d, x, y) for d in range(levels) for x in range(1 << d) for y in range(1 << d)]
    level, x, y = (np.array(c, np.int64) for c in zip(*rows))
    key = np.stack([x, y, np.zeros_like(x)], axis=1)
    side = SIDE / np.exp2(level)
    return Nodes(np.zeros(level.size, np.int64), level, key, np.full(level.size, NODE_POINTS, np.int64),
                 key * side[:, None], side, 10.0 / np.exp2(level))


def run(levels: list[int], budget_points: int, rounds: int, repeats: int) -> Table:
    view = View((SIDE / 2, SIDE / 2, SIDE / 4), (0.0, 0.5, -0.87), 1080, 60.0, up=(0.0, 1.0, 0.0), aspect=16 / 9)
    options = PlanOptions(max_in_flight=64)
    table = Table("plan", "Residency plans of a streamed COPC cloud", "synthetic quadtree terrains",
                  ", ".join(f"{terrain(d).level.size:,} nodes" for d in levels),
                  ("nodes", "resident", "plan ms (median)", "max", "view part kept: ms (median)", "max",
                   "requests"))
    raw = []
    for d in levels:
        state = Residency(terrain(d), budget_points, STORE_BATCH_POINTS)
        for _ in range(rounds):          # resident nodes from earlier plans, as after a while of viewing
            p = plan(state, view, options)
            state.begin(p)
            for r in p.request:
                state.arrived(r.row)
        times, kept = [], []
        part = ViewPart.of(state, view)
        for _ in range(repeats):
            t0 = time.perf_counter()
            p = plan(state, view, options)
            times.append((time.perf_counter() - t0) * 1e3)
            t0 = time.perf_counter()
            again = plan(state, view, options, part)
            kept.append((time.perf_counter() - t0) * 1e3)
            if again.request != p.request or again.evict != p.evict:
                raise AssertionError("a plan with the view part kept differs from the plan made anew")
        resident = int(np.count_nonzero(state.status != 0))
        table.rows.append((state.status.size, resident, statistics.median(times), max(times),
                           statistics.median(kept), max(kept), len(p.request)))
        raw.append({"nodes": int(state.status.size), "resident": resident, "ms": times, "kept_ms": kept})
    table.notes = [f"Budget {budget_points:,} points; {rounds} plans booked and their nodes arrived first; then "
                   f"{repeats} plans of the same view timed (the frame thread runs one at most every "
                   "progressive/streaming.py PLAN_SECONDS while the camera moves, and one after each frame's "
                   "arrivals): made anew, and with the view's part (errors, their order, the target) kept from "
                   "an earlier plan of the view, as the streamer plans after arrivals; both plans checked equal."]
    table.raw = {"rows": raw}
    return table


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", type=int, nargs="+", default=[6, 7, 8, 9])
    ap.add_argument("--budget-points", type=int, default=400_000_000)
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--machine", default="local", help="the results folder's name (no GPU is asked)")
    ap.add_argument("--out", default="bench/results")
    args = ap.parse_args(argv)
    table = run(args.levels, args.budget_points, args.rounds, args.repeats)
    table.publish(RunInfo.cpu_only("plan only", args.machine), None, Path(args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
