"""E57 and PLY input, held to independent readers: pye57 (with pyquaternion for the poses)
and the values written with plyfile from a real cloud read by laspy."""

from __future__ import annotations

import json
import uuid
from pathlib import Path

import laspy
import numpy as np
import plyfile
import pye57
import pytest
from pye57 import libe57
from test_hard_input import assert_one_error_line, cli

from conftest import BUNNY, SAMPLE
from progressive.loaders import CloudLoader
from progressive.loaders.lookup import read_point

SMALL = ("--width", "96", "--height", "64")


def load(paths) -> tuple:
    """The cloud's info and, in file order, its file coordinates (origin + float32
    positions, in float64) and attributes."""
    with CloudLoader(paths) as loader:
        info = loader.info
        batches = sorted(loader, key=lambda b: b.start)
        counted = loader.nonfinite_positions
    xyz = np.concatenate([info.origin + b.positions.astype(np.float64) for b in batches])
    attrs = {a.name: np.concatenate([b.attributes[a.name] for b in batches])
             for a in info.attributes if a.name != "elevation"}
    return info, xyz, attrs, counted


def assert_positions(xyz: np.ndarray, expected: np.ndarray, info) -> None:
    """Within the float32 rounding of a position relative to the origin."""
    step = np.abs(expected - info.origin).max() * 2.0 ** -23 + 1e-12
    np.testing.assert_allclose(xyz, expected, rtol=0, atol=step)


def autzen(n: int | None = None) -> laspy.LasData:
    las = laspy.read(SAMPLE)
    return las if n is None else las[:n]


# E57 ------------------------------------------------------------------------------------

def test_bunny_against_pye57():
    ref = pye57.E57(str(BUNNY)).read_scan(0, ignore_missing_fields=True)
    expected = np.stack([ref[f] for f in ("cartesianX", "cartesianY", "cartesianZ")], axis=1)
    info, xyz, attrs, counted = load([BUNNY])
    assert info.files[0].format == "E57" and info.points == len(expected) == 30_571 and counted == 0
    assert_positions(xyz, expected, info)
    np.testing.assert_array_equal(info.bounds_min, expected.min(axis=0))
    np.testing.assert_array_equal(info.bounds_max, expected.max(axis=0))
    np.testing.assert_allclose(info.origin, (expected.min(axis=0) + expected.max(axis=0)) / 2)
    assert [a.name for a in info.attributes] == ["elevation"] and attrs == {}


def posed_scans(path: Path) -> list[dict]:
    """Two Cartesian scans with poses, intensity and 8-bit colour from autzen, some points
    marked invalid; written by pye57."""
    las = autzen(3000)
    local = np.stack([las.x - 636500.0, las.y - 849200.0, las.z - 450.0], axis=1)
    poses = [((0.9, 0.1, -0.3, 0.2), (1000.0, -250.0, 12.5)), ((0.2, 0.0, 0.0, 0.98), (5.0e5, 4.2e6, 80.0))]
    scans = []
    with pye57.E57(str(path), mode="w") as e57:
        for i, (q, t) in enumerate(poses):
            part = slice(i * 1500, (i + 1) * 1500)
            data = {"cartesianX": local[part, 0].copy(), "cartesianY": local[part, 1].copy(),
                    "cartesianZ": local[part, 2].copy(), "intensity": np.asarray(las.intensity[part], np.float32),
                    "colorRed": (np.asarray(las.red[part]) & 255).astype(np.uint8),
                    "colorGreen": (np.asarray(las.green[part]) & 255).astype(np.uint8),
                    "colorBlue": (np.asarray(las.blue[part]) & 255).astype(np.uint8),
                    "cartesianInvalidState": (np.arange(1500) % 97 == 5).astype(np.int8)}
            e57.write_scan_raw(data, name=f"station {i}", rotation=np.array(q) / np.linalg.norm(q),
                               translation=np.array(t))
            scans.append(data)
    return scans


