"""Faster-than-real-time runs: a scenario straight into a recorded session.

``run_fast(scenario, log=OUT.tlog, truth=OUT.csv)`` writes

* ``OUT.tlog``: the MAVLink stream the vehicle would have sent, with receive
  timestamps ``epoch + t`` (deterministic for a seed); or, named ``OUT.bin``, the DataFlash log
  the vehicle itself would have kept from boot (:mod:`.flight_log`); or, named ``OUT.ulg``, the
  ULog PX4's logger would have kept (:mod:`.px4_log`);
* ``OUT.csv``: the truth sidecar, every state at 100 Hz (``t`` is vehicle time);
* ``OUT.truth.json``: the whole scenario, undeclared effects included (scoring only);
* ``OUT.declared.json`` beside the log: what the ground station may be told.
"""

from __future__ import annotations

import csv
import json
import struct
import time
from dataclasses import dataclass
from pathlib import Path

from .flight_log import FlightLogs
from .mavlink_out import MavlinkEncoder
from .px4_log import Px4Log
from .scenario import Scenario
from .simulator import Simulator

#: Recording epoch of simulated sessions (2026-01-01 00:00 UTC): fixed, so a
#: seed gives the same bytes every time.
EPOCH = 1_767_225_600.0
_TS = struct.Struct(">Q")


@dataclass
class FastResult:
    frames: int
    seconds: float
    wall: float
    log: Path
    truth: Path | None

    @property
    def speedup(self) -> float:
        return self.seconds / self.wall if self.wall > 0 else float("inf")


def declared_path(log: Path) -> Path:
    return log.with_suffix(".declared.json")


def run_fast(
    scenario: Scenario,
    log: str | Path,
    truth: str | Path | None = None,
    duration: float | None = None,
    sysid: int = 1,
) -> FastResult:
    log = Path(log)
    log.parent.mkdir(parents=True, exist_ok=True)
    seconds = scenario.duration if duration is None else duration
    sim = Simulator(scenario)
    sim.keep_truth = truth is not None
    enc = MavlinkEncoder(scenario.vehicle, sysid=sysid, ground_alt=scenario.sensors.ground_alt)
    t0 = time.perf_counter()
    if log.suffix.lower() == ".bin":
        frames = _dataflash(sim, scenario.vehicle, log, seconds)
    elif log.suffix.lower() == ".ulg":
        frames = _ulog(sim, scenario.vehicle, log, seconds)
    else:
        frames = _tlog(sim, enc, log, seconds)
    wall = time.perf_counter() - t0
    truth_path = None
    if truth is not None:
        truth_path = Path(truth)
        rows = sim.truth_rows
        with open(truth_path, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else ["t"])
            w.writeheader()
            w.writerows(rows)
        truth_path.with_suffix(".truth.json").write_text(json.dumps(scenario.truth_json(), indent=2))
    declared_path(log).write_text(json.dumps(scenario.declared_json(), indent=2))
    return FastResult(frames, seconds, wall, log, truth_path)


def _tlog(sim: Simulator, enc: MavlinkEncoder, log: Path, seconds: float) -> int:
    """The MAVLink stream the vehicle would send, as a tlog; the frames written."""
    frames = 0
    next_hb = 0.0
    pack_ts = _TS.pack
    with open(log, "wb") as f:
        write = f.write
        for _ in range(int(round(seconds / sim.dt))):
            samples = sim.step()
            if sim.t >= next_hb:
                next_hb += 1.0
                write(pack_ts(int((EPOCH + sim.t) * 1e6)) + enc.heartbeat(sim.profile(sim.t).armed))
                frames += 1
            for s in samples:
                stamp = pack_ts(int((EPOCH + s.t) * 1e6))
                for fr in enc.encode(s):
                    write(stamp + fr)
                    frames += 1
    return frames


def _ulog(sim: Simulator, vehicle: str, log: Path, seconds: float) -> int:
    """What PX4's logger would keep from boot, as a ULog (:mod:`.px4_log`); the samples written."""
    n = 0
    with open(log, "wb") as f:
        px4 = Px4Log(f, vehicle, esc=sim.scenario.sensors.esc)
        for _ in range(int(round(seconds / sim.dt))):
            samples = sim.step()
            n += len(samples)
            px4.step(sim.t, samples)
    return n


def _dataflash(sim: Simulator, vehicle: str, log: Path, seconds: float) -> int:
    """What the vehicle itself would log from boot (``LOG_DISARMED`` 1), as a DataFlash ``.bin``
    (:mod:`.flight_log`); the records written."""
    logs = FlightLogs(vehicle, EPOCH, lambda: (), lambda: 0, log_disarmed=True, card_bytes=1 << 62)
    n = 0
    for _ in range(int(round(seconds / sim.dt))):
        samples = sim.step()
        n += len(samples)
        logs.step(sim.t, samples, True)
    logs.close()
    log.write_bytes(logs.logs[1].data if logs.logs else b"")
    return n
