"""Hostile command lines (issue 14, CLI side): file arguments that are not regular
files, outputs that would replace an input, a device or each other, a full disk, a
full stdout, signals mid-run, umask and long names, camera JSON built to break the
parser or the float pipeline. Every bad case ends in one line `progressive: error:`,
exit 2, nothing left behind and nothing replaced; a signal ends with 128+signal.

Cases that could hang if they regress (FIFOs) or that need real file descriptors and
signals run in a subprocess with a timeout."""

from __future__ import annotations

import json
import math
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import laspy
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_hard_input import TINY, assert_one_error_line, cli

from conftest import REPO, SAMPLE

pytestmark = pytest.mark.filterwarnings("error")

FUZZ = settings(max_examples=int(os.environ.get("PROGRESSIVE_FUZZ_EXAMPLES", "25")), deadline=None,
                derandomize=True, database=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
CAMERA = {"position": [637000.0, 848500.0, 1500.0], "target": [636800.0, 849000.0, 450.0],
          "up": [0, 0, 1], "fov_y_deg": 50, "near": 10, "far": 5000}
"""A camera that sees the bundled sample."""
TIMEOUT_S = 60


def progressive(*argv, **kwargs) -> subprocess.CompletedProcess:
    """The console command in its own process (its own signals, fds and umask)."""
    return subprocess.run([sys.executable, "-m", "progressive", *map(str, argv)], capture_output=True, text=True,
                          timeout=TIMEOUT_S, cwd=REPO, **kwargs)


def assert_one_line(proc: subprocess.CompletedProcess) -> None:
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith("progressive: error: ") and proc.stderr.count("\n") == 1, proc.stderr


@pytest.fixture(scope="module")
def small_cloud(tmp_path_factory) -> Path:
    """2,000 points of the sample: renders in a fraction of the sample's time."""
    las = laspy.read(SAMPLE)
    small = laspy.LasData(las.header, points=las.points[:2000].copy())
    path = tmp_path_factory.mktemp("small") / "small.las"
    small.write(path)
    return path


@pytest.fixture
def out_dir(tmp_path) -> Path:
    (tmp_path / "out").mkdir()
    return tmp_path / "out"


# --- file arguments that are not regular files ------------------------------------------------

@pytest.mark.parametrize("option", ["--camera", "--camera-path"])
def test_fifo_as_camera_is_refused_not_read(tmp_path, option):
    fifo = tmp_path / "camera.json"
    os.mkfifo(fifo)
    proc = progressive("render", *TINY, "--method", "progressive", option, fifo, "--out", tmp_path / "x.png")
    assert_one_line(proc)
    assert "not a regular file" in proc.stderr
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("option", ["--camera", "--camera-path"])
def test_directory_as_camera(capsys, tmp_path, out_dir, option):
    code, _, err = cli(capsys, "render", *TINY, "--method", "progressive", option, tmp_path, "--out", out_dir / "x.png")
    assert_one_error_line(code, err, out_dir)


def test_character_device_as_output_stays_a_device(capsys):
    code, _, err = cli(capsys, "render", *TINY, "--out", os.devnull)
    assert code == 2 and err.count("\n") == 1 and "not a regular file" in err, err
    assert stat.S_ISCHR(os.stat(os.devnull).st_mode)


@pytest.mark.parametrize("option", ["--out", "--ids", "--stats", "--save-camera"])
def test_directory_as_output(capsys, out_dir, option):
    (out_dir / "d").mkdir()
    code, _, err = cli(capsys, "render", *TINY, option, out_dir / "d")
    assert code == 2 and err.count("\n") == 1 and "is a directory" in err, err
    assert (out_dir / "d").is_dir() and not any((out_dir / "d").iterdir())
    assert [p.name for p in out_dir.iterdir()] == ["d"]


def test_read_only_output_folder(capsys, tmp_path):
    """As root permissions do not stop a write, so the folder is a read-only mount there."""
    folder = tmp_path / "ro"
    folder.mkdir()
    mounted = os.geteuid() == 0 and subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(folder)],
                                                   capture_output=True).returncode == 0
    if os.geteuid() == 0 and not mounted:
        pytest.skip("root without mount: a read-only folder cannot be made")
    if not mounted:
        folder.chmod(0o555)
    try:
        code, _, err = cli(capsys, "render", *TINY, "--out", folder / "x.png")
        assert code == 2 and err.startswith("progressive: error: ") and err.count("\n") == 1, err
        assert not any(folder.iterdir())
    finally:
        if mounted:
            subprocess.run(["umount", str(folder)], check=True)
        else:
            folder.chmod(0o755)


