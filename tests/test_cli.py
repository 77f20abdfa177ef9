"""The command line: outputs, the camera contract, and one-line errors for bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import SAMPLE
from progressive.cli import main

SMALL = ["--width", "160", "--height", "120"]


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_render_writes_png_ids_stats_and_camera(tmp_path, capsys):
    png, ids, stats, cam = (tmp_path / n for n in ("a.png", "a.npy", "a.json", "cam.json"))
    code, _, err = run(capsys, "render", *SMALL, "--out", png, "--ids", ids, "--stats", stats, "--save-camera", cam)
    assert code == 0, err
    from PIL import Image

    image = np.asarray(Image.open(png))
    assert image.shape == (120, 160, 3)
    ids_a = np.load(ids)
    assert ids_a.shape == (120, 160) and ids_a.dtype == np.uint32
    assert 0.05 < np.mean(ids_a != 0xFFFFFFFF) < 1.0
    covered = ids_a != 0xFFFFFFFF
    assert np.array_equal(image[covered].any(axis=1), np.ones(covered.sum(), bool)) or image[covered].any()
    s = json.loads(stats.read_text())
    assert s["points"] == 110_000 and s["points_loaded"] == 110_000
    assert {"device", "load_seconds", "load_points_per_second", "gpu_ms"} <= set(s)
    assert {"raster", "resolve"} <= set(s["gpu_ms"])
    ids_b, png_b = tmp_path / "b.npy", tmp_path / "b.png"
    code, _, err = run(capsys, "render", *SMALL, "--camera", cam, "--ids", ids_b, "-o", png_b)
    assert code == 0, err
    assert np.array_equal(np.load(ids_b), ids_a)
    assert np.array_equal(np.asarray(Image.open(png_b)), image)


def test_camera_as_json_text_and_raster_choices(tmp_path, capsys):
    cam = {"position": [637000.0, 848500.0, 1500.0], "target": [636800.0, 849000.0, 450.0],
           "up": [0, 0, 1], "fov_y_deg": 50, "near": 10, "far": 5000}
    outs = {}
    for raster in ("compute", "compute32", "points"):
        path = tmp_path / f"{raster}.npy"
        code, _, err = run(capsys, "render", *SMALL, "--camera", json.dumps(cam), "--raster", raster, "--ids", path)
        assert code == 0, err
        outs[raster] = np.load(path)
    assert np.array_equal(outs["compute"], outs["compute32"])
    covered = (outs["compute"] != 0xFFFFFFFF) | (outs["points"] != 0xFFFFFFFF)
    assert covered.sum() > 100
    assert np.mean(outs["compute"][covered] == outs["points"][covered]) >= 0.99


@pytest.mark.parametrize("name", ["classification", "Intensity", "GpsTime", "elevation", "ReturnNumber", "z"])
def test_color_by_names(tmp_path, capsys, name):
    code, _, err = run(capsys, "render", *SMALL, "--color-by", name, "--out", tmp_path / "x.png")
    assert code == 0, err


def test_info_json(capsys):
    code, out, _ = run(capsys, "info", "--json", SAMPLE)
    assert code == 0
    d = json.loads(out)
    assert d["points"] == 110_000 and d["point_format"] == 3 and d["version"] == "1.2"
    assert set(d["bounds"]) == {"min", "max"} and len(d["bounds"]["min"]) == 3
    assert "intensity" in d["attributes"]


def test_convert_then_render_fast_format_gives_same_ids(tmp_path, capsys, monkeypatch):
    """The fast format stores float32 positions: convert computes a LAS batch's on the
    loader's parser threads, not on the thread that writes the file."""
    import threading

    from progressive.loaders.types import Grid

    on_main, real = [], Grid.positions

    def spy(self, *args, **kwargs):
        on_main.append(threading.current_thread() is threading.main_thread())
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Grid, "positions", spy)
    fast = tmp_path / "sample.prgs"
    code, _, err = run(capsys, "convert", SAMPLE, fast)
    assert code == 0, err
    assert on_main and not any(on_main), on_main
    monkeypatch.undo()
    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    assert run(capsys, "render", *SMALL, SAMPLE, "--ids", a)[0] == 0
    assert run(capsys, "render", *SMALL, fast, "--ids", b)[0] == 0
    assert np.array_equal(np.load(a), np.load(b))


