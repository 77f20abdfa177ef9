"""Progressive frames on a large cloud: frame time against the target with the
adaptive budget (and fixed budgets), per-pass GPU times, the share of the frame
spent filling, and frames and milliseconds to exact convergence, for a still camera
and an orbit. Accuracy is the GPU-counted share of pixels equal to brute force."""

from __future__ import annotations

import argparse
import datetime
import json
import math
import time
from pathlib import Path

import numpy as np

from bench.synthetic import SAMPLE, add_cloud_args, setup
from progressive.budget import BudgetParams
from progressive.camera import Camera, auto_camera
from progressive.frame_loop import ProgressiveOptions, ProgressiveRenderer
from progressive.renderer import Renderer



def orbit(cam: Camera, degrees: float) -> Camera:
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    rel = np.subtract(cam.position, cam.target)
    pos = np.array([c * rel[0] - s * rel[1], s * rel[0] + c * rel[1], rel[2]]) + cam.target
    return Camera(tuple(pos.tolist()), cam.target, cam.up, cam.fov_y_deg, cam.near, cam.far)


def summarize(stats, label, target_ms, points, converge_after=0):
    """Times from a run without a reference render; convergence is the first frame
    after the motion by which every point was filled since the last change (the GPU's
    count; exact by construction and by tests/test_progressive.py)."""
    timed = [s for s in stats if s.gpu_ms]
    frame = np.array([s.gpu_ms["frame"] for s in timed])
    converged = next((s.frame for s in timed if s.frame >= converge_after and s.filled_since_change >= points), None)
    until = [s for s in timed if converged is None or s.frame <= converged]
    return {
        "run": label, "target_ms": target_ms, "frames": len(timed),
        "frame_ms_median": float(np.median(frame)), "frame_ms_p95": float(np.percentile(frame, 95)),
        "frame_ms_max": float(frame.max()),
        "pass_ms_median": {k: float(np.median([s.gpu_ms[k] for s in timed])) for k in ("reproject", "fill", "prepare", "resolve")},
        "fill_fraction_median": float(np.median([s.gpu_ms["fill"] / s.gpu_ms["frame"] for s in timed])),
        "budget_median": float(np.median([s.first_fill + s.budget for s in timed])),
        "gathered_median": float(np.median([s.gathered for s in timed])),
        "covered_median": float(np.median([s.covered_pixels for s in timed])),
        "converged_frame": converged,
        "ms_to_converge": float(sum(s.gpu_ms["frame"] for s in until)) if converged is not None else None,
    }


def run_frames(glc, scene, cloud, width, height, budget, max_frames, orbit_frames, reference):
    r = ProgressiveRenderer(glc, cloud.info, cloud.attribute,
                            ProgressiveOptions(width, height, budget=budget, reference=reference, frames_in_flight=2),
                            scene=scene)
    cam = auto_camera(cloud.info.bounds_min, cloud.info.bounds_max, width / height)
    style = r.scene.style()
    cpu_ms = []
    for k in range(max_frames):
        t0 = time.perf_counter()
        r.frame(orbit(cam, min(k, orbit_frames)), style)
        cpu_ms.append((time.perf_counter() - t0) * 1e3)
        if k > orbit_frames and r.converged:
            break
    stats = r.flush()
    extra = {"cpu_frame_ms_median": float(np.median(cpu_ms)), "stats_dropped": r.stats_ring.dropped,
             "pacing_waits": r.pacing_waits}
    r.release()
    return stats, extra


def run_case(glc, scene, cloud, width, height, budget: BudgetParams, label, max_frames, orbit_frames=0):
    """A timing run, then the same frames with the reference for accuracy."""
    stats, extra = run_frames(glc, scene, cloud, width, height, budget, max_frames, orbit_frames, reference=False)
    target = budget.target_ns / 1e6 if budget.fixed is None else None
    summary = summarize(stats, label, target, cloud.points, orbit_frames)
    summary.update(extra)
    accuracy, _ = run_frames(glc, scene, cloud, width, height, budget, max_frames, orbit_frames, reference=True)
    motion = [s.equal_fraction for s in accuracy if s.frame < orbit_frames and s.equal_fraction is not None]
    summary["equal_during_motion_median"] = float(np.median(motion)) if motion else None
    summary["equal_frame"] = next((s.frame for s in accuracy if s.frame >= orbit_frames and s.equal_fraction == 1.0), None)
    return summary, {"timing": [s.as_dict() for s in stats], "accuracy": [s.as_dict() for s in accuracy]}