# --- outputs that would replace an input or each other ----------------------------------------

def spellings(folder: Path, name: str) -> dict[str, Path]:
    """Names of folder/name as given, through a symlink, a hard link and ../ ."""
    (folder / "link").symlink_to(name)
    os.link(folder / name, folder / "hard")
    return {"same": folder / name, "symlink": folder / "link", "hardlink": folder / "hard",
            "dotdot": folder / ".." / folder.name / name}


@pytest.mark.parametrize("spelling", ["same", "symlink", "hardlink", "dotdot"])
@pytest.mark.parametrize("command", ["render --out", "render --ids", "render --stats", "convert"])
def test_output_naming_the_input_is_refused(capsys, tmp_path, command, spelling):
    source = tmp_path / "in.las"
    source.write_bytes(SAMPLE.read_bytes())
    out = spellings(tmp_path, "in.las")[spelling]
    before = sorted(p.name for p in tmp_path.iterdir())
    if command == "convert":
        argv = ["convert", source, out]
    else:
        argv = ["render", *TINY, source, command.split()[1], out]
    code, _, err = cli(capsys, *argv)
    assert code == 2 and err.count("\n") == 1 and "is the input" in err, err
    assert source.read_bytes() == SAMPLE.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("option", ["--camera", "--camera-path"])
def test_output_naming_the_camera_is_refused(capsys, tmp_path, option):
    camera = tmp_path / "camera.json"
    text = json.dumps([CAMERA] if option == "--camera-path" else CAMERA)
    camera.write_text(text)
    code, _, err = cli(capsys, "render", *TINY, "--method", "progressive", option, camera,
                       "--save-camera", tmp_path / "." / "camera.json")
    assert code == 2 and "is the input" in err and err.count("\n") == 1, err
    assert camera.read_text() == text


@pytest.mark.parametrize("second", ["a.png", "./a.png", "sub/../a.png"])
def test_outputs_naming_each_other(capsys, out_dir, second):
    (out_dir / "sub").mkdir()
    code, _, err = cli(capsys, "render", *TINY, "--out", out_dir / "a.png", "--ids", out_dir / second)
    assert code == 2 and "same file" in err and err.count("\n") == 1, err
    assert [p.name for p in out_dir.iterdir()] == ["sub"]


@pytest.mark.parametrize("argv", [
    ["render", *TINY, "--out", "a\0b.png"], ["render", *TINY, "a\0b.las", "--out", "x.png"],
    ["render", *TINY, "--camera", "a\0b.json", "--out", "x.png"],
    ["render", *TINY, "--method", "progressive", "--camera-path", "a\0b.json", "--out", "x.png"],
    ["convert", "a\0b.las", "x.prgs"], ["convert", SAMPLE, "x\0.prgs"], ["info", "a\0b.las"],
    ["render", *TINY, "--out", "folder/"], ["render", *TINY, "--out", ""], ["render", *TINY, "--stats", "."],
])
def test_impossible_file_names(capsys, tmp_path, monkeypatch, argv):
    monkeypatch.chdir(tmp_path)
    code, _, err = cli(capsys, *argv)
    assert_one_error_line(code, err, tmp_path)


@pytest.mark.parametrize("out", ["device", "input"])
def test_view_without_display_checks_its_output_first(capsys, tmp_path, monkeypatch, out):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    source = tmp_path / "in.las"
    source.write_bytes(SAMPLE.read_bytes())
    code, _, err = cli(capsys, "view", *TINY, source, "--out", os.devnull if out == "device" else source)
    assert code == 2 and err.startswith("progressive: error: ") and err.count("\n") == 1, err
    assert source.read_bytes() == SAMPLE.read_bytes() and stat.S_ISCHR(os.stat(os.devnull).st_mode)


