"""A log's records as columns, per message type, on the clock the measurements use.

The measurement stream (:class:`~groundstation.core.measurement.Measurement`) carries what an
estimator reads. A log says more: the autopilot's errors, events, modes, vibration, motor
outputs, its own filter's innovations, its parameters. Those are read here, unconverted (each
message's own fields and units), as a :class:`LogTables`: ``tables["ERR"]["Subsys"]``, with
``tables["ERR"].t`` in seconds on the same clock as the log's measurements, so that what is
found in them (:mod:`groundstation.diagnosis.triage`) can cut the same stretches out of the fit.

The clock is named in :attr:`LogTables.clock`:

* ``vehicle``: the vehicle's time, as the measurements have it (DataFlash ``TimeUS``/``TimeMS``
  or its row clock, ULog ``timestamp``);
* ``recording``: a telemetry log's receive time since the recording began (a tlog: the vehicle's
  clock goes back at each reboot, the recording's does not). The measurements' ``t_rx`` is on it.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

from drivers.tlog import TlogIndex

from .bulk import load_tlog


@dataclass
class Table:
    """All records of one message type: ``t`` [s] and one array per field."""

    t: np.ndarray
    cols: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.t)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.cols[name]

    def __contains__(self, name: str) -> bool:
        return name in self.cols

    def get(self, *names: str) -> np.ndarray | None:
        """The first of ``names`` this table has (message versions rename fields), or None."""
        for n in names:
            if n in self.cols:
                return self.cols[n]
        return None

    def floats(self, *names: str) -> np.ndarray:
        """As :meth:`numeric`, for a field the caller knows is there (KeyError if not)."""
        v = self.numeric(*names)
        if v is None:
            raise KeyError(f"no numeric field {' or '.join(names)}")
        return v

    def numeric(self, *names: str) -> np.ndarray | None:
        """As :meth:`get`, as float64 (None if the field is not a number)."""
        v = self.get(*names)
        if v is None or v.dtype.kind not in "biuf":
            return None
        with np.errstate(invalid="ignore"):  # a damaged record's value out of a float's reach: NaN, no warning
            return v.astype(float)


@dataclass
class LogTables:
    """A log's message types as :class:`Table` s, its parameters, and the clock they share."""

    tables: dict[str, Table] = field(default_factory=dict)
    params: dict[str, float] = field(default_factory=dict)
    clock: str = "vehicle"
    fmt: str = ""  # "dataflash", "tlog", "ulog", "crazyflie"
    autopilot: str = ""  # "ardupilot", "px4", or "" when the log does not say
    #: the firmware's own words for itself where the log has them ("ArduCopter V3.1 (5c6503e2)",
    #: "PX4 v1.14.0"), else ""
    firmware: str = ""
    origin: float = 0.0  # on the recording clock: the receive time [s, UNIX] its zero stands for

    def __getitem__(self, name: str) -> Table:
        return self.tables[name]

    def __contains__(self, name: str) -> bool:
        return name in self.tables and len(self.tables[name]) > 0

    def get(self, *names: str) -> Table | None:
        """The first of ``names`` the log has records of, or None."""
        for n in names:
            if n in self:
                return self.tables[n]
        return None

    def starting(self, prefix: str) -> Iterator[tuple[str, Table]]:
        """The types whose names start with ``prefix`` (IMU, IMU2, IMU3...), in name order."""
        for name in sorted(self.tables):
            if name.startswith(prefix) and len(self.tables[name]):
                yield name, self.tables[name]

    @property
    def span(self) -> tuple[float, float]:
        """The first and last record time over all types [s]."""
        firsts = [float(np.nanmin(tb.t)) for tb in self.tables.values() if len(tb) and np.isfinite(tb.t).any()]
        lasts = [float(np.nanmax(tb.t)) for tb in self.tables.values() if len(tb) and np.isfinite(tb.t).any()]
        return (min(firsts), max(lasts)) if firsts else (0.0, 0.0)


