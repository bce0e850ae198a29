"""CSV exports: estimates (the contract other tools read) and decoded measurements.

Estimates, one row per estimate (after each measurement update)::

    t,<state>...,sigma_<state>...

``t`` is vehicle time [s]; states in the model's units (see its docstring);
``sigma_<state>`` the square root of the covariance's diagonal. Written from
the same :class:`~groundstation.estimation.loop.Snapshot` objects the dashboard reads. Beside it,
``OUT.counters.json`` says what the estimator skipped (by sensor and reason) and how often it
started over.

Decoded measurements (tidy/long format):

One row per measurement component::

    t,kind,instance,component,value,variance,source

``t`` is vehicle time [s], ``value`` is in SI units (see
:mod:`groundstation.core.measurement`), ``variance`` is empty when the sensor gave
none. Long format keeps the columns fixed whatever sensors a file has; pivot
it (pandas ``pivot_table``) for a wide view. Estimates are exported in the
estimator's own format (``t``, states, ``sigma_<state>``) by the estimation loop.

**Flight segments.** When the vehicle's time goes back by more than
:data:`~drivers.mavlink.clock.RESTART_BACK_S` (it restarted; a replay looped or was sought back)
the rows go on in a new file beside the first, ``OUT.seg2.csv``, ``OUT.seg3.csv``, ...: time
never goes back within one file. At most :data:`MAX_SEGMENTS` files: past them (a link whose time
steps back again and again, forged or broken) the rows that would go back in time are counted
(``back_in_time``), not written, and the last file goes on where time does.

**What is refused.** A row whose time is not finite or not a possible uptime (negative, or the
uint32 milliseconds' sentinel and beyond: :data:`MAX_UPTIME_S`), or whose values are not finite,
is counted (``refused``), not written: a CSV of the session must read back as numbers. In the
measurements' long format a reading with some components NaN and others not (SERVO_OUTPUT_RAW's
unused channels beside the motors') keeps its numbers: NaN there is "no value", and its
components are left out, not counted; a reading with no number at all, or an infinite one, is
refused whole.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from drivers.mavlink.clock import RESTART_BACK_S, RESTART_CONFIRM
from groundstation.core.measurement import KIND_COMPONENTS, Measurement

HEADER = ("t", "kind", "instance", "component", "value", "variance", "source")
#: [s] readings behind a source's newest agree on a restart within this (the clock's jump_s)
RESTART_AGREE_S = 1.0
#: flight segments' files a session writes at most
MAX_SEGMENTS = 8
#: [s] a vehicle time at or past this is no uptime: UINT32_MAX ms (time_boot_ms's all-ones), 49.7 days
MAX_UPTIME_S = 4294967.295


def segment_path(path: Path, n: int) -> Path:
    """The file of flight segment ``n`` (1: ``path`` itself; then ``OUT.seg2.csv``, ...)."""
    return path if n == 1 else path.with_name(f"{path.stem}.seg{n}{path.suffix}")


class _SegmentedCsv:
    """A CSV writer that starts a new file, with the same header, when time goes back."""

    def __init__(self, path: str | Path, header) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.header = list(header)
        self.segments = 1
        self.refused = 0  # rows of impossible times or values not finite
        self.back_in_time = 0  # rows that would have gone back in time, past the last segment
        self._f = open(self.path, "w", newline="")
        self._w = csv.writer(self._f)
        self._w.writerow(self.header)

    def _possible(self, t: float, values) -> bool:
        if 0.0 <= t < MAX_UPTIME_S and all(math.isfinite(v) for v in values):
            return True
        self.refused += 1
        return False

    def _start(self) -> bool:
        """The next segment's file; False (and nothing opened) past :data:`MAX_SEGMENTS`."""
        if self.segments >= MAX_SEGMENTS:
            return False
        self._f.close()
        self.segments += 1
        self._f = open(segment_path(self.path, self.segments), "w", newline="")
        self._w = csv.writer(self._f)
        self._w.writerow(self.header)
        return True

    @property
    def paths(self) -> list[Path]:
        return [segment_path(self.path, n) for n in range(1, self.segments + 1)]

    def close(self) -> None:
        for held in getattr(self, "_held", {}).values():  # never confirmed: outliers
            self.back_in_time += len(held)
        if hasattr(self, "_held"):
            self._held.clear()
        if not self._f.closed:
            self._f.close()


def _fmt(x: float) -> str:
    return "" if x is None or (isinstance(x, float) and math.isnan(x)) else repr(float(x))


