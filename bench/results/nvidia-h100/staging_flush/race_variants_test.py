"""The two tests that failed on the H100 with the coherent ring, repeated in one process
before the two files they come from (as ../pytest_64de055/race_probe_test.py found
them failing most: after other GPU work in the process), for whichever ring VARIANT
sets (staging_variants.py, through sitecustomize.py). bench/gpu.sh staging-race copies
it into tests/ (it takes the suite's fixtures) and runs it as

    python -m pytest -q --tb=no -rf -k "not flushed_before" tests/test_zz_probe_race.py \
        tests/test_switch_words.py tests/test_upload_ring.py
"""
import pytest

from progressive.encoding import Encoding
from tests import test_switch_words as t


@pytest.mark.parametrize("rep", range(12))
@pytest.mark.parametrize("name", t.NAMES)
@pytest.mark.parametrize("encoding", list(Encoding), ids=lambda e: e.name.lower())
def test_load_and_switch(gl, sample_batches, name, encoding, rep):
    t.test_switched_words_equal_the_reference(gl, sample_batches, encoding, name)


@pytest.mark.parametrize("rep", range(30))
@pytest.mark.parametrize("encoding", list(Encoding), ids=lambda e: e.name.lower())
def test_interrupted(gl, sample_batches, encoding, rep):
    t.test_interrupted_switches_and_switching_while_loading(gl, sample_batches, encoding)
