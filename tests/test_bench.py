"""Smoke test of `python -m bench`: every section runs on a tiny cloud and writes
well-formed tables, JSON and PNG plots (not a timed test)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np

import progressive
from bench import headline
from bench.__main__ import main
from progressive.encoding import Encoding


def test_bench_writes_every_section(tmp_path):
    out = tmp_path / "results"
    assert main(["--smoke", "--out", str(out), "--cache", str(tmp_path / "cache")]) == 0
    names = {"load", "first_image", "raster_30000", "progressive_30000", "accuracy", "accuracy_motion", "attributes"}
    for name in names:
        md = (out / f"{name}.md").read_text()
        assert md.startswith("# ") and "Device: " in md and "Driver: " in md and "N: " in md
        payload = json.loads((out / f"{name}.json").read_text())
        assert payload["name"] == name and payload["run"]["device"]
        widths = {len(payload["columns"])} | {len(r) for r in payload["rows"]}
        assert len(widths) == 1, name
        if payload["rows"]:
            rows = [line for line in md.splitlines() if line.startswith("|")]
            assert len(rows) == len(payload["rows"]) + 2
            assert {line.count("|") for line in rows} == {len(payload["columns"]) + 1}
        for image in payload["images"]:
            assert (out / image).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads((out / "accuracy.json").read_text())["images"] == ["accuracy.png"]
    warm_laz = [r for r in json.loads((out / "load.json").read_text())["raw"]["rows"] if r["format"] == "LAZ" and not r["cold"]]
    assert warm_laz and all(r["lazrs_one_core_points_per_s"] > 0 for r in warm_laz)
    text = (out / "headline.md").read_text()
    assert "GL_POINTS" in text and "laspy" in text and "first image" in text
    assert "Progressive, 30,000 points, adaptive" in text       # a small store's rows have gathers only


def test_load_section_reads_only_the_formats_named(tmp_path):
    out = tmp_path / "results"
    assert main(["--smoke", "--sections", "load", "--load-formats", "LAS", "--load-repeats", "2", "--out", str(out),
                 "--cache", str(tmp_path / "cache")]) == 0
    raw = json.loads((out / "load.json").read_text())["raw"]
    rows = raw["rows"]
    assert rows and {r["format"] for r in rows} == {"LAS"} and raw["repeats"] == 2
    assert not list((tmp_path / "cache").glob("*.laz")) and not list((tmp_path / "cache").glob("*.prg"))
    assert all(r["laspy_seconds"] > 0 and r["raw_seconds"] > 0 for r in rows)


def test_headline_goes_between_markers(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text("a\n<!-- bench:headline:m -->\nold\n<!-- /bench:headline:m -->\nb\n")
    headline.insert(readme, "m", "- new\n")
    assert readme.read_text() == "a\n<!-- bench:headline:m -->\n- new\n<!-- /bench:headline:m -->\nb\n"


def test_kernel_section_times_every_read_pattern(gl):
    """bench.kernel: each read pattern once; the raster stages where 64-bit atomics exist,
    on the word stores at both precisions and with the walk's variants."""
    from bench import kernel

    table = kernel.run(gl, 30_000, (96, 64), 1)
    reads = [r for r in table.rows if r[0] == "read"]
    assert [r[1] for r in reads] == list(kernel.READS) and all(r[4] > 0 for r in reads)
    stages = [r for r in table.rows if r[0] == "raster"]
    words = sum(encoding is Encoding.WORDS for _, encoding in kernel.STORES)
    floats = len(kernel.STORES) - words
    expected = words * 2 * (len(kernel.STAGES) + len(kernel.VARIANTS)) + floats * len(kernel.STAGES)
    assert len(stages) == (expected if gl.caps.atomic_int64 else 0)
    assert all(r[4] > 0 for r in stages)
    prototype = [r for r in table.rows if r[0] == "prototype"]
    assert len(prototype) == (len(kernel.PROTOTYPE_BODIES) * len(kernel.PROTOTYPE_LOOPS) * len(kernel.PROTOTYPE_PLACES) if gl.caps.atomic_int64 else 0)
    assert all(r[4] > 0 for r in prototype)
    assert gl.ctx.error == "GL_NO_ERROR"


