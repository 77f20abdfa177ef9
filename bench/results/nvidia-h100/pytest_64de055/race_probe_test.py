"""The probe behind race_probe.txt: the two tests that failed on the H100, repeated with
four ways of staging. Copied into tests/ (it takes the suite's fixtures) and run as

    python -m pytest -q --tb=no -rf tests/test_zz_probe_race.py tests/test_switch_words.py tests/test_upload_ring.py
"""
import pytest

from progressive.encoding import Encoding
from progressive.passes import distribute
from tests import test_switch_words as t

VARIANTS = ("as_is", "finish_before_acquire", "copy_only", "finish_after_scatter")


def _apply(monkeypatch, gl, variant):
    if variant == "finish_before_acquire":
        real = distribute.StagingRing.acquire
        monkeypatch.setattr(distribute.StagingRing, "acquire", lambda self: (gl.ctx.finish(), real(self))[1])
    elif variant == "copy_only":
        monkeypatch.setattr(distribute.BufferStorage, "offered", staticmethod(lambda *a: False))
    elif variant == "finish_after_scatter":
        real = distribute.DistributePass._scatter
        monkeypatch.setattr(distribute.DistributePass, "_scatter",
                            lambda self, *a, **k: (real(self, *a, **k), gl.ctx.finish())[0])


@pytest.mark.parametrize("rep", range(6))
@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("name", t.NAMES)
@pytest.mark.parametrize("encoding", list(Encoding), ids=lambda e: e.name.lower())
def test_load_and_switch(gl, sample_batches, monkeypatch, variant, name, encoding, rep):
    _apply(monkeypatch, gl, variant)
    t.test_switched_words_equal_the_reference(gl, sample_batches, encoding, name)


@pytest.mark.parametrize("rep", range(10))
@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("encoding", list(Encoding), ids=lambda e: e.name.lower())
def test_interrupted(gl, sample_batches, monkeypatch, variant, encoding, rep):
    _apply(monkeypatch, gl, variant)
    t.test_interrupted_switches_and_switching_while_loading(gl, sample_batches, encoding)
