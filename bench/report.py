"""Tables and raw JSON with the same heading everywhere: device, driver, date, data
set and N, so no figure leaves a run without the machine it was measured on."""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
import platform
import re
from dataclasses import dataclass, field
from pathlib import Path

from progressive.context import Capabilities

INDEX_PASS_LABELS = {True: "candidates", False: "every point"}
"""What the 32-bit path's index pass walks (ComputeTuning.candidates), as the raster and
progressive tables name it."""


def index_pass_label(candidates: bool, passes: int) -> str:
    """A row's index pass (INDEX_PASS_LABELS); nothing for the one-pass rasterizers."""
    return INDEX_PASS_LABELS[candidates] if passes > 1 else ""


def machine_name(caps: Capabilities) -> str:
    """A folder name from the GL renderer: `llvmpipe`, `nvidia-h100`, `nvidia-h200`, ..."""
    renderer = caps.renderer.lower()
    if "llvmpipe" in renderer:
        return "llvmpipe"
    model = re.search(r"\b([a-z]+\d+[a-z]*)\b", renderer)
    vendor = caps.vendor.split()[0].lower() if caps.vendor else "gpu"
    return re.sub(r"[^a-z0-9-]+", "-", f"{vendor}-{model.group(1)}" if model else renderer).strip("-")


@dataclass(frozen=True)
class RunInfo:
    device: str
    driver: str
    machine: str
    date: str
    host: str
    mode: str

    @classmethod
    def from_caps(cls, caps: Capabilities, mode: str) -> RunInfo:
        return cls(device=caps.renderer, driver=caps.version, machine=machine_name(caps),
                   date=datetime.datetime.now().isoformat(timespec="seconds"), host=platform.node(), mode=mode)

    @classmethod
    def cpu_only(cls, mode: str, machine: str = "cpu") -> RunInfo:
        """GPU-free benches: the CPU stands where the other tables name the GL device."""
        import laspy
        import numpy as np
        return cls(device=f"CPU only: {cpu_name()}", driver=f"numpy {np.__version__}, laspy {laspy.__version__}",
                   machine=machine, date=datetime.datetime.now().isoformat(timespec="seconds"),
                   host=platform.node(), mode=mode)


def cpu_name() -> str:
    """The CPU's model name (Linux), else what the platform says."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


@dataclass
class Table:
    """One section's Markdown table, and its raw JSON beside it."""

    name: str
    title: str
    data: str
    points: str
    columns: tuple[str, ...]
    rows: list[tuple] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    raw: dict = field(default_factory=dict)
    images: list[str] = field(default_factory=list)

    def markdown(self, run: RunInfo) -> str:
        lines = [f"# {self.title}", "",
                 f"Device: {run.device}  ", f"Driver: {run.driver}  ", f"Date: {run.date} ({run.mode})  ",
                 f"Data: {self.data}  ", f"N: {self.points}", ""]
        lines += [n + "\n" for n in self.notes]
        if self.rows:
            lines.append("| " + " | ".join(self.columns) + " |")
            lines.append("|" + "|".join("---" if i == 0 else "---:" for i in range(len(self.columns))) + "|")
            lines += ["| " + " | ".join(cell(v) for v in r) + " |" for r in self.rows]
            lines.append("")
        lines += [f"![{Path(i).stem}]({i})" for i in self.images]
        return "\n".join(lines).rstrip() + "\n"

    def write(self, out: Path, run: RunInfo) -> None:
        out.mkdir(parents=True, exist_ok=True)
        (out / f"{self.name}.md").write_text(self.markdown(run))
        payload = {"name": self.name, "run": dataclasses.asdict(run), "title": self.title, "data": self.data, "points": self.points,
                   "columns": list(self.columns), "rows": [list(r) for r in self.rows], "notes": self.notes,
                   "images": self.images, "raw": self.raw}
        # compact: the per-frame data of 1 B-point runs is megabytes, and the checkout travels
        # to the GPU machine under a size limit (bench/carry_gpu.sh); the .md is the table to read
        text = json.dumps(clean(payload), separators=(",", ":"), default=jsonable, allow_nan=False)
        (out / f"{self.name}.json").write_text(text)


    def publish(self, run: RunInfo, out: Path | None, results: Path) -> None:
        """Write to `out`, else to the machine's folder under `results`, and print it."""
        self.write(out or results / run.machine, run)
        print(self.markdown(run))


def cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        if not math.isfinite(v):
            return "∞" if v > 0 else ""
        return f"{v:.3g}" if abs(v) >= 1e4 or abs(v) < 0.01 and v != 0 else f"{v:.2f}"
    if isinstance(v, int) and not isinstance(v, bool):
        return f"{v:,}"
    return str(v)


def jsonable(v):
    """numpy scalars and enums in raw JSON."""
    if hasattr(v, "item"):
        return v.item()
    if hasattr(v, "value"):
        return v.value
    return str(v)


def clean(v):
    """JSON has no infinity or NaN: they become null (an 'exact' flag says which null is ∞)."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [clean(x) for x in v]
    return v


def finite(v: float | None) -> float | None:
    """JSON has no infinity: exact matches (PSNR ∞) are stored as null with a flag beside."""
    return None if v is None or not math.isfinite(v) else float(v)
