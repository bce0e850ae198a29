"""Telemetry behind a MAVProxy router left at its defaults, for as long as a flight.

    python bench/router_streams.py [--minutes 10]

``groundstation sim`` → ``mavproxy.py --master=udpin:… --out=udpout:…`` (no ``--streamrate``: the
router asks the vehicle for every stream at 4 Hz, again and again) → a ground-station link. Prints,
per message, the rate asked for, the rate received over the whole window and a minute at a time,
and the ratio received/asked (the baseline: what the link asked for). Target: ≥ 0.90 for every
stream over 10 minutes. `tests/test_streams.py` checks a minute of it in ``make test`` and ten in
``make soak``, which CI runs.
"""

from __future__ import annotations

import argparse
import asyncio
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from drivers.mavlink.link import DEFAULT_STREAMS, MavlinkLink  # noqa: E402

MAVPROXY = Path(sys.executable).parent / "mavproxy.py"
MESSAGES = ("HIGHRES_IMU", "SCALED_PRESSURE", "DISTANCE_SENSOR", "ATTITUDE", "GPS_RAW_INT",
            "GLOBAL_POSITION_INT", "SERVO_OUTPUT_RAW", "SYS_STATUS", "BATTERY_STATUS")  # fmt: skip


def free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def measure(minutes: float) -> tuple[dict[str, float], list[dict[str, float]], list[str]]:
    vehicle_port, gcs_port = free_udp_port(), free_udp_port()
    link = MavlinkLink(f"udpin:127.0.0.1:{gcs_port}", ack_timeout=0.5, check_every=2.0)
    await link.open()
    procs = []
    with tempfile.TemporaryDirectory() as state:
        try:
            procs.append(subprocess.Popen(
                [MAVPROXY, f"--master=udpin:127.0.0.1:{vehicle_port}", f"--out=udpout:127.0.0.1:{gcs_port}",
                 "--non-interactive", f"--state-basedir={state}", "--default-modules=link"],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            ))  # fmt: skip
            procs.append(subprocess.Popen(
                [sys.executable, "-m", "groundstation", "sim", "--udp", f"127.0.0.1:{vehicle_port}",
                 "--duration", str(60 * minutes + 120)],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            ))  # fmt: skip
            end = time.monotonic() + 60
            while not link.requester.vehicles.get(1) or not link.requester.vehicles[1].acked:
                if time.monotonic() > end:
                    raise SystemExit("no vehicle behind the router within 60 s")
                await asyncio.sleep(0.2)
            start, t0 = dict(link.counters.by_type), time.monotonic()
            per_minute = []
            last, t_last = dict(start), t0
            for _ in range(int(round(minutes))):
                await asyncio.sleep(60.0)  # a measurement window
                now, counts = time.monotonic(), dict(link.counters.by_type)
                per_minute.append({n: (counts.get(n, 0) - last.get(n, 0)) / (now - t_last) for n in MESSAGES})
                last, t_last = counts, now
            dt = time.monotonic() - t0
            total = {n: (link.counters.by_type.get(n, 0) - start.get(n, 0)) / dt for n in MESSAGES}
            return total, per_minute, list(link.stream_notes)
        finally:
            for p in procs:
                p.terminate()
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()
            await link.close()


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=10.0)
    args = ap.parse_args()
    total, per_minute, notes = asyncio.run(measure(args.minutes))
    print(f"{'message':<22}{'asked [Hz]':>11}{'got [Hz]':>10}{'ratio':>8}{'worst minute':>14}")
    ok = True
    for n in MESSAGES:
        asked = DEFAULT_STREAMS[n]
        worst = min((m[n] for m in per_minute), default=float("nan")) / asked
        ratio = total[n] / asked
        ok &= ratio >= 0.9
        print(f"{n:<22}{asked:>11.1f}{total[n]:>10.1f}{ratio:>8.2f}{worst:>14.2f}")
    print(f"{len(notes)} notes on the link's streams; " + (notes[-1] if notes else "none"))
    print("target >= 0.90 each over the window: " + ("met" if ok else "NOT met"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
