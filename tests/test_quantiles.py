"""The exact percentile select: its numpy twin against np.percentile, the GPU pass
against the twin on a real cloud's store, and when the scene takes its range."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from progressive import quantiles
from progressive.colors import ColorMode
from progressive.loaders.records import pack_records
from progressive.scene import RANGE_GROWTH, Scene

float32s = hnp.arrays(np.float32, st.integers(1, 400),
                      elements=st.floats(width=32, allow_nan=True, allow_infinity=True))


def numpy_percentiles(words: np.ndarray, percents=quantiles.PERCENTILES):
    values = words.view(np.float32).astype(np.float64)
    values = values[np.isfinite(values)]
    return None if values.size == 0 else tuple(float(v) for v in np.percentile(values, percents))


@settings(max_examples=200, deadline=None)
@given(float32s, st.lists(st.floats(0, 100), min_size=1, max_size=2))
def test_select_equals_numpy_percentile(values, percents):
    words = values.view(np.uint32)
    assert quantiles.percentiles_of_words(words, percents) == numpy_percentiles(words, percents)


@pytest.mark.parametrize("n", [1, 2, 3, 100, 101, 65_537, 1_000_003])
def test_select_sizes_and_ties(n):
    rng = np.random.default_rng(n)
    for values in (rng.normal(0, 1e4, n), rng.integers(-3, 3, n).astype(float), np.full(n, -0.0), rng.random(n) * 1e-40):
        words = values.astype(np.float32).view(np.uint32)
        assert quantiles.percentiles_of_words(words) == numpy_percentiles(words)


def test_order_keys_order_like_floats():
    values = np.array([-np.inf, -3e38, -1.0, -1e-45, -0.0, 0.0, 1e-45, 1.0, 3e38, np.inf], dtype=np.float32)
    keys = quantiles.order_keys(values.view(np.uint32))
    assert np.all(np.diff(keys.astype(np.int64)) > 0)
    assert [quantiles.key_value(k) for k in keys] == [float(v) for v in values]




def stored_words(info, batches, name) -> np.ndarray:
    """The words the GPU holds for the batches, less those of points never drawn."""
    records = np.concatenate([pack_records(b, info.attribute(name), float(info.origin[2])) for b in batches])
    finite = np.isfinite(records[:, :3].view(np.float32)).all(axis=1)
    return records[finite, 3]


@pytest.mark.parametrize("name", ["elevation", "intensity", "gps_time"])
def test_gpu_select_equals_numpy_on_the_store(gl, sample_batches, name):
    info, batches = sample_batches
    scene = Scene(gl, info, info.attribute(name), chunk_points=60_000)
    try:
        for b in batches:
            scene.add_batch(b)
        assert scene.value_range() == numpy_percentiles(stored_words(info, batches, name))
        assert gl.ctx.error == "GL_NO_ERROR"
    finally:
        scene.release()


def test_range_follows_loading_and_switches(gl, sample_batches):
    """Taken exact after the first batch, again once the loaded points have grown
    RANGE_GROWTH times, and when loading completes; after a switch, over the new words."""
    info, batches = sample_batches
    scene = Scene(gl, info, info.attribute("elevation"), keep_batches=True)
    try:
        scene.add_batch(batches[0])
        first = numpy_percentiles(stored_words(info, batches[:1], "elevation"))
        assert scene.value_range() == first
        k = 1
        while sum(b.count for b in batches[:k + 1]) < RANGE_GROWTH * batches[0].count:
            k += 1
            scene.add_batch(batches[k - 1])
            assert scene.value_range() == first
        scene.add_batch(batches[k])
        assert scene.value_range() == numpy_percentiles(stored_words(info, batches[:k + 1], "elevation"))
        for b in batches[k + 1:]:
            scene.add_batch(b)
        assert scene.complete
        assert scene.value_range() == numpy_percentiles(stored_words(info, batches, "elevation"))
        style = scene.style()
        assert style.automatic and style.mode is ColorMode.SCALAR

        scene.begin_switch(info.attribute("intensity"))
        while not scene.stream():
            pass
        assert scene.value_range() == numpy_percentiles(stored_words(info, batches, "intensity"))
        assert scene.resolved(style).value_range == scene.value_range()
    finally:
        scene.release()


def test_range_is_taken_when_loading_ends_short(gl, sample_batches):
    """A partial load ends below the header's count: the range is taken over what loaded
    once the session says no more will come."""
    info, batches = sample_batches
    scene = Scene(gl, info, info.attribute("elevation"))
    try:
        part = batches[: len(batches) // 2 + 1]
        for b in part:
            scene.add_batch(b)
        scene.value_range()
        scene.add_batch(batches[len(part)])
        assert not scene.complete
        scene.finished = True
        assert scene.value_range() == numpy_percentiles(stored_words(info, batches[: len(part) + 1], "elevation"))
    finally:
        scene.release()
