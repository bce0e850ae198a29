"""What a session does with its measurements: one estimation loop, status line and set of export
files per vehicle, and which vehicle the dashboard shows.

A link can carry several vehicles (MAVLink system ids: two simulators on one ``udpin`` port, a
MAVProxy router with a fleet behind it). Each gets its own estimator: merged, one filter would
fuse one vehicle's range with another's and its status would flip between them. The first
vehicle heard keeps the file names given (``--export est.csv``); the next ones write beside
them with their system id (``est.sys2.csv``). Measurements from no vehicle (a sensor board on
its own port, a ground station on the link) go to the first vehicle's.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from pathlib import Path

from groundstation.core.counts import counted
from groundstation.core.measurement import source_system
from groundstation.estimation.export import EstimateCsvWriter, MeasurementCsvWriter
from groundstation.estimation.loop import EstimationLoop
from groundstation.estimation.noise import load_noise
from groundstation.estimation.registry import build_estimator
from groundstation.estimation.vehicles import declared_effects

from .console import StatusLine

#: vehicles a session keeps outputs (estimators, exports) for; more system ids are counted
MAX_VEHICLES = 16


def beside(path: Path | None, sysid: int) -> Path | None:
    """``est.csv`` -> ``est.sys2.csv``: a further vehicle's file beside the first one's."""
    return None if path is None else path.with_name(f"{path.stem}.sys{sysid}{path.suffix}")


class Outputs:
    """The estimation loop and the files a command writes, fed measurement by measurement."""

    def __init__(
        self,
        args,
        declared_path: Path | None,
        dashboard=None,
        vehicle: str | None = None,
        *,
        scene: bool = False,
        in_time_order: bool = False,
        stated: Sequence[dict] = (),
    ) -> None:
        """``dashboard``: shown there from the start; ``scene``: the session has a dashboard (this
        vehicle may be shown there later, :meth:`show_on`); ``in_time_order``: the measurements come
        in vehicle-time order (a log made ready, :func:`~groundstation.estimation.logs.load_blocked`):
        nothing to roll back, so no checkpoints for it; ``stated``: what the log states of its
        sensors (:attr:`~groundstation.estimation.logs.BlockedLog.stated`)."""
        self.declared = declared_effects(declared_path)
        self.model, self.airframe = args.model, vehicle
        self.estimator = build_estimator(
            args.model, self.declared, load_noise(args.noise), vehicle=vehicle, stated=stated
        )
        estimators = [self.estimator]
        if dashboard is not None or scene:
            # the 3D view needs a horizontal place and its covariance; none of the
            # documents' models has one (see models/horizontal.py)
            estimators.append(build_estimator("horizontal"))
        self.loop = EstimationLoop(estimators, reorder_s=0.0) if in_time_order else EstimationLoop(estimators)
        self.status = StatusLine()
        self.dashboard = None
        self.measurements = MeasurementCsvWriter(args.export_measurements) if args.export_measurements else None
        self.estimates = None
        if args.export:
            self.estimates = EstimateCsvWriter(args.export, self.estimator.name, self.estimator.model.states)
        # the exporter and the dashboard read the same snapshots
        self._snaps = self.loop.snapshots.subscribe() if (args.export or dashboard or scene) else None
        if dashboard is not None:
            self.show_on(dashboard)

    def show_on(self, dashboard) -> None:
        """Feed this vehicle to ``dashboard`` from now on (None: to no dashboard)."""
        self.dashboard = dashboard
        if dashboard is not None:
            dashboard.attach_session(
                model=self.model, declared=self.declared, counters=self.estimator.counters, vehicle=self.airframe
            )

    def see(self, m) -> None:
        """One measurement of a recording: every one is estimated."""
        self._show(m)
        self.loop.push(m)
        self._drain()

    def see_live(self, batch: list) -> None:
        """A live link's batch: estimated within the loop's latency budget (shed under load)."""
        for m in batch:
            self._show(m)
        self.loop.push_many(batch)
        self._drain()

    def _show(self, m) -> None:
        self.status.see(m)
        if self.measurements is not None:
            self.measurements.write(m)
        if self.dashboard is not None:
            self.dashboard.feed_measurement(m)

    def _drain(self) -> None:
        if self._snaps is None:
            return
        for snap in self._snaps.get_nowait():
            if self.estimates is not None:
                self.estimates.write(snap)
            if self.dashboard is not None:
                self.dashboard.feed_snapshot(snap)

    def skipped(self) -> str:
        """What the estimator rejected so far, and its restarts, for the status line ('' if nothing)."""
        c = self.estimator.counters
        parts = [f"skipped {counted(c.rejected)}"] if c.rejected else []
        if c.diverged:
            parts.append(f"diverged and restarted {c.diverged}x")
        if self.loop.counters.shed:
            parts.append(f"decimated {self.loop.counters.shed} readings under load")
        return "; ".join(parts)

    def close(self) -> str:
        self._drain()
        parts = []
        c = self.estimator.counters
        if c.rejected:
            parts.append(f"the estimator skipped {counted(c.rejected)}")
        if c.diverged:
            parts.append(f"the estimator diverged and restarted {c.diverged} times")
        if self.loop.counters.shed:
            parts.append(f"decimated {self.loop.counters.shed} readings under load")
        if note := self.estimator.still_noise_note:
            parts.append(note)
        for w, what in ((self.estimates, "estimates"), (self.measurements, "measurement rows")):
            if w is None:
                continue
            if w is self.estimates:
                self.estimates.close(counters=c, loop=self.loop.counters)
            else:
                w.close()
            parts.append(
                f"wrote {w.rows} {what} to {w.path}" + (f" and {w.segments - 1} more segment(s)" * (w.segments > 1))
            )
            if w.refused or w.back_in_time:
                parts.append(
                    f"{w.refused} {what} of impossible times or values and {w.back_in_time} going back in time "
                    f"past the last segment file were not written"
                )
        return "; ".join(parts)


class VehicleOutputs:
    """One :class:`Outputs` per vehicle, made when its first measurement comes.

    ``is_vehicle(sysid)``: whether a system id is a vehicle (for a link: not one it heard a ground
    station's heartbeat from); anything else goes to the first vehicle's outputs. ``on_new(sysids)`` is told the
    vehicles whenever one is added (the dashboard's picker)."""

    def __init__(
        self,
        args,
        declared_path: Path | None,
        dashboard=None,
        vehicle: str | None = None,
        *,
        is_vehicle: Callable[[int], bool] = lambda sysid: True,
        on_new: Callable[[list[int]], None] | None = None,
        in_time_order: bool = False,
        stated: Sequence[dict] = (),
    ) -> None:
        self.args, self.declared_path, self.dashboard, self.airframe = args, declared_path, dashboard, vehicle
        self.in_time_order, self.stated = in_time_order, stated
        self.is_vehicle, self.on_new = is_vehicle, on_new
        self.by_id: dict[int, Outputs] = {}
        #: system ids past :data:`MAX_VEHICLES`, with their measurements (the first vehicle's outputs
        #: take them, as a non-vehicle's): 254 forged ids had made 508 export files
        self.beyond: dict[int, int] = {}
        self.first: Outputs | None = None
        self.first_id: int | None = None
        self.shown: int | None = None  # the system id the dashboard shows
        self._route: dict[str, Outputs] = {}  # a vehicle's measurement source -> its outputs

    def _new(self, sysid: int | None) -> Outputs:
        if self.first is None:
            out = self.first = Outputs(
                self.args,
                self.declared_path,
                self.dashboard,
                self.airframe,
                in_time_order=self.in_time_order,
                stated=self.stated,
            )
            self.first_id = self.shown = sysid
        elif self.first_id is None:  # the first outputs had only measurements of no vehicle yet
            out, self.first_id, self.shown = self.first, sysid, sysid
        else:
            assert sysid is not None
            args = argparse.Namespace(**vars(self.args))
            args.export, args.export_measurements = beside(args.export, sysid), beside(args.export_measurements, sysid)
            out = Outputs(
                args,
                self.declared_path,
                None,
                self.airframe,
                scene=self.dashboard is not None,
                in_time_order=self.in_time_order,
                stated=self.stated,
            )
        if sysid is not None:
            self.by_id[sysid] = out
            if self.on_new is not None and len(self.by_id) > 1:
                self.on_new(sorted(self.by_id))
        return out

    def of(self, source: str) -> Outputs:
        """The outputs a measurement from ``source`` goes to (a vehicle's: remembered by source)."""
        out = self._route.get(source)
        if out is not None:
            return out
        sysid = source_system(source)
        if sysid is not None and self.is_vehicle(sysid):
            out = self.by_id.get(sysid)
            if out is None:
                if len(self.by_id) >= MAX_VEHICLES:
                    self.beyond[sysid] = self.beyond.get(sysid, 0) + 1
                    return self.first if self.first is not None else self._new(None)
                out = self._new(sysid)
            self._route[source] = out
            return out
        return self.first if self.first is not None else self._new(None)

    def see(self, m) -> None:
        self.of(m.source).see(m)

    def see_live(self, batch: list) -> None:
        groups: dict[int, tuple[Outputs, list]] = {}
        for m in batch:
            out = self.of(m.source)
            groups.setdefault(id(out), (out, []))[1].append(m)
        for out, ms in groups.values():
            out.see_live(ms)

    def show(self, sysid: int) -> None:
        """The dashboard shows this vehicle from now on."""
        out = self.by_id.get(sysid)
        if out is None or self.dashboard is None or sysid == self.shown:
            return
        for other in self.by_id.values():
            other.dashboard = None
        self.dashboard.clear_view()
        out.show_on(self.dashboard)
        self.shown = sysid

    @property
    def outputs(self) -> list[tuple[int | None, Outputs]]:
        """(system id, outputs), the first vehicle first."""
        rest = [(k, o) for k, o in sorted(self.by_id.items()) if o is not self.first]
        return ([(self.first_id, self.first)] if self.first is not None else []) + rest

    @property
    def count(self) -> int:
        """Measurements seen, all vehicles'."""
        return sum(o.status.count for _, o in self.outputs)

    def print_status(self, state: str, counters, extra: str = "") -> None:
        """A status line a vehicle (named when there are several), each with ``extra``."""
        many = len(self.by_id) > 1
        for sysid, out in self.outputs:
            text = out.status.line(state, counters, "  ".join(x for x in (extra, out.skipped()) if x))
            print(f"vehicle {sysid}: {text}" if many else text, flush=True)

    def close(self) -> str:
        parts = [
            (f"vehicle {k}: " if len(self.by_id) > 1 and k is not None else "") + text
            for k, o in self.outputs
            if (text := o.close())
        ]
        if self.beyond:
            parts.append(
                f"{len(self.beyond)} more system ids ({sum(self.beyond.values())} readings) past the "
                f"{MAX_VEHICLES} vehicles a session follows were not given outputs of their own"
            )
        return "; ".join(parts)
