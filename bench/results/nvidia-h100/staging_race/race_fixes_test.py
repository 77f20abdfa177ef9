"""Probe: which change to the staging ring ends the wrong words the H100 gave with the
flushed ring too (../pytest_<commit>/ d-z, test_interrupted_switches_and_switching_while_loading[words]).
The two tests that failed are repeated in one process, the ways of staging taking turns
rep after rep, until PROBE_SECONDS have passed; failures are counted, nothing asserted.
Then each way uploads THROUGHPUT_POINTS float records (median of 3), for its cost.
bench/gpu.sh staging-fixes copies it into tests/ (it takes the suite's fixtures):

    PROBE_SECONDS=150 PROBE_OUT=$OUT/race_fixes.json python -m pytest -q -s tests/test_zz_race_fixes.py

Ways: `committed` (flushed ring, 640bf08); `gl_flush` (glFlush after each piece's
barrier, before its scatter: the scatter starts a new submission); `read_bit` (the ring
mapped with GL_MAP_READ_BIT too: another kind of host memory); `own_buffers` (each slot
a buffer of its own, 1 MiB apart at least); `finish_before_acquire` (glFinish before a
slot is handed out: no failure in ../pytest_64de055/race_probe.txt); `fence_after_barrier`
(each slot's fence placed after the memory barrier that follows its scatter, not
before); `wait_previous` (a blocking wait for the last piece's fence before a slot is
handed out: the scatters done, later commands not); `device_copy` (each flushed piece
copied by glCopyNamedBufferSubData into a buffer in GPU memory, which the scatter
reads: the GPU's shaders never read the mapped memory); `kept_buffers` (a released ring's
mapping kept and handed to the next ring of its size, never deleted: if the driver gives a
new mapping host pages whose lines the GPU still caches from a deleted one, and its
barrier skips a buffer it has not read yet, only fresh rings would read stale words, which
fits the failures coming late in a process); `copy` (no ring).

Each failure is also traced back (`_Trace`): every piece the case staged is kept as the
CPU left it at its bind (ring) or write (copy), and each wrong word of the failed check
(the first WRONG_TRACED) is looked for among them: a word the same ring slot held at
the same offset for an earlier piece than the right word's (the GPU read the slot as it
was before the CPU rewrote it), a word of the same piece at another offset, of another
piece, or one never staged.
"""
import ctypes
import json
import os
import time
from collections import Counter

import moderngl
import numpy as np
import pytest

from progressive import glext
from progressive.bindings import Binding
from progressive.encoding import Encoding
from progressive.passes import distribute
from progressive.pointstore import PointStore
from tests import test_switch_words as t

THROUGHPUT_POINTS = 20_000_000
"""Float records each way scatters, in loader-sized pieces, for what it costs."""

WAYS = ("committed", "gl_flush", "read_bit", "own_buffers", "fence_after_barrier", "wait_previous",
        "device_copy", "kept_buffers", "finish_before_acquire", "copy")

WRONG_TRACED = 512
"""Wrong words of a failed check traced back to the pieces staged."""

_KEPT: dict[int, list] = {}
"""kept_buffers: released mappings by size, handed out again instead of new ones."""


