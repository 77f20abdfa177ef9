"""Picking: `render --pick X,Y` and Session.pick name the point the ids show at that
pixel (or the nearest within the radius) and give all of it as laspy reads it."""

from __future__ import annotations

import json

import laspy
import numpy as np
import pytest

from conftest import SAMPLE, shared_file
from progressive.cli import main

W, H = 160, 120
EMPTY = 0xFFFFFFFF


def pick(capsys, tmp_path, files, x, y) -> tuple[dict, np.ndarray]:
    ids_path = tmp_path / "ids.npy"
    capsys.readouterr()
    assert main(["render", *map(str, files), "--width", str(W), "--height", str(H), "--ids", str(ids_path),
                 f"--pick={x},{y}"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1
    return json.loads(out[0]), np.load(ids_path)


def covered_pixel(ids: np.ndarray) -> tuple[int, int]:
    rows, cols = np.nonzero(ids != EMPTY)
    k = len(rows) // 2
    return int(cols[k]), int(rows[k])


@pytest.mark.parametrize("name", ["autzen_trim.las", "extrabytes.las", "las_with_several_extra_byte_bloc.laz"])
def test_pick_gives_the_shown_point_as_laspy_reads_it(capsys, tmp_path, name):
    path = SAMPLE if name == "autzen_trim.las" else shared_file(name)
    _, ids = pick(capsys, tmp_path, [path], 0, 0)
    x, y = covered_pixel(ids)
    got, _ = pick(capsys, tmp_path, [path], x + 0.5, y + 0.5)
    assert got["found"] and got["pixel"] == [x, y] and got["index"] == int(ids[y, x])
    las = laspy.read(path)
    i = got["index"]
    digits = [round(-np.log10(s)) for s in las.header.scales]
    for axis, d in zip("xyz", digits):
        assert got[axis] == round(float(las[axis][i]), d)
        assert abs(got[axis] - float(las[axis][i])) <= 0.5 * 10.0 ** -d
    for dim in las.point_format.dimension_names:
        if dim in ("X", "Y", "Z"):
            continue
        expected = np.asarray(las[dim])[i]
        assert np.array_equal(np.asarray(got["attributes"][dim]), expected), dim
    assert got["file"] == str(path)


def test_pick_in_a_cloud_of_two_files_names_the_file(capsys, tmp_path):
    files = [SAMPLE, shared_file("extrabytes.las")]
    _, ids = pick(capsys, tmp_path, files, 0, 0)
    second = np.nonzero((ids >= 110_000) & (ids != EMPTY))
    assert second[0].size, "the second file is not in view"
    x, y = int(second[1][0]), int(second[0][0])
    got, _ = pick(capsys, tmp_path, files, x, y)
    assert got["file"] == str(files[1]) and got["cloud_index"] == int(ids[y, x]) and got["index"] == ids[y, x] - 110_000


def test_pick_searches_the_radius_and_reports_nothing_beyond(capsys, tmp_path):
    _, ids = pick(capsys, tmp_path, [SAMPLE], 0, 0)
    rows, cols = np.nonzero(ids == EMPTY)
    covered = np.argwhere(ids != EMPTY)
    # an empty pixel with a covered one 2 pixels away, and one far from everything
    distance = [np.min(np.abs(covered - [r, c]).max(axis=1)) for r, c in zip(rows, cols)]
    near = next(k for k, d in enumerate(distance) if d == 2)
    far = int(np.argmax(distance))
    assert distance[far] > 7
    got, _ = pick(capsys, tmp_path, [SAMPLE], cols[near], rows[near])
    px, py = got["pixel"]
    assert got["found"] and ids[py, px] != EMPTY and max(abs(px - cols[near]), abs(py - rows[near])) <= 2
    got, _ = pick(capsys, tmp_path, [SAMPLE], cols[far], rows[far])
    assert got == {"found": False}


def test_pick_outside_the_image_and_bad_values(capsys, tmp_path):
    got, _ = pick(capsys, tmp_path, [SAMPLE], -50, 10_000)
    assert got == {"found": False}
    for bad in ("1", "1,nan", "a,b"):
        capsys.readouterr()
        assert main(["render", "--pick", bad]) == 2
        err = capsys.readouterr().err
        assert err.startswith("progressive: error: ") and err.count("\n") == 1


def test_pick_rounds_to_the_decimals_of_scale_and_offset(capsys, tmp_path):
    """A scale of 0.0025 and an offset of 0.005 carry four decimals: nothing is cut."""
    src = laspy.read(SAMPLE)
    header = laspy.LasHeader(point_format=src.header.point_format, version=src.header.version)
    header.scales = np.array([0.0025, 0.0025, 0.0025])
    header.offsets = np.array([636000.005, 849000.005, 0.005])
    out = laspy.LasData(header)
    out.x, out.y, out.z = src.x, src.y, src.z
    for dim in ("intensity", "classification", "red", "green", "blue"):
        out[dim] = src[dim]
    path = tmp_path / "odd.las"
    out.write(path)
    _, ids = pick(capsys, tmp_path, [path], 0, 0)
    x, y = covered_pixel(ids)
    got, _ = pick(capsys, tmp_path, [path], x, y)
    las = laspy.read(path)
    for axis in "xyz":
        assert got[axis] == round(float(las[axis][got["index"]]), 4)
