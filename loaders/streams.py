"""Read-only binary streams laspy and lazrs read as files: a file with patches, a COPC
file over HTTP. They share positioning; each says where it ends and how it reads."""

from __future__ import annotations

import io


class PositionedReader(io.RawIOBase):
    """A readable, seekable raw stream that keeps its own position: subclasses give
    `end()` (what SEEK_END is relative to) and `readinto`."""

    def __init__(self):
        super().__init__()
        self._pos = 0

    def end(self) -> int:
        raise NotImplementedError

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self._pos

    def seek(self, pos: int, whence: int = io.SEEK_SET) -> int:
        base = {io.SEEK_SET: 0, io.SEEK_CUR: self._pos, io.SEEK_END: self.end()}[whence]
        self._pos = base + pos
        return self._pos