# --- outputs written whole, with the usual permissions --------------------------------------

def test_output_names_of_255_bytes(capsys, out_dir, small_cloud):
    names = {ext: "x" * (255 - len(ext)) + ext for ext in (".png", ".npy", ".json", ".prgs")}
    code, _, err = cli(capsys, "render", *TINY, small_cloud, "--out", out_dir / names[".png"],
                       "--ids", out_dir / names[".npy"], "--stats", out_dir / names[".json"])
    assert code == 0, err
    code, _, err = cli(capsys, "convert", small_cloud, out_dir / names[".prgs"])
    assert code == 0, err
    assert sorted(p.name for p in out_dir.iterdir()) == sorted(names.values())
    assert np.load(out_dir / names[".npy"]).shape == (48, 64)


@pytest.mark.parametrize("umask", [0o077, 0o002])
def test_outputs_follow_the_umask(capsys, tmp_path, small_cloud, umask):
    """render, convert and the viewer's P (write_png); the umask is restored after."""
    from progressive.output import write_png

    outs = [tmp_path / n for n in ("a.png", "a.npy", "a.json", "cam.json", "a.prgs", "shot.png")]
    previous = os.umask(umask)
    try:
        code, _, err = cli(capsys, "render", *TINY, small_cloud, "--out", outs[0], "--ids", outs[1],
                           "--stats", outs[2], "--save-camera", outs[3])
        assert code == 0, err
        code, _, err = cli(capsys, "convert", small_cloud, outs[4])
        assert code == 0, err
        write_png(outs[5], np.zeros((4, 4, 4), np.uint8))
    finally:
        os.umask(previous)
    for path in outs:
        assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask, path


