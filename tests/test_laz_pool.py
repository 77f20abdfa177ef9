"""LAZ decoded in decoder processes (loaders/laz_pool.py) against laspy and against the
in-process decoder: every real LAZ file, one and several workers, in order, partial
loads and damaged files as in-process, and no process or memory left behind."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import time
import uuid

import laspy
import lazrs
import numpy as np
import pytest
from test_loader_parallel import CHUNKED, assert_equals_laspy, records_of
from test_loaders import assert_covers, joined, load, one_line_naming

from conftest import REPO, SAMPLE, shared_file, shared_files
from progressive.errors import InputError
from progressive.loaders import CloudLoader, laz_pool
from progressive.loaders.copc import CopcSource
from progressive.loaders.las import open_las
from progressive.loaders.laz import decode_chunks
from progressive.loaders.laz_pool import NICENESS, DecoderPool, Decoders, LazOptions, runs
from progressive.loaders.types import BATCH_POINTS

pytestmark = pytest.mark.skipif(not laz_pool.available(), reason="no decoder processes on this platform")

PROCESSES = LazOptions(Decoders.PROCESSES, processes=3)
THREADS = LazOptions(Decoders.THREADS)
LAZ_FILES = [p for p in shared_files() if p.suffix.lower() == ".laz"]


def started_pools(monkeypatch) -> list[DecoderPool]:
    """Every pool that decodes from now on, to check afterwards that it was used and ended."""
    pools = []
    original = DecoderPool.decode

    def decode(self, *args, **kwargs):
        pools.append(self)
        yield from original(self, *args, **kwargs)
    monkeypatch.setattr(DecoderPool, "decode", decode)
    return pools


def ended(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] in ("Z", "X")
    except FileNotFoundError:
        return True


def open_fds() -> set[str]:
    return set(os.listdir("/proc/self/fd"))


@pytest.mark.parametrize("path", LAZ_FILES or [pytest.param(None, marks=pytest.mark.skip("no shared data"))],
                         ids=lambda p: getattr(p, "name", "none"))
def test_every_real_laz_through_processes_equals_laspy(path, monkeypatch):
    """Every real LAZ file loads through the processes where its chunk table allows
    (through laspy where not, and a COPC file through its nodes, as in-process) to
    exactly laspy's points and attributes."""
    with laspy.open(path) as reader:
        if reader.header.point_count > 3_000_000:
            pytest.skip(f"{path.name} is large; the loader is measured in bench/")
    pools = started_pools(monkeypatch)
    las = laspy.read(path)
    loader, batches = load([path], laz=PROCESSES)
    assert loader.done and not loader.warnings
    assert_equals_laspy(loader, batches, las)
    source = loader._sources[0]
    assert bool(pools) == (bool(source.laz.chunks) and not isinstance(source, CopcSource))


@pytest.mark.parametrize("name", CHUNKED)
def test_pool_decode_equals_in_process_for_one_and_several_workers(name):
    """The pool yields what decode_chunks yields, in file order, with the probe's chunks
    skipped, a cut count, a small first job, and only the layers asked for."""
    path = shared_file(name)
    source = open_las(path)
    laz, dtype = source.laz, source.records.dtype
    expected = records_of(path)
    chunk = laz.chunks[0][0]
    cut = min(len(expected), 2 * chunk + 17)
    selected = laspy.DecompressionSelection.base() | laspy.DecompressionSelection.Z
    for processes in (1, 3):
        with DecoderPool(processes) as pool:
            for first_read, piece in ((1, 2 * chunk), (chunk + 1, 7_919), (len(expected), 500_000)):
                got = list(pool.decode(str(path), laz, len(expected), first_read, dtype, piece))
                np.testing.assert_array_equal(np.concatenate(got), expected, err_msg=f"{processes} workers")
                assert len(got[0]) <= max(first_read, chunk)
            skipped = list(pool.decode(str(path), laz, len(expected), 1, dtype, chunk, skip=1))
            np.testing.assert_array_equal(np.concatenate(skipped) if skipped else expected[:0],
                                          expected[laz.chunks[0][0]:])
            np.testing.assert_array_equal(np.concatenate(list(pool.decode(str(path), laz, cut, 1, dtype, chunk))),
                                          expected[:cut])
            layered = np.concatenate(list(pool.decode(str(path), laz, len(expected), 1, dtype, chunk, selected)))
            in_process = np.concatenate(list(decode_chunks(str(path), laz, len(expected), 1, dtype, 2,
                                                           selected.to_lazrs())))
            for field in ("X", "Y", "Z"):
                np.testing.assert_array_equal(layered[field], in_process[field])