def test_posed_scans_against_pye57(tmp_path):
    path = tmp_path / "posed.e57"
    posed_scans(path)
    e57 = pye57.E57(str(path))
    refs = [e57.read_scan(i, intensity=True, colors=True) for i in range(2)]   # invalid points left out
    raws = [e57.read_scan_raw(i) for i in range(2)]
    info, xyz, attrs, counted = load([path])
    valid = np.concatenate([r["cartesianInvalidState"] == 0 for r in raws])
    assert info.points == 3000 and counted == int((~valid).sum()) == 2 * 16
    assert np.isnan(xyz[~valid]).all()
    expected = np.concatenate([np.stack([r[f] for f in ("cartesianX", "cartesianY", "cartesianZ")], axis=1)
                               for r in refs])
    assert_positions(xyz[valid], expected, info)
    np.testing.assert_allclose(info.bounds_min, expected.min(axis=0), rtol=1e-14)     # pose rounding differs
    np.testing.assert_allclose(info.bounds_max, expected.max(axis=0), rtol=1e-14)
    assert [a.name for a in info.attributes] == ["rgb", "intensity", "elevation"]
    np.testing.assert_array_equal(attrs["intensity"][valid], np.concatenate([r["intensity"] for r in refs]))
    rgb = np.concatenate([np.stack([r[c] for c in ("colorRed", "colorGreen", "colorBlue")], axis=1) for r in refs])
    np.testing.assert_array_equal(attrs["rgb"][valid], rgb)
    assert info.files[0].rgb_16bit is False
    assert valid[1600]
    assert read_point(info, 1600) == pytest.approx(expected[np.count_nonzero(valid[:1600])], abs=1e-9)


def test_info_reports_the_scans(tmp_path, capsys):
    path = tmp_path / "posed.e57"
    posed_scans(path)
    code, out, err = cli(capsys, "info", path, "--json")
    assert code == 0, err
    scans = json.loads(out)["files"][0]["scans"]
    e57 = pye57.E57(str(path))
    header = e57.get_header(1)
    assert [(s["name"], s["points"], s["coordinates"]) for s in scans] == \
        [("station 0", 1500, "cartesian"), ("station 1", 1500, "cartesian")]
    assert scans[1]["rotation"] == pytest.approx(list(header.rotation), abs=1e-12)
    assert scans[1]["translation"] == pytest.approx([5.0e5, 4.2e6, 80.0])
    code, out, err = cli(capsys, "info", path)
    assert "scans of" in out and "station 1: 1,500 points, cartesian" in out, out


def write_spherical(path: Path, rae: np.ndarray, invalid: np.ndarray, q, t) -> None:
    """One spherical scan (range, azimuth, elevation as doubles) with a pose, through
    libE57's node API (pye57 writes only Cartesian scans)."""
    with pye57.E57(str(path), mode="w") as e57:
        imf = e57.image_file
        scan = libe57.StructureNode(imf)
        scan.set("guid", libe57.StringNode(imf, f"{{{uuid.uuid4()}}}"))
        scan.set("name", libe57.StringNode(imf, "spherical"))
        pose, rotation, translation = (libe57.StructureNode(imf) for _ in range(3))
        for name, value in zip("wxyz", q, strict=True):
            rotation.set(name, libe57.FloatNode(imf, float(value)))
        for name, value in zip("xyz", t, strict=True):
            translation.set(name, libe57.FloatNode(imf, float(value)))
        pose.set("rotation", rotation)
        pose.set("translation", translation)
        scan.set("pose", pose)
        prototype = libe57.StructureNode(imf)
        names = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
        for name, column in zip(names, rae.T, strict=True):
            prototype.set(name, libe57.FloatNode(imf, float(column.min()), libe57.E57_DOUBLE, float(column.min()), float(column.max())))
        prototype.set("sphericalInvalidState", libe57.IntegerNode(imf, 0, 0, 2))
        points = libe57.CompressedVectorNode(imf, prototype, libe57.VectorNode(imf, True))
        scan.set("points", points)
        e57.data3d.append(scan)
        arrays = [np.ascontiguousarray(c) for c in rae.T] + [invalid.astype(np.int8)]
        buffers = libe57.VectorSourceDestBuffer()
        for name, array in zip((*names, "sphericalInvalidState"), arrays, strict=True):
            buffers.append(libe57.SourceDestBuffer(imf, name, array, len(array), True, True))
        writer = points.writer(buffers)
        writer.write(len(rae))
        writer.close()


