"""The classification palette: Potree's colours for codes 0-9 and 12, CloudCompare's for
10-22, one visible fallback for 23-255, and --palette FILE.json overriding entries; the
colours of a rendered PNG against tables taken from those projects' sources."""

from __future__ import annotations

import json

import laspy
import numpy as np
import pytest
from PIL import Image

from conftest import SAMPLE
from progressive.cli import main

W, H = 160, 120

POTREE = {   # potree src/materials/ClassificationScheme.js, DEFAULT (fractions of 1)
    0: (0.5, 0.5, 0.5), 1: (0.5, 0.5, 0.5), 2: (0.63, 0.32, 0.18), 3: (0.0, 1.0, 0.0), 4: (0.0, 0.8, 0.0),
    5: (0.0, 0.6, 0.0), 6: (1.0, 0.66, 0.0), 7: (1.0, 0.0, 1.0), 8: (1.0, 0.0, 0.0), 9: (0.0, 0.0, 1.0),
    12: (1.0, 1.0, 0.0),
}
QT = {"darkGray": (128, 128, 128), "darkBlue": (0, 0, 128), "darkYellow": (128, 128, 0), "darkCyan": (0, 128, 128),
      "darkRed": (128, 0, 0), "black": (0, 0, 0)}
CLOUDCOMPARE = {   # CloudCompare libs/qCC_db/src/ccColorScalesManager.cpp, ASPRS_CLASSES
    10: (85, 85, 0), 11: QT["darkGray"], 13: (191, 231, 205), 14: (193, 230, 125), 15: QT["darkBlue"],
    16: QT["darkYellow"], 17: QT["darkCyan"], 18: QT["darkRed"], 19: (270 & 0xFF, 170, 255), 20: (50, 255, 198),
    21: (255, 250, 250), 22: QT["black"],
}


def expected_table() -> dict[int, tuple[int, int, int]]:
    table = {code: tuple(round(c * 255) for c in rgb) for code, rgb in POTREE.items()}   # GL: round to nearest
    table.update(CLOUDCOMPARE)
    return table


@pytest.fixture(scope="module")
def every_code(tmp_path_factory):
    """The sample with classification codes 0..255 (point format 7 has 8 bits of class)."""
    src = laspy.read(SAMPLE)
    las = laspy.convert(src, point_format_id=7, file_version="1.4")
    las.classification = np.arange(len(src.points)) % 256
    path = tmp_path_factory.mktemp("palette") / "codes.las"
    las.write(path)
    return path


def render(tmp_path, path, *args) -> tuple[np.ndarray, np.ndarray]:
    out, ids = tmp_path / "out.png", tmp_path / "ids.npy"
    assert main(["render", str(path), "--color-by", "classification", "--width", str(W), "--height", str(H),
                 "--out", str(out), "--ids", str(ids), *args]) == 0
    return np.asarray(Image.open(out).convert("RGB")).astype(np.int32), np.load(ids)


def shown_colours(image, ids, codes) -> dict[int, set]:
    """Per class code shown: the set of pixel colours showing it."""
    covered = ids != 0xFFFFFFFF
    out: dict[int, set] = {}
    for pixel, index in zip(image[covered], ids[covered]):
        out.setdefault(int(codes[index]), set()).add(tuple(int(c) for c in pixel))
    return out


def test_default_palette_is_potree_cloudcompare_and_a_visible_fallback(tmp_path, every_code):
    codes = np.asarray(laspy.read(every_code).classification)
    seen = shown_colours(*render(tmp_path, every_code), codes)
    assert len(seen) == 256, "every code is on screen"
    table = expected_table()
    assert set(table) == set(range(23)) and all(seen[c] == {table[c]} for c in table)
    fallback = seen[23]
    assert all(seen[c] == fallback for c in range(23, 256))
    (colour,) = fallback
    assert colour not in table.values() and colour != (0, 0, 0), "the fallback stands out from classes and background"


def test_palette_file_overrides_entries(tmp_path, every_code):
    codes = np.asarray(laspy.read(every_code).classification)
    given = {"2": [1, 2, 3], "22": "#Ff8000", "200": [250, 251, 252]}
    palette = tmp_path / "palette.json"
    palette.write_text(json.dumps(given))
    seen = shown_colours(*render(tmp_path, every_code, "--palette", str(palette)), codes)
    assert seen[2] == {(1, 2, 3)} and seen[22] == {(255, 128, 0)} and seen[200] == {(250, 251, 252)}
    table = expected_table()
    assert all(seen[c] == {table[c]} for c in table if str(c) not in given)
    default = shown_colours(*render(tmp_path, every_code), codes)
    assert all(seen[c] == default[c] for c in range(23, 256) if str(c) not in given)


@pytest.mark.parametrize("text, says", [
    ("{", "JSON"),
    ("[1, 2]", "JSON object"),
    ("{}", "JSON object"),
    ('{"256": [1, 2, 3]}', "class code"),
    ('{"-1": [1, 2, 3]}', "class code"),
    ('{"two": [1, 2, 3]}', "class code"),
    ('{"2": [1, 2]}', "[r, g, b]"),
    ('{"2": [1, 2, 256]}', "[r, g, b]"),
    ('{"2": [1, 2, 3.5]}', "[r, g, b]"),
    ('{"2": [true, 2, 3]}', "[r, g, b]"),
    ('{"2": "#12345g"}', "[r, g, b]"),
    ('{"2": "red"}', "[r, g, b]"),
])
def test_bad_palette_is_one_line(tmp_path, capsys, text, says):
    palette = tmp_path / "palette.json"
    palette.write_text(text)
    out = tmp_path / "x.png"
    capsys.readouterr()
    assert main(["render", str(SAMPLE), "--color-by", "classification", "--palette", str(palette), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("progressive: error: ") and err.count("\n") == 1 and says in err, err
    assert not out.exists()


def test_missing_palette_file_is_one_line(tmp_path, capsys):
    capsys.readouterr()
    assert main(["render", str(SAMPLE), "--palette", str(tmp_path / "none.json"), "--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("progressive: error: ") and err.count("\n") == 1 and "not found" in err
