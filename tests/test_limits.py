"""Resource limits: a cloud larger than the GPU (or a configured limit) shows a
uniform random subset and says so; frames of any size; no leaks over many frames."""

from __future__ import annotations

import dataclasses
import gc
import json
import math
import os

import laspy
import moderngl
import numpy as np

from conftest import SAMPLE
from progressive import memory
from progressive.cli import main
from progressive.permutation import LAYOUT, Permutation
from progressive.reference import EMPTY, reference_ids, subset_reference_ids

SMALL = ["--width", "160", "--height", "120"]


def limit_for(points: int, pixels: int = 160 * 120) -> int:
    return memory.bytes_for(points, pixels)


def test_plan(gl):
    caps = gl.caps
    assert memory.plan(1000, dataclasses.replace(caps, free_memory_kib=None), 100).capacity == 1000
    limited = memory.plan(110_000, caps, 160 * 120, limit_for(40_000))
    assert limited.capacity == 40_000 and limited.subset and "40,000 of 110,000" in limited.message()
    nvx = dataclasses.replace(caps, free_memory_kib=limit_for(5000) // 1024 + 1)
    assert memory.plan(10**9, nvx, 160 * 120).capacity < 10_000
    assert memory.plan(10, caps, 10**6, 1000).capacity == 0


def test_plan_takes_the_default_given_where_no_limit_is(gl):
    """default_bytes (a streamed cloud's STREAM_BYTES) stands where no limit is
    configured, less where the driver reports less free, and says so."""
    unknown = dataclasses.replace(gl.caps, free_memory_kib=None)
    default = memory.plan(10**9, unknown, 160 * 120, default_bytes=limit_for(5000))
    assert default.capacity == 5000 and default.subset and "by default" in default.message()
    assert memory.plan(10**9, unknown, 160 * 120, limit_for(7000), default_bytes=limit_for(5000)).capacity == 7000
    free = dataclasses.replace(gl.caps, free_memory_kib=limit_for(2_000_000) // 1024)
    assert memory.plan(10**9, free, 160 * 120, default_bytes=limit_for(5000)).capacity == 5000
    reported = memory.plan(10**9, free, 160 * 120, default_bytes=limit_for(4_000_000))
    assert 5000 < reported.capacity < 2_000_000 and reported.source == "free GPU memory"
    assert memory.plan(1000, unknown, 160 * 120, default_bytes=limit_for(5000)).capacity == 1000


def test_a_software_renderer_streams_within_less_by_default(gl):
    """A streamed cloud's default memory: SOFTWARE_STREAM_BYTES on a rasterizer that runs
    on the CPU (its buffers are host memory zeroed when made), STREAM_BYTES on a GPU."""
    named = {name: dataclasses.replace(gl.caps, renderer=name)
             for name in ("llvmpipe (LLVM 15.0.6, 256 bits)", "softpipe", "NVIDIA H200/PCIe/SSE2", "AMD Radeon RX 7900 XTX")}
    assert [c.software for c in named.values()] == [True, True, False, False]
    assert [memory.stream_bytes(c) for c in named.values()] == [memory.SOFTWARE_STREAM_BYTES] * 2 + [memory.STREAM_BYTES] * 2
    assert memory.SOFTWARE_STREAM_BYTES < memory.STREAM_BYTES
    assert gl.caps.software == ("llvmpipe" in gl.caps.renderer)


def test_a_cloud_beyond_the_drivers_buffers_shows_a_subset(tmp_path, capsys, monkeypatch):
    """A cloud larger than the store's buffers may hold on the driver (MAX_POINT_CHUNKS
    of its largest: llvmpipe's hold 67 M points, and a larger cloud was an error) shows
    the uniform random subset they hold, with the warning naming why."""
    from progressive import context
    from progressive.bindings import MAX_POINT_CHUNKS
    from progressive.loaders.records import RECORD_BYTES
    from progressive.pointstore import BLOCK_RECORDS

    real = context.read_capabilities
    small = 2 * BLOCK_RECORDS * RECORD_BYTES        # buffers of two blocks: 65,536 points in all
    monkeypatch.setattr(context, "read_capabilities", lambda *a: dataclasses.replace(real(*a), max_ssbo_bytes=small))
    stats = tmp_path / "s.json"
    code = main(["render", *SMALL, str(SAMPLE), "--out", str(tmp_path / "a.png"), "--stats", str(stats)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert f"at most {MAX_POINT_CHUNKS} buffers" in err and "uniform random subset" in err
    assert 0 < json.loads(stats.read_text())["points_on_gpu"] <= MAX_POINT_CHUNKS * 2 * BLOCK_RECORDS < 110_000


def test_subset_is_uniform_and_rendered_exactly(tmp_path, capsys):
    ids_path, stats_path = tmp_path / "ids.npy", tmp_path / "s.json"
    # file order: the kept points are then the permutation's, computed here from file indices
    code = main(["render", *SMALL, str(SAMPLE), "--gpu-memory-limit", str(limit_for(40_000)), "--batch-order", "file",
                 "--ids", str(ids_path), "--stats", str(stats_path), "--save-camera", str(tmp_path / "c.json")])
    err = capsys.readouterr().err
    assert code == 0, err
    perm = Permutation.for_count(110_000, order=LAYOUT)
    kept = np.nonzero(perm.forward(np.arange(110_000)) < 40_000)[0]
    assert 39_000 < kept.size <= 40_000       # the layout pads the last batch: some slots hold no point
    assert f"uniform random subset of {kept.size:,} of 110,000" in err and err.startswith("progressive: warning:")
    assert json.loads(stats_path.read_text())["points_on_gpu"] == kept.size
    per_tenth = np.histogram(kept, bins=10, range=(0, 110_000))[0]
    assert per_tenth.min() > 0.8 * 4000 and per_tenth.max() < 1.2 * 4000, per_tenth
    las = laspy.read(SAMPLE)
    xyz = np.stack([las.x, las.y, las.z], axis=1)
    from progressive.camera import Camera

    cam = Camera.from_json((tmp_path / "c.json").read_text())
    ids = np.load(ids_path)
    ref = subset_reference_ids(xyz, kept, cam, 160, 120, perm.forward(np.arange(110_000)).astype(np.int64))
    assert np.mean(ids == ref) >= 0.999


def test_progressive_converges_on_a_subset(tmp_path, capsys):
    stats = tmp_path / "s.json"
    code = main(["render", *SMALL, str(SAMPLE), "--method", "progressive", "--budget", "7000", "--converge",
                 "--gpu-memory-limit", str(limit_for(30_000)), "--stats", str(stats)])
    assert code == 0, capsys.readouterr().err
    s = json.loads(stats.read_text())
    kept = Permutation.for_count(110_000, order=LAYOUT).kept(30_000)
    assert s["points_on_gpu"] == kept and s["converged_frame"] >= math.ceil(30_000 / 7000) - 1


def test_limit_too_small(tmp_path, capsys):
    code = main(["render", *SMALL, "--gpu-memory-limit", "1M", "--out", str(tmp_path / "x.png")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "no points fit" in err
    assert not (tmp_path / "x.png").exists()


def test_frames_wider_than_2048(gl):
    """The original code drew nothing past 2048 pixels; buffers follow the frame size."""
    from progressive.attributes import default_attribute
    from progressive.camera import auto_camera
    from progressive.loaders import CloudLoader
    from progressive.renderer import Renderer

    with CloudLoader([SAMPLE]) as loader:
        info = loader.info
        r = Renderer(gl, info, default_attribute(info), width=64, height=48)
        loader.start()
        for b in loader:
            r.add_batch(b)
    las = laspy.read(SAMPLE)
    xyz = np.stack([las.x, las.y, las.z], axis=1)
    slots = r.store.slots_of(np.arange(info.points)).astype(np.int64)
    for w, h in ((2300, 2300), (64, 48), (2600, 1400)):
        cam = auto_camera(info.bounds_min, info.bounds_max, w / h)
        ids = r.render(cam, w, h, r.style()).ids
        gl.check()
        assert ids.shape == (h, w)
        if w > 2048:
            assert (ids[:, 2048:] != EMPTY).sum() > 20, "nothing drawn past column 2048"
        assert np.mean(ids == reference_ids(xyz, cam, w, h, tie_key=slots)) >= 0.999
    r.release()


def gpu_objects() -> int:
    gc.collect()
    from progressive.programs import ComputeProgram

    kinds = (moderngl.Buffer, moderngl.Texture, moderngl.Framebuffer, moderngl.ComputeShader, ComputeProgram,
             moderngl.Program, moderngl.VertexArray)
    return sum(isinstance(o, kinds) for o in gc.get_objects())


LEAK_FRAMES = int(os.environ.get("PROGRESSIVE_LEAK_FRAMES", "400"))


def test_no_leaks_over_many_frames(gl):
    """Camera motion, colormap and attribute switches, point size, eye-dome lighting,
    hidden classes and resizes for LEAK_FRAMES frames (400 in CI; 10,000 on the GPU
    machine with PROGRESSIVE_LEAK_FRAMES=10000): GPU objects and fences stay bounded,
    Python memory flat."""
    import tracemalloc

    from progressive.budget import BudgetParams
    from progressive.camera import auto_camera
    from progressive.colors import Colormap
    from progressive.effects import Effects, EyeDome
    from progressive.frame_loop import ProgressiveOptions, ProgressiveRenderer
    from progressive.loaders import CloudLoader

    with CloudLoader([SAMPLE]) as loader:
        info = loader.info
        loader.start()
        batches = list(loader)
    pr = ProgressiveRenderer(gl, info, info.attribute("intensity"),
                             ProgressiveOptions(64, 48, budget=BudgetParams(fixed=5000), frames_in_flight=2,
                                                keep_batches=True))
    for b in batches:
        pr.add_batch(b)
    cam = auto_camera(info.bounds_min, info.bounds_max, 64 / 48)
    maps = list(Colormap)
    attributes = [info.attribute(n) for n in ("intensity", "classification", "rgb", "gps_time")]
    effects = [Effects(), Effects(point_size=3), Effects(eye_dome=EyeDome()), Effects(2, EyeDome(0.5, 2.0))]

    def run(frames, start):
        for k in range(start, start + frames):
            c = cam if k % 3 else dataclasses.replace(cam, position=tuple(np.add(cam.position, (k % 7, 0, 0))))
            if k % 50 == 0:
                pr.resize(64 + 8 * (k // 50 % 2), 48)
            if k % 40 == 20:
                pr.switch_attribute(attributes[k // 40 % len(attributes)])
            hidden = frozenset({2}) if k % 60 < 30 else frozenset()
            pr.frame(c, pr.scene.style(maps[k % len(maps)]), effects[k // 10 % len(effects)], hidden)
            if k % 25 == 0:
                pr._take(pr.stats_ring.collect())

    run(100, 0)
    objects = gpu_objects()
    tracemalloc.start()
    before = tracemalloc.take_snapshot()
    run(LEAK_FRAMES - 100, 100)
    pr.flush()
    pr.history.clear()
    after = tracemalloc.take_snapshot()
    tracemalloc.stop()
    grown = sum(s.size_diff for s in after.compare_to(before, "filename"))
    assert gpu_objects() <= objects + 2
    assert len(pr.stats_ring.pending) == 0 and len(pr._in_flight) <= 2
    assert grown < 2_000_000, f"Python memory grew by {grown} bytes over {LEAK_FRAMES} frames"
    assert pr.scene.switch is not None and pr.scene.switch.streamed > 0
    gl.check()
    pr.release()


def test_tiny_clouds_render_and_converge(tmp_path, capsys):
    """1, 2, 3 and 7 points (no shuffle prime below 3; a ring of one slot): brute force
    and progressive agree, and convergence is reached, not stalled."""
    las = laspy.read(SAMPLE)
    for n in (1, 2, 3, 7):
        small = laspy.LasData(las.header)
        small.points = las.points[:: 110_000 // n][:n].copy()
        path = tmp_path / f"tiny{n}.las"
        small.write(path)
        brute, prog, stats = tmp_path / f"b{n}.npy", tmp_path / f"p{n}.npy", tmp_path / f"s{n}.json"
        assert main(["render", *SMALL, str(path), "--ids", str(brute)]) == 0
        code = main(["render", *SMALL, str(path), "--method", "progressive", "--converge", "--max-frames", "50",
                     "--ids", str(prog), "--stats", str(stats)])
        assert code == 0, capsys.readouterr().err
        assert np.array_equal(np.load(brute), np.load(prog))
        assert 0 < (np.load(brute) != EMPTY).sum() <= n


def tiled(path, copies: int) -> None:
    """The bundled sample side by side `copies` times (the points of a larger survey)."""
    las = laspy.read(SAMPLE)
    header = laspy.LasHeader(point_format=las.header.point_format, version=las.header.version)
    header.scales, header.offsets = las.header.scales, las.header.offsets
    with laspy.open(path, mode="w", header=header) as w:
        for k in range(copies):
            p = las.points.copy()
            p.X = p.X + (k % 8) * 60_000
            p.Y = p.Y + (k // 8) * 60_000
            w.write_points(p)


def peak_rss(path, tmp_path, *args) -> int:
    """--stats' peak resident memory of a render in a process of its own."""
    import subprocess
    import sys

    stats = tmp_path / f"{path.stem}.json"
    subprocess.run([sys.executable, "-m", "progressive", "render", str(path), "--color-by", "elevation", *SMALL,
                    "--stats", str(stats), *args], check=True, capture_output=True, timeout=300)
    return json.loads(stats.read_text())["peak_rss_bytes"]


def test_host_memory_does_not_grow_with_the_cloud(tmp_path):
    """With the GPU limited to a small subset, rendering twice the points takes about
    the same host memory: the pipeline holds a bounded number of batches (about nine
    of them at 4.4 M points; a brute-force render used to hold every batch at once)."""
    small, large = tmp_path / "small.las", tmp_path / "large.las"
    tiled(small, 40)
    tiled(large, 80)
    limit = ["--gpu-memory-limit", "16M"]
    growth = peak_rss(large, tmp_path, *limit) - peak_rss(small, tmp_path, *limit)
    one_batch = memory.BATCH_POINTS * 90        # raw records, positions and attributes of one batch, roughly
    assert growth < one_batch, f"peak RSS grew by {growth / 2**20:.0f} MiB for 4.4 M more points"