def broken_files(tmp_path):
    data = SAMPLE.read_bytes()
    offset = int.from_bytes(data[96:100], "little")
    record = int.from_bytes(data[105:107], "little")
    cases = {
        "missing": tmp_path / "missing.las",
        "directory": tmp_path,
        "random": tmp_path / "random.las",
        "empty": tmp_path / "empty.las",
        "signature": tmp_path / "signature.las",
        "truncated": tmp_path / "truncated.las",
        "zero_points": tmp_path / "zero.las",
        "count_larger": tmp_path / "larger.las",
    }
    cases["random"].write_bytes(np.random.default_rng(0).bytes(5000))
    cases["empty"].write_bytes(b"")
    cases["signature"].write_bytes(b"XXXX" + data[4:])
    cases["truncated"].write_bytes(data[: offset + record * 5000 + 7])
    header_only = bytearray(data[:offset])
    header_only[107:111] = (0).to_bytes(4, "little")
    header_only[111:131] = bytes(20)
    cases["zero_points"].write_bytes(bytes(header_only))
    larger = bytearray(data)
    larger[107:111] = (200_000).to_bytes(4, "little")
    cases["count_larger"].write_bytes(bytes(larger))
    return cases


@pytest.mark.parametrize("case", ["missing", "directory", "random", "empty", "signature", "truncated",
                                  "zero_points", "count_larger"])
def test_bad_files_one_line_error(tmp_path, capsys, case):
    bad = broken_files(tmp_path)[case]
    out = tmp_path / "out" / "x.png"
    out.parent.mkdir()
    code, _, err = run(capsys, "render", *SMALL, bad, "--out", out)
    assert code == 2
    assert err.startswith("progressive: error: ") and err.count("\n") == 1, err
    assert not any(out.parent.iterdir()), "nothing may be written"


def test_partial_renders_truncated_with_warning(tmp_path, capsys):
    bad = broken_files(tmp_path)["truncated"]
    out = tmp_path / "x.npy"
    code, _, err = run(capsys, "render", *SMALL, bad, "--partial", "--ids", out)
    assert code == 0, err
    assert "warning" in err
    ids = np.load(out)
    assert ids[ids != 0xFFFFFFFF].max() < 5000


@pytest.mark.parametrize("argv", [
    ["--color-by", "nonexistent"],
    ["--camera", "{not json"],
    ["--camera", '{"position": [0, 0, 0], "target": [0, 0, 0]}'],
    ["--camera", '{"position": [0, 0, 1], "target": [0, 0, 0], "near": -1}'],
    ["--camera", "/no/such/camera.json"],
    ["--width", "0"],
    ["--width", "100000"],
    ["--raster", "bogus"],
    ["--colormap", "nope"],
    ["--point-size", "0"],
    ["--point-size", "99"],
    ["--eye-dome", "--eye-dome-radius", "0"],
    ["--eye-dome", "--eye-dome-strength", "nan"],
    ["--hide-classes", "300"],
    ["--hide-classes", "ground"],
])
def test_bad_options_one_line_error(tmp_path, capsys, argv):
    out = tmp_path / "x.png"
    code, _, err = run(capsys, "render", *argv, "--out", out)
    assert code == 2
    assert err.startswith("progressive: error: ") and err.count("\n") == 1, err
    assert not out.exists()


def test_output_folder_missing(tmp_path, capsys):
    code, _, err = run(capsys, "render", *SMALL, "--out", tmp_path / "no" / "x.png")
    assert code == 2 and "does not exist" in err


