"""Estimation benchmark: filter update rates, whole-recording throughput, live latency.

    python bench/estimation.py [--minutes 10] [--live-seconds 30]

1. Updates per second of each estimator (its measurement update with the
   prediction before it), isolated from decoding.
2. Whole-recording throughput: a simulated 10-minute flight with a 1 kHz IMU,
   50 Hz barometer and 20 Hz range sensor, read from its tlog and run through
   the altitude filter, as simulated seconds per wall second. Baseline: real
   time (1x); target >= 20x on one core reading by reading, >= 50x as a replay
   at max speed takes it (the log as columns, the IMU in 10 ms blocks).
3. Live latency at 1 kHz input: the simulated vehicle (its own process, as a
   vehicle is its own device) sends over loopback UDP (IMU at 1 kHz), the link
   decodes, the loop runs the filter; for every
   processed measurement, socket read -> estimate done. Target p99 < 2 ms.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from drivers.mavlink.link import MavlinkLink  # noqa: E402
from drivers.replay import Replay  # noqa: E402
from groundstation.core.measurement import Kind, Measurement  # noqa: E402
from groundstation.estimation.logs import load_blocked  # noqa: E402
from groundstation.estimation.loop import EstimationLoop  # noqa: E402
from groundstation.estimation.registry import build_estimator  # noqa: E402
from sim_bridge.fast import run_fast  # noqa: E402
from sim_bridge.scenario import Scenario  # noqa: E402

RATES = {"imu": 1000, "baro": 50, "range": 20}


def scenario(seconds: float, d: Path) -> Scenario:
    p = d / "scenario.json"
    p.write_text(
        json.dumps(
            {
                "vehicle": "quad",
                "seed": 1,
                "duration": seconds,
                "effects": [{"name": "range_tilt"}],
                "sensors": {"rates": RATES},
            }
        )
    )
    return Scenario.load(p)


def updates_per_second(n: int = 20000) -> float:
    est = build_estimator("altitude", [{"name": "range_tilt"}])
    acc = np.array([0.0, 0.0, -9.80665])
    ms = []
    for k in range(n):
        ms.append(Measurement(k * 0.02, Kind.ACCEL, acc, "b/1.1", k * 0.02))
        ms.append(Measurement(k * 0.02 + 0.01, Kind.RANGE, np.array([1.0]), "b/1.1", k * 0.02 + 0.01))
    t0 = time.perf_counter()
    for m in ms:
        est.handle(m)
    return n / (time.perf_counter() - t0)


def whole_recording(minutes: float, d: Path) -> tuple[float, float]:
    """The recording through the altitude filter, as multiples of real time (best of two each,
    interleaved): reading by reading through the live receive path, as a paced replay plays it, and
    as ``replay --speed max`` without a dashboard takes it (:func:`load_blocked`: the log read as
    columns, the IMU in 10 ms blocks)."""
    sc = scenario(minutes * 60.0, d)
    run_fast(sc, d / "long.tlog")
    each = blocked = 0.0
    for _ in range(2):
        t0 = time.perf_counter()
        est = build_estimator("altitude", [{"name": "range_tilt"}])
        loop = EstimationLoop([est])
        for m in Replay(d / "long.tlog").iter_measurements():
            loop.push(m)
        each = max(each, minutes * 60.0 / (time.perf_counter() - t0))
        t0 = time.perf_counter()
        log = load_blocked(d / "long.tlog")
        assert log is not None
        est = build_estimator("altitude", [{"name": "range_tilt"}])
        loop = EstimationLoop([est], reorder_s=0.0)  # in time order: nothing to roll back
        for m in log.measurements:
            loop.push(m)
        blocked = max(blocked, minutes * 60.0 / (time.perf_counter() - t0))
    return each, blocked


async def live(seconds: float, d: Path) -> dict:
    link = MavlinkLink(
        "udpin:127.0.0.1:0",
        streams={"HIGHRES_IMU": 1000.0, "SCALED_PRESSURE": 50.0, "DISTANCE_SENSOR": 20.0, "ATTITUDE": 50.0},
    )
    sub = link.measurements()
    await link.open()
    scenario(seconds + 5, d)  # writes d / scenario.json
    # the vehicle is another device: the simulator runs in its own process
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "groundstation",
        "sim",
        "--scenario",
        str(d / "scenario.json"),
        "--udp",
        f"127.0.0.1:{link.transport.local_address[1]}",
        "--duration",
        str(seconds),
        stdout=asyncio.subprocess.DEVNULL,
        stderr=asyncio.subprocess.DEVNULL,
    )
    est = build_estimator("altitude", [{"name": "range_tilt"}])
    loop = EstimationLoop([est])
    lat_all, lat_upd, cost = [], [], []

    def sink(ms):  # the loop runs in the link's receive path
        for m in ms:
            n = est.counters.updates
            t_in = time.perf_counter()
            loop.push(m)
            if m.kind in loop.kinds and m.t > 3.0:  # after take-off and stream set-up
                cost.append((time.perf_counter() - t_in) * 1e3)
                dt = (time.time() - m.t_rx) * 1e3
                lat_all.append(dt)
                if est.counters.updates != n:
                    lat_upd.append(dt)

    link.sinks.append(sink)

    drained = 0

    async def drain():  # an ordinary subscriber too, as the dashboard would be
        nonlocal drained
        async for _ in sub:
            drained += 1

    task = asyncio.create_task(drain())
    try:
        await asyncio.wait_for(proc.wait(), seconds + 30)
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
        await link.close()
        await task
    a, u, pr = np.array(lat_all), np.array(lat_upd), np.array(cost)
    return {
        "n": len(a),
        "p50": np.percentile(a, 50),
        "p99": np.percentile(a, 99),
        "max": a.max(),
        "proc_p99": np.percentile(pr, 99),
        "proc_p50": np.percentile(pr, 50),
        "upd_p99": np.percentile(u, 99) if len(u) else float("nan"),
        "imu_hz": est.counters.predictions / seconds,
        "drained": drained,
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--live-seconds", type=float, default=30.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        ups = updates_per_second()
        print(f"{'measure':<58}{'value':>14}  target")
        print(f"{'altitude filter: range updates (with prediction) per s':<58}{ups:>14,.0f}  -")
        each, blocked = whole_recording(args.minutes, d)
        print(
            f"{f'{args.minutes:g}-min recording (1 kHz IMU) -> altitude filter, x real time':<58}"
            f"{each:>13.1f}x  >= 20x {'met' if each >= 20 else 'NOT met'}"
        )
        print(
            f"{'  the same, log as columns, IMU in 10 ms blocks (replay max)':<58}"
            f"{blocked:>13.1f}x  >= 50x {'met' if blocked >= 50 else 'NOT met'}  ({blocked / each:.1f}x the above)"
        )
        if args.live_seconds > 0:
            r = asyncio.run(live(args.live_seconds, d))
            verdict = "met" if r["p99"] < 2.0 else "NOT met"
            print(f"{'live 1 kHz over UDP: socket read -> estimate, p50 [ms]':<58}{r['p50']:>14.3f}")
            print(f"{'live 1 kHz over UDP: socket read -> estimate, p99 [ms]':<58}{r['p99']:>14.3f}  < 2 ms {verdict}")
            print(f"{'  (measurement updates only, p99 [ms])':<58}{r['upd_p99']:>14.3f}")
            print(f"{'  (max [ms]; samples)':<58}{r['max']:>14.3f}  {r['n']} samples")
            print(f"{'  of which the loop and filter, p50 / p99 [ms]':<58}{r['proc_p50']:>7.3f} /{r['proc_p99']:>5.3f}")
            print(f"{'  (a second, ordinary subscriber received; measurements)':<58}{r['drained']:>14}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