def test_workers_yield_the_cores_to_the_loaders_process():
    """Each worker runs NICENESS above the loader's nice value (capped at 19), so the frame
    loop and the parser threads are scheduled before the decode."""
    path = shared_file(CHUNKED[0])
    source = open_las(path)
    with DecoderPool(2) as pool:
        assert list(pool.decode(str(path), source.laz, 1000, 1000, source.records.dtype, 1000))
        ours = os.getpriority(os.PRIO_PROCESS, 0)
        assert [os.getpriority(os.PRIO_PROCESS, pid) for pid in pool.pids()] == [min(ours + NICENESS, 19)] * 2
    assert ours == os.getpriority(os.PRIO_PROCESS, 0)


def test_waiting_for_the_workers_ends_with_their_start_or_the_pool():
    """wait_started returns once start_soon's start has ended (the workers ready), and at
    once, not ready, for a closed pool: a streaming read never waits out the timeout."""
    pool = DecoderPool(2)
    pool.start_soon()
    assert pool.wait_started(laz_pool.START_S) and pool.ready
    pool.close()
    t0 = time.monotonic()
    assert not pool.wait_started(laz_pool.START_S)
    closed = DecoderPool(2)
    closed.close()
    closed.start_soon()
    assert not closed.wait_started(laz_pool.START_S)
    assert time.monotonic() - t0 < 1.0


def test_jobs_are_runs_of_whole_chunks():
    chunks = tuple((n, 10) for n in (50, 50, 50, 50, 30, 200, 50))
    assert runs(chunks, 60, 100) == [(0, 1), (1, 3), (3, 5), (5, 6), (6, 7)]
    assert runs(chunks, 1, 1000) == [(0, 1), (1, 7)]
    assert runs((), 1, 1) == []


@pytest.mark.parametrize("name", ["pine_plot.laz", "las_with_several_extra_byte_bloc.laz"])
def test_loader_batches_equal_with_threads_and_processes(name, monkeypatch):
    """The same points whichever decodes, for any parser threads and batch sizes that
    cut chunks (where batches end follows the jobs, as in-process it follows the reads)."""
    path = shared_file(name)
    las = laspy.read(path)
    chunk = open_las(path).laz.chunks[0][0]
    pools = started_pools(monkeypatch)
    for threads, batch, processes in ((1, chunk - 1, 1), (3, 7_919, 2), (2, 500_000, 4)):
        _, reference = load([path], parser_threads=threads, batch_points=batch, laz=THREADS)
        loader, batches = load([path], parser_threads=threads, batch_points=batch,
                               laz=LazOptions(Decoders.PROCESSES, processes))
        assert_covers(batches, len(las.points), batch)
        np.testing.assert_array_equal(joined(batches), joined(reference))
        assert_equals_laspy(loader, batches, las)
    assert len(pools) == 3 and all(not p.pids() for p in pools)


def test_auto_keeps_small_files_and_few_cores_in_process(monkeypatch):
    """Decoders.AUTO starts no process for a file of fewer points left than
    MIN_PROCESS_POINTS, nor for fewer cores than MIN_AUTO_PROCESSES."""
    path = shared_file("pine_plot.laz")
    pools = started_pools(monkeypatch)
    monkeypatch.setattr(laz_pool, "MIN_AUTO_PROCESSES", 1)
    load([path])
    assert not pools
    monkeypatch.setattr(laz_pool, "MIN_PROCESS_POINTS", 1)
    load([path])
    assert len(pools) == 1
    monkeypatch.setattr(laz_pool, "MIN_AUTO_PROCESSES", 3)
    assert DecoderPool.chosen(LazOptions(processes=2)) is None
    assert DecoderPool.chosen(LazOptions(processes=3)) is not None
    assert DecoderPool.chosen(LazOptions(Decoders.PROCESSES, processes=1)) is not None


