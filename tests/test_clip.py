"""Clip boxes and slabs: every rasterizer draws exactly the float64 render contract of
the points inside (the test on stored float32 positions, progressive/camera.py Clip),
progressive frames converge to the clipped brute-force render, batches outside the box
are culled, and bad boxes are one line."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from progressive.attributes import find_attribute
from progressive.budget import BudgetParams
from progressive.camera import NO_CLIP, CameraError, Clip, auto_camera, view_uniforms
from progressive.cli import main
from progressive.frame_loop import ProgressiveOptions, ProgressiveRenderer
from progressive.permutation import BATCH_POINTS
from progressive.reference import EMPTY, subset_reference_ids
from progressive.renderer import Raster, Renderer
from progressive.scene import Scene

W, H = 160, 120


@pytest.fixture(scope="module")
def sample(sample_batches):
    info, parts = sample_batches
    positions = np.concatenate([b.positions for b in parts])
    return info, parts, positions


def clips(info) -> dict[str, Clip]:
    lo, hi = info.bounds_min, info.bounds_max
    size = hi - lo
    return {
        "box": Clip(tuple(lo + size * [0.2, 0.3, 0.0]), tuple(lo + size * [0.6, 0.7, 0.4])),
        "slab": Clip((-math.inf, -math.inf, lo[2] + 0.1 * size[2]), (math.inf, math.inf, lo[2] + 0.3 * size[2])),
        "outside": Clip(tuple(hi + 1), tuple(hi + 2)),
    }


def expected_ids(info, positions, cam, clip: Clip, perm) -> np.ndarray:
    """The contract's ids over the points the clip keeps (ties by slot, as the GPU)."""
    kept = np.nonzero(clip.keeps(positions, info.origin))[0]
    slots = perm.forward(np.arange(positions.shape[0])).astype(np.int64)
    return subset_reference_ids(positions.astype(np.float64) + info.origin, kept, cam, W, H, slots)


@pytest.mark.parametrize("raster", [Raster.COMPUTE, Raster.COMPUTE32, Raster.POINTS])
@pytest.mark.parametrize("name", ["box", "slab", "outside"])
def test_clipped_ids_equal_the_reference(gl, sample, raster, name):
    info, parts, positions = sample
    clip = clips(info)[name]
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    r = Renderer(gl, info, find_attribute(info, "elevation"), raster=raster, width=W, height=H)
    try:
        for b in parts:
            r.add_batch(b)
        ids = r.render(cam, W, H, r.style(), clip=clip).ids
        expected = expected_ids(info, positions, cam, clip, r.store.permutation)
        assert np.mean(ids == expected) >= 0.999
        if name == "outside":
            assert (ids == EMPTY).all()
        else:
            assert 0 < np.count_nonzero(ids != EMPTY) < np.count_nonzero(r.render(cam, W, H, r.style()).ids != EMPTY)
        assert gl.ctx.error == "GL_NO_ERROR"
    finally:
        r.release()


def test_progressive_converges_to_the_clipped_brute_force_render(gl, sample):
    info, parts, _ = sample
    attr = find_attribute(info, "elevation")
    scene = Scene(gl, info, attr)
    brute = Renderer(gl, info, attr, width=W, height=H, scene=scene)
    pr = ProgressiveRenderer(gl, info, attr, ProgressiveOptions(W, H, budget=BudgetParams(fixed=20_000)), scene=scene)
    try:
        for b in parts:
            scene.add_batch(b)
        cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
        style = scene.style()
        for clip in (clips(info)["box"], NO_CLIP, clips(info)["slab"]):     # a clip change starts the image again
            expected = brute.render(cam, W, H, style, clip=clip).ids
            for _ in range(scene.store.capacity // 20_000 + 3):
                pr.frame(cam, style, clip=clip)
            pr.flush()
            assert pr.converged
            assert np.array_equal(pr.read_ids(), expected)
    finally:
        pr.release()
        brute.release()
        scene.release()


def test_batches_outside_the_clip_are_culled(sample):
    from progressive import batches

    info, _, positions = sample
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    _, grown = batches.boxes_of(positions, 0)
    everything = batches.in_view(grown, view_uniforms(cam, info.origin, W, H))
    outside = batches.in_view(grown, view_uniforms(cam, info.origin, W, H, clip=clips(info)["outside"]))
    box = batches.in_view(grown, view_uniforms(cam, info.origin, W, H, clip=clips(info)["box"]))
    assert everything.all() and not outside.any()
    keeps = clips(info)["box"].keeps(positions, info.origin)
    with_points = np.unique(np.nonzero(keeps)[0] // BATCH_POINTS)
    assert box[with_points].all() and box.sum() < everything.sum()


def test_clip_must_be_a_box():
    with pytest.raises(CameraError):
        Clip((0, 0, 1), (1, 1, 0))
    with pytest.raises(CameraError):
        Clip((0, math.nan, 0), (1, 1, 1))
    both = Clip((0, 0, 0), (10, 10, 10)).intersect(Clip((-math.inf, -math.inf, 2), (math.inf, math.inf, 3)))
    assert both == Clip((0, 0, 2), (10, 10, 3))


def test_cli_clip_options(tmp_path, capsys):
    stats = tmp_path / "s.json"
    assert main(["render", "--width", str(W), "--height", str(H), "--clip-z", "420,440",
                 "--clip-box=-1e9,-1e9,-1e9,1e9,1e9,430", "--stats", str(stats)]) == 0
    clip = json.loads(stats.read_text())["clip"]
    assert clip == {"min": [-1e9, -1e9, 420.0], "max": [1e9, 1e9, 430.0]}
    for bad in (["--clip-z", "5"], ["--clip-z", "5,nan"], ["--clip-box", "1,2,3,0,5,6"], ["--clip-z", "9,1"],
                ["--clip-box", "0,0,0,1,1,1", "--clip-z", "5,6"]):
        capsys.readouterr()
        assert main(["render", "--out", str(tmp_path / "x.png"), *bad]) == 2
        err = capsys.readouterr().err
        assert err.startswith("progressive: error: ") and err.count("\n") == 1
    assert not (tmp_path / "x.png").exists()
