"""`--reproject`: files in different coordinate systems load as one cloud in the target
CRS, each point pyproj's float64 transform of laspy's coordinates; picks report the
target's coordinates, the file's own and latitude and longitude; info names every
file's CRS. The references are laspy and pyproj."""

from __future__ import annotations

import json

import laspy
import numpy as np
import pyproj
import pytest

from conftest import SAMPLE, shared_file
from progressive.camera import Camera
from progressive.cli import main
from progressive.permutation import LAYOUT, Permutation
from progressive.reference import EMPTY, reference_ids
from progressive.reproject import ReprojectingLoader, target_crs

W, H = 160, 120
UTM = "EPSG:32610"          # the sample's zone
SHIFT = 500.0               # metres east of the sample, so the copies sit side by side
UTM_SCALE = 0.001


def las_xyz(path) -> np.ndarray:
    las = laspy.read(path)
    return np.stack([las.x, las.y, las.z], axis=1)


def metres_per_height_unit(crs) -> float:
    """The vertical axis's unit in metres, else the horizontal unit's (a metre for degrees)."""
    axis = next((a for a in crs.axis_info if a.direction == "up"), crs.axis_info[0])
    return axis.unit_conversion_factor if "degree" not in axis.unit_name else 1.0


def pyproj_xyz(path, target: str) -> np.ndarray:
    """The reference: laspy's float64 coordinates through pyproj's float64 transform,
    heights converted by the units of the two CRSs."""
    source = laspy.open(path).header.parse_crs()
    dst = pyproj.CRS.from_user_input(target)
    xyz = las_xyz(path)
    x, y = pyproj.Transformer.from_crs(source, dst, always_xy=True).transform(xyz[:, 0], xyz[:, 1])
    z = xyz[:, 2] * (metres_per_height_unit(source) / metres_per_height_unit(dst))
    return np.stack([x, y, z], axis=1)


@pytest.fixture(scope="module")
def utm_copy(tmp_path_factory):
    """The sample in UTM zone 10N (metres, EPSG code in GeoTIFF keys), SHIFT m east."""
    src = laspy.read(SAMPLE)
    xyz = pyproj_xyz(SAMPLE, UTM)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = [UTM_SCALE] * 3
    header.offsets = [494000.0, 4877000.0, 0.0]
    header.add_crs(pyproj.CRS.from_user_input(UTM))
    out = laspy.LasData(header)
    out.x, out.y, out.z = xyz[:, 0] + SHIFT, xyz[:, 1], xyz[:, 2]
    for dim in ("intensity", "classification", "red", "green", "blue", "gps_time", "return_number", "number_of_returns"):
        setattr(out, dim, getattr(src, dim))
    path = tmp_path_factory.mktemp("reproject") / "autzen_utm.las"
    out.write(path)
    return path


@pytest.fixture(scope="module")
def no_crs(tmp_path_factory):
    src = laspy.read(SAMPLE)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = src.header.scales, src.header.offsets
    out = laspy.LasData(header)
    out.x, out.y, out.z = src.x[:1000], src.y[:1000], src.z[:1000]
    path = tmp_path_factory.mktemp("reproject") / "no_crs.las"
    out.write(path)
    return path


@pytest.mark.parametrize("target", [UTM, "EPSG:26910", "EPSG:3857"])
def test_positions_are_pyproj_of_laspy(utm_copy, target):
    files = [SAMPLE, utm_copy]
    expected = np.concatenate([pyproj_xyz(f, target) for f in files])
    got = np.full(expected.shape, np.nan, dtype=np.float32)
    with ReprojectingLoader(files, target_crs(target)) as loader:
        origin = loader.info.origin
        for batch in loader:
            got[batch.start:batch.start + batch.count] = batch.positions
            assert np.array_equal(batch.bounds[0], expected[batch.start:batch.start + batch.count].min(axis=0))
    assert np.array_equal(got, (expected - origin).astype(np.float32))
    assert np.all(loader.info.bounds_min <= expected.min(axis=0) + 1e-6 * np.abs(expected).max())
    assert np.all(loader.info.bounds_max >= expected.max(axis=0) - 1e-6 * np.abs(expected).max())


def test_render_ids_are_the_reference_of_the_reprojected_points(tmp_path, capsys, utm_copy):
    files = [SAMPLE, utm_copy]
    ids_path, camera_path = tmp_path / "ids.npy", tmp_path / "cam.json"
    capsys.readouterr()
    assert main(["render", *map(str, files), "--reproject", UTM, "--width", str(W), "--height", str(H),
                 "--ids", str(ids_path), "--save-camera", str(camera_path)]) == 0
    assert capsys.readouterr().err == ""           # no 'different coordinate systems' warning: they are reprojected
    xyz = np.concatenate([pyproj_xyz(f, UTM) for f in files])
    slots = Permutation.for_count(len(xyz), order=LAYOUT).forward(np.arange(len(xyz))).astype(np.int64)
    ids = np.load(ids_path)
    ref = reference_ids(xyz, Camera.from_json(camera_path.read_text()), W, H, tie_key=slots)
    assert np.mean(ids == ref) >= 0.999
    shown = ids[ids != EMPTY]
    assert (shown < 110_000).any() and (shown >= 110_000).any(), "both files are in view, side by side"


def pick(capsys, files, *args) -> dict:
    capsys.readouterr()
    assert main(["render", *map(str, files), "--width", str(W), "--height", str(H), *args]) == 0
    return json.loads(capsys.readouterr().out)