def test_console_script_no_traceback(tmp_path):
    bad = tmp_path / "bad.las"
    bad.write_bytes(b"LASF" + bytes(50))
    proc = subprocess.run([sys.executable, "-m", "progressive", "render", str(bad), "--out", str(tmp_path / "x.png")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1, proc.stderr


def test_progressive_converge_equals_brute_ids(tmp_path, capsys):
    brute, prog, stats = tmp_path / "b.npy", tmp_path / "p.npy", tmp_path / "s.json"
    assert run(capsys, "render", *SMALL, "--ids", brute)[0] == 0
    code, _, err = run(capsys, "render", *SMALL, "--method", "progressive", "--budget", "30000", "--converge",
                       "--ids", prog, "--stats", stats)
    assert code == 0, err
    assert np.array_equal(np.load(brute), np.load(prog))
    s = json.loads(stats.read_text())
    assert s["converged_frame"] is not None and s["converged_frame"] >= 3
    frames = s["frames"]
    first = next(f for f in frames if "distribute" in f["passes"])
    assert "reproject" not in first["passes"] and "fill" in first["passes"]
    assert all(f["passes"] == ["resolve"] for f in frames[: frames.index(first)])
    assert all({"reproject", "fill", "prepare", "resolve"} <= set(f["gpu_ms"]) for f in frames if f["gpu_ms"])


def test_camera_path_replays_one_camera_per_frame(tmp_path, capsys):
    from progressive.camera import auto_camera
    from progressive.loaders import open_cloud

    info = open_cloud([SAMPLE])
    cam = auto_camera(info.bounds_min, info.bounds_max, 160 / 120)
    path = []
    for k in range(5):
        d = cam.to_dict()
        d["position"] = [d["position"][0] + 10 * k, d["position"][1], d["position"][2]]
        path.append(d)
    cam_file = tmp_path / "path.json"
    cam_file.write_text(json.dumps(path))
    stats = tmp_path / "s.json"
    code, _, err = run(capsys, "render", *SMALL, "--method", "progressive", "--camera-path", cam_file,
                       "--frames", "3", "--stats", stats)
    assert code == 0, err
    assert json.loads(stats.read_text())["frames_rendered"] == 3
    code, _, err = run(capsys, "render", *SMALL, "--method", "progressive", "--camera-path", cam_file,
                       "--converge", "--stats", stats)
    assert code == 0, err
    s = json.loads(stats.read_text())
    assert s["frames_rendered"] >= 5 and s["converged_frame"] >= 4
    assert s["camera"]["position"] == path[-1]["position"]
    complete = [f for f in s["frames"] if f["points_loaded"] == s["points"] and "fill" in f["passes"]]
    assert complete and all(f["equal_fraction"] is not None for f in complete)


@pytest.mark.parametrize("argv,needle", [
    (["--method", "progressive", "--budget", "lots"], "budget"),
    (["--method", "progressive", "--target-ms", "0"], "target-ms"),
    (["--converge"], "progressive"),
    (["--method", "progressive", "--camera-path", "/no/such/path.json"], "not found"),
])
def test_bad_progressive_options(tmp_path, capsys, argv, needle):
    code, _, err = run(capsys, "render", *SMALL, *argv, "--out", tmp_path / "x.png")
    assert code == 2 and err.count("\n") == 1 and needle in err, err


def test_malformed_camera_path(tmp_path, capsys):
    bad = tmp_path / "path.json"
    bad.write_text('[{"position": [0, -5, 1], "target": [0, 0, 0]}, {"position": "x"}]')
    code, _, err = run(capsys, "render", *SMALL, "--method", "progressive", "--camera-path", bad, "--out", tmp_path / "x.png")
    assert code == 2 and "camera 1" in err and err.count("\n") == 1


def test_laz_without_backend(tmp_path, capsys, monkeypatch):
    import laspy

    from conftest import shared_file

    laz = shared_file("pine_plot.laz")
    monkeypatch.setattr(laspy.LazBackend, "is_available", lambda self: False)
    code, _, err = run(capsys, "render", *SMALL, laz, "--out", tmp_path / "x.png")
    assert code == 2 and "no LAZ decoder" in err and err.count("\n") == 1, err
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("name, warned", [("TLSSparseCloud_xyzOnly.laz", True), ("wires.laz", False),
                                         ("autzen_trim.las", False)])
def test_default_colour_is_real_rgb_else_elevation(tmp_path, capsys, name, warned):
    """TLSSparseCloud has RGB fields that are all zero (passed over, with a warning),
    wires.laz no RGB (elevation, not its all-zero intensity), autzen real RGB (MANIFEST)."""
    from conftest import SAMPLE, shared_file

    stats = tmp_path / "s.json"
    path = SAMPLE if name == "autzen_trim.las" else shared_file(name)
    code, _, err = run(capsys, "render", *SMALL, path, "--stats", stats)
    assert code == 0, err
    assert json.loads(stats.read_text())["attribute"] == ("rgb" if name == "autzen_trim.las" else "elevation")
    assert ("all zero" in err and "colouring by elevation" in err and err.startswith("progressive: warning:")) == warned


def test_render_effects_and_hidden_classes(tmp_path, capsys):
    """Effects change only the pixels, hidden classes the ids: what the viewer shows."""
    import laspy
    from PIL import Image

    classes = np.asarray(laspy.read(SAMPLE).classification)
    plain, big = tmp_path / "plain.png", tmp_path / "big.png"
    ids_plain, ids_big, ids_hidden = tmp_path / "a.npy", tmp_path / "b.npy", tmp_path / "c.npy"
    assert main(["render", *SMALL, "--out", str(plain), "--ids", str(ids_plain)]) == 0
    assert main(["render", *SMALL, "--out", str(big), "--ids", str(ids_big), "--point-size", "3", "--eye-dome"]) == 0
    np.testing.assert_array_equal(np.load(ids_plain), np.load(ids_big))
    covered = (np.asarray(Image.open(plain))[:, :, :3] > 0).any(axis=2).sum()
    assert (np.asarray(Image.open(big))[:, :, :3] > 0).any(axis=2).sum() > covered
    assert main(["render", *SMALL, "--color-by", "classification", "--hide-classes", "2", "--ids", str(ids_hidden)]) == 0
    ids = np.load(ids_hidden)
    assert ids[ids != 0xFFFFFFFF].size and not np.any(classes[ids[ids != 0xFFFFFFFF]] == 2)


def test_view_leaves_point_size_and_eye_dome_to_the_viewer_unless_given(tmp_path, capsys):
    """view: None (the viewer's rules) unless given, so 1 and off stay the user's; render
    keeps 1 and off as its defaults and has no --no-eye-dome."""
    from progressive.cli import build_parser

    parse = build_parser().parse_args
    view = parse(["view"])
    assert (view.point_size, view.eye_dome) == (None, None)
    assert parse(["view", "--point-size", "1", "--no-eye-dome"]).point_size == 1
    assert parse(["view", "--no-eye-dome"]).eye_dome is False and parse(["view", "--eye-dome"]).eye_dome is True
    render = parse(["render"])
    assert (render.point_size, render.eye_dome) == (1, False)
    code, _, err = run(capsys, "render", *SMALL, "--no-eye-dome", "--out", tmp_path / "x.png")
    assert code == 2 and err == "progressive: error: unrecognized arguments: --no-eye-dome\n"


@pytest.mark.parametrize("argv", [
    ["--point-size", "0"],
    ["--eye-dome-radius", "0"],                     # the rules may turn eye-dome lighting on
    ["--eye-dome", "--eye-dome-strength", "nan"],
    ["--eye-dome", "--no-eye-dome", "--point-size", "99"],
])
def test_bad_view_effects_one_line_error(tmp_path, capsys, monkeypatch, argv):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    out = tmp_path / "x.png"
    code, _, err = run(capsys, "view", *SMALL, *argv, "--out", out)
    assert code == 2
    assert err.startswith("progressive: error: ") and err.count("\n") == 1, err
    assert not out.exists()


def test_headless_view_draws_what_render_draws(tmp_path, capsys, monkeypatch):
    """Without a display, what view leaves to the viewer's rules is 1 pixel and no
    lighting, as render's defaults; given effects are drawn as render draws them."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    from PIL import Image

    for flags in ([], ["--point-size", "3", "--eye-dome"]):
        seen, drawn = tmp_path / "view.png", tmp_path / "render.png"
        assert run(capsys, "view", *SMALL, *flags, "--out", seen)[0] == 0
        assert run(capsys, "render", *SMALL, *flags, "--out", drawn)[0] == 0
        np.testing.assert_array_equal(np.asarray(Image.open(seen)), np.asarray(Image.open(drawn)))


def test_stats_to_standard_output(tmp_path, capsys, monkeypatch):
    """`--stats -` prints the JSON a file would hold (no file named "-"), and --pick,
    which prints too, cannot share standard output with it."""
    monkeypatch.chdir(tmp_path)
    stats = tmp_path / "a.json"
    code, _, err = run(capsys, "render", *SMALL, "--stats", stats)
    assert code == 0, err
    code, out, err = run(capsys, "render", *SMALL, "--stats", "-")
    assert code == 0, err
    printed, written = json.loads(out), json.loads(stats.read_text())
    assert printed["points"] == written["points"] == 110_000
    assert printed["covered_pixels"] == written["covered_pixels"] > 0
    assert set(printed) == set(written)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]
    code, out, err = run(capsys, "render", *SMALL, "--stats", "-", "--pick", "80,60")
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("progressive: error: --stats - and --pick")
