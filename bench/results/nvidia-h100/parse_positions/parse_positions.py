"""A/B in one process: a LAS batch's positions (loaders/las.py _positions) a column at a
time (9 numpy calls, the loader's) against all three columns at once through transposed
views (3 calls, each with its inner loop along the points). On one thread the second is
slower; on many threads each call's return waits for the GIL, so fewer may win. Each
thread parses every batch (spans, every attribute); rounds alternate; ns a point.

    python parse_positions.py FILE [THREADS...]
"""

import sys
from functools import partial
from pathlib import Path

import numpy as np

from progressive.loaders import las as L

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "parse_calls"))
import parse_calls  # noqa: E402  (the same rounds and timing of threads that each parse every batch)
from parse_calls import alternate, opened  # noqa: E402


def positions_at_once(cells: np.ndarray, scales: np.ndarray, offsets: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """The same values as las._positions, three columns a call."""
    positions = np.empty(cells.shape, np.float32)
    scaled = np.empty((3, cells.shape[0]))
    np.multiply(cells.T, scales[:, None], out=scaled)
    scaled += offsets[:, None]
    np.subtract(scaled, origin[:, None], out=positions.T, casting="same_kind")
    return positions


def main() -> None:
    path, threads = sys.argv[1], [int(t) for t in sys.argv[2:]] or [1, 2]
    src, spans, names, points = opened(path)
    ways = {"a column a call (9)": L._positions, "three columns a call (3)": positions_at_once}
    cells = np.random.default_rng(1).integers(-2**31, 2**31 - 1, (100_000, 3), dtype=np.int32)
    args = (src.records.scales, src.records.offsets, np.float64([1e5 + 0.3, -2e5 + 0.7, 12.25]))
    with np.errstate(over="ignore", invalid="ignore"):
        assert np.array_equal(L._positions(cells, *args), positions_at_once(cells, *args))

    print(f"{path}: {len(spans)} batches, {points:,} points, every attribute, rounds {parse_calls.ROUNDS}")
    alternate(ways, partial(setattr, L, "_positions"), src, spans, names, points, threads)


if __name__ == "__main__":
    main()
