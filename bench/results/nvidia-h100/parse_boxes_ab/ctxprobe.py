"""Probe: seconds to create the headless context in a fresh process (this tree)."""
import sys
import time

t0 = time.perf_counter()
from progressive.context import create_context  # noqa: E402

t1 = time.perf_counter()
glc = create_context()
t2 = time.perf_counter()
print(sys.argv[1], f"import {t1 - t0:.3f} context {t2 - t1:.3f}", flush=True)
