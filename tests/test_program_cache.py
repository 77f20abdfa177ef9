"""The program binary cache (progressive/programs.py): a loaded binary renders what a
compiled program renders, the key misses on any change of source or driver, and a
damaged or unwritable cache costs one warning and a compile, never an error."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conftest import SAMPLE
from progressive import shaderlib
from progressive.context import create_context, program_key
from progressive.programs import ENV_VAR, Programs
from progressive.session import Method, Session, SessionOptions

OPTIONS = SessionOptions(width=160, height=120, method=Method.BRUTE)


def render_ids(glc) -> np.ndarray:
    with Session([SAMPLE], OPTIONS, glc=glc) as s:
        s.frame(s.auto_camera())
        ids = s.ids()
        assert s.warnings == []
    glc.check()
    return ids


@pytest.fixture
def cached(tmp_path, monkeypatch):
    """A context whose cache directory comes from the environment variable."""
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "programs"))
    contexts = []

    def make():
        contexts.append(create_context())
        return contexts[-1]
    yield make
    for glc in contexts:
        glc.release()


def test_hit_renders_what_a_compile_renders(cached, tmp_path):
    first = cached()
    if first.programs.directory is None:
        pytest.skip("the driver offers no program binary formats")
    compiled = render_ids(first)
    built = first.programs.stats.hits + first.programs.stats.misses
    assert first.programs.stats.misses > 0          # a hit here: two passes build the same program
    entries = sorted((tmp_path / "programs").glob("*.bin"))
    assert len(entries) == first.programs.stats.misses
    assert not list((tmp_path / "programs").glob(".tmp-*"))
    second = cached()
    loaded = render_ids(second)
    assert second.programs.stats.misses == 0 and second.programs.stats.hits == built
    assert (compiled != 0xFFFFFFFF).sum() > 1000
    np.testing.assert_array_equal(loaded, compiled)
    uncached = create_context(program_cache=None)
    try:
        np.testing.assert_array_equal(render_ids(uncached), compiled)
        assert uncached.programs.stats.hits == 0
    finally:
        uncached.release()


def test_progressive_frames_from_loaded_programs(cached):
    cached().release()
    glc = cached()
    options = dataclasses.replace(OPTIONS, method=Method.PROGRESSIVE)
    with Session([SAMPLE], options, glc=glc) as s:
        cam = s.auto_camera()
        for _ in range(40):
            if s.converged:
                break
            s.frame(cam)
        assert s.converged
        ids = s.ids()
    glc.check()
    np.testing.assert_array_equal(ids, render_ids(glc))


def programs_for(glc, directory, key=None) -> Programs:
    return Programs(glc.programs.calls, key or program_key(glc.caps), directory)


def test_source_and_driver_changes_miss(gl, tmp_path):
    p = programs_for(gl, tmp_path)
    if p.directory is None:
        pytest.skip("the driver offers no program binary formats")
    one = shaderlib.source("clear.comp")
    other = shaderlib.source("clear.comp", {"UNUSED_DEFINE": 1})
    for text in (one, one, other, other):
        p.compute(text, "clear").release()
    assert (p.stats.misses, p.stats.hits) == (2, 2)
    driver = dataclasses.replace(gl.caps, version=gl.caps.version + " (another build)")
    q = programs_for(gl, tmp_path, program_key(driver))
    q.compute(one, "clear").release()
    assert (q.stats.misses, q.stats.hits) == (1, 0)
    assert len(list(tmp_path.glob("*.bin"))) == 3
    assert p.warnings == q.warnings == []
    gl.check()


@pytest.mark.parametrize("damage", ["truncated", "garbage payload", "empty"])
def test_damaged_entry_warns_once_and_is_rewritten(gl, tmp_path, damage):
    import hashlib

    from progressive.programs import _HEADER, MAGIC

    p = programs_for(gl, tmp_path)
    if p.directory is None:
        pytest.skip("the driver offers no program binary formats")
    text = shaderlib.source("clear.comp")
    p.compute(text, "clear").release()
    entry = p.entry(text)
    good = entry.read_bytes()
    if damage == "truncated":
        entry.write_bytes(good[: len(good) // 2])
    elif damage == "empty":
        entry.write_bytes(b"")
    else:      # a sound header over bytes the driver must refuse
        payload = bytes(range(256)) * 8
        fmt = _HEADER.unpack_from(good)[1]
        entry.write_bytes(_HEADER.pack(MAGIC, fmt, len(payload), hashlib.sha256(payload).digest()) + payload)
    q = programs_for(gl, tmp_path)
    program = q.compute(text, "clear")
    assert "u_count" in program
    program.release()
    assert len(q.warnings) == 1 and entry.name in q.warnings[0] and "\n" not in q.warnings[0]
    assert (q.stats.misses, q.stats.hits) == (1, 0)
    gl.check()
    r = programs_for(gl, tmp_path)
    r.compute(text, "clear").release()
    assert (r.stats.hits, r.warnings) == (1, [])
    gl.check()


def test_unwritable_directory_is_one_warning(gl, tmp_path):
    blocker = tmp_path / "not-a-directory"
    blocker.write_text("")
    p = programs_for(gl, blocker / "programs")
    if p.directory is None:
        pytest.skip("the driver offers no program binary formats")
    for name in ("clear.comp", "compare.comp", "cull.comp"):
        p.compute(shaderlib.source(name), name).release()
    assert p.stats.misses == 3
    assert len(p.warnings) == 1 and "cannot be written" in p.warnings[0]
    gl.check()


def test_disabled_by_the_environment(monkeypatch, tmp_path):
    from progressive.programs import cache_directory

    assert cache_directory({ENV_VAR: "0", "XDG_CACHE_HOME": str(tmp_path)}) is None
    assert cache_directory({"XDG_CACHE_HOME": str(tmp_path)}) == tmp_path / "progressive" / "programs"
    assert cache_directory({ENV_VAR: "1", "XDG_CACHE_HOME": "relative"}).parts[-3:] == (".cache", "progressive", "programs")
    assert cache_directory({ENV_VAR: str(tmp_path / "x")}) == tmp_path / "x"
    monkeypatch.setenv(ENV_VAR, "0")
    glc = create_context()
    try:
        assert glc.programs.directory is None
        render_ids(glc)
        assert glc.programs.stats.hits == 0
    finally:
        glc.release()
