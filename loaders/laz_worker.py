"""One LAZ decoder process of loaders/laz_pool.py, run by path with `python -P`: it imports
lazrs and the standard library only, never the package, so it is ready in the time
lazrs takes to import and shares no state (no GL context, no threads) with the loader.

It says READY on the socket whose descriptor is its argument, then reads jobs from it,
one message each with the memfd to decode into attached: it reads the job's compressed
chunks from the file itself (or, for chunks fetched over HTTP, from a second memfd sent
with the job) and decodes them on one core (RAYON_NUM_THREADS=1), then
answers with the job's id and, where decoding failed, the exception's name and message.
It ends when the socket closes; Ctrl+C reaches the whole process group and is the
loader's to handle.
"""

import mmap
import os
import pickle
import signal
import socket
import stat
import sys

import lazrs

READY = b"ready"
"""The first message, once lazrs is imported."""
MESSAGE_BYTES = 1 << 20
"""Largest job message read (a job holds at most laz_pool.JOB_CHUNKS chunks)."""


class _Files:
    """The file of the last job, kept open while jobs read the same path."""

    def __init__(self):
        self.path, self.fd = None, -1

    def get(self, path: str) -> int:
        if path != self.path:
            self.close()
            fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)     # a FIFO put in the file's place is not waited on
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                os.close(fd)
                raise OSError(f"{path} is no longer a regular file")
            self.path, self.fd = path, fd
        return self.fd

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
        self.path, self.fd = None, -1


def _read(fd: int, size: int, offset: int) -> bytes:
    parts, got = [], 0
    while got < size:
        part = os.pread(fd, size - got, offset + got)
        if not part:
            raise EOFError("the file ends inside its LAZ chunk data")
        parts.append(part)
        got += len(part)
    return b"".join(parts)


def _decode(files: _Files, job: tuple, fds: list[int]) -> None:
    """Path None: the chunks are in the second memfd sent (a node fetched over HTTP)."""
    _, path, offset, table, vlr, layers, nbytes = job
    out_fd = fds[0]
    compressed = _read(files.get(path) if path is not None else fds[1], sum(n for _, n in table), offset)
    selection = None if layers is None else lazrs.DecompressionSelection(layers)
    with mmap.mmap(out_fd, nbytes) as out:
        view = memoryview(out)
        try:
            lazrs.decompress_points_with_chunk_table(compressed, vlr, view, table, selection)
        finally:
            view.release()


def main(fd: int) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    sock = socket.socket(fileno=fd)
    sock.sendall(READY)
    files = _Files()
    while True:
        try:
            message, fds, _, _ = socket.recv_fds(sock, MESSAGE_BYTES, 2)
        except OSError:
            return
        if not message:
            return
        job = pickle.loads(message)
        try:
            _decode(files, job, fds)
            answer = (job[0], None, None)
        except BaseException as exc:        # lazrs panics are BaseExceptions
            answer = (job[0], type(exc).__name__, str(exc))
        finally:
            for f in fds:
                os.close(f)
        try:
            sock.sendall(pickle.dumps(answer))
        except OSError:
            return


if __name__ == "__main__":
    main(int(sys.argv[1]))
