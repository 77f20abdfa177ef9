"""Clip boxes, slabs and sections: every rasterizer draws exactly the float64 render
contract of the points inside (the test on stored float32 positions, progressive/camera.py
Clip; a section against laspy's coordinates in float64), progressive frames converge to
the clipped brute-force render, batches outside the clip are culled and batches holding
a kept point never are, and bad boxes and sections are one line."""

from __future__ import annotations

import contextlib
import json
import math

import laspy
import numpy as np
import pytest

from conftest import SAMPLE, shared_file
from progressive.attributes import find_attribute
from progressive.budget import BudgetParams
from progressive.camera import NO_CLIP, CameraError, Clip, Section, auto_camera, section_keeps, view_uniforms
from progressive.cli import main
from progressive.frame_loop import ProgressiveOptions, ProgressiveRenderer
from progressive.passes.cull import CullPass
from progressive.permutation import BATCH_POINTS
from progressive.reference import EMPTY, clipped_reference_ids, subset_reference_ids
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
        "section": Clip(section=sections(info)["diagonal"]),
    }


def sections(info) -> dict[str, Section]:
    """A diagonal section across the sample, one along y, and a thin one."""
    lo, size = info.bounds_min, info.bounds_max - info.bounds_min
    at = lambda fx, fy: (float(lo[0] + fx * size[0]), float(lo[1] + fy * size[1]))  # noqa: E731
    diagonal = float(np.hypot(size[0], size[1]))
    return {
        "diagonal": Section(at(0.15, 0.25), at(0.85, 0.7), 0.04 * diagonal),
        "along y": Section(at(0.5, 0.9), at(0.5, 0.1), 0.02 * diagonal),
        "thin": Section(at(0.3, 0.3), at(0.7, 0.55), 0.002 * diagonal),
    }


@pytest.fixture(scope="module")
def las_xyz():
    las = laspy.read(SAMPLE)
    return np.stack([las.x, las.y, las.z], axis=1).astype(np.float64)


@contextlib.contextmanager
def loaded(gl, info, parts, raster):
    """A brute-force renderer of the cloud coloured by elevation, every batch added."""
    r = Renderer(gl, info, find_attribute(info, "elevation"), raster=raster, width=W, height=H)
    try:
        for b in parts:
            r.add_batch(b)
        yield r
    finally:
        r.release()


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
    with loaded(gl, info, parts, raster) as r:
        ids = r.render(cam, W, H, r.style(), clip=clip).ids
        expected = expected_ids(info, positions, cam, clip, r.store.permutation)
        assert np.mean(ids == expected) >= 0.999
        if name == "outside":
            assert (ids == EMPTY).all()
        else:
            assert 0 < np.count_nonzero(ids != EMPTY) < np.count_nonzero(r.render(cam, W, H, r.style()).ids != EMPTY)
        assert gl.ctx.error == "GL_NO_ERROR"


@pytest.mark.parametrize("raster", [Raster.COMPUTE, Raster.COMPUTE32])
def test_only_a_view_with_a_filter_draws_with_the_filter_tests(gl, sample, raster):
    """The compute raster's programs without filter tests draw views without a filter
    (llvmpipe would run the tests on every point); those with them are built when the
    first filtered view draws, and the image without the clip comes back unchanged."""
    info, parts, _ = sample
    if raster is Raster.COMPUTE and not gl.caps.atomic_int64:
        pytest.skip("no GL_NV_shader_atomic_int64")
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    with loaded(gl, info, parts, raster) as r:
        whole = r.render(cam, W, H, r.style()).ids
        assert r.raster.built and not any(label.endswith("filtered") for label in r.raster.built)
        clipped = r.render(cam, W, H, r.style(), clip=clips(info)["box"]).ids
        assert any(label.endswith("filtered") for label in r.raster.built)
        assert np.count_nonzero(clipped != EMPTY) < np.count_nonzero(whole != EMPTY)
        assert np.array_equal(r.render(cam, W, H, r.style()).ids, whole)
        assert gl.ctx.error == "GL_NO_ERROR"


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
        section = clips(info)["section"]
        for clip in (clips(info)["box"], NO_CLIP, clips(info)["slab"], section,
                     section.intersect(clips(info)["slab"])):     # a clip change starts the image again
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


