"""The file pyulog reads a ULog from: the bytes in memory, with pyulog's resynchronisation made to move
forward.

Past a message header it takes for corruption (type 0, size 0 or over 10000) or for a data message
met among the definitions, pyulog seeks back by the header's declared size, ``seek(-2 - size, 1)``
(to one byte past the header) or ``seek(-(3 + size), 1)`` (to the header). That is right only when
all ``size`` bytes were read. Near the end of a damaged file the read comes back short, the seek
lands before the header (at the file's start, at worst), and pyulog reads the same bytes for ever:
a 4 kB file with two flipped bytes kept pyulog 1.3 busy until it was killed. Here a backward
relative seek right after a short read of a message's payload is moved on by the bytes the read
did not return, so that it lands where pyulog meant. A budget of reads besides stops any other loop
a damaged file may find: pyulog reads a message in two reads, and a byte-by-byte search in three.
"""

from __future__ import annotations

import io

#: reads allowed a byte of the file, and in all besides (a whole file read message by message takes
#: under one a byte; a byte-by-byte resynchronisation, three)
READS_PER_BYTE = 8
READS_BESIDES = 1000


class ULogLoopError(RuntimeError):
    """pyulog read the file far more often than its size allows: it went round in circles."""


class ULogSource(io.BytesIO):
    """``data`` as the file object pyulog's ``ULog`` takes (see the module docstring)."""

    def __init__(self, data: bytes) -> None:
        super().__init__(data)
        self._budget = READS_PER_BYTE * len(data) + READS_BESIDES
        self._after_header = False  #: the last read was a message's 3-byte header
        self._short = 0  #: bytes the last payload read did not return (it met the end)

    def read(self, size: int | None = -1) -> bytes:
        self._budget -= 1
        if self._budget < 0:
            raise ULogLoopError("pyulog went round in circles in it")
        out = super().read(size)
        payload = self._after_header and size is not None and size >= 0
        self._short = size - len(out) if payload and size is not None else 0
        self._after_header = size == 3 and not payload
        return out

    def seek(self, offset: int, whence: int = 0) -> int:
        if whence == io.SEEK_CUR and offset < 0:
            offset += self._short  # as if the payload had been read whole
        self._short, self._after_header = 0, False
        return super().seek(offset, whence)