def brute_ms(glc, scene, cloud, width, height) -> float:
    r = Renderer(glc, cloud.info, cloud.attribute, width=width, height=height, scene=scene)
    cam = auto_camera(cloud.info.bounds_min, cloud.info.bounds_max, width / height)
    times = [r.render(cam, width, height, r.style()).gpu_ms["raster"] for _ in range(4)]
    r.release()
    return float(np.median(times[1:]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    add_cloud_args(ap)
    ap.add_argument("--targets-ms", type=float, nargs="+", default=[16.6, 11.1])
    ap.add_argument("--fixed", type=int, nargs="*", default=[])
    ap.add_argument("--max-frames", type=int, default=400)
    ap.add_argument("--orbit-frames", type=int, default=60)
    args = ap.parse_args(argv)
    s = setup(args)
    glc, cloud, scene, load_s, width, height = s.glc, s.cloud, s.scene, s.upload_seconds, s.width, s.height
    print(json.dumps({"points": args.points, "upload_s": load_s}), flush=True)
    rows, raw = [], {}
    rows.append({"run": "brute force (compute)", "frame_ms_median": brute_ms(glc, scene, cloud, width, height)})
    print(json.dumps(rows[-1]), flush=True)
    run_case(glc, scene, cloud, width, height, BudgetParams(fixed=1_000_000), "warm-up", 8)
    cases = [(BudgetParams(target_ns=int(t * 1e6)), f"adaptive {t} ms") for t in args.targets_ms]
    cases += [(BudgetParams(fixed=f), f"fixed {f:,}") for f in args.fixed]
    for budget, label in cases:
        for motion in (0, args.orbit_frames):
            name = f"{label}, {'orbit then still' if motion else 'still'}"
            summary, frames = run_case(glc, scene, cloud, width, height, budget, name, args.max_frames, motion)
            rows.append(summary)
            raw[name] = frames
            print(json.dumps(summary), flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"device": glc.caps.description, "date": datetime.date.today().isoformat(), "points": args.points,
            "upload_seconds": load_s,
            "size": args.size, "data": f"{SAMPLE.name} tiled on a grid", "rows": rows}
    (out / "progressive.json").write_text(json.dumps(meta, indent=2))
    (out / "progressive_frames.json").write_text(json.dumps(raw))
    lines = [f"# Progressive frames, {args.points:,} points, {args.size}", "",
             f"Device: {meta['device']}  ", f"Date: {meta['date']}  ", f"Data: {meta['data']}", "",
             "GPU times from timestamps, in runs without a reference render. Converged = the first frame after the "
             "motion by which every point was filled since the camera last moved (counted on the GPU); ms to converge "
             "= GPU frame time summed up to it. A second run with a per-frame brute-force reference gives the share "
             "of pixels equal to brute force during the orbit and the first frame equal to it (exact).", "",
             "| run | frame ms median | p95 | max | reproject | fill | prepare | resolve | fill share | points/frame | converged at frame | ms to converge | equal pixels during orbit | equal at frame | CPU ms/frame |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        if "pass_ms_median" not in r:
            lines.append(f"| {r['run']} | {r['frame_ms_median']:.2f} | | | | | | | | {args.points:,} | 0 | {r['frame_ms_median']:.2f} | | 0 | |")
            continue
        p = r["pass_ms_median"]
        conv = r["converged_frame"]
        converged = f"{conv} | {r['ms_to_converge']:.1f}" if conv is not None else "no | "
        motion = f"{r['equal_during_motion_median']:.1%}" if r["equal_during_motion_median"] is not None else ""
        lines.append(
            f"| {r['run']} | {r['frame_ms_median']:.2f} | {r['frame_ms_p95']:.2f} | {r['frame_ms_max']:.2f} | "
            f"{p['reproject']:.2f} | {p['fill']:.2f} | {p['prepare']:.2f} | {p['resolve']:.2f} | "
            f"{r['fill_fraction_median']:.0%} | {r['budget_median']:,.0f} | {converged} | {motion} | {r['equal_frame']} | {r['cpu_frame_ms_median']:.2f} |")
    (out / "progressive.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
