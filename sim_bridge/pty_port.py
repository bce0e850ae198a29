"""A serial port that the simulator owns: the master side of a pseudo-terminal.

The ground station opens the slave path with pyserial exactly as it would a
USB radio. ``link_path`` optionally maintains a stable symlink (as udev's
``/dev/serial/by-id/...`` does), so a device can be "unplugged" (:meth:`unplug`)
and "plugged back" (:meth:`plug`) under the same name with a new pty behind it.
"""

from __future__ import annotations

import asyncio
import os
import tty
from collections.abc import Callable
from pathlib import Path


class PtyPort:
    def __init__(self, link_path: str | os.PathLike | None = None) -> None:
        self.link_path = Path(link_path) if link_path else None
        self.master: int | None = None
        self._slave: int | None = None
        self.slave_path: str | None = None
        self.on_data: Callable[[bytes], object] = lambda _b: None
        self._loop: asyncio.AbstractEventLoop | None = None

    @property
    def path(self) -> str:
        """The path a user passes to the ground station."""
        return str(self.link_path) if self.link_path else (self.slave_path or "")

    def plug(self) -> str:
        master, slave = os.openpty()
        tty.setraw(slave)  # no line discipline: bytes pass unchanged
        os.set_blocking(master, False)
        self.master, self._slave = master, slave
        self.slave_path = os.ttyname(slave)
        if self.link_path:
            tmp = self.link_path.with_name(self.link_path.name + ".new")
            if tmp.is_symlink() or tmp.exists():
                tmp.unlink()
            tmp.symlink_to(self.slave_path)
            os.replace(tmp, self.link_path)
        try:
            self._loop = asyncio.get_running_loop()
            self._loop.add_reader(master, self._readable)
        except RuntimeError:
            self._loop = None
        return self.path

    def _readable(self) -> None:
        if self.master is None:
            return
        try:
            data = os.read(self.master, 65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            return  # no reader on the other side yet
        if data:
            self.on_data(data)

    def write(self, data: bytes) -> int:
        """Write as a device would: what does not fit in the tty buffer is lost."""
        if self.master is None:
            return 0
        try:
            return os.write(self.master, data)
        except (BlockingIOError, OSError):
            return 0

    def unplug(self) -> None:
        """Remove the device: the other side's reads fail, the name disappears."""
        if self.master is not None:
            if self._loop is not None:
                try:
                    self._loop.remove_reader(self.master)
                except (RuntimeError, ValueError):
                    pass
            for fd in (self.master, self._slave):
                if fd is None:
                    continue
                try:
                    os.close(fd)
                except OSError:
                    pass
        self.master = self._slave = None
        if self.link_path and (self.link_path.is_symlink() or self.link_path.exists()):
            self.link_path.unlink()

    close = unplug
