"""Diagnosis on a live session: the last minutes of measurements, in a worker process.

The dashboard keeps a bounded buffer of what the link delivered (:class:`SessionBuffer`)
and, when asked, hands a window of it to :func:`diagnose_window` in its own process,
so the estimation loop never waits on the tens of seconds a diagnosis takes. The
worker returns report.json's content with its plain-language conclusion (the
Diagnosis object itself holds filter closures that do not cross processes).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence

from groundstation.core.imu import block_mean, starts_block
from groundstation.core.measurement import Kind, Measurement
from groundstation.diagnosis.engine import diagnose
from groundstation.diagnosis.model_names import RIG_MODEL_HELP
from groundstation.diagnosis.report.conclusion import conclusion, format_params
from groundstation.diagnosis.report.report import as_json
from groundstation.diagnosis.rig import report as rig_report
from groundstation.diagnosis.rig.diagnose import diagnose_rig
from groundstation.estimation.models.heli3dof_rig import Heli3dofRig
from groundstation.estimation.registry import vehicle_config

#: the live diagnosis worker's niceness: it yields the CPU to the link and the estimation loop (on
#: two cores, a 2 kHz link's p99 socket-to-record went from 5.8 ms to 1.9 ms with a diagnosis beside it)
DIAGNOSIS_NICE = 10


class SessionBuffer:
    """The latest measurements, bounded by count, the IMU already averaged over ``imu_dt`` blocks exactly as
    :func:`~groundstation.diagnosis.runs.run.prepare` averages a log's (:mod:`groundstation.core.imu`), so a live
    diagnosis sees the same input as one of the recorded session, at a fifth of the memory."""

    def __init__(self, maxlen: int = 300_000, imu_dt: float = 0.01) -> None:
        self.items: deque[Measurement] = deque(maxlen=maxlen)
        self._imu_dt = imu_dt
        self._block: dict[Kind, tuple[Measurement, float, list]] = {}

    def add(self, m: Measurement) -> None:
        if self.items and m.t < self.items[-1].t - 1.0:  # time went back (seek, loop): start over
            self.items.clear()
            self._block.clear()
        if m.kind in (Kind.ACCEL, Kind.GYRO) and m.instance == 0:
            block = self._block.get(m.kind)
            if block is not None:
                first, t_last, values = block
                if not starts_block(first.t, m.t, self._imu_dt):
                    values.append(m.value)
                    self._block[m.kind] = (first, m.t, values)
                    return
                self.items.append(block_mean(first, t_last, values))
            self._block[m.kind] = (m, m.t, [m.value])
            return
        self.items.append(m)

    def window(self, seconds: float) -> list[Measurement]:
        if not self.items:
            return []
        t1 = self.items[-1].t
        return [m for m in self.items if m.t >= t1 - seconds]


def diagnose_window(
    ms: Sequence[Measurement], model: str = "altitude", declared: Sequence[dict] = (), vehicle: str | None = None
) -> dict:
    """Run in a worker process: the closed loop on ``ms``, as report.json plus its conclusion.
    ``vehicle``: the airframe file the session's estimator was given, as ``diagnose --vehicle``; for
    the 3-DOF rig (``heli3dof``), its constants, which the rig's diagnosis starts from."""
    if model in RIG_MODEL_HELP:
        return _rig_window(ms, vehicle)
    try:
        d = diagnose(ms, source="live session", model_name=model, declared=list(declared), vehicle=vehicle)
    except ValueError as e:
        return {"error": str(e)}
    j = as_json(d)
    j["conclusion"] = conclusion(d, j)
    return j


def _rig_window(ms: Sequence[Measurement], vehicle: str | None) -> dict:
    """The rig's diagnosis (:mod:`.rig`) of a live window, as its report.json."""
    try:
        section = vehicle_config(vehicle, "heli3dof").get("rig") if vehicle else None
        start = Heli3dofRig.from_vehicle(section) if isinstance(section, dict) else None
        d = diagnose_rig(ms, start=start, source="live session")
    except ValueError as e:
        return {"error": str(e)}
    seconds = ms[-1].t - ms[0].t if ms else 0.0
    return rig_report.as_json(d, "live session", f"the last {seconds:.0f} s of the session")


def _rig_markdown(j: dict, seconds: float) -> str:
    rows = "\n".join(
        f"| {e['name']} | "
        + ", ".join(f"{k} {v:.4g} {e['units'][k]}".rstrip() for k, v in e["params"].items() if k != "d")
        + " |"
        for e in j["effects"]
    )
    table = f"| effect | parameters |\n|---|---|\n{rows}\n\n" if rows else ""
    return f"**last {seconds:.0f} s, model heli3dof (the rig)**\n\n{table}{j['conclusion']}"


def markdown(j: dict, seconds: float) -> str:
    """The panel's text: effects found, the conclusion, NIS before and after."""
    if "error" in j:
        return f"**cannot diagnose:** {j['error']}"
    if j.get("model") in RIG_MODEL_HELP:
        return _rig_markdown(j, seconds)
    rows = "\n".join(f"| {e['name']} | {format_params(e['name'], e['params'])} |" for e in j.get("effects", []))
    table = f"| effect | parameters |\n|---|---|\n{rows}\n\n" if rows else ""
    nis = " · ".join(
        f"{s}: NIS {j['before']['sensors'][s]['nis_mean']:.2f} → {j['after']['sensors'][s]['nis_mean']:.2f}"
        for s in j["after"]["sensors"]
        if s in j["before"]["sensors"]
    )
    a = j.get("airframe")
    airframe = (
        f", vehicle {j['vehicle']}"
        if j.get("vehicle")
        else f", thrust curve from the accelerometer (α {a['alpha']:.1f}, β {a['beta']:.2f} m/s²)"
        if a and a.get("used")
        else ""
    )
    return (
        f"**last {seconds:.0f} s, model {j.get('model', '')}{airframe}**\n\n{table}{j.get('conclusion', '')}\n\n{nis}"
    )