def test_passes_bench_runs(tmp_path):
    """bench.passes times every pass of a progressive frame through the passes' handles."""
    from bench import passes

    assert passes.main(["--points", "20000", "--size", "96x64", "--budget", "5000", "--out", str(tmp_path)]) == 0
    table = (tmp_path / "passes_20000.md").read_text()
    assert all(f"| {name} |" in table for name in ("reproject", "fill first", "prepare", "resolve with point size 7"))


def test_packing_bench_runs(tmp_path):
    """bench.packing packs every attribute's words at each thread count, checked against
    the reference words (it raises where they differ)."""
    from bench import packing

    assert packing.main(["--points", "300000", "--threads", "1", "2", "--piece-words", "100000", "300000",
                         "--repeats", "1", "--out", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "local" / "packing.json").read_text())["raw"]["rows"]
    assert sorted((r["attribute"], r["piece_words"], r["threads"]) for r in rows) == sorted(
        (name, piece, k) for name, _ in packing.CASES for piece in (100000, 300000) for k in (1, 2))


def test_convert_bench_runs(tmp_path):
    """bench.convert converts in memory and out of core in fresh processes (the scratch
    where asked, left empty); it raises where the two hierarchies differ."""
    from bench import convert

    scratch = tmp_path / "scratch"
    scratch.mkdir()
    assert convert.main(["--points", "300000", "--memory-points", "60000", "--laz", "--cache",
                         str(tmp_path / "cache"), "--scratch", str(scratch), "--out", str(tmp_path)]) == 0
    assert [p.suffix for p in (tmp_path / "cache").iterdir()] == [".laz"]
    assert list(scratch.iterdir()) == []
    rows = json.loads((tmp_path / "local" / "convert.json").read_text())["raw"]["rows"]
    assert [r["build"] for r in rows] == ["in memory", "out of core"]
    assert rows[0]["points"] == rows[1]["points"] == 300_000 and rows[0]["nodes"] == rows[1]["nodes"]


def test_mainthread_bench_runs(tmp_path):
    """bench.mainthread times the frames of loading sessions beside the loader alone, a
    row for each count of parser threads, and profiles one session of each (the fast
    format's one session: it holds one attribute). Its 40 functions that took longest
    with what they call: the frame among them, or from Python 3.12 (whose profile holds
    every thread's calls, and on the H100 machine's 16 cores left out the frame whatever
    the count) functions of the package's own modules."""
    from bench import mainthread

    out = tmp_path / "out"
    assert mainthread.main(["--points", "30000", "--repeats", "1", "--size", "96x64", "--label", "test",
                            "--cache", str(tmp_path / "cache"), "--out", str(out), "--profile", "40",
                            "--parser-threads", "1", "2"]) == 0
    rows = json.loads((out / "mainthread.json").read_text())["raw"]["rows"]
    expected = [(f, t, s) for f in ("LAS", "LAZ", "fast") for t in (1, 2)
                for s in (("shown",) if f == "fast" else ("shown", "viewer, others later"))]
    assert [(r["format"], r["parser_threads"], r["session"]) for r in rows] == expected
    for r in rows:
        assert r["loaded_s"] >= r["frames_wall_s"] > 0 and r["frames"] >= 1 and r["loader_alone_s"] > 0
        assert 0 < r["frames_cpu_s"] <= r["frames_wall_s"] * 1.05
    suffixes = {"LAS": "las", "LAZ": "laz", "fast": "prg"}
    for fmt, threads, session in expected:
        session = session.split(",")[0]
        head, *rest = (out / f"profile_{fmt}_{threads}_{session}.txt").read_text().splitlines()
        assert head.startswith(f"autzen_trim_x30000.{suffixes[fmt]}, session {session}") and "(profiled: " in head
        assert any("function calls" in line for line in rest)
        ours = str(Path(progressive.__file__).parent) + os.sep if sys.version_info >= (3, 12) else "(frame)"
        assert any(ours in line for line in rest), ours


