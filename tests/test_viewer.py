"""Runs tests/viewer_cases.py in a fresh process: Mesa refuses a GLX window context
in a process whose EGL context (the suite's `gl` fixture) was made current."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent


def test_viewer_cases_in_their_own_process():
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb not installed (scripts/setup.sh installs it)")
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(HERE / "viewer_cases.py")],
                       cwd=HERE.parent, capture_output=True, text=True, timeout=600)
    summary = r.stdout.strip().splitlines()[-1] if r.stdout.strip() else ""
    assert r.returncode == 0, f"viewer cases failed ({summary}):\n{r.stdout[-6000:]}\n{r.stderr[-2000:]}"
    assert " passed" in summary and "skipped" not in summary, summary
    print(summary)
