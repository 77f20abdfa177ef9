"""Coordinate systems: files whose EPSG codes differ are refused as one cloud (one line
naming both); labels that only may differ warn; info names each file's CRS."""

from __future__ import annotations

import json

from conftest import SAMPLE, shared_file
from progressive.cli import main


def test_different_epsg_codes_are_one_line(tmp_path, capsys):
    a, b = shared_file("wires.laz"), shared_file("las_with_several_extra_byte_bloc.laz")
    capsys.readouterr()
    assert main(["render", str(a), str(b), "--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("progressive: error: ") and err.count("\n") == 1
    assert "EPSG:2948" in err and "EPSG:2154" in err and not (tmp_path / "x.png").exists()


def test_labels_without_two_codes_warn_and_render(tmp_path, capsys):
    wires = shared_file("wires.laz")
    capsys.readouterr()
    assert main(["render", str(SAMPLE), str(wires), "--out", str(tmp_path / "x.png"), "--width", "64", "--height", "48"]) == 0
    err = capsys.readouterr().err
    assert "different coordinate systems" in err and err.startswith("progressive: warning: ")


def test_info_names_the_crs(capsys):
    capsys.readouterr()
    assert main(["info", str(shared_file("wires.laz")), "--json"]) == 0
    assert "EPSG:2948" in json.dumps(json.loads(capsys.readouterr().out))