def shown_pixel(tmp_path, capsys, files, *args) -> tuple[int, int]:
    ids_path = tmp_path / "ids.npy"
    capsys.readouterr()
    assert main(["render", *map(str, files), "--width", str(W), "--height", str(H), "--ids", str(ids_path), *args]) == 0
    ids = np.load(ids_path)
    rows, cols = np.nonzero(ids != EMPTY)
    return int(cols[len(cols) // 3]), int(rows[len(rows) // 3])


def test_pick_reports_target_file_and_geographic_coordinates(tmp_path, capsys, utm_copy):
    files = [SAMPLE, utm_copy]
    x, y = shown_pixel(tmp_path, capsys, files, "--reproject", UTM)
    got = pick(capsys, files, "--reproject", UTM, f"--pick={x + 0.5},{y + 0.5}")
    assert got["found"]
    path = SAMPLE if got["cloud_index"] < 110_000 else utm_copy
    i = got["index"]
    expected = pyproj_xyz(path, UTM)[i]
    assert [got["x"], got["y"], got["z"]] == expected.tolist()
    file_xyz = las_xyz(path)[i]
    digits = [round(-np.log10(s)) for s in laspy.open(path).header.scales]
    assert [got["file_coordinates"][a] for a in "xyz"] == [round(float(v), d) for v, d in zip(file_xyz, digits)]
    lon, lat = pyproj.Transformer.from_crs(UTM, "EPSG:4326", always_xy=True).transform(expected[0], expected[1])
    assert (got["lon"], got["lat"]) == (lon, lat)
    assert "EPSG:32610" in got["crs"]


def test_pick_without_reprojecting_has_latitude_and_longitude(tmp_path, capsys):
    x, y = shown_pixel(tmp_path, capsys, [SAMPLE])
    got = pick(capsys, [SAMPLE], f"--pick={x + 0.5},{y + 0.5}")
    xyz = las_xyz(SAMPLE)[got["index"]]
    crs = laspy.open(SAMPLE).header.parse_crs()
    lon, lat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(xyz[0], xyz[1])
    assert (got["lon"], got["lat"]) == (lon, lat)
    assert 44 < got["lat"] < 45 and -124 < got["lon"] < -123       # Eugene, Oregon


def test_pick_where_the_crs_allows_none(tmp_path, capsys, no_crs):
    x, y = shown_pixel(tmp_path, capsys, [no_crs])
    got = pick(capsys, [no_crs], f"--pick={x + 0.5},{y + 0.5}")
    assert got["found"] and got["lat"] is None and got["lon"] is None and got["crs"] is None


def one_line_error(capsys, argv) -> str:
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("progressive: error: ") and err.count("\n") == 1, err
    return err


@pytest.mark.parametrize("command", ["render", "view", "info"])
def test_a_file_without_crs_is_one_line(tmp_path, capsys, monkeypatch, no_crs, command):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    out = tmp_path / "x.png"
    extra = {"render": ["--out", str(out)], "view": ["--out", str(out)], "info": []}[command]
    err = one_line_error(capsys, [command, str(SAMPLE), str(no_crs), "--reproject", UTM, *extra])
    assert "no_crs.las" in err and "no coordinate system" in err and not out.exists()


@pytest.mark.parametrize("code", ["EPSG:999999", "utm", "EPSG:", "/etc/passwd"])
def test_unknown_target_is_one_line(tmp_path, capsys, code):
    err = one_line_error(capsys, ["render", str(SAMPLE), "--reproject", code, "--out", str(tmp_path / "x.png")])
    assert "--reproject" in err and not (tmp_path / "x.png").exists()


def test_different_codes_are_refused_without_reproject_and_load_with_it(tmp_path, capsys):
    a, b = shared_file("wires.laz"), shared_file("las_with_several_extra_byte_bloc.laz")
    err = one_line_error(capsys, ["render", str(a), str(b), "--out", str(tmp_path / "x.png")])
    assert "EPSG:2948" in err and "EPSG:2154" in err
    capsys.readouterr()
    assert main(["info", str(a), str(b), "--reproject", "EPSG:4326", "--json"]) == 0
    desc = json.loads(capsys.readouterr().out)
    for f, path in zip(desc["files"], (a, b)):
        expected = pyproj_xyz(path, "EPSG:4326")
        assert f["reprojected_bounds"] == {"min": expected.min(axis=0).tolist(), "max": expected.max(axis=0).tolist()}
    assert desc["epsg"] == 4326 and desc["points"] == laspy.open(a).header.point_count + laspy.open(b).header.point_count


@pytest.mark.parametrize("name", ["autzen_trim.las", "wires.laz", "las_with_several_extra_byte_bloc.laz"])
def test_info_names_crs_and_epsg_as_pyproj_reads_them(capsys, name):
    path = SAMPLE if name == "autzen_trim.las" else shared_file(name)
    crs = laspy.open(path).header.parse_crs()
    capsys.readouterr()
    assert main(["info", str(path), "--json"]) == 0
    desc = json.loads(capsys.readouterr().out)
    assert desc["files"][0]["crs_name"] == crs.name and desc["files"][0]["epsg"] == crs.to_epsg()
    assert main(["info", str(path)]) == 0
    assert crs.name in capsys.readouterr().out


def test_session_point_is_in_the_target_crs(utm_copy):
    from progressive.session import Session, SessionOptions

    files = [SAMPLE, utm_copy]
    expected = np.concatenate([pyproj_xyz(f, UTM) for f in files])
    with Session(files, SessionOptions(width=W, height=H, reproject=UTM)) as session:
        for index in (0, 109_999, 110_000, 219_999):
            assert session.point(index).tolist() == expected[index].tolist()
    with Session([SAMPLE], SessionOptions(width=W, height=H)) as session:
        assert session.point(5).tolist() == las_xyz(SAMPLE)[5].tolist()