@pytest.mark.parametrize("raster", [Raster.COMPUTE, Raster.COMPUTE32, Raster.POINTS])
@pytest.mark.parametrize("name", ["diagonal", "along y", "thin", "diagonal and slab"])
def test_section_ids_equal_the_float64_reference(gl, sample, las_xyz, raster, name):
    """The float64 render contract over the points inside the section by its float64
    test on laspy's coordinates; every point shown passes the float32 twin."""
    info, parts, positions = sample
    section = sections(info)[name.removesuffix(" and slab")]
    clip = Clip(section=section).intersect(clips(info)["slab"]) if name.endswith("slab") else Clip(section=section)
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    with loaded(gl, info, parts, raster) as r:
        ids = r.render(cam, W, H, r.style(), clip=clip).ids
        slots = r.store.slots_of(np.arange(positions.shape[0])).astype(np.int64)
        expected = clipped_reference_ids(las_xyz, clip, cam, W, H, slots)
        assert np.mean(ids == expected) >= 0.999
        shown = ids[ids != EMPTY]
        assert shown.size > 0 and clip.keeps(positions[shown], info.origin).all()
        assert shown.size < np.count_nonzero(r.render(cam, W, H, r.style()).ids != EMPTY)
        assert gl.ctx.error == "GL_NO_ERROR"