def test_spherical_scan_against_pye57(tmp_path):
    rng = np.random.default_rng(3)
    n = 2000
    rae = np.stack([rng.uniform(1, 80, n), rng.uniform(-np.pi, np.pi, n), rng.uniform(-1.2, 1.2, n)], axis=1)
    invalid = np.where(np.arange(n) % 50 == 7, 2, 0)
    q = np.array([0.8, -0.2, 0.1, 0.55])
    path = tmp_path / "spherical.e57"
    write_spherical(path, rae, invalid, q / np.linalg.norm(q), (631000.0, 4834000.0, 120.0))
    ref = pye57.E57(str(path)).read_scan(0)
    expected = np.stack([ref[f] for f in ("cartesianX", "cartesianY", "cartesianZ")], axis=1)
    info, xyz, _, counted = load([path])
    valid = invalid == 0
    assert info.files[0].scans[0].coordinates == "spherical" and counted == int((~valid).sum())
    assert_positions(xyz[valid], expected, info)
    np.testing.assert_allclose(info.bounds_min, expected.min(axis=0), rtol=0, atol=1e-8)


# PLY ------------------------------------------------------------------------------------

def write_ply(path: Path, las: laspy.LasData, *, coords="f8", colours=("red", "green", "blue"),
              colour_type="u1", text=False, byte_order="<", extra=True, order=("x", "y", "z")) -> np.ndarray:
    """The LAS points as a PLY vertex element (colours of the given names and type,
    `quality` an extra float property), plus a face element to be ignored."""
    fields = [(a, coords) for a in order] + [(c, colour_type) for c in colours] + [("intensity", "u2")]
    fields += [("quality", "f4")] if extra else []
    v = np.empty(len(las.x), dtype=fields)
    for a in "xyz":
        v[a] = getattr(las, a)
    scale = 256 if colour_type == "u2" else 1
    for c, dim in zip(colours, ("red", "green", "blue"), strict=True):
        v[c] = np.asarray(las[dim]) * scale
    v["intensity"] = las.intensity
    if extra:
        v["quality"] = np.asarray(las.gps_time) - 245_000
    faces = np.empty(2, dtype=[("vertex_indices", "O")])
    faces["vertex_indices"] = [np.array([0, 1, 2], np.int32), np.array([1, 2, 3], np.int32)]
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex"), plyfile.PlyElement.describe(faces, "face")],
                    text=text, byte_order=byte_order).write(str(path))
    return v


PLY_CASES = {
    "binary little endian, double, uchar": dict(coords="f8"),
    "binary big endian, float, ushort, r/g/b": dict(coords="f4", byte_order=">", colour_type="u2",
                                                   colours=("r", "g", "b")),
    "ascii, double, z first": dict(text=True, order=("z", "x", "y")),
}


@pytest.mark.parametrize("case", PLY_CASES)
def test_ply_against_what_was_written(tmp_path, case):
    kwargs = PLY_CASES[case]
    las = autzen(5000 if kwargs.get("text") else None)
    path = tmp_path / "cloud.ply"
    v = write_ply(path, las, **kwargs)
    info, xyz, attrs, counted = load([path])
    f = info.files[0]
    assert f.format == "PLY" and f.points == len(v) and counted == 0
    assert f.rgb_16bit is (kwargs.get("colour_type") == "u2")
    expected = np.stack([v[a].astype(np.float64) for a in "xyz"], axis=1)
    assert_positions(xyz, expected, info)
    np.testing.assert_array_equal(info.bounds_min, expected.min(axis=0))
    assert [a.name for a in info.attributes] == ["rgb", "intensity", "elevation", "quality"]
    np.testing.assert_array_equal(attrs["rgb"], np.stack([las.red, las.green, las.blue], axis=1))
    np.testing.assert_array_equal(attrs["intensity"], las.intensity)
    np.testing.assert_array_equal(attrs["quality"], v["quality"])
    assert read_point(info, 1234) == pytest.approx(expected[1234], abs=0)


def test_ply_renders_as_the_las_it_was_made_from(tmp_path, capsys):
    """Same points in the same order at the same origin: the same ids, pixel for pixel."""
    ply, cam = tmp_path / "autzen.ply", tmp_path / "cam.json"
    write_ply(ply, autzen())
    ids = {}
    for name, path, camera in (("las", SAMPLE, ("--save-camera", cam)), ("ply", ply, ("--camera", cam))):
        ids[name] = tmp_path / f"{name}.npy"
        code, _, err = cli(capsys, "render", path, *SMALL, "--out", tmp_path / f"{name}.png",
                           "--ids", ids[name], *camera)
        assert code == 0, err
    a, b = np.load(ids["las"]), np.load(ids["ply"])
    assert (a != 0xFFFFFFFF).sum() > 1000
    np.testing.assert_array_equal(a, b)


