"""Measurements against numpy, at UTM magnitudes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from progressive.measure import Measurement

OFFSET = np.array([500_000.0, 5_000_000.0, 300.0])


def test_segments_length_and_area_of_a_known_polygon():
    square = [OFFSET + p for p in ([0, 0, 0], [3, 0, 4], [3, 3, 4], [0, 3, 0])]
    m = Measurement(())
    for p in square:
        m = m.add(p)
    assert m.segments()[0] == {"distance": 5.0, "horizontal": 3.0, "vertical": 4.0}
    assert m.length == pytest.approx(5 + 3 + 5)
    assert m.area == pytest.approx(9.0, abs=1e-9)
    assert Measurement(tuple(map(tuple, square[:2]))).area == 0.0


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(*[st.floats(-1e3, 1e3)] * 3), min_size=1, max_size=12))
def test_against_numpy(points):
    xyz = np.asarray(points, dtype=np.float64) + OFFSET
    m = Measurement(tuple(map(tuple, xyz)))
    d = np.diff(xyz, axis=0)
    assert np.allclose([s["distance"] for s in m.segments()], np.linalg.norm(d, axis=1), rtol=1e-12, atol=1e-9)
    assert np.allclose([s["horizontal"] for s in m.segments()], np.linalg.norm(d[:, :2], axis=1), rtol=1e-12, atol=1e-9)
    assert np.allclose([s["vertical"] for s in m.segments()], np.abs(d[:, 2]), atol=1e-9)
    rel = np.column_stack([xyz[:, :2] - xyz[0, :2], np.zeros(len(xyz))])
    expected = abs(float(np.cross(rel[1:-1], rel[2:])[:, 2].sum())) / 2 if len(points) >= 3 else 0.0   # a fan of triangles
    assert m.area == pytest.approx(expected if len(points) >= 3 else 0.0, rel=1e-9, abs=1e-6)
    assert m.to_dict()["length"] == pytest.approx(float(np.linalg.norm(d, axis=1).sum()), abs=1e-6)
