"""Progressive frames on a large cloud: fixed budgets and the adaptive budget at
16.6 and 11.1 ms, for a still camera and three camera paths (orbit, zoom-in,
fly-through) that then stop: per-pass GPU ms, frame time median/p95/max against the
target, the share of the frame spent filling, and frames and GPU ms to exact
convergence once the camera stops. Accuracy lives in bench/accuracy.py."""

from __future__ import annotations

import argparse
import enum
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.report import INDEX_PASS_LABELS, RunInfo, Table, index_pass_label
from bench.synthetic import SAMPLE, TiledCloud, load, tiled
from progressive.budget import BudgetParams
from progressive.camera import Camera, auto_camera
from progressive.context import GLContext, create_context
from progressive.encoding import Encoding
from progressive.frame_loop import COLD_TIMES, FrameStats, ProgressiveOptions, ProgressiveRenderer
from progressive.passes.raster_compute import DEFAULT_TUNING, ComputeTuning
from progressive.pointstore import RecordOrder
from progressive.renderer import Renderer
from progressive.scene import Scene


class CameraPath(enum.Enum):
    """Camera paths: `motion` frames of movement, then the last camera held still."""

    STILL = "still"
    ORBIT = "orbit 60°"
    ZOOM = "zoom-in"
    FLY = "fly-through"


def orbit(cam: Camera, degrees: float) -> Camera:
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    rel = np.subtract(cam.position, cam.target)
    pos = np.array([c * rel[0] - s * rel[1], s * rel[0] + c * rel[1], rel[2]]) + cam.target
    return Camera(tuple(pos.tolist()), cam.target, cam.up, cam.fov_y_deg, cam.near, cam.far)


def camera_at(path: CameraPath, base: Camera, lo: np.ndarray, hi: np.ndarray, frame: int, motion: int) -> Camera:
    """The camera of `frame`: moving for `motion` frames, then still at the end of the path."""
    t = 0.0 if path is CameraPath.STILL or motion == 0 else min(frame, motion) / motion
    if path is CameraPath.ORBIT:
        return orbit(base, 60.0 * t)
    if path is CameraPath.ZOOM:
        rel = np.subtract(base.position, base.target)
        pos = np.asarray(base.target) + rel * (1.0 - 0.8 * t)
        return Camera(tuple(pos.tolist()), base.target, base.up, base.fov_y_deg, base.near, base.far)
    if path is CameraPath.FLY:
        extent = float(np.max(hi - lo))
        mid = (lo + hi) / 2
        pos = np.array([lo[0] + (hi[0] - lo[0]) * (0.05 + 0.5 * t), mid[1], hi[2] + 0.05 * extent])
        target = pos + np.array([0.3 * extent, 0.0, -0.1 * extent])
        return Camera(tuple(pos.tolist()), tuple(target.tolist()), base.up, base.fov_y_deg, base.near, base.far)
    return base


@dataclass(frozen=True)
class Budget:
    label: str
    params: BudgetParams

    @property
    def target_ms(self) -> float | None:
        return None if self.params.fixed is not None else self.params.target_ns / 1e6


def budgets(fixed: list[int], targets_ms: list[float]) -> list[Budget]:
    return ([Budget(f"fixed {f:,}", BudgetParams(fixed=f)) for f in fixed] +
            [Budget(f"adaptive {t} ms", BudgetParams(target_ns=round(t * 1e6))) for t in targets_ms])