def test_plan_bench_runs(tmp_path):
    """bench.plan times residency plans of synthetic hierarchies, their nodes resident."""
    from bench import plan

    assert plan.main(["--levels", "3", "5", "--rounds", "2", "--repeats", "1", "--out", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "local" / "plan.json").read_text())["rows"]
    assert [r[0] for r in rows] == [21, 341] and all(r[1] > 0 and r[2] > 0 and r[4] > 0 for r in rows)


def test_startup_bench_times_scaled_files(tmp_path, monkeypatch):
    """bench.startup --scaled: the phases to the first image of the sample tiled as LAS,
    LAZ and fast format, each in a fresh process (the files made in a cache of the test's)."""
    from bench import data, startup

    made = data.scaled(30_000, cache=tmp_path / "cache")
    monkeypatch.setattr(data, "scaled", lambda points: made)
    assert startup.main(["--scaled", "30000", "--commands", "view", "--caches", "Mesa + program cache",
                         "--repeats", "1", "--width", "96", "--height", "64", "--out", str(tmp_path / "out")]) == 0
    rows = json.loads((tmp_path / "out" / "startup_30000.json").read_text())["raw"]["rows"]
    assert [r["file"] for r in rows] == [p.name for p in (made.las, made.laz, made.fast)]
    assert all(r["median"]["process"] > r["median"]["first_frame"] > 0 for r in rows)
    monkeypatch.setattr(data, "tiled", lambda points, compress: made.laz if compress else made.las)
    assert startup.main(["--scaled", "30000", "--laz-only", "--commands", "view", "--caches", "Mesa + program cache",
                         "--repeats", "1", "--width", "96", "--height", "64", "--out", str(tmp_path / "laz")]) == 0
    rows = json.loads((tmp_path / "laz" / "startup_30000.json").read_text())["raw"]["rows"]
    assert [r["file"] for r in rows] == [made.laz.name]


def test_upload_bench_runs(tmp_path):
    """bench.upload: ring and copy, each for the loads and a headless start whose session
    reports (SessionStatus.staging) the staging it was given."""
    from bench import upload
    from progressive.passes.distribute import Staging

    assert upload.main(["--points", "20000", "--repeats", "1", "--startup-repeats", "1", "--width", "96",
                        "--height", "64", "--out", str(tmp_path)]) == 0
    payload = json.loads((tmp_path / "upload.json").read_text())
    starts = payload["raw"]["startup"]
    assert {staging: [run["staging"] for run in runs] for staging, runs in starts.items()} == \
        {s.value: [s.value] for s in Staging}


def test_upload_pieces_are_loader_batches_of_consecutive_tiles():
    """bench.upload stages the GPU side in pieces of about a loader batch: consecutive
    tiles joined (a gap in the starts ends a piece), every record once, in order."""
    from bench.upload import loader_pieces
    from progressive.loaders.types import BATCH_POINTS

    tile = 120_000
    starts = [k * tile for k in range(9)] + [20 * tile]
    tiles = [(start, np.full((tile, 4), start, np.uint32)) for start in starts]
    pieces = loader_pieces(tiles)
    assert [start for start, _ in pieces] == [0, 5 * tile, 20 * tile]
    assert all(rec.shape[0] < BATCH_POINTS + tile for _, rec in pieces)
    assert np.array_equal(np.concatenate([rec for _, rec in pieces]), np.concatenate([rec for _, rec in tiles]))


