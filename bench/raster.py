"""Brute-force rasterization time: compute 64-bit, compute 32-bit and GL_POINTS on
the same cloud, camera and resolution. Writes JSON and a Markdown table."""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import statistics
import time
from pathlib import Path

from bench.synthetic import tiled
from progressive.camera import auto_camera
from progressive.context import create_context
from progressive.renderer import Raster, Renderer

SAMPLE = Path(__file__).resolve().parents[1] / "progressive" / "data" / "autzen_trim.las"


def measure(glc, cloud, raster, width, height, repeats):
    r = Renderer(glc, cloud.info, cloud.attribute, raster=raster, width=width, height=height)
    t0 = time.perf_counter()
    for start, rec in cloud.batches():
        r.scene.distribute.upload(rec, start)
    glc.ctx.finish()
    upload_s = time.perf_counter() - t0
    cam = auto_camera(cloud.info.bounds_min, cloud.info.bounds_max, width / height)
    style = r.style()
    times = []
    for _ in range(repeats + 1):
        frame = r.render(cam, width, height, style)
        times.append(frame.gpu_ms["raster"])
    covered = int((frame.slots != 0xFFFFFFFF).sum())
    path = r.raster_path
    r.release()
    return {"raster": path, "ms": statistics.median(times[1:]), "ms_all": times[1:],
            "covered_pixels": covered, "upload_s": upload_s}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, nargs="+", default=[1_000_000])
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--methods", nargs="+", default=["compute", "compute32", "points"])
    ap.add_argument("--out", default="bench/results/local")
    args = ap.parse_args(argv)
    width, height = (int(v) for v in args.size.split("x"))
    glc = create_context()
    rows = []
    for n in args.points:
        cloud = tiled(str(SAMPLE), n)
        for m in args.methods:
            raster = Raster[m.upper()]
            if raster is Raster.COMPUTE and not glc.caps.atomic_int64:
                continue
            res = measure(glc, cloud, raster, width, height, args.repeats)
            res.update(points=n, width=width, height=height, points_per_s=n / (res["ms"] / 1e3))
            rows.append(res)
            print(json.dumps({k: v for k, v in res.items() if k != "ms_all"}), flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"device": glc.caps.description, "date": datetime.date.today().isoformat(),
            "host": platform.node(), "data": f"{SAMPLE.name} tiled on a grid", "rows": rows}
    (out / "raster.json").write_text(json.dumps(meta, indent=2))
    lines = [f"# Brute-force rasterization, {width}x{height}", "",
             f"Device: {meta['device']}  ", f"Date: {meta['date']}  ", f"Data: {meta['data']}", "",
             "| points | rasterizer | ms (median) | points/s | covered pixels |", "|---:|---|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['points']:,} | {r['raster']} | {r['ms']:.2f} | {r['points_per_s']:.3g} | {r['covered_pixels']:,} |")
    (out / "raster.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
