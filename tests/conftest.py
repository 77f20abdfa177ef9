"""Shared fixtures: the real data folder beside the checkout and one headless GL context."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("PROGRESSIVE_SHARED_DATA", REPO.parent / "shared" / "data"))
SAMPLE = REPO / "progressive" / "data" / "autzen_trim.las"
BUNNY = REPO / "tests" / "data" / "bunnyDouble.e57"
"""The bundled E57 (tests/data/README.md), so the GPU machine need not carry the shared copy."""
LAS_SUFFIXES = (".las", ".laz")
RECORDS = pytest.mark.parametrize("winners", [False, True], ids=["gathered", "winners pass"])
"""Prepare's records from hints and gathers, or from the raster's winners pass
(ComputeTuning.winners): the tests' small stores default to the first, a store of a
few hundred MiB to the second, so each test that takes `winners` runs both."""


def shared_files() -> list[Path]:
    """Every LAS/LAZ file in ../shared/data (empty when the folder is absent)."""
    if not SHARED_DATA.is_dir():
        return []
    return sorted(p for p in SHARED_DATA.iterdir() if p.suffix.lower() in LAS_SUFFIXES)


def shared_file(name: str) -> Path:
    path = SHARED_DATA / name
    if not path.is_file():
        pytest.skip(f"{path} not available")
    return path


@pytest.fixture(scope="session", autouse=True)
def program_cache(tmp_path_factory):
    """Program binaries in a directory of this run (the CLI's subprocesses inherit it),
    not the user's cache."""
    from progressive.programs import ENV_VAR

    before = os.environ.get(ENV_VAR)
    os.environ[ENV_VAR] = str(tmp_path_factory.mktemp("programs")) if before is None else before
    yield
    if before is None:
        del os.environ[ENV_VAR]


@pytest.fixture(scope="session")
def sample_path() -> Path:
    return SAMPLE


@pytest.fixture(scope="session")
def gl():
    """One headless context for the whole run (creating one costs ~0.1 s on llvmpipe)."""
    from progressive.context import create_context

    handle = create_context()
    yield handle
    handle.release()


@pytest.fixture(scope="session")
def sample_batches():
    """(CloudInfo, batches in file order) of the bundled sample, in batches of 20,000."""
    from progressive.loaders import CloudLoader

    with CloudLoader([SAMPLE], batch_points=20_000) as loader:
        info = loader.info
        loader.start()
        batches = sorted(loader, key=lambda b: b.start)
    return info, batches


@pytest.fixture(scope="session")
def fast_sample(tmp_path_factory) -> Path:
    """The bundled sample in the fast format, its attribute word the intensity (a SCALAR)."""
    from progressive.loaders import CloudLoader, open_cloud, write_fast

    out = tmp_path_factory.mktemp("fast") / "sample.prgs"
    info = open_cloud([SAMPLE])
    write_fast(out, CloudLoader([SAMPLE]), info, info.attribute("intensity"))
    return out


def file_xyz(path) -> np.ndarray:
    """(n, 3) float64 x, y, z of a LAS/LAZ file as laspy scales them: the independent
    reference of positions."""
    import laspy

    las = laspy.read(path)
    return np.stack([las.x, las.y, las.z], axis=1)


def bounded(call, seconds: float):
    """call() run on a thread that must end within `seconds`: its result (or exception)
    and the time it took."""
    outcome: dict = {}

    def run():
        try:
            outcome["value"] = call()
        except BaseException as exc:        # handed to the test
            outcome["error"] = exc

    began = time.monotonic()
    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"did not end within {seconds} s"
    if "error" in outcome:
        raise outcome["error"]
    return outcome["value"], time.monotonic() - began