def test_stream_bench_runs(tmp_path):
    """bench.stream on the sample converted to COPC (cached, so a second run reuses it):
    after a warm-up session (its first image reported), for the file and over HTTP (a
    session for each number of requests in flight, each answer 5 ms late), the overview
    and each leg of the path settle and converge within the limit's room, and the HTTP
    rows count what was fetched."""
    from bench import stream

    args = ["--points", "110000", "--limit", "9M", "--size", "96x64", "--frames", "3", "--still-seconds", "60",
            "--cache", str(tmp_path / "cache"), "--out", str(tmp_path), "--http-requests", "2", "3",
            "--http-latency", "5"]
    assert stream.main(args) == 0
    payload = json.loads((tmp_path / "stream.json").read_text())
    assert payload["name"] == "stream" and payload["run"]["device"] and payload["columns"] == list(stream.COLUMNS)
    rows = [dict(zip(stream.COLUMNS, r)) for r in payload["rows"]]
    legs = ["overview", "zoom in", "fly along", "zoom out"]
    assert [(r["source"], r["leg"]) for r in rows] == [(s, leg) for s in ("file", "HTTP 2", "HTTP 3") for leg in legs]
    assert all(r["converged s"] is not None and r["1 px detail s"] <= r["settled s"] <= r["converged s"] for r in rows)
    assert all(r["moving frames"] == (0 if r["leg"] == "overview" else 3) for r in rows)
    raw = payload["raw"]
    assert raw["built"]["points"] == 110_000 and not raw["built"]["cached"]
    assert raw["warm_up"]["first_image_s"] > 0 and "programs" in raw["warm_up"]["startup"]
    assert sorted(raw["http"]) == ["2", "3"] and raw["http_latency_s"] == 0.005
    ceiling = raw["decode_ceiling"]     # every point of the file, decoded with the layers the stream read
    assert ceiling["points"] == 110_000 and ceiling["names"] == raw["file"]["names"] and ceiling["points_per_s"] > 0
    for run in (raw["file"], *raw["http"].values()):
        assert 0 < run["resident_points"] <= run["capacity_points"]
        assert all(leg["nodes_read"] >= leg["resident_nodes"] for leg in run["legs"])
    assert all(r["MB fetched"] > 0 and r["requests"] > 0 for r in rows if r["source"].startswith("HTTP"))
    assert all(r["MB fetched"] is None for r in rows if r["source"] == "file")
    assert stream.build(110_000, tmp_path / "cache").cached
    md = (tmp_path / "stream.md").read_text()
    assert md.startswith("# ") and "N: 110,000" in md and "Decode ceiling, measured after the runs" in md
    assert {line.count("|") for line in md.splitlines() if line.startswith("|")} == {len(stream.COLUMNS) + 1}


def test_stream_bench_builds_from_laz_alone(tmp_path, capsys):
    """--laz --build-only: the sample tiled as LAZ, converted to COPC, the LAZ removed, and
    nothing streamed (the 1 B-point file takes a device call of its own)."""
    from bench import stream

    cache = tmp_path / "cache"
    assert stream.main(["--points", "120000", "--laz", "--build-only", "--cache", str(cache)]) == 0
    assert "120,000 points" in capsys.readouterr().out
    assert sorted(p.name for p in cache.iterdir()) == ["autzen_trim_x120000.copc.json", "autzen_trim_x120000.copc.laz"]
    assert stream.build(120_000, cache).cached


def test_detail_bench_runs(tmp_path):
    """bench.detail on the sample converted to COPC: a row for each finest detail, a
    coarser one reading no more points, shares of the reference's covered pixels."""
    from bench import detail
    from conftest import SAMPLE
    from progressive.cli import main as cli

    copc = tmp_path / "sample.copc.laz"
    assert cli(["convert", str(SAMPLE), str(copc)]) == 0
    table, info = detail.run([(copc, (160, 120))], 0.5, (0.0, 4.0))
    rows = table.raw["rows"]
    assert [r["detail_px"] for r in rows] == [0.0, 4.0] and info.device
    assert 0 < rows[1]["resident_points"] <= rows[0]["resident_points"] <= rows[0]["points"] // 2 + 1
    for r in rows:
        assert r["covered"] > 0 and 0 <= r["empty"] + r["other"] <= 1 and 0 <= r["rgb"] <= 255
    assert len(table.rows) == 2


def test_committed_headlines_are_built_from_their_folders_json():
    """Each committed results folder's headline.md, and the README's copy of it, is what
    bench.headline builds from that folder's tables, whose JSON is committed plain or,
    where large, xz-compressed (NAME.json.xz)."""
    results = Path(__file__).resolve().parents[1] / "bench" / "results"
    readme = headline.README.read_text()
    folders = [f for f in sorted(results.iterdir()) if (f / "headline.md").exists()]
    assert any(list(f.glob("*.json.xz")) for f in folders)      # the compressed form is read too
    for folder in folders:
        text = headline.build(folder)
        assert text == (folder / "headline.md").read_text(), folder.name
        assert f"<!-- bench:headline:{folder.name} -->\n{text.rstrip()}\n<!-- /bench:headline:{folder.name} -->" in readme