@pytest.fixture(scope="module")
def damaged_laz(tmp_path_factory):
    """The sample as a LAZ of 50,000-point chunks whose second chunk's bytes are
    overwritten (the chunk table still adds up)."""
    stream = io.BytesIO()
    laspy.read(SAMPLE).write(stream, laz_backend=laspy.LazBackend.Lazrs)
    data = bytearray(stream.getvalue())
    header = laspy.LasHeader.read_from(io.BytesIO(bytes(data)))
    table_stream = io.BytesIO(bytes(data))
    table_stream.seek(header.offset_to_point_data)
    table = lazrs.read_chunk_table(table_stream, lazrs.LazVlr(bytes(header.vlrs.get("LasZipVlr")[0].record_data)))
    second = header.offset_to_point_data + 8 + table[0][1]
    data[second + table[1][1] // 3: second + table[1][1] // 3 + 64] = bytes(range(64))
    path = tmp_path_factory.mktemp("damaged") / "damaged.laz"
    path.write_bytes(bytes(data))
    return path


def test_damaged_file_reads_as_in_process(damaged_laz, monkeypatch):
    """A chunk that fails to decode in a worker: a partial load keeps what the in-process
    decoder keeps, with the same warning; a full load fails in the same one line."""
    pools = started_pools(monkeypatch)
    for batch in (20_000, 500_000):
        reference_loader, reference = load([damaged_laz], partial=True, batch_points=batch, laz=THREADS)
        loader, batches = load([damaged_laz], partial=True, batch_points=batch, laz=PROCESSES)
        assert pools, "the pool should have decoded the file"
        assert_covers(batches, sum(b.count for b in reference), batch)
        np.testing.assert_array_equal(joined(batches), joined(reference))
        assert loader.warnings == reference_loader.warnings
    errors = []
    for options in (THREADS, PROCESSES):
        with pytest.raises(InputError) as err:
            load([damaged_laz], laz=options)
        one_line_naming(err.value, damaged_laz)
        errors.append(str(err.value))
    assert errors[0] == errors[1]
    assert all(not p.pids() for p in pools)


def test_nothing_is_left_behind_after_close_mid_load(monkeypatch):
    """Closing a loader while its workers decode ends them within the grace time and
    leaves no descriptor (memfd, socket) open and nothing in /dev/shm."""
    path = shared_file("pine_plot.laz")
    shm = set(os.listdir("/dev/shm")) if os.path.isdir("/dev/shm") else set()
    fds = open_fds()
    pools = started_pools(monkeypatch)
    loader = CloudLoader([path], batch_points=20_000, parser_threads=1,
                         laz=LazOptions(Decoders.PROCESSES, processes=2))
    batches = iter(loader)
    next(batches)
    deadline = time.monotonic() + 10
    while not pools[0].pids() and time.monotonic() < deadline:
        time.sleep(0.01)
    pids = pools[0].pids()
    assert pids
    t0 = time.monotonic()
    loader.close()
    assert time.monotonic() - t0 < laz_pool.GRACE_S + 2
    assert all(ended(p) for p in pids)
    del batches
    assert open_fds() <= fds
    if shm or os.path.isdir("/dev/shm"):
        assert set(os.listdir("/dev/shm")) <= shm


def test_a_worker_that_dies_is_one_line_not_a_hang(monkeypatch):
    """A decoder process killed (here before its first job): the load fails in one line
    naming the file, the other workers are ended, and nothing waits for the dead one."""
    path = shared_file("pine_plot.laz")
    fds = open_fds()
    started = []
    original = DecoderPool._start

    def start_and_kill(self):
        workers = original(self)
        started.extend(w.process.pid for w in workers)
        workers[1].process.kill()
        workers[1].process.wait()
        return workers
    monkeypatch.setattr(DecoderPool, "_start", start_and_kill)
    t0 = time.monotonic()
    with pytest.raises(InputError) as err:
        load([path], batch_points=5_000, parser_threads=1, laz=LazOptions(Decoders.PROCESSES, processes=2))
    assert time.monotonic() - t0 < 10
    one_line_naming(err.value, path)
    assert "decoder process ended" in str(err.value)
    assert started and all(ended(p) for p in started)
    assert open_fds() <= fds


def test_after_a_lost_worker_the_next_files_decode_here(monkeypatch):
    """A worker lost on one file (partial load: its points up to there, a warning): the
    files after it are decoded in the loader's process, to the same points."""
    path = shared_file("pine_plot.laz")
    original = DecoderPool._start
    pools = started_pools(monkeypatch)

    def start_and_kill(self):
        workers = original(self)
        workers[1].process.kill()
        workers[1].process.wait()
        return workers
    monkeypatch.setattr(DecoderPool, "_start", start_and_kill)
    _, reference = load([path, path], laz=THREADS)
    loader, batches = load([path, path], partial=True, batch_points=5_000, laz=PROCESSES)
    assert len(pools) == 2 and pools[0]._failed and not pools[0].pids()
    assert len(loader.warnings) == 1 and "decoder process ended" in loader.warnings[0]
    n = loader.info.files[0].points
    assert_covers(batches, sum(b.count for b in batches), 5_000)
    tail = joined(batches)[-n:]
    np.testing.assert_array_equal(tail, joined(reference)[n:])


def test_workers_that_cannot_start_leave_the_decoding_here(tmp_path, monkeypatch):
    """A worker that ends before it is ready (a Python without lazrs, say): the file is
    decoded in the loader's process, to the same points, and no process is left."""
    broken = tmp_path / "worker.py"
    broken.write_text("import sys\nsys.exit(1)\n")
    monkeypatch.setattr(laz_pool, "WORKER", broken)
    pools = started_pools(monkeypatch)
    path = shared_file("pine_plot.laz")
    loader, batches = load([path], laz=PROCESSES)
    assert pools and pools[0]._failed and not pools[0].pids()
    assert_equals_laspy(loader, batches, laspy.read(path))


def test_keyboard_interrupt_mid_load_ends_the_workers(monkeypatch):
    """Ctrl+C while the consumer iterates (the CLI's Interrupted comes the same way): the
    loader's context ends its workers, and no descriptor is left open."""
    path = shared_file("pine_plot.laz")
    fds = open_fds()
    pools = started_pools(monkeypatch)
    with pytest.raises(KeyboardInterrupt), CloudLoader([path], batch_points=20_000, parser_threads=1,
                                                       laz=LazOptions(Decoders.PROCESSES, processes=2)) as loader:
        for _ in loader:
            pids = pools[0].pids() if pools else []
            raise KeyboardInterrupt
    assert pids and all(ended(p) for p in pids)
    del loader
    assert open_fds() <= fds


@pytest.fixture(scope="module")
def large_laz(tmp_path_factory):
    """The sample tiled past MIN_PROCESS_POINTS after the first BATCH_POINTS, which the
    probe decodes (the CLI decodes the rest in processes)."""
    las = laspy.read(SAMPLE)
    copies = (laz_pool.MIN_PROCESS_POINTS + BATCH_POINTS) // len(las.points) + 2
    out = laspy.LasData(las.header)
    out.points = laspy.ScaleAwarePointRecord(np.tile(las.points.array, copies), las.header.point_format,
                                             las.header.scales, las.header.offsets)
    path = tmp_path_factory.mktemp("large") / "large.laz"
    out.write(path, laz_backend=laspy.LazBackend.LazrsParallel)
    return path


def tagged_workers(tag: str) -> list[int]:
    """Decoder processes whose environment holds `tag` (this test's, not another run's)."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                if b"laz_worker.py" not in f.read():
                    continue
            with open(f"/proc/{entry}/environ", "rb") as f:
                if tag.encode() in f.read() and not ended(int(entry)):
                    found.append(int(entry))
        except OSError:
            continue
    return found


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL])
def test_signal_to_the_cli_while_processes_decode_leaves_none(tmp_path, large_laz, sig):
    """The CLI signalled (SIGINT to its whole process group, as a terminal sends it;
    SIGTERM to it alone) while its decoder processes decode: it ends with 128+signal
    and no traceback, and no decoder process outlives it, nor one of a CLI killed
    (SIGKILL: its workers see their sockets close)."""
    tag = f"PROGRESSIVE_TEST_TAG={uuid.uuid4().hex}"
    env = {**os.environ, tag.split("=")[0]: tag.split("=")[1]}
    argv = ["render", str(large_laz), "--width", "64", "--height", "48", "--out", str(tmp_path / "out.png")]
    cli = ("from progressive.loaders import laz_pool; laz_pool.MIN_AUTO_PROCESSES = 1\n"   # processes on any machine
           f"from progressive.cli import main; raise SystemExit(main({argv!r}))")
    proc = subprocess.Popen([sys.executable, "-c", cli], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 60
        while not (found := tagged_workers(tag)) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert found, "the CLI should be decoding in processes"
        if sig == signal.SIGINT:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
        proc.communicate()
    if sig == signal.SIGKILL:
        assert proc.returncode == -sig
    else:
        assert proc.returncode == 128 + sig, err
        assert "Traceback" not in err and err == "", err
    deadline = time.monotonic() + laz_pool.GRACE_S + 5
    while tagged_workers(tag) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not tagged_workers(tag)
    assert not (tmp_path / "out.png").exists()