def test_section_on_a_utm_file_equals_the_float64_reference(gl):
    """A Toronto tile in UTM (northings near 4.8 million): a diagonal section's ids
    equal the float64 contract over laspy's coordinates inside it, for compute,
    compute32 and GL_POINTS, and a progressive view converges to the brute-force one."""
    from progressive.loaders import CloudLoader

    path = shared_file("TO_core_last_zoom.laz")
    with CloudLoader([path], batch_points=50_000) as loader:
        info = loader.info
        loader.start()
        parts = sorted(loader, key=lambda b: b.start)
    las = laspy.read(path)
    xyz = np.stack([las.x, las.y, las.z], axis=1).astype(np.float64)
    lo, size = info.bounds_min, info.bounds_max - info.bounds_min
    clip = Clip(section=Section((lo[0] + 0.1 * size[0], lo[1] + 0.8 * size[1]),
                                (lo[0] + 0.9 * size[0], lo[1] + 0.2 * size[1]), 0.03 * float(np.hypot(*size[:2]))))
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    attr = find_attribute(info, "elevation")
    scene = Scene(gl, info, attr)
    try:
        for b in parts:
            scene.add_batch(b)
        slots = scene.store.slots_of(np.arange(info.points)).astype(np.int64)
        expected = clipped_reference_ids(xyz, clip, cam, W, H, slots)
        assert np.count_nonzero(expected != EMPTY) > 100
        brute = {}
        for raster in (Raster.COMPUTE, Raster.COMPUTE32, Raster.POINTS):
            r = Renderer(gl, info, attr, raster=raster, width=W, height=H, scene=scene)
            try:
                brute[raster] = r.render(cam, W, H, r.style(), clip=clip).ids
            finally:
                r.release()
            assert np.mean(brute[raster] == expected) >= 0.999, raster
        pr = ProgressiveRenderer(gl, info, attr, ProgressiveOptions(W, H, budget=BudgetParams(fixed=50_000)),
                                 scene=scene)
        try:
            for _ in range(scene.store.capacity // 50_000 + 3):
                pr.frame(cam, scene.style(), clip=clip)
            pr.flush()
            assert pr.converged and np.array_equal(pr.read_ids(), brute[Raster.COMPUTE])
        finally:
            pr.release()
        assert gl.ctx.error == "GL_NO_ERROR"
    finally:
        scene.release()


def test_section_twin_agrees_with_float64(sample, las_xyz):
    """The float32 test (the shaders' twin) differs from the float64 one only within
    float32 rounding of the boundary: a handful of points at most."""
    info, _, positions = sample
    for section in sections(info).values():
        clip = Clip(section=section)
        f32, f64 = clip.keeps(positions, info.origin), clip.contains(las_xyz)
        assert f64.sum() > 0 and np.count_nonzero(f32 != f64) <= max(2, f64.sum() // 10_000)
        # the float64 test against numpy's own distance to the segment's line
        a, b = np.asarray(section.start), np.asarray(section.end)
        q = las_xyz[:, :2] - a
        along = q @ (b - a) / np.sum((b - a) ** 2)
        across = np.abs(np.cross(np.c_[np.broadcast_to(b - a, q.shape), np.zeros(len(q))],
                                 np.c_[q, np.zeros(len(q))])[:, 2]) / np.linalg.norm(b - a)
        inside = (along >= 0) & (along <= 1) & (across <= section.width / 2)
        margin = np.abs(across - section.width / 2) > 1e-6
        np.testing.assert_array_equal(f64[margin], inside[margin])


@pytest.mark.parametrize("name", ["along y", "thin"])
def test_culling_never_drops_a_point_inside_the_section(gl, sample, name):
    """The GPU's flags (cull.comp) equal the numpy twin's, keep every batch holding a
    point the section keeps, and drop some of the others."""
    from progressive import batches

    info, parts, positions = sample
    clip = Clip(section=sections(info)[name])
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    scene = Scene(gl, info, find_attribute(info, "elevation"))
    cull = CullPass(gl, scene.store)
    try:
        for b in parts:
            scene.add_batch(b)
        view = view_uniforms(cam, info.origin, W, H, clip=clip)
        cull.run(view)
        n = scene.store.permutation.batches
        flags = np.frombuffer(cull.flags.read(), dtype=np.uint32)[:n] != 0
        twin = batches.in_view(scene.store.boxes, view)
        np.testing.assert_array_equal(flags, twin)
        held = np.unique(np.nonzero(clip.keeps(positions, info.origin))[0] // BATCH_POINTS)
        assert flags[held].all() and flags.sum() < np.count_nonzero(batches.in_view(scene.store.boxes, view_uniforms(
            cam, info.origin, W, H)))
        assert gl.ctx.error == "GL_NO_ERROR"
    finally:
        cull.release()
        scene.release()


def test_section_culling_is_conservative_at_the_edges():
    """Boxes just touching the section's rectangle (a side, an end, a corner) are kept;
    boxes a clear gap away are culled; without a section nothing is."""
    from progressive import batches

    section = Section((1000.0, 2000.0), (1300.0, 2400.0), 10.0)       # axis (0.6, 0.8), normal (-0.8, 0.6)
    origin = np.array([900.0, 1900.0, 0.0])
    cam = auto_camera(np.array([900.0, 1900.0, -10.0]), np.array([1500.0, 2600.0, 10.0]), W / H)
    view = view_uniforms(cam, origin, W, H, clip=Clip(section=section))
    u, nrm = np.array([0.6, 0.8]), np.array([-0.8, 0.6])
    a = np.array([1000.0, 2000.0]) - origin[:2]

    def box(centre, half):
        b = batches.empty_boxes(1)
        b[0, 0:2], b[0, 4:6] = centre - half, centre + half
        b[0, 2], b[0, 6] = -1.0, 1.0
        return b

    touching = [a + nrm * (5.0 + 1.0), a + u * 500.0 + u * 1.0, a - u * 1.0 + nrm * 5.0]
    away = [a + nrm * (5.0 + 3.0), a + u * (500.0 + 3.0), a - u * 3.0 - nrm * 8.0]
    half = 1.0 / np.sqrt(2.0) * np.ones(2)          # corner distance along u or n: at most |half|·(|ux|+|uy|) = 0.99
    for c in touching:
        assert batches.section_meets(box(c, half * 1.02), view).all(), c
    for c in away:
        assert not batches.section_meets(box(c, half), view).any(), c
    assert batches.section_meets(box(a + nrm * 1e6, half), view_uniforms(cam, origin, W, H)).all()
    # points on the rectangle's edge are kept by the twin (sides inclusive)
    line, extent = section.uniforms(origin)
    assert section_keeps(np.array([[*(a + u * 100.0), 0.0]], dtype=np.float32), line, extent).all()


def test_section_must_be_a_segment_with_a_width():
    for bad in (((0, 0), (0, 0), 1.0), ((0, 0), (1, 0), 0.0), ((0, 0), (1, 0), -1.0), ((0, math.nan), (1, 0), 1.0),
                ((0, 0), (1, 0), math.inf), ((0, 0), (1e16, 0), 1.0)):
        with pytest.raises(CameraError):
            Section(*bad)
    s = Section((0, 0), (3, 4), 2.0)
    assert Clip(section=s).intersect(NO_CLIP).section == s
    with pytest.raises(CameraError):
        Clip(section=s).intersect(Clip(section=Section((0, 0), (4, 3), 2.0)))


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
    assert clip == {"min": [-1e9, -1e9, 420.0], "max": [1e9, 1e9, 430.0], "section": None}
    for bad in (["--clip-z", "5"], ["--clip-z", "5,nan"], ["--clip-box", "1,2,3,0,5,6"], ["--clip-z", "9,1"],
                ["--clip-box", "0,0,0,1,1,1", "--clip-z", "5,6"]):
        capsys.readouterr()
        assert main(["render", "--out", str(tmp_path / "x.png"), *bad]) == 2
        err = capsys.readouterr().err
        assert err.startswith("progressive: error: ") and err.count("\n") == 1
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("orthographic", [False, True])
def test_pixel_ray_inverts_screen_points(orthographic):
    """Points along the ray through an image position project back onto it (both
    projections), and screen_points floors to camera.project's pixels."""
    from progressive.camera import Camera, Projection, pixel_ray, project, screen_points

    extra = {"projection": Projection.ORTHOGRAPHIC, "height": 40.0} if orthographic else {}
    cam = Camera((100.0, -50.0, 30.0), (5.0, 7.0, 1.0), near=0.5, far=1e4, **extra)
    rng = np.random.default_rng(3)
    for x, y in rng.uniform([0, 0], [W, H], size=(20, 2)):
        origin, d = pixel_ray(cam, x, y, W, H)
        assert np.linalg.norm(d) == pytest.approx(1.0)
        points = origin + np.outer([5.0, 50.0, 500.0], d)
        xy, depth = screen_points(cam, points, W, H)
        np.testing.assert_allclose(xy, np.broadcast_to([x, y], xy.shape), atol=1e-7)
        pixel, _ = project(cam, points, W, H)
        assert (pixel == int(y) * W + int(x)).all() and np.all(np.diff(depth) > 0)


def test_clip_box_on_screen_and_its_drag():
    """The box's 12 edges end at its corners' screen positions; an edge crossing the near
    plane is cut there; a face whose normal points along the view cannot be grabbed; a
    drag moves the face by the cursor's travel along its axis, never past the opposite
    face, and keeps the section."""
    from progressive.camera import Camera, Projection, screen_points
    from progressive.viewer import clipbox

    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([10.0, 20.0, 5.0])
    cam = Camera((40.0, -30.0, 25.0), (5.0, 10.0, 2.5), near=1.0, far=1e3)
    edges = clipbox.box_edges(cam, lo, hi, (W, H))
    corners = np.array([[(hi if c >> k & 1 else lo)[k] for k in range(3)] for c in range(8)])
    xy, _ = screen_points(cam, corners, W, H)
    ends = {tuple(np.round(p, 9)) for e in edges for p in e}
    assert len(edges) == 12 and ends == {tuple(np.round(p, 9)) for p in xy}
    inside = Camera((5.0, 10.0, 2.5), (5.0, 30.0, 2.5), near=1.0, far=1e3)          # the eye in the box
    cut = clipbox.box_edges(inside, lo, hi, (W, H))
    assert 0 < len(cut) < 12
    for a, b in cut:
        assert np.isfinite(a).all() and np.isfinite(b).all()
    top = Camera((5.0, 10.0, 100.0), (5.0, 10.0, 2.5), near=1.0, far=1e3, projection=Projection.ORTHOGRAPHIC,
                 height=30.0)
    handles = clipbox.face_handles(top, lo, hi, (W, H))
    zmax = handles[clipbox.Face(2, 1)]
    assert clipbox.handle_at(top, lo, hi, (W, H), *zmax) is None       # the top face is seen face on
    xmax = handles[clipbox.Face(0, 1)]
    assert clipbox.handle_at(top, lo, hi, (W, H), *(xmax + 2.0)) == clipbox.Face(0, 1)
    centre = clipbox.face_centre(lo, hi, clipbox.Face(0, 1))
    start = clipbox.along_axis(top, centre, 0, (W, H), *xmax)
    per_pixel = top.height / H                                          # the orthographic image's scale
    moved = clipbox.along_axis(top, centre, 0, (W, H), xmax[0] - 10.0, xmax[1] + 3.0)
    assert start == pytest.approx(0.0, abs=1e-9) and moved == pytest.approx(-10.0 * per_pixel)
    clip = Clip(tuple(lo), tuple(hi), Section((0.0, 0.0), (10.0, 20.0), 1.0))
    dragged = clipbox.dragged(clip, clipbox.Face(0, 1), 10.0, start, moved)
    assert dragged.hi == (10.0 - 10.0 * per_pixel, 20.0, 5.0) and dragged.lo == clip.lo
    assert dragged.section == clip.section
    assert clipbox.dragged(clip, clipbox.Face(0, 1), 10.0, 0.0, -50.0).hi[0] == 0.0      # stops at min x
    slab = Clip((-math.inf, -math.inf, 1.0), (math.inf, math.inf, 2.0))
    shown_lo, shown_hi = clipbox.shown_box(slab, lo, hi)
    assert tuple(shown_lo) == (0.0, 0.0, 1.0) and tuple(shown_hi) == (10.0, 20.0, 2.0)


def test_cli_clip_section(tmp_path, capsys, las_xyz):
    """render --clip-section draws the float64 contract of the points in the section
    (with --clip-z too), reports it in --stats, and bad sections are one line."""
    from progressive.camera import Camera
    from progressive.loaders import open_cloud
    from progressive.permutation import LAYOUT, Permutation

    info = open_cloud([str(SAMPLE)])
    section = sections(info)["diagonal"]
    spec = ",".join(repr(float(v)) for v in (*section.start, *section.end, section.width))
    ids, stats, cam = tmp_path / "ids.npy", tmp_path / "s.json", tmp_path / "cam.json"
    z = f"{float(info.bounds_min[2] + 0.1 * (info.bounds_max[2] - info.bounds_min[2]))!r},{float(info.bounds_max[2])!r}"
    assert main(["render", "--width", str(W), "--height", str(H), f"--clip-section={spec}", "--clip-z", z,
                 "--ids", str(ids), "--stats", str(stats), "--save-camera", str(cam)]) == 0
    clip = Clip((-math.inf, -math.inf, float(z.split(",")[0])), (math.inf, math.inf, float(z.split(",")[1])),
                section)
    slots = Permutation.for_count(info.points, order=LAYOUT).forward(np.arange(info.points)).astype(np.int64)
    expected = clipped_reference_ids(las_xyz, clip, Camera.from_json(cam.read_text()), W, H, slots)
    got = np.load(ids)
    assert (got != EMPTY).sum() > 100 and np.mean(got == expected) >= 0.999
    reported = json.loads(stats.read_text())["clip"]["section"]
    assert reported == {"start": list(section.start), "end": list(section.end), "width": section.width}
    for bad in ("1,2,3,4", "1,2,1,2,5", "0,0,10,0,0", "0,0,10,0,nan"):
        capsys.readouterr()
        assert main(["render", "--out", str(tmp_path / "x.png"), f"--clip-section={bad}"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("progressive: error: ") and err.count("\n") == 1
    assert not (tmp_path / "x.png").exists()