def table_from_rows(ts: Iterable[float], rows: list[dict]) -> Table:
    """Rows of one type (dicts of field -> value, as pymavlink's ``to_dict``) to columns. A
    field a row lacks is NaN (numbers) or '' (text)."""
    t = np.fromiter(ts, dtype=float, count=len(rows))
    names: dict[str, None] = {}
    for r in rows:
        for k in r:
            names.setdefault(k, None)
    cols: dict[str, np.ndarray] = {}
    for k in names:
        if k == "mavpackettype":
            continue
        vals = [r.get(k) for r in rows]
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vals if v is not None):
            cols[k] = np.array([math_nan if v is None else v for v in vals], dtype=float)
        else:
            cols[k] = np.array(["" if v is None else _text(v) for v in vals], dtype=object)
    return Table(t, cols)


math_nan = float("nan")


def _text(v) -> str:
    if isinstance(v, bytes):
        return v.split(b"\0", 1)[0].decode("latin-1")
    return str(v)


#: an autopilot's banner, as ArduPilot writes it at boot (a DataFlash MSG, a text log's header line, a
#: STATUSTEXT): "ArduCopter V3.1 (5c6503e2)", "APM:Copter V3.2", "ArduSub V4.1.1 BETA5", "APMrover2 v2.51"
FIRMWARE = re.compile(r"^\s*(Ardu\w+|APM:\w+|APMrover2|AntennaTracker|Blimp)\s+V?\d", re.IGNORECASE)


#: MAV_TYPE_GCS: a ground station's heartbeat; its records in a tlog are not the vehicle's
_MAV_TYPE_GCS = 6


def tables_from_tlog(
    path, *, index: TlogIndex | None = None, only: tuple[str, ...] = (), without: tuple[str, ...] = ()
) -> LogTables:
    """A tlog's messages as tables on the recording's clock (seconds since its first record),
    without the ground stations' own (their HEARTBEATs would read as the vehicle's modes).
    PARAM_VALUE messages give the parameters (the last value of each). ``index``: the file's, if
    already scanned; ``only``: just these message types (HEARTBEAT among them, to know the ground
    stations); ``without``: message types left out."""
    b = load_tlog(path, index=index, only=tuple(dict.fromkeys((*only, "HEARTBEAT"))) if only else (), without=without)
    t0 = min((float(m.t.min()) for m in b.messages.values() if len(m)), default=0.0)
    gcs: set[int] = set()
    hb = b.messages.get("HEARTBEAT")
    if hb is not None and hb.sysid is not None:
        gcs = {int(s) for s in np.unique(hb.sysid[hb["type"] == _MAV_TYPE_GCS])}
    out = LogTables(fmt="tlog", clock="recording", origin=t0)
    for name in list(b.messages):
        m = b.messages.pop(name)  # each type's rows freed as its table is made
        keep = np.ones(len(m), bool) if m.sysid is None else ~np.isin(m.sysid, list(gcs))
        if not keep.any():
            continue
        every = bool(keep.all())
        cols: dict[str, np.ndarray] = {}
        for f in m.names:
            col = m[f] if every else m[f][keep]  # every row kept: the record array's own column, not a copy
            if col.dtype.kind == "S":
                col = np.array([_text(v) for v in col], dtype=object)
            elif col.ndim > 1:  # an array field (e.g. a name as chars): kept as text
                col = np.array([_text(bytes(v)) for v in col], dtype=object)
            cols[f] = col
        if m.sysid is not None:
            cols["_sysid"] = m.sysid[keep].astype(float)
        out.tables[name] = Table(m.t[keep] - t0, cols)
    pv = out.get("PARAM_VALUE")
    if pv is not None:
        for pid, val in zip(pv["param_id"], pv["param_value"]):
            out.params[str(pid)] = float(val)
    st = out.get("STATUSTEXT")
    if st is not None and "text" in st:
        out.firmware = next((str(x) for x in st["text"] if FIRMWARE.match(str(x))), "")
    if hb is not None and len(hb):
        ap = hb["autopilot"][~np.isin(hb.sysid, list(gcs))] if hb.sysid is not None else hb["autopilot"]
        vals = set(ap.tolist())
        out.autopilot = "ardupilot" if 3 in vals else "px4" if 12 in vals else ""
    return out
