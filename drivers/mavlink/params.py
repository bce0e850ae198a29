"""The MAVLink parameter protocol from the ground station's side: fetch all, get, set with
verification, and the parameter files MAVProxy and QGroundControl write.

Over a lossy link the list is fetched with PARAM_REQUEST_LIST, then every index still missing is
asked for on its own (PARAM_REQUEST_READ by index) until all have come or the retries run out;
a set is sent until the vehicle's PARAM_VALUE echoes the new value (float32, as the wire carries
it). Files: MAVProxy's ``NAME VALUE`` lines (Mission Planner's ``NAME,VALUE`` reads the same) and
QGroundControl's tab-separated ``sysid compid NAME VALUE type``.
"""

from __future__ import annotations

import asyncio
import struct
from collections.abc import Callable
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .exchange import Exchange

RETRIES = 5
INTEGER_TYPES = {
    mavlink.MAV_PARAM_TYPE_UINT8,
    mavlink.MAV_PARAM_TYPE_INT8,
    mavlink.MAV_PARAM_TYPE_UINT16,
    mavlink.MAV_PARAM_TYPE_INT16,
    mavlink.MAV_PARAM_TYPE_UINT32,
    mavlink.MAV_PARAM_TYPE_INT32,
}


class ParamError(RuntimeError):
    """A parameter exchange that did not complete (one line: what, and how far it got)."""


def _f32(v: float) -> float:
    return struct.unpack("<f", struct.pack("<f", v))[0]


def _name(raw) -> str:
    return (raw.decode("latin-1") if isinstance(raw, bytes) else str(raw)).split("\0", 1)[0]


class ParamClient(Exchange):
    """Parameters of one vehicle over a :class:`~drivers.mavlink.link.MavlinkLink`."""

    def __init__(self, link, sysid: int, compid: int = 1, *, timeout: float = 1.0) -> None:
        self.values: dict[str, float] = {}
        self.types: dict[str, int] = {}
        self.count: int | None = None
        self._by_index: dict[int, str] = {}
        super().__init__(link, sysid, compid, timeout=timeout)

    def _on_message(self, m, _t_rx: float) -> None:
        if m.get_type() != "PARAM_VALUE" or m._header.srcSystem != self.sysid:
            return
        name = _name(m.param_id)
        self.values[name] = float(m.param_value)
        self.types[name] = int(m.param_type)
        self.count = int(m.param_count)
        if 0 <= m.param_index < 65535:
            self._by_index[int(m.param_index)] = name
        self._changed_now()

    async def fetch_all(self, progress: Callable[[int, int], None] | None = None) -> dict[str, float]:
        """Every parameter; ParamError naming how many came if some never did."""
        self.link.send(mavlink.MAVLink_param_request_list_message(self.sysid, self.compid))
        quiet = 0
        while quiet < RETRIES:
            if await self._wait_change(self.timeout):
                quiet = 0
                if progress is not None and self.count:
                    progress(len(self._by_index), self.count)
                if self.count is not None and len(self._by_index) >= self.count:
                    return dict(self.values)
                continue
            quiet += 1
            if self.count is None:  # nothing at all yet: ask for the list again
                self.link.send(mavlink.MAVLink_param_request_list_message(self.sysid, self.compid))
                continue
            for k in (i for i in range(self.count) if i not in self._by_index):
                self.link.send(mavlink.MAVLink_param_request_read_message(self.sysid, self.compid, b"", k))
        got = len(self._by_index)
        raise ParamError(f"parameters: {got} of {self.count if self.count is not None else '?'} received")

    async def get(self, name: str) -> float:
        for _ in range(RETRIES):
            self.values.pop(name, None)
            self.link.send(mavlink.MAVLink_param_request_read_message(self.sysid, self.compid, name.encode(), -1))
            if await self._until(lambda: name in self.values):
                return self.values[name]
        raise ParamError(f"parameter {name}: no answer (does the vehicle have it?)")

    async def set(self, name: str, value: float) -> float:
        """Set and verify: the vehicle's echo must carry the value (as float32). Returns it."""
        ptype = self.types.get(name, mavlink.MAV_PARAM_TYPE_REAL32)
        want = float(round(value)) if ptype in INTEGER_TYPES else _f32(value)
        for _ in range(RETRIES):
            self.link.send(mavlink.MAVLink_param_set_message(self.sysid, self.compid, name.encode(), value, ptype))
            if await self._until(lambda: self.values.get(name) is not None and _f32(self.values[name]) == _f32(want)):
                return self.values[name]
        have = self.values.get(name)
        raise ParamError(f"parameter {name}: set to {value:g} not confirmed (the vehicle says {have})")

    async def _until(self, cond: Callable[[], bool]) -> bool:
        loop = asyncio.get_running_loop()
        end = loop.time() + self.timeout
        while not cond():
            left = end - loop.time()
            if left <= 0 or not await self._wait_change(left):
                return cond()
        return True


def save(path: Path, values: dict[str, float], *, qgc: bool = False, sysid: int = 1, compid: int = 1,
         types: dict[str, int] | None = None) -> None:  # fmt: skip
    """MAVProxy's ``NAME VALUE`` file, or QGroundControl's (``qgc``)."""
    types = types or {}
    if qgc:
        lines = ["# Onboard parameters", "# Vehicle-Id Component-Id Name Value Type"]
        lines += [
            f"{sysid}\t{compid}\t{n}\t{v:.18g}\t{types.get(n, mavlink.MAV_PARAM_TYPE_REAL32)}"
            for n, v in sorted(values.items())
        ]
    else:
        lines = [f"{n:<16s} {v:.7g}" for n, v in sorted(values.items())]  # float32: 7 digits hold it
    path.write_text("\n".join(lines) + "\n")


def load(path: Path) -> dict[str, float]:
    """A parameter file of either format (and Mission Planner's ``NAME,VALUE``); one-line errors."""
    out: dict[str, float] = {}
    for k, raw in enumerate(path.read_text().splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.replace(",", " ").split()
        try:
            if len(parts) >= 5 and parts[0].isdigit() and parts[1].isdigit():  # QGroundControl
                out[parts[2]] = float(parts[3])
            elif len(parts) >= 2:
                out[parts[0]] = float(parts[1])
            else:
                raise ValueError
        except ValueError:
            raise ParamError(f"{path}:{k}: not a parameter line: {raw.strip()!r}") from None
    return out