def summarize(stats: list[FrameStats], points: int, target_ms: float | None, motion: int) -> dict:
    """From a run without a reference render. Converged = the first frame after the
    motion by which every point was filled since the last change (the GPU's count;
    exact by construction and by tests/test_progressive.py)."""
    timed = [s for s in stats if s.gpu_ms]
    frame = np.array([s.gpu_ms["frame"] for s in timed])
    converged = next((s.frame for s in timed if s.frame >= motion and s.filled_since_change >= points), None)
    after = [s for s in timed if s.frame >= motion and (converged is None or s.frame <= converged)]
    return {
        "frames": len(timed), "frame_ms_median": float(np.median(frame)),
        "frame_ms_p95": float(np.percentile(frame, 95)), "frame_ms_max": float(frame.max()),
        "over_target": float(np.mean(frame > target_ms)) if target_ms else None,
        "pass_ms_median": {k: float(np.median([s.gpu_ms[k] for s in timed]))
                           for k in ("reproject", "fill", "prepare", "resolve")},
        "fill_share_median": float(np.median([s.gpu_ms["fill"] / s.gpu_ms["frame"] for s in timed])),
        "points_per_frame_median": float(np.median([s.first_fill + s.budget for s in timed])),
        "gathered_median": float(np.median([s.gathered for s in timed])),
        "converged_frame": converged,
        "frames_to_converge": converged - motion + 1 if converged is not None else None,
        "ms_to_converge": float(sum(s.gpu_ms["frame"] for s in after)) if converged is not None else None,
        "cold_frame": cold_frame(timed),
    }


COLD_PARTS = (*COLD_TIMES, "fill later passes")


def cold_frame(timed: list[FrameStats]) -> dict | None:
    """The run's first cold frame (no fill rate known: the growth stages ran): its points
    and the GPU milliseconds of each part of its first pass and of its later passes."""
    cold = next((s for s in timed if COLD_TIMES.keys() <= s.gpu_ms.keys()), None)
    if cold is None:
        return None
    return {"points": cold.first_fill + cold.budget, "frame_ms": cold.gpu_ms["frame"],
            "ms": {k: cold.gpu_ms[k] for k in COLD_PARTS}}


def cold_parts(cold: dict | None) -> str | None:
    """'first fill / adaptive / grow 1 / grow 2 + later passes' in ms, for the table."""
    if cold is None:
        return None
    ms = cold["ms"]
    return " / ".join(f"{ms[k]:.2f}" for k in COLD_PARTS[:-1]) + f" + {ms[COLD_PARTS[-1]]:.2f}"


def run_case(glc: GLContext, scene: Scene, cloud: TiledCloud, size: tuple[int, int], budget: Budget,
             path: CameraPath, motion: int, max_frames: int,
             tuning: ComputeTuning = DEFAULT_TUNING, prepare_ballot: bool | None = None) -> tuple[dict, list[dict]]:
    width, height = size
    r = ProgressiveRenderer(glc, cloud.info, cloud.attribute, ProgressiveOptions(
        width, height, budget=budget.params, frames_in_flight=2, tuning=tuning, prepare_ballot=prepare_ballot),
        scene=scene)
    lo, hi = cloud.info.bounds_min, cloud.info.bounds_max
    base = auto_camera(lo, hi, width / height)
    style = scene.style()
    motion = 0 if path is CameraPath.STILL else motion
    cpu_ms = []
    for k in range(max_frames):
        t0 = time.perf_counter()
        r.frame(camera_at(path, base, lo, hi, k, motion), style)
        cpu_ms.append((time.perf_counter() - t0) * 1e3)
        if k >= motion and r.converged:
            break
    stats = r.flush()
    summary = summarize(stats, cloud.points, budget.target_ms, motion)
    summary.update(budget=budget.label, target_ms=budget.target_ms, path=path.value, motion_frames=motion,
                   cpu_frame_ms_median=float(np.median(cpu_ms)), pacing_waits=r.pacing_waits,
                   batch_groups=r.raster.batch_groups if hasattr(r.raster, "batch_groups") else False,
                   winners=r.raster.winners is not None, prepare=PREPARE_LABELS[r.prepare.ballot],
                   index_pass=index_pass_label(r.raster.candidates, r.raster.passes),
                   default_index_pass=tuning.candidates == DEFAULT_TUNING.candidates)
    r.release()
    return summary, [s.as_dict() for s in stats]


