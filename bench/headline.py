"""headline.md: the ratios the README quotes, computed from one results folder's JSON
(every ratio measured side by side within one section of one run), and its insertion
into README.md between `<!-- bench:headline:MACHINE -->` and
`<!-- /bench:headline:MACHINE -->`, so no figure in the README is typed in.

    python -m bench.headline bench/results/llvmpipe [--readme README.md]
"""

from __future__ import annotations

import argparse
import json
import lzma
import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _load(folder: Path, stem: str) -> dict | None:
    """A table's JSON, as the bench wrote it or xz-compressed as committed where large
    (STEM.json.xz: bench/carry_gpu.sh says why)."""
    for path in (folder / f"{stem}.json", folder / f"{stem}.json.xz"):
        if path.exists():
            text = lzma.decompress(path.read_bytes()).decode() if path.suffix == ".xz" else path.read_text()
            return json.loads(text)
    return None


def _largest(folder: Path, prefix: str) -> dict | None:
    """The table of that section with the most points (chunked GPU runs write one per N)."""
    points = [int(m.group(1)) for p in folder.iterdir() if (m := re.fullmatch(rf"{prefix}_(\d+)\.json(\.xz)?", p.name))]
    return _load(folder, f"{prefix}_{max(points)}") if points else None


def _x(v: float) -> str:
    return f"{v:.1f}×" if v < 100 else f"{v:.0f}×"


def _rate(points_per_s: float) -> str:
    return f"{points_per_s / 1e9:.1f} G points/s" if points_per_s >= 1e9 else f"{points_per_s / 1e6:.0f} M points/s"