def _mapped_with_read(self, size):
    name = glext._u(0)
    self.create_buffers(1, ctypes.byref(name))
    flags = glext.GL_MAP_WRITE_BIT | glext.GL_MAP_PERSISTENT_BIT
    self.named_buffer_storage(name.value, size, None, flags | 0x0001)          # GL_MAP_READ_BIT
    address = self.map_named_buffer_range(name.value, 0, size, flags | 0x0001 | glext.GL_MAP_FLUSH_EXPLICIT_BIT)
    if not address:
        raise RuntimeError("could not map")
    words = np.ctypeslib.as_array(ctypes.cast(address, ctypes.POINTER(ctypes.c_uint32)), shape=(size // 4,))
    return glext.MappedBuffer(int(name.value), size, words)


def _apply(mp, gl, way, gl_flush):
    if way == "gl_flush":
        bind = distribute.StagingRing.bind
        mp.setattr(distribute.StagingRing, "bind", lambda self, slot, size: (bind(self, slot, size), gl_flush())[0])
    elif way == "read_bit":
        mp.setattr(glext.BufferStorage, "mapped", _mapped_with_read)
    elif way == "own_buffers":
        init = distribute.StagingRing.__init__

        def own(self, glc, storage, slot_bytes, slots=distribute.RING_SLOTS):
            init(self, glc, storage, slot_bytes, 1)
            self.rings = [self] + [OneSlot(glc, storage, slot_bytes) for _ in range(slots - 1)]
            self.fences = [None] * slots

        class OneSlot:
            def __init__(self, glc, storage, slot_bytes):
                self.inner = distribute.StagingRing.__new__(distribute.StagingRing)
                init(self.inner, glc, storage, max(slot_bytes, 1 << 20), 1)

        def view(self, slot, count, width):
            r = self if slot == 0 else self.rings[slot].inner
            return r.mapped.words[: count * width].reshape(count, width)

        def bind(self, slot, size):
            r = self if slot == 0 else self.rings[slot].inner
            r.storage.flush(r.mapped, 0, size)
            r.glc.ctx.memory_barrier(glext.GL_CLIENT_MAPPED_BUFFER_BARRIER_BIT)
            r.buffer.bind_to_storage_buffer(Binding.DISTRIBUTE, offset=0, size=size)

        mp.setattr(distribute.StagingRing, "__init__", own)
        mp.setattr(distribute.StagingRing, "view", view)
        mp.setattr(distribute.StagingRing, "bind", bind)
    elif way == "fence_after_barrier":
        def read(self, slot):
            self.glc.ctx.memory_barrier()
            self.fences[slot] = self.glc.gl.fence()
        mp.setattr(distribute.StagingRing, "read", read)
    elif way == "wait_previous":
        acquire = distribute.StagingRing.acquire

        def waiting(self):
            last = self.fences[(self.next - 1) % self.slots]
            if last is not None:
                self.glc.gl.wait(last)
            return acquire(self)
        mp.setattr(distribute.StagingRing, "acquire", waiting)
    elif way == "device_copy":
        bind = distribute.StagingRing.bind

        def copied(self, slot, size):
            bind(self, slot, size)
            if getattr(self, "device", None) is None:
                self.device = self.glc.ctx.buffer(reserve=self.slot_bytes)
            self.glc.gl.copy_named_buffer_sub_data(self.mapped.glo, self.device.glo, slot * self.slot_bytes, 0, size)
            self.glc.ctx.memory_barrier()
            self.device.bind_to_storage_buffer(Binding.DISTRIBUTE, offset=0, size=size)
        mp.setattr(distribute.StagingRing, "bind", copied)
    elif way == "kept_buffers":
        mapped = glext.BufferStorage.mapped

        def kept_or_new(self, size):
            free = _KEPT.get(size)
            return free.pop() if free else mapped(self, size)
        ring_release = distribute.StagingRing.release

        def release_when_read(self):
            for fence in self.fences:       # a kept mapping is written again at once: its last reads must be done
                if fence is not None:
                    self.glc.gl.wait(fence)
            ring_release(self)
        mp.setattr(glext.BufferStorage, "mapped", kept_or_new)
        mp.setattr(glext.BufferStorage, "release", lambda self, buffer: _KEPT.setdefault(buffer.size, []).append(buffer))
        mp.setattr(distribute.StagingRing, "release", release_when_read)
    elif way == "finish_before_acquire":
        acquire = distribute.StagingRing.acquire
        mp.setattr(distribute.StagingRing, "acquire", lambda self: (gl.ctx.finish(), acquire(self))[1])
    elif way == "copy":
        mp.setattr(distribute.BufferStorage, "offered", staticmethod(lambda *a: False))


class _Trace:
    """The pieces a case stages, in order: (ring id, or 0 for the copy path; slot; the
    words as the CPU left them), and the arrays of the first check that failed."""

    def __init__(self):
        self.pieces: list[tuple[int, int, np.ndarray]] = []
        self.failed: tuple[np.ndarray, np.ndarray] | None = None

    def patch(self, mp) -> None:
        """After _apply: the way's bind and view are the ones traced."""
        trace, bind, write, check = self, distribute.StagingRing.bind, moderngl.Buffer.write, np.testing.assert_array_equal

        def traced_bind(ring, slot, size):
            trace.pieces.append((id(ring), slot, ring.view(slot, size // 4, 1).reshape(-1).copy()))
            return bind(ring, slot, size)

        def traced_write(buffer, data, offset=0):
            if getattr(buffer, "label", "") == "distribute stage":
                trace.pieces.append((0, 0, np.frombuffer(bytes(data), dtype=np.uint32).copy()))
            return write(buffer, data, offset)

        def kept_check(actual, desired, *args, **kwargs):
            try:
                check(actual, desired, *args, **kwargs)
            except AssertionError:
                if trace.failed is None:
                    trace.failed = (np.asarray(actual).copy(), np.asarray(desired).copy())
                raise

        mp.setattr(distribute.StagingRing, "bind", traced_bind)
        mp.setattr(moderngl.Buffer, "write", traced_write)
        mp.setattr(np.testing, "assert_array_equal", kept_check)

    def explain(self) -> dict:
        """Where the wrong words of the failed check were staged (module docstring)."""
        actual, desired = self.failed
        wrong = np.flatnonzero(actual != desired)
        traced = wrong[:WRONG_TRACED]
        needed = np.unique(np.concatenate([actual[traced], desired[traced]]))
        where: dict[int, list[tuple[int, int, int, int]]] = {}
        for seq, (ring, slot, words) in enumerate(self.pieces):
            for o in np.flatnonzero(np.isin(words, needed)).tolist():
                where.setdefault(int(words[o]), []).append((seq, ring, slot, o))
        kinds, gaps = Counter(), Counter()
        for i in traced.tolist():
            right, got = where.get(int(desired[i]), []), where.get(int(actual[i]), [])
            if not right or not got:
                kinds["right word never staged" if not right else "wrong word never staged"] += 1
                continue
            seq, ring, slot, offset = right[-1]
            stale = [q for q, r, s, o in got if (r, s, o) == (ring, slot, offset) and q < seq and r]
            if stale:
                kinds["stale: the same ring slot and offset held it for an earlier piece"] += 1
                gaps[seq - stale[-1]] += 1
            elif any(q == seq for q, *_ in got):
                kinds["the same piece, another offset"] += 1
            elif any((r, s) == (ring, slot) for _, r, s, _ in got):
                kinds["the same slot, another piece and offset"] += 1
            else:
                kinds["another piece elsewhere"] += 1
        return {"wrong": int(wrong.size), "of": int(actual.size), "traced": int(traced.size),
                "pieces": len(self.pieces), "copied pieces": sum(1 for r, *_ in self.pieces if r == 0),
                "kinds": dict(kinds), "pieces between stale and right": {str(k): v for k, v in sorted(gaps.items())}}


def _records() -> np.ndarray:
    """THROUGHPUT_POINTS float records: positions in the unit cube, any attribute word."""
    rng = np.random.default_rng(0)
    records = np.empty((THROUGHPUT_POINTS, 4), dtype=np.uint32)
    records[:, :3] = rng.random((THROUGHPUT_POINTS, 3), dtype=np.float32).view(np.uint32)
    records[:, 3] = rng.integers(0, 2**32, THROUGHPUT_POINTS, dtype=np.uint32)
    return records


def _throughput(gl, way, gl_flush, records, repeats=3) -> float:
    """Median M points/s of the records uploaded (staged and scattered into a
    float-record store, to glFinish) the way given."""
    with pytest.MonkeyPatch.context() as mp:
        _apply(mp, gl, way, gl_flush)
        store = PointStore(gl, THROUGHPUT_POINTS, position_encoding=Encoding.FLOAT)
        d = distribute.DistributePass(gl, store)
        times = []
        for k in range(repeats + 1):
            gl.ctx.finish()
            t0 = time.perf_counter()
            for lo in range(0, THROUGHPUT_POINTS, d.batch_points):
                d.upload(records[lo: lo + d.batch_points], lo)
            gl.ctx.finish()
            if k:
                times.append(time.perf_counter() - t0)
        d.release()
        store.release()
    return THROUGHPUT_POINTS / sorted(times)[len(times) // 2] / 1e6


def test_probe(gl, sample_batches):
    gl_flush = glext._entry(glext.egl_proc_loader(), "glFlush")
    seconds = float(os.environ.get("PROBE_SECONDS", "20"))
    counts = {w: {"runs": 0, "failed": 0, "failures": [], "traced": []} for w in WAYS}
    cases = [("interrupted", lambda: t.test_interrupted_switches_and_switching_while_loading(
                  gl, sample_batches, Encoding.WORDS)),
             ("switch elevation", lambda: t.test_switched_words_equal_the_reference(
                  gl, sample_batches, Encoding.WORDS, "elevation")),
             ("switch gps_time", lambda: t.test_switched_words_equal_the_reference(
                  gl, sample_batches, Encoding.WORDS, "gps_time"))]
    t0, rep = time.perf_counter(), 0
    while time.perf_counter() - t0 < seconds:
        for i in range(len(WAYS)):
            way = WAYS[(i + rep) % len(WAYS)]
            for name, case in cases:
                trace = _Trace()
                with pytest.MonkeyPatch.context() as mp:
                    _apply(mp, gl, way, gl_flush)
                    trace.patch(mp)
                    try:
                        case()
                    except AssertionError as exc:
                        counts[way]["failed"] += 1
                        counts[way]["failures"].append(f"rep {rep} {name}: {str(exc).splitlines()[3:4]}")
                        if trace.failed is not None:
                            counts[way]["traced"].append(trace.explain())
                    counts[way]["runs"] += 1
        rep += 1
    records = _records()
    for w in WAYS:
        counts[w]["upload_mpoints_s"] = _throughput(gl, w, gl_flush, records)
    summary = {w: f"{c['failed']} of {c['runs']} failed, upload {c['upload_mpoints_s']:.0f} M points/s"
               for w, c in counts.items()}
    print(json.dumps(summary, indent=1))
    if os.environ.get("PROBE_OUT"):
        with open(os.environ["PROBE_OUT"], "w") as f:
            json.dump({"seconds": seconds, "reps": rep, "counts": counts}, f, indent=1)
