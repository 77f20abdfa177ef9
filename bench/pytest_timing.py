"""A pytest plugin for the GPU machine's runs (`bench/gpu.sh pytest`): each test phase's
duration and outcome appended as it ends to $PYTEST_TIMING_DIR/durations.tsv, and each
failure's report to failures.txt there, so that a run the call's time limit kills still
says where its time went and why a test failed (pytest's own summary comes only at the end).

    PYTEST_TIMING_DIR=DIR python -m pytest -p bench.pytest_timing tests
"""
import os
import time
from pathlib import Path

_T0 = time.monotonic()


def _folder() -> Path:
    return Path(os.environ.get("PYTEST_TIMING_DIR", "."))


def pytest_runtest_logreport(report) -> None:
    with open(_folder() / "durations.tsv", "a") as f:
        f.write(f"{time.monotonic() - _T0:.2f}\t{report.duration:.3f}\t{report.when}\t{report.outcome}\t{report.nodeid}\n")
    if report.failed:
        with open(_folder() / "failures.txt", "a") as f:
            f.write(f"==== {report.nodeid} ({report.when})\n{report.longreprtext}\n\n")