def brute_ms(glc: GLContext, scene: Scene, cloud: TiledCloud, size: tuple[int, int], repeats: int = 3) -> float:
    width, height = size
    r = Renderer(glc, cloud.info, cloud.attribute, width=width, height=height, scene=scene)
    cam = auto_camera(cloud.info.bounds_min, cloud.info.bounds_max, width / height)
    times = [r.render(cam, width, height, r.style()).gpu_ms["raster"] for _ in range(repeats + 1)]
    r.release()
    return float(np.median(times[1:]))


WARM_UP_S = 3.0
"""Seconds of frames before the first measured case: a GPU that has just loaded the cloud
runs its first second or two at lower clocks (on the H200 every pass took about twice
as long in the first cases of a run after a four-frame warm-up)."""
CASE_WARM_UP_S = 0.5
"""Seconds of the same frames before each case: a light case (a fixed fill of 1 M points,
frames of 0.7 ms) lets the GPU lower its clocks again, and on the H200 at 1 B points the
fixed 10 M fills after it took 1.54 ms where two runs without such cases before gave 0.47
and 0.48 ms (bench/results/nvidia-h200/record_order/no_case_warm_up/ and README.md)."""


def warm_up(glc: GLContext, scene: Scene, cloud: TiledCloud, size: tuple[int, int], seconds: float = WARM_UP_S) -> None:
    width, height = size
    r = ProgressiveRenderer(glc, cloud.info, cloud.attribute, ProgressiveOptions(
        width, height, budget=BudgetParams(fixed=max(1, cloud.points // 8)), frames_in_flight=2), scene=scene)
    base = auto_camera(cloud.info.bounds_min, cloud.info.bounds_max, width / height)
    style = scene.style()
    end, k = time.perf_counter() + seconds, 0
    while time.perf_counter() < end:
        r.frame(orbit(base, k), style)
        k += 1
    r.flush()
    r.release()


STORE_LABELS = {Encoding.WORDS: "words", Encoding.FLOAT: "float records"}
"""The store column: the renderer's word planes, or float32 records (the baseline)."""
RECORD_ORDER = ProgressiveOptions().records
RECORD_ORDER_LABELS = {RecordOrder.SLOTS: ", records in slot order", RecordOrder.BATCHES: ", each batch's records together"}
"""Appended to the store column where the store keeps its records in another order than
the renderer's (ProgressiveOptions.records)."""
RECORDS_LABELS = {True: "winners pass", False: "gathered"}
"""The records column: where prepare takes new winners' records (ComputeTuning.winners)."""
PREPARE_LABELS = {True: "ballot", False: "barriers"}
"""The prepare column: how its pixels take list entries (ProgressiveOptions.prepare_ballot)."""


def run(glc: GLContext, points: int, size: tuple[int, int], fixed: list[int], targets_ms: list[float],
        paths: list[CameraPath], motion: int, max_frames: int, compare_walk: bool = False,
        encodings: tuple[Encoding, ...] = (Encoding.WORDS,), winners: tuple[bool | None, ...] = (None,),
        record_orders: tuple[RecordOrder, ...] = (RECORD_ORDER,),
        prepare: tuple[bool | None, ...] = (None,), index_pass: tuple[bool | None, ...] = (None,)) -> Table:
    """compare_walk: also run every case with fill pieces walked one invocation a slot
    (ComputeTuning.batch_groups off), side by side with the renderer's batch walk;
    encodings and record_orders: the stores to run every case on, one after the other
    in this run; winners: with and/or without the winners pass, each case side by side
    (None: the renderer's choice for the store); prepare: prepare's list entries by
    ballot and/or after barriers, side by side (None: the renderer's choice); index_pass:
    the 32-bit path's index pass over the depth pass's candidates and/or over every
    point, side by side (ComputeTuning.candidates; None: the renderer's choice)."""
    walks = (True, False) if compare_walk else (True,)
    tunings = [ComputeTuning(batch_groups=g, winners=w, candidates=DEFAULT_TUNING.candidates if c is None else c)
               for g in walks for w in winners for c in index_pass]
    cloud = tiled(str(SAMPLE), points)
    rows, frames, brute = [], {}, {}
    for position_encoding, records in ((e, o) for e in encodings for o in record_orders):
        store = STORE_LABELS[position_encoding] + ("" if records is RECORD_ORDER else RECORD_ORDER_LABELS[records])
        scene, upload_s = load(glc, cloud, records=records, position_encoding=position_encoding)
        warm_up(glc, scene, cloud, size)
        brute[store] = brute_ms(glc, scene, cloud, size)
        for budget in budgets(fixed, targets_ms):
            for path in paths:
                for tuning, ballot in ((t, b) for t in tunings for b in prepare):
                    warm_up(glc, scene, cloud, size, CASE_WARM_UP_S)
                    summary, stats = run_case(glc, scene, cloud, size, budget, path, motion, max_frames, tuning,
                                              ballot)
                    summary.update(store=store, upload_s=upload_s)
                    rows.append(summary)
                    walk = "" if tuning.batch_groups else ", one invocation a slot"
                    entries = "" if prepare == (None,) else f", prepare by {summary['prepare']}"
                    index = "" if index_pass == (None,) else f", index pass over {summary['index_pass']}"
                    frames[f"{store}, {budget.label}, {path.value}{walk}, {RECORDS_LABELS[summary['winners']]}"
                           f"{entries}{index}"] = stats
        scene.release()
    table = Table(f"progressive_{points}", f"Progressive frames, {size[0]}x{size[1]}",
                  f"{SAMPLE.name} tiled on a grid", f"{points:,}", (
                      "store", "budget", "camera", "fill work group", "records", "prepare entries", "index pass", "frame ms median", "p95",
                      "max", "target ms",
                      "frames over target", "reproject", "fill", "prepare", "resolve", "fill share", "points/frame",
                      "gathered/frame", "frames to converge", "ms to converge", "cold frame ms", "cold frame points",
                      "cold frame parts ms"))
    for r in rows:
        p = r["pass_ms_median"]
        table.rows.append((r["store"], r["budget"], r["path"], "batch" if r["batch_groups"] else "256 slots",
                           RECORDS_LABELS[r["winners"]], r["prepare"], r["index_pass"], r["frame_ms_median"], r["frame_ms_p95"],
                           r["frame_ms_max"],
                           r["target_ms"], f"{r['over_target']:.0%}" if r["over_target"] is not None else None,
                           p["reproject"], p["fill"], p["prepare"], p["resolve"], f"{r['fill_share_median']:.0%}",
                           round(r["points_per_frame_median"]), round(r["gathered_median"]),
                           r["frames_to_converge"] or "no", r["ms_to_converge"],
                           *((c["frame_ms"], c["points"]) if (c := r["cold_frame"]) else (None, None)),
                           cold_parts(r["cold_frame"])))
    table.notes = [
        "One brute-force frame (compute, every point) takes " + ", ".join(
            f"{ms:.2f} ms ({store})" for store, ms in brute.items()) + " here, same camera.",
        (f"GPU milliseconds from timestamps (medians per pass over all frames of a run). Camera paths move for "
         f"{motion} frames (orbit 60° about the target, zoom to 20 % of the distance, fly across the cloud at low "
         f"height), then hold the last camera. Frames to converge count from the first still frame to the first "
         f"frame by which every point was filled since the last change (exact: the image then equals brute "
         f"force); ms to converge sums their GPU frame times. Runs stop there or at {max_frames} frames. "
         f"Two frames in flight, as a swap chain paces a window; each case after {CASE_WARM_UP_S} s of orbiting "
         f"frames filling an eighth of the cloud (so that the GPU's clocks are up). Fill work group: batch = fill pieces walked "
         f"one work group a batch (the renderer's), 256 slots = one invocation a slot. Store: words = the "
         f"renderer's (three 10-bit position words and the attribute word, each in its plane), float records = "
         f"float32 xyz and the attribute word together, each with its records in the renderer's order "
         f"({RECORD_ORDER.value}: slice k of every batch before slice k+1 of any, so a fill piece's records lie "
         f"together) unless the store says otherwise (each batch's records together: as brute force keeps "
         f"them); each store loaded and run in turn. Records: where "
         f"prepare takes the records of the points visible now, for the next frame's reprojection and resolve: "
         f"winners pass = the raster's last pass over the frame's points leaves each pixel's record (its time "
         f"is in the fill column), gathered = from the last list where a hint finds it, else from the store at "
         f"random; gathered/frame = median records a frame read from the store that way. Prepare entries: how "
         f"prepare's pixels take their places in the list, a subgroup at a time by ballot (GL_ARB_shader_ballot) or "
         f"a work group at a time after a barrier. Index pass (the 32-bit path): over the points that lowered or met "
         f"their pixel's depth in the depth pass (candidates, the renderer's default; it runs inside "
         f"the first pass) or over every point again. Cold frame: the "
         f"case's first frame, which knows no fill rate yet and so adds the growth stages (budget.grow); its "
         f"parts: the first pass's first fill / adaptive part / grow 1 / grow 2, + the later passes over the "
         f"same points (the 32-bit path's index pass over every point, the winners pass).")]
    table.raw = {"brute_ms": brute, "rows": rows, "frames": frames}
    return table


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="progressive section alone (python -m bench runs every section)")
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--targets-ms", type=float, nargs="+", default=[16.6, 11.1])
    ap.add_argument("--fixed", type=int, nargs="*", default=[1_000_000])
    ap.add_argument("--motion-frames", type=int, default=30)
    ap.add_argument("--max-frames", type=int, default=400)
    ap.add_argument("--compare-walk", action="store_true", help="also run each case with one invocation a slot")
    ap.add_argument("--stores", nargs="+", choices=list(STORE_LABELS.values()), default=["words"],
                    help="run every case on each store in turn")
    ap.add_argument("--records", nargs="+", choices=list(RECORDS_LABELS.values()),
                    help="run every case with prepare's records from each source in turn (default: the renderer's choice)")
    ap.add_argument("--prepare", nargs="+", choices=list(PREPARE_LABELS.values()),
                    help="run every case with prepare's list entries taken each way in turn (default: the renderer's)")
    ap.add_argument("--index-pass", nargs="+", choices=list(INDEX_PASS_LABELS.values()),
                    help="run every case with the 32-bit index pass over each in turn (default: the renderer's choice)")
    ap.add_argument("--record-orders", nargs="+", choices=[o.value for o in RecordOrder], default=[RECORD_ORDER.value],
                    help="run every case with the store's records in each order in turn")
    ap.add_argument("--out", default="bench/results/local")
    args = ap.parse_args(argv)
    glc = create_context()
    size = tuple(int(v) for v in args.size.split("x"))
    table = run(glc, args.points, size, args.fixed, args.targets_ms, list(CameraPath), args.motion_frames,
                args.max_frames, args.compare_walk,
                tuple(e for e, label in STORE_LABELS.items() if label in args.stores),
                tuple(w for w, label in RECORDS_LABELS.items() if label in args.records) if args.records else (None,),
                tuple(RecordOrder(o) for o in args.record_orders),
                tuple(b for b, label in PREPARE_LABELS.items() if label in args.prepare) if args.prepare else (None,),
                tuple(c for c, label in INDEX_PASS_LABELS.items() if label in args.index_pass) if args.index_pass else (None,))
    info = RunInfo.from_caps(glc.caps, "progressive only")
    table.write(Path(args.out), info)
    print(table.markdown(info))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