class MeasurementCsvWriter(_SegmentedCsv):
    """Each source's time is followed on its own (a board and a vehicle may keep different clocks).
    A source's time going back starts a new segment once :data:`~drivers.mavlink.clock.RESTART_CONFIRM`
    of its readings in a row say so, as the link's clock declares a restart: the readings before that
    are held, and written in the new segment or, when its time comes back (one corrupt or forged
    timestamp), counted as ``back_in_time``."""

    def __init__(self, path: str | Path) -> None:
        super().__init__(path, HEADER)
        self.rows = 0
        self._newest: dict[str, float] = {}  # source -> its newest time written
        self._held: dict[str, list[Measurement]] = {}  # source -> its readings behind its newest

    def write(self, m: Measurement) -> None:
        values = m.value.tolist()
        if any(math.isnan(v) for v in values) and not all(math.isnan(v) for v in values):
            values = [v for v in values if not math.isnan(v)]  # the components it gives (module docstring)
        if not self._possible(m.t, values):
            return
        newest = self._newest.get(m.source)
        held = self._held.get(m.source)
        if newest is not None and m.t < newest - RESTART_BACK_S:
            if held and abs(m.t - max(h.t for h in held)) > RESTART_AGREE_S:
                self.back_in_time += len(held)  # those were outliers: this one disagrees with them
                held.clear()
            held = self._held.setdefault(m.source, [])
            held.append(m)
            if len(held) < RESTART_CONFIRM:
                return
            del self._held[m.source]
            if not self._start():
                self.back_in_time += len(held)
                return
            self._newest.clear()
            for h in held:
                self._row(h)
            return
        if held:  # time came back: what was held behind it were outliers
            self.back_in_time += len(held)
            del self._held[m.source]
        self._row(m)

    def _row(self, m: Measurement) -> None:
        newest = self._newest.get(m.source)
        if newest is None or m.t > newest:
            self._newest[m.source] = m.t
        names = KIND_COMPONENTS.get(m.kind)
        var = m.variance
        for j, v in enumerate(m.value.tolist()):
            if math.isnan(v):  # a component the reading does not give
                continue
            name = names[j] if names and j < len(names) else str(j)
            self._w.writerow(
                (_fmt(m.t), m.kind.value, m.instance, name, _fmt(v), _fmt(var[j]) if var is not None else "", m.source)
            )
            self.rows += 1


class EstimateCsvWriter(_SegmentedCsv):
    """``t, states, sigma_<state>`` from snapshots of one estimator."""

    def __init__(self, path: str | Path, estimator: str, states: list[str]) -> None:
        super().__init__(path, ["t", *states, *[f"sigma_{s}" for s in states]])
        self.estimator = estimator
        self.rows = 0
        self._newest = -math.inf

    def write(self, snap) -> None:
        if snap.estimator != self.estimator:
            return
        if not self._possible(snap.t, [*snap.x.tolist(), *snap.sigma.tolist()]):
            return
        if snap.t < self._newest - RESTART_BACK_S:
            if not self._start():
                self.back_in_time += 1
                return
            self._newest = -math.inf
        self._newest = max(self._newest, snap.t)
        # tolist(): Python floats, the shortest repr that reads back the same number
        self._w.writerow([repr(float(snap.t)), *map(repr, snap.x.tolist()), *map(repr, snap.sigma.tolist())])
        self.rows += 1

    def close(self, counters=None, loop=None) -> None:
        """Close the CSV; with the estimator's ``counters``, write beside it (``OUT.counters.json``)
        what it skipped, by sensor and reason, and how often it started over; with the estimation
        loop's, what it dropped as late and decimated under load."""
        super().close()
        if counters is not None:
            self.counters_path.write_text(
                json.dumps(
                    {
                        "estimator": self.estimator,
                        "estimates": self.rows,
                        "segments": [p.name for p in self.paths],
                        "refused_rows": self.refused,
                        "back_in_time_rows": self.back_in_time,
                        "updates": counters.updates,
                        "skipped": counters.rejected,
                        "diverged": counters.diverged,
                        "reinitialisations": counters.reinitialisations,
                        **(
                            {"late": loop.late, "rolled_back": loop.rollbacks, "decimated": loop.shed}
                            if loop is not None
                            else {}
                        ),
                    },
                    indent=2,
                )
            )

    @property
    def counters_path(self) -> Path:
        return self.path.with_suffix(".counters.json")