@pytest.fixture
def small_disk(tmp_path):
    """A 64 KiB tmpfs whose free space is two pages: a tiny PNG fits, 30 frames of
    statistics do not."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(disk)],
                                           capture_output=True).returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    try:
        vfs = os.statvfs(disk)
        (disk / "filler").write_bytes(bytes(vfs.f_bavail * vfs.f_frsize - 2 * vfs.f_frsize))
        (disk / "out").mkdir()
        yield disk / "out"
    finally:
        subprocess.run(["umount", str(disk)], check=True)


def test_full_disk_while_writing_stats_leaves_no_png(capsys, small_disk, small_cloud):
    code, _, err = cli(capsys, "render", *TINY, small_cloud, "--method", "progressive", "--frames", 30,
                       "--out", small_disk / "x.png", "--stats", small_disk / "x.json")
    assert_one_error_line(code, err, small_disk)
    assert "No space left" in err


def test_full_disk_while_converting(capsys, small_disk):
    code, _, err = cli(capsys, "convert", SAMPLE, small_disk / "x.prgs")
    assert_one_error_line(code, err, small_disk)


@pytest.mark.parametrize("command", ["convert", "info"])
def test_stdout_full_is_one_line_and_removes_the_output(tmp_path, small_cloud, command):
    argv = ["convert", small_cloud, tmp_path / "x.prgs"] if command == "convert" else ["info", small_cloud]
    with open("/dev/full", "w") as full:
        proc = subprocess.run([sys.executable, "-m", "progressive", *map(str, argv)],
                              stdout=full, stderr=subprocess.PIPE, text=True, timeout=TIMEOUT_S, cwd=REPO)
    assert_one_line(proc)
    assert "standard output" in proc.stderr
    assert not any(tmp_path.iterdir())


def test_existing_output_is_kept_when_the_run_fails(capsys, out_dir, small_cloud):
    old = out_dir / "x.png"
    old.write_bytes(b"old")
    code, _, err = cli(capsys, "render", *TINY, small_cloud, "--out", old, "--camera", '{"position": [1, 2, 3]}')
    assert code == 2 and err.count("\n") == 1, err
    assert old.read_bytes() == b"old" and [p.name for p in out_dir.iterdir()] == ["x.png"]


# --- signals -----------------------------------------------------------------------------------

COPIES = 40
"""Copies of the sample given to convert: 4.4M points, a second or two of writing."""


def catches(pid: int, sig: int) -> bool:
    """Whether the process has a handler for sig (Linux: SigCgt in /proc/PID/status)."""
    status = Path(f"/proc/{pid}/status").read_text()
    mask = int(next(line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), 16)
    return bool(mask >> (sig - 1) & 1 and mask >> (signal.SIGTERM - 1) & 1)


@pytest.mark.parametrize("command", ["convert", "render"])
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_signal_mid_run_cleans_up(tmp_path, command, sig):
    """convert is signalled once its temporary exists (mid-write); render once its
    handlers are in place, while it loads or renders (16,384 frames of a small budget)."""
    if command == "convert":
        argv = ["convert", *[SAMPLE] * COPIES, tmp_path / "out.prgs"]
    else:
        argv = ["render", *TINY, "--method", "progressive", "--budget", 1000, "--frames", 16384,
                "--out", tmp_path / "out.png", "--ids", tmp_path / "out.npy"]
    # A shell's background job starts with SIGINT ignored, and one under nohup with
    # SIGHUP ignored; a child keeps that (and the CLI, rightly, leaves an ignored signal
    # ignored): give it the default disposition, as a terminal would, so what is tested
    # is the CLI's.
    proc = subprocess.Popen([sys.executable, "-m", "progressive", *map(str, argv)], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(sig, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + TIMEOUT_S
        if command == "convert":
            while not list(tmp_path.glob(".*.tmp")) and proc.poll() is None and time.monotonic() < deadline:
                time.sleep(0.005)
        else:
            while not catches(proc.pid, sig) and proc.poll() is None and time.monotonic() < deadline:
                time.sleep(0.005)
            time.sleep(0.3)
        assert proc.poll() is None, "finished before the signal: give it more work"
        sent = time.monotonic()
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=TIMEOUT_S)
        assert time.monotonic() - sent < 10, "not prompt"
    finally:
        proc.kill()
        proc.communicate()
    assert proc.returncode == 128 + sig, err
    assert "Traceback" not in err and err == "", err
    assert not any(tmp_path.iterdir()), list(tmp_path.iterdir())


def test_signal_handlers_are_restored(capsys, out_dir, small_cloud):
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    cli(capsys, "render", *TINY, small_cloud, "--out", out_dir / "x.png")
    assert {s: signal.getsignal(s) for s in before} == before


# --- messages stay one line --------------------------------------------------------------------

@pytest.mark.parametrize("name", ["a\nb.las", "a\rb.las", "tab\there.las", "esc\x1b[31m.las", "nul\u2028x.las"])
def test_control_characters_in_names_are_escaped(capsys, out_dir, name):
    code, _, err = cli(capsys, "render", *TINY, out_dir / name, "--out", out_dir / "x.png")
    assert_one_error_line(code, err, out_dir)
    assert "\r" not in err and "\x1b" not in err and "\t" not in err and "\u2028" not in err


def test_view_notice_names_its_output_on_one_line(capsys, out_dir, monkeypatch, small_cloud):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    code, _, err = cli(capsys, "view", *TINY, small_cloud, "--out", out_dir / "a\nb.png")
    assert code == 0 and err.count("\n") == 1 and "a\\nb.png" in err, err
    assert [p.name for p in out_dir.iterdir()] == ["a\nb.png"]


def test_control_characters_in_option_values_are_escaped(capsys, out_dir):
    code, _, err = cli(capsys, "render", *TINY, "--color-by", "x\ny", "--out", out_dir / "x.png")
    assert_one_error_line(code, err, out_dir)


# --- every other value ------------------------------------------------------------------------

@pytest.mark.parametrize("argv", [
    ["--width", "9" * 5000], ["--height", "-1"], ["--width", "1e3"],
    ["--point-size", "0"], ["--point-size", str(10**9)], ["--point-size", "9" * 5000],
    ["--eye-dome", "--eye-dome-strength", "nan"], ["--eye-dome", "--eye-dome-strength", "-1"],
    ["--eye-dome", "--eye-dome-strength", "inf"], ["--eye-dome", "--eye-dome-radius", "1e400"],
    ["--method", "progressive", "--target-ms", "inf"], ["--method", "progressive", "--target-ms", "nan"],
    ["--method", "progressive", "--target-ms", "-5"], ["--method", "progressive", "--target-ms", "0"],
    ["--method", "progressive", "--budget", "0"], ["--method", "progressive", "--budget", str(2**64)],
    ["--method", "progressive", "--budget", "nan"], ["--method", "progressive", "--budget", "9" * 5000],
    ["--method", "progressive", "--frames", str(10**12)], ["--method", "progressive", "--frames", "0"],
    ["--method", "progressive", "--converge", "--max-frames", str(10**12)],
    ["--gpu-memory-limit", "nan"], ["--gpu-memory-limit", "inf"], ["--gpu-memory-limit", "0.1"],
    ["--gpu-memory-limit", "-4G"], ["--gpu-memory-limit", "1" + "0" * 400], ["--gpu-memory-limit", "1e400"],
    ["--background", "256,0,0"], ["--background", "-1,0,0"], ["--background", "1,2"],
    ["--background", "nan,0,0"], ["--background", "9" * 5000 + ",0,0"],
    ["--hide-classes", "-1"], ["--hide-classes", "9" * 5000], ["--hide-classes", ","],
    ["--colormap", ""], ["--raster", "\x00"], ["--method", "sideways"],
])
def test_hostile_values_one_line(capsys, out_dir, argv):
    code, _, err = cli(capsys, "render", *TINY, *argv, "--out", out_dir / "x.png")
    assert_one_error_line(code, err, out_dir)
    assert len(err) < 400, err


def test_camera_path_longer_than_the_frame_limit(capsys, tmp_path, out_dir):
    from progressive.cli import MAX_FRAMES

    path = tmp_path / "path.json"
    path.write_text(json.dumps([CAMERA] * (MAX_FRAMES + 1)))
    code, _, err = cli(capsys, "render", *TINY, "--method", "progressive", "--camera-path", path,
                       "--out", out_dir / "x.png")
    assert_one_error_line(code, err, out_dir)


# --- camera JSON -------------------------------------------------------------------------------

@pytest.mark.parametrize("text", [
    '{"position": [1' + "0" * 400 + ', 0, 0], "target": [0, 0, 0]}',
    '{"position": [1' + "0" * 5000 + ', 0, 0], "target": [0, 0, 0]}',
    '{"position": [0, 0, 1], "target": [0, 0, 0], "near": 1e-' + "9" * 5000 + "}",
    "[" * 5000 + "]" * 5000,
    '{"a": ' * 5000 + "1" + "}" * 5000,
    '{"position": [0, 0, 1], "target": [0, 0, 0], "pad": "' + "x" * (17 * 2**20) + '"}',
    '{"position": [0, 0, 1e300], "target": [0, 0, 0]}',
    '{"position": [0, 0, 1], "target": [0, 0, 0], "far": 1e39}',
    '{"position": [0, 0, 1], "target": [0, 0, 0], "near": 1e-300}',
    '{"position": [0, 0, 1], "target": [0, 0, 0], "fov_y_deg": 1e-300}',
    '{"position": [0, 0, 1], "target": [0, 0, 0], "up": [1e-300, 0, 0]}',
    '{"position": [0, 0, 1e-300], "target": [0, 0, 0]}',
    '{"position": [0, 0, 1], "target": [0, 0, 0], "up": [0, 0, 1e300]}',
    '{"position": [0, 0, NaN], "target": [0, 0, 0]}',
    '{"position": [0, 0, Infinity], "target": [0, 0, 0]}',
    '{"position": [0, 0, 1], "target": [0, 0, 0], "near": 2, "far": 1}',
    '{"position": [0, 0, 1], "target": [0, 0, 0], "near": 0}',
])
@pytest.mark.parametrize("how", ["text", "file", "path"])
def test_hostile_camera_json(capsys, tmp_path, out_dir, text, how):
    code, _, err = render_camera(capsys, tmp_path, out_dir, text, how)
    assert_one_error_line(code, err, out_dir)
    assert len(err) < 400, err


@pytest.mark.parametrize("up", [[0, 0, 1], [0, 1e-12, 1], [1e-300, 0, 1]])
def test_plan_views_with_z_up_render(capsys, out_dir, small_cloud, up):
    """A camera straight above the target with Z up (or almost) is a plan view, not an error."""
    cam = dict(CAMERA, position=[CAMERA["target"][0], CAMERA["target"][1], CAMERA["target"][2] + 1000.0], up=up)
    code, _, err = cli(capsys, "render", *TINY, small_cloud, "--camera", json.dumps(cam), "--out", out_dir / "x.png")
    assert code == 0 and err == "", err


def test_large_far_and_position_in_range_render(capsys, tmp_path, out_dir, small_cloud):
    """The bounds are not refused too eagerly: far 1e30 and a camera 1e14 away render."""
    far = dict(CAMERA, far=1e30)
    away = dict(CAMERA, position=[1e14, 848500.0, 1500.0], far=2e14)
    for cam in (far, away):
        code, _, err = cli(capsys, "render", *TINY, small_cloud, "--camera", json.dumps(cam), "--out", out_dir / "x.png")
        assert code == 0 and err == "", err


def test_extreme_valid_camera_prints_nothing(tmp_path, small_cloud):
    """In its own process, so any warning from any thread would show on stderr."""
    cam = dict(CAMERA, fov_y_deg=1e-6, near=1e-30, far=1e30)
    proc = progressive("render", *TINY, small_cloud, "--camera", json.dumps(cam), "--out", tmp_path / "x.png")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr


def render_camera(capsys, tmp_path: Path, out_dir: Path, text: str, how: str, cloud: Path = SAMPLE):
    """Render with camera JSON given as text, as a --camera file or as a one-camera path."""
    if how == "text":
        option = ["--camera", text if text.lstrip().startswith("{") else " {" + text]
    elif how == "file":
        (tmp_path / "cam.json").write_text(text)
        option = ["--camera", tmp_path / "cam.json"]
    else:
        (tmp_path / "path.json").write_text("[" + text + "]")
        option = ["--method", "progressive", "--camera-path", tmp_path / "path.json"]
    return cli(capsys, "render", *TINY, cloud, *option, "--out", out_dir / "x.png")


NUMBERS = st.one_of(
    st.integers(-10, 10), st.integers(), st.integers(min_value=10**300, max_value=10**400),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([1e300, -1e300, 1e39, 1e-300, 5e-324, 0.0, -0.0]),
    st.floats(-1e6, 1e6), st.just("9" * 5000))
"""JSON numbers, some far beyond what a camera may hold; a str is a raw token."""


def token(value) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, float) and not math.isfinite(value):
        return {math.inf: "Infinity", -math.inf: "-Infinity"}.get(value, "NaN")
    return json.dumps(value)


VECTOR = st.one_of(
    st.lists(NUMBERS, min_size=0, max_size=4).map(lambda v: "[" + ", ".join(map(token, v)) + "]"),
    st.sampled_from(['"abc"', "null", "true", "{}", "[[1, 2, 3]]", '[1, "2", 3]', "[true, 0, 1]"]))
VALID = {"position": "[637000, 848500, 1500]", "target": "[636800, 849000, 450]", "up": "[0, 0, 1]",
         "fov_y_deg": "50", "near": "10", "far": "5000"}


@st.composite
def camera_texts(draw) -> str:
    """A camera JSON text: each field valid, hostile, of the wrong type or missing; extra
    fields; then possibly nested deep or cut short."""
    fields = {}
    for key, valid in VALID.items():
        choice = draw(st.sampled_from(["valid"] * 4 + ["hostile", "missing"]))
        if choice == "valid":
            fields[key] = valid
        elif choice == "hostile":
            fields[key] = draw(VECTOR) if key in ("position", "target", "up") else token(draw(NUMBERS))
    if draw(st.booleans()) and draw(st.booleans()):
        fields[draw(st.sampled_from(["extra", "Position", ""]))] = token(draw(NUMBERS))
    text = "{" + ", ".join(f"{json.dumps(k)}: {v}" for k, v in fields.items()) + "}"
    depth = draw(st.sampled_from([0] * 6 + [1, 9, 5000]))
    if depth:
        text = '{"a": [' * depth + text + "]}" * depth
    if draw(st.integers(0, 9)) == 0:
        text = text[: draw(st.integers(0, len(text)))]
    return text


@FUZZ
@given(text=camera_texts(), how=st.sampled_from(["text", "file", "path"]))
def test_fuzzed_camera_json_renders_or_one_line(capsys, tmp_path, small_cloud, text, how):
    out_dir = tmp_path / "fuzz-out"
    out_dir.mkdir(exist_ok=True)
    for p in out_dir.iterdir():
        p.unlink()
    code, out, err = render_camera(capsys, tmp_path, out_dir, text, how, small_cloud)
    if code == 0:
        assert err == "" and [p.name for p in out_dir.iterdir()] == ["x.png"], err
    else:
        assert_one_error_line(code, err, out_dir)
        assert "Traceback" not in err and len(err) < 400, err


def magnitudes(low: float, high: float) -> st.SearchStrategy:
    """Floats whose magnitude is spread evenly in log scale over [low, high], either sign."""
    return st.tuples(st.floats(math.log10(low), math.log10(high)), st.booleans()).map(
        lambda t: (-1 if t[1] else 1) * 10.0 ** t[0])


@st.composite
def edge_cameras(draw) -> dict:
    """Cameras at the edges of what the contract accepts (and a little beyond)."""
    centre = [636900.0, 848700.0, 500.0]
    position = [c + draw(magnitudes(1e-32, 2e15)) for c in centre]
    target = [c + draw(magnitudes(1e-32, 1e3)) for c in centre]
    up = [draw(magnitudes(1e-32, 2e15)) for _ in range(3)]
    near = abs(draw(magnitudes(1e-32, 1e31)))
    return {"position": position, "target": target, "up": up, "fov_y_deg": draw(st.floats(1e-7, 180.0)),
            "near": near, "far": near * abs(draw(magnitudes(1.0, 1e62)))}


@FUZZ
@given(camera=edge_cameras())
def test_every_accepted_camera_renders(capsys, tmp_path, small_cloud, camera):
    """Brute and progressive (reprojection included): a camera from_dict accepts renders
    with nothing on stderr; one it refuses is one line."""
    from progressive.camera import Camera, CameraError

    try:
        Camera.from_dict(camera)
        accepted = True
    except CameraError:
        accepted = False
    out = tmp_path / "x.png"
    for method in (["--method", "brute"], ["--method", "progressive", "--frames", "3", "--budget", "700"]):
        code, _, err = cli(capsys, "render", *TINY, small_cloud, *method, "--camera", json.dumps(camera),
                           "--out", out)
        if accepted:
            assert code == 0 and err == "", err
        else:
            assert code == 2 and err.startswith("progressive: error: camera") and err.count("\n") == 1, err


@pytest.mark.parametrize("at", [0, 1, 2])
def test_signal_during_commit_still_commits_every_output(tmp_path, monkeypatch, at):
    """The renames are the last step: once begun, an interrupt lets them finish."""
    from progressive import output

    replace, calls = os.replace, []

    def interrupted_replace(src, dst):
        replace(src, dst)
        calls.append(dst)
        if len(calls) == at + 1:
            raise KeyboardInterrupt

    finals = [tmp_path / f"{k}.json" for k in range(3)]
    with pytest.raises(KeyboardInterrupt), output.Outputs() as outputs:
        for k, path in enumerate(finals):
            outputs.write(path, output.json_writer(k))
        monkeypatch.setattr(output.os, "replace", interrupted_replace)
        outputs.commit()
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == [p.name for p in finals]
    assert [json.loads(p.read_text()) for p in finals] == [0, 1, 2]
