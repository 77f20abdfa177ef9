"""Probe: render's session (shown) on 100M LAS and fast: first image, all points on GPU, frames; this tree."""
import sys

from bench import data
from bench.load import first_image, warm_programs
from progressive.context import create_context

glc = create_context()
files = data.scaled(100_000_000)
for fmt, path in files.formats():
    if fmt == "LAZ":
        continue
    warm_programs(glc, path, (1920, 1080), "shown")
    for _ in range(2):
        r = first_image(glc, path, 1920, 1080, False, 100000, "shown")
        print(sys.argv[1], fmt, {k: (round(v, 3) if isinstance(v, float) else v) for k, v in r.items()}, flush=True)
