"""Accuracy against time: per budget, the share of pixels equal to the converged
brute-force render and the PSNR of the colour image, per frame and against the GPU
time spent, with the shuffled fill order and with the file order (the paper's
Table 4 / Figure 5 baseline, FillOrder.FILE); and during camera motion, how much of
the image reprojection keeps. Images are read back every frame, so this section
measures what frames show, not how fast they run (bench/progressive.py does that)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from bench.progressive import Budget, CameraPath, camera_at
from bench.report import Table, finite
from progressive.attributes import default_attribute
from progressive.camera import Camera, auto_camera, view_uniforms
from progressive.context import GLContext
from progressive.frame_loop import ProgressiveOptions, ProgressiveRenderer
from progressive.loaders import CloudLoader
from progressive.loaders.types import CloudInfo
from progressive.passes.visibility import EMPTY
from progressive.permutation import FillOrder
from progressive.renderer import Renderer
from progressive.scene import Scene

SceneMaker = Callable[[FillOrder], Scene]
LEVELS = (0.9, 0.99)


def file_scenes(glc: GLContext, path: Path) -> tuple[CloudInfo, SceneMaker]:
    """A real file as it is, on the GPU in either fill order."""
    with CloudLoader([path]) as loader:
        info = loader.info
        loader.start()
        batches = sorted(loader, key=lambda b: b.start)
    attribute = default_attribute(info)

    def make(order: FillOrder) -> Scene:
        scene = Scene(glc, info, attribute, order=order)
        for b in batches:
            scene.add_batch(b)
        return scene

    return info, make


def psnr(image: np.ndarray, reference: np.ndarray) -> float:
    """PSNR in dB of the RGB channels (8-bit); infinite when equal."""
    mse = float(np.mean((image[..., :3].astype(np.float64) - reference[..., :3]) ** 2))
    return math.inf if mse == 0 else 10 * math.log10(255.0**2 / mse)


@dataclass(frozen=True)
class Reference:
    slots: np.ndarray
    image: np.ndarray


def reference(r: Renderer, cam: Camera, size: tuple[int, int]) -> Reference:
    """The brute-force render of `cam`, compared by slot (same store, so equal slots mean
    equal points) to skip the inverse permutation of every pixel that ids would cost."""
    view = view_uniforms(cam, r.info.origin, *size)
    r.vis.resize(*size)
    r.vis.clear()
    r.raster.draw(view, 0, r.store.capacity)
    r.shading.resolve.run(r.style())
    return Reference(r.vis.read()[:, :, 0].copy(), r.shading.read())


def frames(glc: GLContext, scene: Scene, size: tuple[int, int], budget: Budget, path: CameraPath, motion: int,
           max_frames: int) -> list[dict]:
    """Per frame: pixels equal to the brute-force render of that frame's camera, PSNR,
    covered pixels and those kept by reprojection, GPU ms of the frame."""
    width, height = size
    pr = ProgressiveRenderer(glc, scene.info, scene.attribute, ProgressiveOptions(width, height, budget=budget.params),
                             scene=scene)
    lo, hi = scene.info.bounds_min, scene.info.bounds_max
    base = auto_camera(lo, hi, width / height)
    style = scene.style()
    motion = 0 if path is CameraPath.STILL else motion
    brute = Renderer(glc, scene.info, scene.attribute, width=width, height=height, scene=scene)
    ref, ref_cam, out = None, None, []
    for k in range(max_frames):
        cam = camera_at(path, base, lo, hi, k, motion)
        if cam != ref_cam:
            ref, ref_cam = reference(brute, cam, size), cam
        pr.frame(cam, style)
        slots, image = pr.read_slots(), pr.read_image()
        same = slots == ref.slots
        shown = (slots != EMPTY) | (ref.slots != EMPTY)
        equal = float(same[shown].mean()) if shown.any() else 1.0
        out.append({"frame": k, "moving": k < motion, "equal": equal, "equal_all_pixels": float(same.mean()),
                    "psnr": psnr(image, ref.image)})
        if k >= motion and equal == 1.0 and out[-1]["psnr"] == math.inf:
            break
    stats = {s.frame: s for s in pr.flush()}
    elapsed = 0.0
    for rec in out:
        s = stats.get(rec["frame"])
        ms = s.gpu_ms.get("frame", 0.0) if s else 0.0
        elapsed += ms
        covered = s.covered_pixels if s else 0
        rec.update(gpu_ms=ms, elapsed_ms=elapsed, covered=covered,
                   kept=(covered - s.gathered) / covered if s and covered else None)
    pr.release()
    brute.release()
    return out


def first(records: list[dict], level: float, after: int = 0) -> dict | None:
    return next((r for r in records if r["frame"] >= after and r["equal"] >= level), None)


def plot_still(runs: dict[tuple[str, FillOrder], list[dict]], title: str, path: Path) -> None:
    fig = Figure(figsize=(11, 7.5))
    axes = fig.subplots(2, 2, sharey="row")
    colours = {}
    for (label, order), recs in runs.items():
        colour = colours.setdefault(label, f"C{len(colours)}")
        style = "-" if order is FillOrder.SHUFFLED else "--"
        name = f"{label}, {order.value}"
        for col, x in enumerate(("frame", "elapsed_ms")):
            xs = [r[x] + (1 if x == "frame" else 0) for r in recs]
            axes[0, col].plot(xs, [100 * r["equal"] for r in recs], style, color=colour, label=name)
            finite_pts = [(xv, r["psnr"]) for xv, r in zip(xs, recs) if math.isfinite(r["psnr"])]
            if finite_pts:
                axes[1, col].plot(*zip(*finite_pts), style, color=colour, label=name)
    for col, xl in enumerate(("frame", "GPU time spent (ms, cumulative)")):
        axes[1, col].set_xlabel(xl)
        axes[0, col].set_xscale("log")
        axes[1, col].set_xscale("log")
    axes[0, 0].set_ylabel("covered pixels equal to brute force (%)")
    axes[1, 0].set_ylabel("PSNR of the colour image (dB)")
    axes[0, 0].legend(fontsize=7, loc="lower right")
    fig.suptitle(title + "\nsolid: shuffled fill; dashed: file order; PSNR lines end where the image is exact",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def plot_motion(runs: dict[tuple[str, CameraPath], list[dict]], motion: int, title: str, path: Path) -> None:
    fig = Figure(figsize=(11, 4))
    axes = fig.subplots(1, 2)
    for k, ((label, cam_path), recs) in enumerate(runs.items()):
        xs = [r["frame"] + 1 for r in recs]
        axes[0].plot(xs, [100 * r["equal"] for r in recs], color=f"C{k}", label=f"{label}, {cam_path.value}")
        kept = [(x, 100 * r["kept"]) for x, r in zip(xs, recs) if r["kept"] is not None]
        if kept:
            axes[1].plot(*zip(*kept), color=f"C{k}")
    for ax in axes:
        ax.axvline(motion + 0.5, color="grey", lw=0.8, ls=":")
        ax.set_xlabel("frame (camera stops after the dotted line)")
    axes[0].set_ylabel("covered pixels equal to brute force (%)")
    axes[1].set_ylabel("visible pixels kept by reprojection (%)")
    axes[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def run(glc: GLContext, data: str, info: CloudInfo, make: SceneMaker, size: tuple[int, int], budgets: list[Budget],
        motion_budgets: list[Budget], paths: list[CameraPath], motion: int, max_frames: int,
        out: Path) -> tuple[Table, Table]:
    stem = "accuracy"
    still: dict[tuple[str, FillOrder], list[dict]] = {}
    for order in FillOrder:
        scene = make(order)
        for budget in budgets:
            still[(budget.label, order)] = frames(glc, scene, size, budget, CameraPath.STILL, 0, max_frames)
        scene.release()
    scene = make(FillOrder.SHUFFLED)
    moving: dict[tuple[str, CameraPath], list[dict]] = {}
    for budget in motion_budgets:
        for path in paths:
            moving[(budget.label, path)] = frames(glc, scene, size, budget, path, motion, max_frames + motion)
    scene.release()

    out.mkdir(parents=True, exist_ok=True)
    dims = f"{size[0]}x{size[1]}"
    plot_still(still, f"{data}, {info.points:,} points, {dims}, {glc.caps.renderer}", out / f"{stem}.png")
    plot_motion(moving, motion, f"{data}, {info.points:,} points, {dims}, {glc.caps.renderer}: "
                f"{motion} frames of motion, then still", out / f"{stem}_motion.png")

    table = Table(stem, "Accuracy against time, still camera: shuffled against file-order fill", data,
                  f"{info.points:,}", ("budget", "fill order", "equal px, frame 1", "PSNR dB, frame 1",
                                       "frames to 90 %", "GPU ms to 90 %", "frames to 99 %", "GPU ms to 99 %",
                                       "frames to exact", "GPU ms to exact"))
    for (label, order), recs in still.items():
        cells = []
        for level in (*LEVELS, 1.0):
            hit = first(recs, level)
            cells += [hit["frame"] + 1, hit["elapsed_ms"]] if hit else [f"> {len(recs)}", None]
        table.rows.append((label, order.value, f"{recs[0]['equal']:.1%}", recs[0]["psnr"], *cells))
    table.notes = [
        (f"{dims}, auto camera. Equal px = share of the pixels covered in this frame or in the brute-force render "
        "that show the same point as the brute-force render (visible slots read back each frame; background pixels, equal "
        "from the start, do not count; the share of all pixels is in the JSON); PSNR over RGB against the brute-force image (∞ = identical). GPU ms = sum "
        "of the frames' GPU times (timestamps) up to that frame. File order = FillOrder.FILE: the budget fills "
        "the file's first points first (paper Table 4 / Figure 5)."),
    ]
    table.images = [f"{stem}.png"]
    table.raw = {"still": [{"budget": k[0], "fill_order": k[1].value,
                            "frames": [dict(r, psnr=finite(r["psnr"]), exact=r["psnr"] == math.inf) for r in v]}
                           for k, v in still.items()]}

    motion_table = Table(f"{stem}_motion", "Accuracy during camera motion: what reprojection keeps", data,
                         f"{info.points:,}", ("budget", "camera", "equal px while moving (median)",
                                              "equal px while moving (min)", "kept by reprojection (median)",
                                              "PSNR dB while moving (median)", "frames to exact after stop"))
    for (label, path), recs in moving.items():
        mov = [r for r in recs if r["moving"] and r["frame"] > 0]
        exact = first(recs, 1.0, motion)
        kept = [r["kept"] for r in mov if r["kept"] is not None]
        motion_table.rows.append((label, path.value, f"{np.median([r['equal'] for r in mov]):.1%}",
                                  f"{min(r['equal'] for r in mov):.1%}", f"{np.median(kept):.1%}" if kept else None,
                                  float(np.median([r["psnr"] for r in mov])),
                                  exact["frame"] - motion + 1 if exact else "no"))
    motion_table.notes = [
        (f"Shuffled fill, {dims}. Each frame is compared with a brute-force render of its own camera. Kept by "
        "reprojection = visible pixels whose point came from the last frame's visible set rather than being "
        "newly looked up in the store ((covered − gathered) / covered, the GPU's counts). Frames 2 to "
        f"{motion} of the motion count (frame 1 has nothing to reproject)."),
    ]
    motion_table.images = [f"{stem}_motion.png"]
    motion_table.raw = {"motion": [{"budget": k[0], "path": k[1].value,
                                    "frames": [dict(r, psnr=finite(r["psnr"])) for r in v]}
                                   for k, v in moving.items()]}
    return table, motion_table