def raster_lines(raster: dict) -> list[str]:
    """The renderer's layout against GL_POINTS and against the paper's global shuffle,
    and a close-up view against the overview, all rows of one run."""
    rows = raster["raw"]["rows"]
    n = max(r["points"] for r in rows)
    width = max(r["width"] for r in rows)
    rows = [r for r in rows if r["points"] == n and r["width"] == width]
    layout = "batched" if any(r["layout"] == "batched" for r in rows) else "shuffled"

    walks = any(r.get("batch_groups") for r in rows)     # runs before ComputeTuning had no such rows

    def row(layout: str, raster_path: str, view: str = "overview", reduced: bool = False,
            groups: bool | None = None, precision: str = "exact", own_index: bool = True) -> dict | None:
        """The row of the renderer's own tuning (one work group a batch where measured,
        no subgroup reduction, exact precision, the 32-bit index pass it chooses) unless
        `reduced`, `groups`, `precision` or `own_index` asks for another."""
        groups = walks and layout.startswith("batched") if groups is None else groups
        return next((r for r in rows if r["layout"] == layout and r["raster"] == raster_path
                     and r.get("view", "overview") == view and r.get("subgroup_reduction", False) == reduced
                     and r.get("precision", "exact") == precision and r.get("default_index_pass", True) == own_index
                     and (raster_path == "GL_POINTS" or r.get("batch_groups", False) == groups)), None)

    points = row(layout, "GL_POINTS")
    where = f"{n:,} points at {points['width']}x{points['height']}"
    out = []
    for r in rows:
        if (r["layout"] != layout or r["raster"] == "GL_POINTS" or r.get("view", "overview") != "overview"
                or r is not row(layout, r["raster"])):
            continue
        # Runs before the shader copy was measured compared with the driver's copy engine only.
        share = (f"; it streams {r['share_of_copy']:.0%} of the copy bandwidth measured in the same run "
                 f"({raster['raw']['copy_bytes_per_s'] / 1e9:.1f} GB/s, each byte read and written)"
                 if "copy_methods" in raster["raw"] else "")
        if "share_of_read" in r:
            share += (f", {r['share_of_read']:.0%} of the read bandwidth "
                      f"({raster['raw']['read_bytes_per_s'] / 1e9:.1f} GB/s)")
        out.append(f"- Brute force, {where} ({layout} store): {r['raster']} {r['ms']:.2f} ms, "
                   f"{_rate(r['points_per_s'])}, against GL_POINTS {points['ms']:.2f} ms: "
                   f"**{_x(points['ms'] / r['ms'])} faster**{share} (`{raster['_file']}`).")
        shuffled = row("shuffled", r["raster"]) if layout != "shuffled" else None
        if shuffled:
            out.append(f"- Brute force, {where}, {r['raster']}: {layout} store {r['ms']:.2f} ms against the paper's "
                       f"shuffle of the whole cloud {shuffled['ms']:.2f} ms (median of "
                       f"{', '.join(f'{t:.1f}' for t in shuffled['ms_all'])}): **{_x(shuffled['ms'] / r['ms'])}** "
                       f"(`{raster['_file']}`).")
        slot_records = (row(f"{layout}, records in slot order", r["raster"], groups=r.get("batch_groups", False))
                        if layout == "batched" else None)
        if slot_records:
            out.append(f"- Brute force, {where}, {r['raster']}, {layout} store: each batch's records together "
                       f"{r['ms']:.2f} ms against records in slot order {slot_records['ms']:.2f} ms: "
                       f"**{_x(slot_records['ms'] / r['ms'])}** (`{raster['_file']}`).")
        floats = row(f"{layout}, float records", r["raster"]) if layout == "batched" else None
        if floats:
            out.append(f"- Brute force, {where}, {r['raster']}, {layout} store: 30-bit words relative to the batch "
                       f"{r['ms']:.2f} ms ({r['bytes_per_point']:.1f} B a point read) against float records "
                       f"{floats['ms']:.2f} ms ({floats['bytes_per_point']:.1f} B): **{_x(floats['ms'] / r['ms'])}** "
                       f"(`{raster['_file']}`).")
        for view in ("overview", "close-up"):
            exact, adaptive = row(layout, r["raster"], view), row(layout, r["raster"], view, groups=True,
                                                                  precision="adaptive")
            if exact and adaptive:
                out.append(f"- Brute force, {where}, {r['raster']}, {view}: adaptive precision {adaptive['ms']:.2f} ms, "
                           f"{_rate(adaptive['points_per_s'])}, {adaptive['bytes_per_point']:.1f} B a point read, "
                           f"against exact {exact['ms']:.2f} ms ({exact['bytes_per_point']:.1f} B): "
                           f"**{_x(exact['ms'] / adaptive['ms'])}**; {adaptive['pixels_differing']:,} of "
                           f"{adaptive['covered_pixels']:,} covered pixels differ (`{raster['_file']}`).")
        slots = row(layout, r["raster"], groups=False) if r.get("batch_groups") else None
        if slots:
            out.append(f"- Brute force, {where}, {r['raster']}, {layout} store: one work group a batch "
                       f"{r['ms']:.2f} ms against one invocation a slot {slots['ms']:.2f} ms: "
                       f"**{_x(slots['ms'] / r['ms'])}** (`{raster['_file']}`).")
        reduced = row(layout, r["raster"], reduced=True)
        if reduced:
            out.append(f"- Brute force, {where}, {r['raster']}, {layout} store: with the subgroup reduction "
                       f"{reduced['ms']:.2f} ms against {r['ms']:.2f} ms without: **{_x(r['ms'] / reduced['ms'])}** "
                       f"(`{raster['_file']}`).")
        other = row(layout, r["raster"], own_index=False) if r.get("passes", 1) > 1 else None
        if other:
            walks = {True: "the depth pass's candidates", False: "every point"}
            out.append(f"- Brute force, {where}, {r['raster']}, {layout} store: the index pass over "
                       f"{walks[r['candidates']]} (the renderer's choice here) {r['ms']:.2f} ms against over "
                       f"{walks[other['candidates']]} {other['ms']:.2f} ms: **{_x(other['ms'] / r['ms'])}** "
                       f"(`{raster['_file']}`).")
        close = row(layout, r["raster"], "close-up")
        if close:
            out.append(f"- Brute force, {where}, {r['raster']}, a close-up of one tile ({close['batches_culled']:.0%} "
                       f"of the batches culled): {close['ms']:.2f} ms, **{_x(r['ms'] / close['ms'])}** faster than "
                       f"the overview (`{raster['_file']}`).")
    missing = [m for m in raster.get("notes", []) if m.startswith("Compute 64-bit")]
    return out + [f"- {m.split(';')[0]}." for m in missing]


def load_lines(load: dict) -> list[str]:
    """The warm rows of the loader's default parser threads (of a table that does not
    record it: the most threads)."""
    scaled = [r for r in load["raw"]["rows"] if not r["cold"] and r["scaled"]]
    default = load["raw"].get("default_threads")
    threads = default if default is not None else max(r["threads"] for r in scaled)
    which = " (the default)" if default is not None else ""
    out = []
    for r in scaled:
        if r["threads"] != threads:
            continue
        decoders = f", decoded by {r['decoders']}" if r.get("decoders") else ""
        decoders += f", only {r['attributes']} parsed (as `render` keeps)" if r.get("attributes", "every") != "every" else ""
        out.append(f"- Load {r['format']}, {r['points']:,} points, warm cache, {threads} parser threads{which}{decoders}: "
                   f"{r['points_per_s'] / 1e6:.1f} M points/s, {r['gb_per_s']:.2f} GB/s: "
                   f"{_x(r['vs_laspy'])} `laspy.read()` plus conversion ({r['laspy_file']}), "
                   f"{r['share_of_raw']:.2g}× the raw read bandwidth of the same file (`load.md`).")
    cold = [r for r in load["raw"]["rows"] if r["cold"]]
    if cold and not any(r["cold_forced"] for r in cold):
        out.append("- Cold page cache could not be forced on this machine (`load.md`).")
    return out


