"""bench.compactness: the batch compactness table on tiny inputs, and a metric that can fail."""

from __future__ import annotations

import json

import laspy
import numpy as np

from bench import compactness
from bench.compactness import ORDERINGS, Grid, Ordering, Rule, centred, morton_sort, run
from bench.synthetic import morton_order
from progressive.permutation import BATCH_POINTS


def strips(n: int, width: int = 100) -> np.ndarray:
    """A long flat cloud recorded row by row across it (a raster scan): file order is compact."""
    i = np.arange(n)
    return np.stack([i % width, i // width, np.sin(i) * 0.1], axis=1).astype(np.float64)


def test_morton_codes_match_the_bit_loop():
    xyz = np.random.default_rng(3).random((20_000, 3)) * [5.0, 2.0, 0.1]
    assert np.array_equal(morton_sort(xyz, Grid.AXES), morton_order(xyz))
    cube = morton_sort(xyz, Grid.CUBE)
    assert sorted(cube) == list(range(len(xyz)))


def test_scrambled_order_scores_worse_than_file_order():
    n = 6 * BATCH_POINTS
    ordered = centred("strips", "test", strips(n))
    shuffled = centred("shuffled", "test", ordered.xyz[np.random.default_rng(1).permutation(n)])
    table = run([ordered, shuffled])
    assert len(table.rows) == 2 * len(ORDERINGS)
    assert {len(r) for r in table.rows} == {len(table.columns)}
    for name in ("strips", "shuffled"):
        rows = [r for r in table.raw["rows"] if r["data"] == name]
        assert [r["label"] for r in rows] == [o.label for o in ORDERINGS]
        assert all(r["batches"] == 6 for r in rows)
    file, scrambled = (next(r for r in table.raw["rows"] if r["data"] == "strips" and r["rule"] is rule)
                       for rule in (Rule.FILE, Rule.SCRAMBLED))
    assert scrambled["mean_diagonal"] > 2 * file["mean_diagonal"]
    assert scrambled["kept_grid"] > 2 * file["kept_grid"] and scrambled["area"] > 2 * file["area"]
    # a file in no useful order: Morton inside chunks must recover compactness
    bad = [r for r in table.raw["rows"] if r["data"] == "shuffled"]
    bad_file = next(r for r in bad if r["rule"] is Rule.FILE)
    morton = next(r for r in bad if r["rule"] is Rule.MORTON and r["chunk"] == 0)
    assert morton["kept_grid"] < bad_file["kept_grid"] / 2
    assert any(line.startswith("- strips (test") for line in table.notes)


def test_chunks_follow_the_loader():
    o = Ordering("t", Rule.MORTON, 100, 500)
    assert list(o.chunks(1_200)) == [(0, 100), (100, 600), (600, 1_100), (1_100, 1_200)]
    assert list(Ordering("t", Rule.MORTON).chunks(7)) == [(0, 7)]
    xyz = np.random.default_rng(2).random((1_200, 3))
    a = o.arrange(xyz)
    assert sorted(a.permutation) == list(range(1_200)) and (a.sorted_chunks, a.chunks) == (4, 4)
    assert np.array_equal(np.sort(a.permutation[100:600]), np.arange(100, 600))


def test_main_writes_the_table(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    las = laspy.LasData(laspy.LasHeader(point_format=0, version="1.2"))
    xyz = strips(25_000)
    las.header.scales, las.header.offsets = [0.01] * 3, [0.0] * 3
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.write(data / "strips.las")
    (data / "broken.laz").write_bytes(b"not a point cloud")
    out = tmp_path / "out"
    assert compactness.main(["--data", str(data), "--cap", "20000", "--synthetic-points", "30000",
                             "--cost-points", "20000", "--repeats", "1", "--out", str(out)]) == 0
    payload = json.loads((out / "compactness.json").read_text())
    assert len(payload["rows"]) == 3 * len(ORDERINGS)
    assert {r[0] for r in payload["rows"]} == {"strips.las", "autzen_trim.las tiled"}
    assert [r["points"] for r in payload["raw"]["rows"]][0] == 20_000
    assert payload["raw"]["cost"]["sort_s"] > 0 and payload["raw"]["skipped"][0].startswith("broken.laz")
    md = (out / "compactness.md").read_text()
    assert md.startswith("# ") and "Device: CPU only" in md
    assert len([line for line in md.splitlines() if line.startswith("| ")]) == 3 * len(ORDERINGS) + 1