def test_las_and_ply_in_one_cloud(tmp_path):
    las = autzen(4000)
    ply = tmp_path / "part.ply"
    write_ply(ply, las, extra=False)
    info, xyz, attrs, _ = load([SAMPLE, ply])
    assert [f.format for f in info.files] == ["LAS", "PLY"] and info.points == 114_000
    assert [a.name for a in info.attributes] == ["rgb", "intensity", "elevation"]
    np.testing.assert_array_equal(attrs["rgb"][110_000:], np.stack([las.red, las.green, las.blue], axis=1))
    assert_positions(xyz[110_000:], np.stack([las.x, las.y, las.z], axis=1), info)


# Bad input ------------------------------------------------------------------------------

def small_ply(path: Path, *, text=False, without=None) -> bytes:
    names = [a for a in ("x", "y", "z", "q") if a != without]
    v = np.zeros(50, dtype=[(a, "f4") for a in names])
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex")], text=text).write(str(path))
    return path.read_bytes()


def damaged(tmp_path: Path, case: str) -> Path:
    bunny, ply = BUNNY.read_bytes(), small_ply(tmp_path / "ok.ply")
    text = small_ply(tmp_path / "ok_text.ply", text=True)
    data = {
        "e57 truncated": lambda: bunny[:len(bunny) // 2],
        "e57 header only": lambda: bunny[:40],
        "e57 garbage in the data": lambda: bunny[:300_000] + bytes(range(256)) * 8 + bunny[302_048:],
        "e57 garbage at the end (XML)": lambda: bunny[:-3000] + b"\xff" * 3000,
        "e57 empty": lambda: b"",
        "ply truncated": lambda: ply[:-10],
        "ply header cut": lambda: ply[:30],
        "ply garbage": lambda: b"ply\n" + bytes(range(128, 256)) * 4,
        "ply wrong magic": lambda: b"plx\n" + ply[4:],
        "ply count beyond the data": lambda: ply.replace(b"vertex 50", b"vertex 51"),
        "ply count short of the data": lambda: ply.replace(b"vertex 50", b"vertex 49"),
        "ply ascii count short of the data": lambda: text.replace(b"vertex 50", b"vertex 49"),
        "ply ascii malformed": lambda: text[:-20] + b"abc def\n",
        "ply no vertices": lambda: ply.replace(b"vertex 50", b"vertex 0"),
        "ply no vertex element": lambda: ply.replace(b"element vertex", b"element points"),
        "ply no x": lambda: small_ply(tmp_path / "nox.ply", without="x"),
        "ply empty": lambda: b"",
    }[case]()
    path = tmp_path / "in" / ("bad.e57" if case.startswith("e57") else "bad.ply")
    path.parent.mkdir()
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("case", [
    "e57 truncated", "e57 header only", "e57 garbage in the data", "e57 garbage at the end (XML)", "e57 empty",
    "ply truncated", "ply header cut", "ply garbage", "ply wrong magic", "ply count beyond the data",
    "ply count short of the data", "ply ascii count short of the data", "ply ascii malformed",
    "ply no vertices", "ply no vertex element", "ply no x", "ply empty",
])
def test_damaged_files_are_one_line(tmp_path, capsys, case):
    path = damaged(tmp_path, case)
    out = tmp_path / "out"
    out.mkdir()
    code, _, err = cli(capsys, "render", path, *SMALL, "--out", out / "x.png", "--ids", out / "x.npy")
    assert_one_error_line(code, err, out)
    assert "bad." in err


def test_e57_that_is_all_invalid_is_one_line(tmp_path, capsys):
    path = tmp_path / "in.e57"
    n = 100
    write_spherical(path, np.ones((n, 3)), np.full(n, 2), (1.0, 0, 0, 0), (0.0, 0.0, 0.0))
    out = tmp_path / "out"
    out.mkdir()
    code, _, err = cli(capsys, "info", path)
    assert_one_error_line(code, err, out)
    assert "no valid point" in err