def first_image_lines(first: dict) -> list[str]:
    out = []
    for r in first["raw"]["rows"]:
        if not r["cold"] or not r["loaded_s"] or not r["scaled"]:
            continue
        out.append(f"- Open {r['file']} {r['format']}, {r['points']:,} points, cold: first image after {r['first_image_s']:.2f} s, all points on "
                   f"the GPU after {r['loaded_s']:.2f} s ({r['first_image_s'] / r['loaded_s']:.0%} of it; "
                   f"`first_image.md`).")
    return out


def progressive_lines(prog: dict) -> list[str]:
    """The still rows of the renderer's own choices: batch walks, the word store, the
    winners pass where the table has it (a small store's runs have only gathers), the
    32-bit index pass it chooses."""
    out = []
    brute = prog["raw"]["brute_ms"]
    winners = any(r.get("winners", True) for r in prog["raw"]["rows"])
    for r in prog["raw"]["rows"]:
        store = r.get("store", "words")
        if (r["target_ms"] and r["path"] == "still" and r.get("batch_groups", True) and store == "words"
                and r.get("winners", True) == winners and r.get("default_index_pass", True)):
            conv = (f"exact after {r['frames_to_converge']} frames ({r['ms_to_converge']:.1f} ms of GPU time)"
                    if r["frames_to_converge"] else "not converged within the run")
            brute_ms = brute[store] if isinstance(brute, dict) else brute
            out.append(f"- Progressive, {prog['points']} points, {r['budget']}, still camera: frame median "
                       f"{r['frame_ms_median']:.2f} ms, p95 {r['frame_ms_p95']:.2f} ms; {conv}; one brute-force "
                       f"frame {brute_ms:.2f} ms (`{prog['_file']}`).")
    return out


def attribute_lines(attrs: dict) -> list[str]:
    rows = attrs["raw"].get("rows", [])
    if not rows:
        return []
    rates = ", ".join(f"{r['attribute']} {r['points_per_s'] / 1e6:.1f}" for r in rows)
    return [f"- Attribute switch, {rows[0]['points']:,} points kept in host memory: {rates} M points/s streamed to "
            f"the shuffled buffer, no reload (`{attrs['_file']}`)."]


def build(folder: Path) -> str:
    """headline.md for one results folder (a run of `python -m bench`, or its GPU chunks);
    empty when the folder has none of the tables it quotes."""
    tables = {"raster": _largest(folder, "raster"), "progressive": _largest(folder, "progressive"),
              "load": _load(folder, "load"), "first_image": _load(folder, "first_image"),
              "attributes": _load(folder, "attributes")}
    for t in tables.values():
        if t is not None:
            t["_file"] = f"{t['name']}.md"
    head = next((t for t in tables.values() if t), None)
    if head is None:
        return ""
    run = head["run"]
    dates = sorted({t["run"]["date"] for t in tables.values() if t})
    when = dates[0] if len(dates) == 1 else f"{dates[0][:10]} to {dates[-1][:10]} (each table names its date)"
    lines = [(f"Measured by `python -m bench` ({run['mode']}) on {run['device']}, {run['driver']}, {when}; "
             f"tables in `bench/results/{folder.name}/`."), ""]
    if tables["raster"]:
        lines += raster_lines(tables["raster"])
    if tables["load"]:
        lines += load_lines(tables["load"])
    if tables["first_image"]:
        lines += first_image_lines(tables["first_image"])
    if tables["progressive"]:
        lines += progressive_lines(tables["progressive"])
    if tables["attributes"]:
        lines += attribute_lines(tables["attributes"])
    return "\n".join(lines) + "\n"


def insert(readme: Path, machine: str, text: str) -> None:
    """Replace what lies between the machine's markers; the markers must exist."""
    start, end = f"<!-- bench:headline:{machine} -->", f"<!-- /bench:headline:{machine} -->"
    body = readme.read_text()
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.DOTALL)
    if not pattern.search(body):
        raise SystemExit(f"{readme}: markers {start} ... {end} not found; add them where the headline belongs")
    readme.write_text(pattern.sub(lambda _: f"{start}\n{text.rstrip()}\n{end}", body))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="rebuild headline.md from a results folder and put it in README.md")
    ap.add_argument("folder", type=Path)
    ap.add_argument("--readme", type=Path, default=README)
    ap.add_argument("--no-readme", action="store_true", help="only write headline.md")
    args = ap.parse_args(argv)
    text = build(args.folder)
    if not text:
        raise SystemExit(f"{args.folder}: no raster, load or progressive results")
    (args.folder / "headline.md").write_text(text)
    if not args.no_readme:
        insert(args.readme, args.folder.name, text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
