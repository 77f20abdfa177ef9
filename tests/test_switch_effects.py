"""Attribute switching (paper 3.5) and the screen-space effects: the GPU matches numpy
references, a converged image stays exact across a switch, and effects that are not
asked for never run."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import RECORDS
from progressive.attributes import default_attribute
from progressive.budget import BudgetParams
from progressive.camera import auto_camera
from progressive.colors import ColorStyle
from progressive.effects import Effects, EyeDome, footprint
from progressive.errors import ProgressiveError
from progressive.frame_loop import ProgressiveOptions, ProgressiveRenderer
from progressive.loaders.records import attribute_word
from progressive.passes.raster_compute import ComputeTuning
from progressive.reference import EMPTY
from progressive.renderer import Renderer

W, H = 160, 120


@pytest.fixture(scope="module")
def cloud(sample_batches):
    return sample_batches


def progressive_renderer(gl, cloud, **kw):
    info, batches = cloud
    pr = ProgressiveRenderer(gl, info, default_attribute(info),
                             ProgressiveOptions(W, H, budget=BudgetParams(fixed=40_000), batches_per_frame=100,
                                                keep_batches=True, **kw))
    for b in batches:
        pr.add_batch(b)
    return pr


def brute_renderer(gl, cloud, attribute, **kw) -> Renderer:
    info, batches = cloud
    r = Renderer(gl, info, attribute, width=W, height=H, **kw)
    for b in batches:
        r.add_batch(b)
    return r


def brute_frame(gl, cloud, attribute, cam, effects=Effects()):
    r = brute_renderer(gl, cloud, attribute)
    frame = r.render(cam, W, H, r.style(), effects)
    r.release()
    return frame


def converge(pr, cam, style, effects=Effects(), limit=50):
    for _ in range(limit):
        pr.frame(cam, style, effects)
        pr.flush()
        if pr.converged:
            return
    raise AssertionError("did not converge")


def test_switched_words_equal_the_permuted_numpy_values(gl, cloud):
    info, batches = cloud
    pr = progressive_renderer(gl, cloud)
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    converge(pr, cam, pr.scene.style())
    intensity = info.attribute("intensity")
    pr.switch_attribute(intensity)
    frames = 0
    while pr.switching:
        assert pr.frame(cam, pr.scene.style()) == ("stream",)
        frames += 1
    gl.check()
    expected = np.concatenate([attribute_word(b, intensity, float(info.origin[2])) for b in batches])
    slots = pr.store.slots_of(np.arange(info.points))
    words = pr.store.read_records()[:, 3]
    np.testing.assert_array_equal(words[slots], expected)
    assert pr.scene.switch.streamed == info.points and pr.scene.switch.rate > 0
    pr.release()


@RECORDS
def test_converged_image_is_exact_right_after_a_switch(gl, cloud, winners):
    """The visible set does not change with the colouring: the first frame after the
    stream regathers the visible words and equals a brute render by intensity."""
    info, _ = cloud
    pr = progressive_renderer(gl, cloud, tuning=ComputeTuning(winners=winners))
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    converge(pr, cam, pr.scene.style())
    ids_before = pr.read_ids()
    pr.switch_attribute(info.attribute("intensity"))
    while pr.switching:
        pr.frame(cam, pr.scene.style())
    style = pr.scene.style()
    passes = pr.frame(cam, style)
    assert "fill" not in passes and "prepare" in passes, passes
    expected = brute_frame(gl, cloud, info.attribute("intensity"), cam)
    np.testing.assert_array_equal(pr.read_ids(), ids_before)
    np.testing.assert_array_equal(pr.read_image(), expected.image)
    pr.release()


def test_converged_is_not_reported_before_the_switched_image(gl, cloud):
    """A caller that frames until `converged` (the CLI, a notebook's still()) gets the
    switched image: neither the frames that stream the words nor the one that ends the
    stream, whose visible copies still hold the old words, count as converged."""
    info, _ = cloud
    pr = progressive_renderer(gl, cloud)
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    converge(pr, cam, pr.scene.style())
    pr.switch_attribute(info.attribute("intensity"))
    assert not pr.converged
    converge(pr, cam, pr.scene.style())
    expected = brute_frame(gl, cloud, info.attribute("intensity"), cam)
    np.testing.assert_array_equal(pr.read_image(), expected.image)
    pr.release()


def test_switch_changes_the_image_and_back_restores_it(gl, cloud):
    info, _ = cloud
    pr = progressive_renderer(gl, cloud)
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    converge(pr, cam, pr.scene.style())
    rgb = pr.read_image()
    for name in ("classification", "rgb"):
        pr.switch_attribute(info.attribute(name))
        while pr.switching:
            pr.frame(cam, pr.scene.style())
        pr.frame(cam, pr.scene.style())
        image = pr.read_image()
        assert np.array_equal(image, rgb) == (name == "rgb")
    pr.release()


def test_brute_renderer_switch_matches_a_fresh_load(gl, cloud):
    info, batches = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    r = brute_renderer(gl, cloud, default_attribute(info), keep_batches=True)
    r.switch_attribute(info.attribute("gps_time"))
    got = r.render(cam, W, H, r.style())
    r.release()
    expected = brute_frame(gl, cloud, info.attribute("gps_time"), cam)
    np.testing.assert_array_equal(got.image, expected.image)


def test_switching_needs_kept_batches(gl, cloud):
    info, batches = cloud
    r = Renderer(gl, info, default_attribute(info), width=W, height=H)
    r.add_batch(batches[0])
    with pytest.raises(ProgressiveError, match="keep"):
        r.switch_attribute(info.attribute("intensity"))
    r.release()


def dilate_reference(vis: np.ndarray, size: int) -> np.ndarray:
    """(H, W, 2) slot/depth of the nearest point whose disc covers each pixel."""
    reach, radius2 = footprint(size)
    h, w, _ = vis.shape
    key = (vis[:, :, 1].astype(np.uint64) << np.uint64(32)) | vis[:, :, 0].astype(np.uint64)
    best = np.full((h, w), np.iinfo(np.uint64).max, dtype=np.uint64)
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            if dx * dx + dy * dy > radius2:
                continue
            shifted = np.full((h, w), np.iinfo(np.uint64).max, dtype=np.uint64)
            ys, yd = slice(max(0, dy), h + min(0, dy)), slice(max(0, -dy), h + min(0, -dy))
            xs, xd = slice(max(0, dx), w + min(0, dx)), slice(max(0, -dx), w + min(0, -dx))
            shifted[yd, xd] = key[ys, xs]
            best = np.minimum(best, shifted)
    return np.stack([(best & np.uint64(0xFFFFFFFF)).astype(np.uint32), (best >> np.uint64(32)).astype(np.uint32)], -1)


@pytest.mark.parametrize("size", [2, 3, 5, 8, 17, 32])
def test_point_size_dilation_matches_numpy(gl, cloud, size):
    info, _ = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    one = brute_frame(gl, cloud, default_attribute(info), cam)
    r = brute_renderer(gl, cloud, default_attribute(info))
    r.render(cam, W, H, r.style(), Effects(point_size=size))
    vis = r.vis.read()
    dilated = r.shading.shown.read()
    np.testing.assert_array_equal(vis[:, :, 0], one.slots)
    expected = dilate_reference(vis, size)
    np.testing.assert_array_equal(dilated[:, :, 0], expected[:, :, 0])
    np.testing.assert_array_equal(dilated[:, :, 1], np.where(expected[:, :, 0] == EMPTY, 0xFFFFFFFF, expected[:, :, 1]))
    assert (dilated[:, :, 0] != EMPTY).sum() > (one.slots != EMPTY).sum()
    r.release()


@RECORDS
def test_progressive_dilated_image_equals_brute_dilated_image(gl, cloud, winners):
    """Point size changes only the resolve: convergence is still exact."""
    info, _ = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    effects = Effects(point_size=3, eye_dome=EyeDome())
    pr = progressive_renderer(gl, cloud, tuning=ComputeTuning(winners=winners))
    converge(pr, cam, pr.scene.style(), effects)
    pr.frame(cam, pr.scene.style(), effects)
    expected = brute_frame(gl, cloud, default_attribute(info), cam, effects)
    np.testing.assert_array_equal(pr.read_image(), expected.image)
    pr.release()


def eye_dome_reference(vis: np.ndarray, image: np.ndarray, edl: EyeDome) -> np.ndarray:
    h, w, _ = vis.shape
    covered = vis[:, :, 0] != EMPTY
    with np.errstate(divide="ignore"):
        logd = np.log2(vis[:, :, 1].view(np.float32).astype(np.float64))
    total = np.zeros((h, w))
    d = 0.70710678
    for ux, uy in ((1, 0), (-1, 0), (0, 1), (0, -1), (d, d), (-d, d), (d, -d), (-d, -d)):
        dx, dy = int(np.round(ux * edl.radius)), int(np.round(uy * edl.radius))
        ys, yd = slice(max(0, dy), h + min(0, dy)), slice(max(0, -dy), h + min(0, -dy))
        xs, xd = slice(max(0, dx), w + min(0, dx)), slice(max(0, -dx), w + min(0, -dx))
        other = np.full((h, w), np.nan)
        other[yd, xd] = np.where(covered[ys, xs], logd[ys, xs], np.nan)
        step = np.where(np.isnan(other), 0.0, np.maximum(0.0, logd - np.nan_to_num(other)))
        total += np.where(covered, step, 0.0)
    shade = np.exp(-300.0 * edl.strength * total / 8.0)
    out = image.astype(np.float64)
    out[:, :, :3] = np.where(covered[:, :, None], out[:, :, :3] * shade[:, :, None], out[:, :, :3])
    return out


@pytest.mark.parametrize("edl", [EyeDome(1.0, 1.4), EyeDome(0.3, 3.0)])
def test_eye_dome_lighting_matches_numpy(gl, cloud, edl):
    info, _ = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    plain = brute_frame(gl, cloud, default_attribute(info), cam)
    r = brute_renderer(gl, cloud, default_attribute(info))
    lit = r.render(cam, W, H, r.style(), Effects(eye_dome=edl))
    expected = eye_dome_reference(r.vis.read(), plain.image, edl)
    assert np.abs(lit.image.astype(np.float64) - expected).max() <= 1.0   # unorm8 rounding
    assert (lit.image[:, :, :3].astype(int) < plain.image[:, :, :3]).any()
    r.release()


def test_effects_run_only_when_asked(gl, cloud):
    info, _ = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    pr = progressive_renderer(gl, cloud)
    style: ColorStyle = pr.scene.style()
    passes = pr.frame(cam, style)
    assert "dilate" not in passes and "eye_dome" not in passes
    assert pr.shading.dilate is None and pr.shading.eye_dome is None
    passes = pr.frame(cam, style, Effects(point_size=2, eye_dome=EyeDome()))
    assert passes[-3:] == ("dilate", "resolve", "eye_dome"), passes
    gl.check()
    pr.release()


@pytest.mark.parametrize("make", [lambda: Effects(point_size=0), lambda: Effects(point_size=33),
                                  lambda: EyeDome(radius=0.1), lambda: EyeDome(strength=float("nan"))])
def test_bad_effects_are_refused(make):
    with pytest.raises(ValueError):
        make()


@RECORDS
def test_hidden_classes_are_left_out_and_show_what_is_behind(gl, cloud, winners):
    """Hiding a class removes its points from the raster (not just the colour): the
    converged image equals a brute render with the same classes hidden, none of its
    points is visible, and points that were behind them now are."""
    info, batches = cloud
    classes = np.concatenate([b.attributes["classification"] for b in batches])
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    attr = info.attribute("classification")
    r = brute_renderer(gl, cloud, attr, keep_batches=True)
    assert r.scene.categories() == sorted(set(classes.tolist()))
    common = int(np.bincount(classes).argmax())
    shown = r.render(cam, W, H, r.style())
    hidden = r.render(cam, W, H, r.style(), hidden=frozenset({common}))
    visible = hidden.ids[hidden.ids != EMPTY]
    assert visible.size and not np.any(classes[visible] == common)
    newly = set(visible.tolist()) - set(shown.ids[shown.ids != EMPTY].tolist())
    assert newly, "nothing behind the hidden class became visible"
    pr = progressive_renderer(gl, cloud, tuning=ComputeTuning(winners=winners))
    pr.switch_attribute(attr)
    style = pr.scene.style()
    for _ in range(60):
        pr.frame(cam, style, hidden=frozenset({common}))
        pr.flush()
        if pr.converged:
            break
    pr.frame(cam, style, hidden=frozenset({common}))
    np.testing.assert_array_equal(pr.read_ids(), hidden.ids)
    np.testing.assert_array_equal(pr.read_image(), hidden.image)
    # with a scalar shown the mask does nothing
    pr.switch_attribute(info.attribute("intensity"))
    r.switch_attribute(info.attribute("intensity"))
    assert r.scene.drawable(frozenset({common})) == frozenset()
    pr.release()
    r.release()
