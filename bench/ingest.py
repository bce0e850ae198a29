"""Ingest benchmark: bytes -> measurement records, against pymavlink on the same data.

    python bench/ingest.py [--messages 100000] [--live-seconds 60] [--live-rate 2000] [--every-field]

Part 1 (offline, one process, same bytes for every contender, best of 3 runs; its HIGHRES_IMU
flag their fields updated as PX4 flags them, or with ``--every-field`` all of them in every message):
  * pymavlink ``MAVLink.parse_buffer`` alone (framing + CRC + message objects),
  * ours: ``MavlinkReceiver.feed`` (that, plus counters and conversion to records),
  * pymavlink ``mavutil`` tlog ``recv_match`` loop on a tlog of the same frames.
  Target: ours >= 1.5x parse_buffer.
  Then ours in parts: our framer alone, and the very records ours makes built again from
  ready values (a view and a tuple each), so the table shows what is left for the rest
  (counters, vehicle clocks, unit conversion) at 1.5x.

``--instructions`` counts instead of timing: the CPU instructions each contender spends per message,
from valgrind (``cachegrind``, no cache simulation), for one pass over the stream and for two, the
difference being one pass with imports and set-up cancelled out. A count does not move with the
machine's load, so it shows a change of a few per cent that the timed rounds cannot; time per
instruction is not the same for both, so it does not replace the timed ratio.

Part 2 (live): a separate process sends HIGHRES_IMU over loopback UDP at a fixed
rate, stamping each with its send time (CLOCK_MONOTONIC, shared by all
processes); the ground-station link receives, and a
consumer measures loss (sequence numbers and count) and send-to-record latency.
Target: zero loss and p99 < 5 ms at 2,000 msg/s for 60 s.

Part 3 (``--beside-diagnosis LOG``): part 2 again while ``groundstation diagnose LOG`` runs in
another process, at the same priority and at the live diagnosis worker's niceness
(``DIAGNOSIS_NICE``, as the dashboard starts it), each from the end of its triage (when the
filter runs begin) to the end of the live run.
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import os
import random
import re
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from drivers.mavlink.framing import Framer  # noqa: E402
from drivers.mavlink.link import MavlinkLink  # noqa: E402
from drivers.mavlink.receiver import MavlinkReceiver  # noqa: E402
from drivers.tlog import TlogWriter  # noqa: E402
from groundstation.core.measurement import Measurement  # noqa: E402
from groundstation.diagnosis.live import DIAGNOSIS_NICE  # noqa: E402

#: HIGHRES_IMU's fields_updated as PX4 sets it (src/modules/mavlink/streams/HIGHRES_IMU.hpp): accel
#: and gyro in every message, the magnetometer's and the baro's (pressure, pressure altitude,
#: temperature) only in a message sent after they updated, differential pressure never on a
#: rotorcraft without an airspeed sensor
_HR_ACC_GYRO, _HR_MAG, _HR_BARO, _HR_ALL = 0x3F, 0x1C0, 0x1A00, 0x1FFF
#: of a 1 kHz IMU's messages, every 10th follows a magnetometer update (100 Hz), every 20th a baro's (50 Hz)
MAG_EVERY, BARO_EVERY = 10, 20


def make_stream(n: int, seed: int = 1, *, every_field: bool = False) -> bytes:
    """A realistic high-rate MAVLink 2 mix (IMU-heavy, as a 1 kHz vehicle sends). ``every_field``:
    each HIGHRES_IMU flags all its fields updated: six records a message, where PX4's pattern makes
    two, three after a magnetometer update and four after a baro's."""
    rng = random.Random(seed)
    enc = mavlink.MAVLink(None, 1, 1)
    imu_count = itertools.count()

    def updated() -> int:
        k = next(imu_count)
        if every_field:
            return _HR_ALL
        return _HR_ACC_GYRO | (_HR_MAG if k % MAG_EVERY == 0 else 0) | (_HR_BARO if k % BARO_EVERY == 0 else 0)

    mix = [
        (
            0.40,
            lambda i: mavlink.MAVLink_highres_imu_message(
                i * 1000,
                rng.gauss(0, 1),
                rng.gauss(0, 1),
                -9.8,
                0.01,
                0.02,
                0.03,
                0.2,
                0.0,
                0.4,
                1013.0,
                0.0,
                10.0,
                25.0,
                updated(),
                0,
            ),
        ),
        (0.20, lambda i: mavlink.MAVLink_attitude_message(i, 0.1, 0.2, 0.3, 0.01, 0.02, 0.03)),
        (0.08, lambda i: mavlink.MAVLink_scaled_pressure_message(i, 1000.0, 0.1, 2500, 0)),
        (0.05, lambda i: mavlink.MAVLink_distance_sensor_message(i, 10, 500, 150, 0, 0, 25, 0)),
        (0.08, lambda i: mavlink.MAVLink_servo_output_raw_message(i * 1000, 0, 1500, 1500, 1500, 1500, 0, 0, 0, 0)),
        (
            0.05,
            lambda i: mavlink.MAVLink_global_position_int_message(i, 473977418, 85455938, 500000, 12345, 1, 2, 3, 0),
        ),
        (0.04, lambda i: mavlink.MAVLink_vfr_hud_message(1.0, 2.0, 90, 50, 10.0, 0.1)),
        (0.04, lambda i: mavlink.MAVLink_sys_status_message(0, 0, 0, 0, 11800, 1000, 50, 0, 0, 0, 0, 0, 0)),
        (
            0.03,
            lambda i: mavlink.MAVLink_gps_raw_int_message(i * 1000, 3, 473977418, 85455938, 500000, 100, 100, 0, 0, 10),
        ),
        (0.03, lambda i: mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3)),
    ]
    weights = [w for w, _ in mix]
    makers = [m for _, m in mix]
    out = bytearray()
    for i in range(n):
        msg = rng.choices(makers, weights)[0](i + 1)
        out += msg.pack(enc)
        enc.seq = (enc.seq + 1) % 256
    return bytes(out)


def chunks(data: bytes, size: int = 4096):
    return [data[i : i + size] for i in range(0, len(data), size)]


def bench_parse_buffer(parts) -> tuple[float, int]:
    mav = mavlink.MAVLink(None)
    mav.robust_parsing = True
    n = 0
    t0 = time.perf_counter()
    for p in parts:
        msgs = mav.parse_buffer(p)
        if msgs:
            n += len(msgs)
    return time.perf_counter() - t0, n


def bench_ours(parts) -> tuple[float, int]:
    r = MavlinkReceiver("bench")
    n = 0
    t0 = time.perf_counter()
    for p in parts:
        n += len(r.feed(p, 1.7e9))
    return time.perf_counter() - t0, r.counters.messages


def bench_framer(parts) -> tuple[float, int]:
    """Our framer alone: frames found, CRC-checked and unpacked into field tuples; nothing else."""
    n = [0]

    def fast(spec, m, *_):
        n[0] += 1

    fr = Framer(fast, lambda *_: None, lambda: None, lambda: None)
    t0 = time.perf_counter()
    for p in parts:
        fr.feed(p)
    return time.perf_counter() - t0, n[0]


def bench_records(parts) -> tuple[float, int]:
    """The records alone: the very Measurements ours makes of the stream, built again from values
    ready in one array (a view each, as the decoder's are), with no bytes, fields or clocks."""
    r = MavlinkReceiver("bench")
    ms = [m for p in parts for m in r.feed(p, 1.7e9)]
    ends = np.cumsum([len(m.value) for m in ms]).tolist()
    values = np.zeros(ends[-1])
    fields = [(m.t, m.kind, e - len(m.value), e, m.source, m.t_rx, m.variance, m.instance) for m, e in zip(ms, ends)]
    del ms
    new, M = tuple.__new__, Measurement
    t0 = time.perf_counter()
    for k in range(0, len(fields), 256):  # handed on a few hundred at a time, as a feed's are
        out = []
        for t, kind, a, b, source, t_rx, var, inst in fields[k : k + 256]:
            out.append(new(M, (t, kind, values[a:b], source, t_rx, var, inst, 1)))
    return time.perf_counter() - t0, r.counters.messages


def bench_recv_match(tlog: Path) -> tuple[float, int]:
    t0 = time.perf_counter()
    conn = mavutil.mavlink_connection(str(tlog))
    n = 0
    while conn.recv_match() is not None:
        n += 1
    return time.perf_counter() - t0, n


def write_tlog(data: bytes, path: Path) -> None:
    r = MavlinkReceiver("split")
    frames = []
    r.on_frame = lambda f, t: frames.append(f)
    r.feed(data, 0.0)
    w = TlogWriter(path)
    for i, f in enumerate(frames):
        w.write(f, 1.7e9 + i * 1e-3)
    w.close()


SENDER = textwrap.dedent("""
    import socket, sys, time
    from pymavlink.dialects.v20 import ardupilotmega as mavlink
    port, rate, seconds = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
    enc = mavlink.MAVLink(None, 1, 1)
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    n = int(rate * seconds)
    t0 = time.perf_counter() + 0.2
    for i in range(n):
        due = t0 + i / rate
        while (now := time.perf_counter()) < due:
            if due - now > 0.002:
                time.sleep(due - now - 0.001)
        # CLOCK_MONOTONIC is one clock for every process on the machine.
        msg = mavlink.MAVLink_highres_imu_message(int(time.monotonic() * 1e6), 0, 0, -9.8, 0, 0, 0, 0, 0, 0,
                                                  1013.0, 0, 0, 25.0, 0x7, 0)
        s.sendto(msg.pack(enc), ("127.0.0.1", port))
        enc.seq = (enc.seq + 1) % 256
    print(n, flush=True)
""")


async def live(rate: float, seconds: float) -> dict:
    link = MavlinkLink("udpin:127.0.0.1:0", streams={}, heartbeat_hz=1.0)
    sub = link.measurements()
    await link.open()
    port = link.transport.local_address[1]
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", SENDER, str(port), str(rate), str(seconds), stdout=asyncio.subprocess.PIPE
    )
    lat = []
    expected = int(rate * seconds)

    async def consume():
        async for m in sub:
            if m.kind.value == "accel":
                lat.append(time.monotonic() - m.t)
                if len(lat) >= expected:
                    return

    task = asyncio.create_task(consume())
    try:
        out, _ = await asyncio.wait_for(proc.communicate(), seconds + 30)
        sent = int(out.decode().split()[0])
        try:
            await asyncio.wait_for(task, 2.0)
        except TimeoutError:
            pass
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
        task.cancel()
        await link.close()
    a = np.array(lat) * 1e3
    return {
        "sent": sent,
        "received": len(lat),
        "seq_lost": link.counters.seq_lost,
        "p50_ms": float(np.percentile(a, 50)) if len(a) else float("nan"),
        "p99_ms": float(np.percentile(a, 99)) if len(a) else float("nan"),
        "max_ms": float(a.max()) if len(a) else float("nan"),
    }


#: the contenders ``--instructions`` counts, by the name ``--count-only`` takes
_COUNTED = {"parse_buffer": bench_parse_buffer, "ours": bench_ours}


def count_instructions(messages: int, every_field: bool) -> dict[str, float] | None:
    """Instructions per message of each of :data:`_COUNTED` (valgrind), or None without valgrind."""
    valgrind = shutil.which("valgrind")
    if valgrind is None:
        return None
    # the same hashes and one BLAS thread in every run: the counts are then equal from run to run
    env = dict(os.environ, PYTHONHASHSEED="0", OPENBLAS_NUM_THREADS="1")

    def start(name: str, passes: int) -> subprocess.Popen:
        cmd = [valgrind, "--tool=cachegrind", "--cache-sim=no", "--cachegrind-out-file=/dev/null"]
        cmd += [sys.executable, __file__, "--count-only", name, "--passes", str(passes)]
        cmd += ["--messages", str(messages)] + (["--every-field"] if every_field else [])
        return subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

    def total(proc: subprocess.Popen) -> int:
        _, err = proc.communicate()
        found = re.search(r"I\s+refs:\s+([\d,]+)", err)
        if proc.returncode != 0 or found is None:
            raise RuntimeError(f"valgrind failed: {err.strip().splitlines()[-1:]}")
        return int(found.group(1).replace(",", ""))

    per = {}
    for name in _COUNTED:  # one and two passes side by side, a core each
        one, two = start(name, 1), start(name, 2)
        per[name] = (total(two) - total(one)) / messages
    return per


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--messages", type=int, help="messages in the stream (100,000; counted: 20,000)")
    ap.add_argument("--live-seconds", type=float, default=60.0)
    ap.add_argument("--live-rate", type=float, default=2000.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument(
        "--every-field",
        action="store_true",
        help="every HIGHRES_IMU flags all its fields updated (six records a message), not PX4's pattern",
    )
    ap.add_argument("--beside-diagnosis", type=Path, metavar="LOG", help="the live run again beside a diagnosis of LOG")
    ap.add_argument(
        "--instructions",
        action="store_true",
        help="count each contender's instructions per message with valgrind (20,000 messages unless --messages)",
    )
    ap.add_argument("--count-only", choices=sorted(_COUNTED), help=argparse.SUPPRESS)  # one counted run
    ap.add_argument("--passes", type=int, default=1, help=argparse.SUPPRESS)
    args = ap.parse_args()

    if args.count_only:  # a run valgrind counts: the stream, then the passes, nothing printed
        assert args.messages is not None
        parts = chunks(make_stream(args.messages, every_field=args.every_field))
        for _ in range(args.passes):
            _COUNTED[args.count_only](parts)
        return 0
    if args.instructions:
        messages = args.messages or 20_000
        per = count_instructions(messages, args.every_field)
        if per is None:
            print("valgrind is not installed: no instruction counts")
            return 1
        print(f"Instructions per message (valgrind, {messages} messages, one pass)")
        print(f"{'contender':<44}{'instr/msg':>12}{'ratio':>12}")
        print(f"{'pymavlink parse_buffer (frames only)':<44}{per['parse_buffer']:>12,.0f}{'':>12}")
        ratio = per["parse_buffer"] / per["ours"]
        print(f"{'ours: MavlinkReceiver.feed -> Measurement':<44}{per['ours']:>12,.0f}{ratio:>11.2f}x")
        return 0

    args.messages = args.messages or 100_000
    data = make_stream(args.messages, every_field=args.every_field)
    parts = chunks(data)
    with tempfile.TemporaryDirectory() as d:
        tlog = Path(d) / "bench.tlog"
        write_tlog(data, tlog)
        best = dict.fromkeys(("parse_buffer", "ours", "recv_match", "framer", "records"), float("inf"))
        counts = {}
        pairs = []  # parse_buffer's time over ours in the same round: the ratio least moved by the load
        for _ in range(args.repeat):  # interleaved, best of N: the machine is shared and noisy
            took = {}
            for name, fn in (
                ("parse_buffer", lambda: bench_parse_buffer(parts)),
                ("ours", lambda: bench_ours(parts)),
                ("recv_match", lambda: bench_recv_match(tlog)),
                ("framer", lambda: bench_framer(parts)),
                ("records", lambda: bench_records(parts)),
            ):
                dt, n = fn()
                best[name] = min(best[name], dt)
                counts[name] = n
                took[name] = dt
            pairs.append(took["parse_buffer"] / took["ours"])
    rate = {k: counts[k] / v for k, v in best.items()}
    pattern = "every field flagged updated" if args.every_field else "PX4's fields_updated"
    print(
        f"Offline ingest, {args.messages} MAVLink 2 messages ({len(data)} bytes; HIGHRES_IMU with {pattern}), "
        f"best of {args.repeat}"
    )
    print(f"{'contender':<44}{'msg/s':>12}{'ours / it':>12}")
    for name, key in (
        ("pymavlink parse_buffer (frames only)", "parse_buffer"),
        ("pymavlink mavutil tlog recv_match loop", "recv_match"),
    ):
        print(f"{name:<44}{rate[key]:>12,.0f}{rate['ours'] / rate[key]:>12.2f}")
    print(f"{'ours: MavlinkReceiver.feed -> Measurement':<44}{rate['ours']:>12,.0f}{1.0:>12.2f}")
    ok = rate["ours"] / rate["parse_buffer"] >= 1.5
    print(f"target ours >= 1.5x parse_buffer: {'met' if ok else 'NOT met'}")
    print(
        f"ours / parse_buffer round by round: median {float(np.median(pairs)):.2f}x "
        f"(from {min(pairs):.2f}x to {max(pairs):.2f}x in {len(pairs)} rounds)"
    )
    # ours in parts: what its framer and its records alone take, and what is left for the rest
    print(f"\nParts of ours, per message (the records: {counts['records']} messages' worth)")
    per = {k: 1e6 * best[k] / counts["parse_buffer"] for k in best}
    print(f"{'part':<44}{'us/msg':>12}{'of ours':>12}")
    for name, key in (
        ("our framer alone (frames -> field tuples)", "framer"),
        ("the Measurement records alone", "records"),
        ("the rest: counters, clocks, conversion", None),
    ):
        us = per[key] if key else per["ours"] - per["framer"] - per["records"]
        print(f"{name:<44}{us:>12.2f}{us / per['ours']:>12.0%}")
    floor = per["framer"] + per["records"]
    print(
        f"framer + records alone: {per['parse_buffer'] / floor:.2f}x parse_buffer "
        f"(1.5x needs ours at {per['parse_buffer'] / 1.5:.2f} us/msg)"
    )

    if args.live_seconds > 0:
        r = asyncio.run(live(args.live_rate, args.live_seconds))
        print(f"\nLive UDP loopback, {args.live_rate:.0f} msg/s for {args.live_seconds:g} s")
        print(
            f"sent {r['sent']}, received {r['received']}, sequence loss {r['seq_lost']}, "
            f"latency send->record p50 {r['p50_ms']:.2f} ms, p99 {r['p99_ms']:.2f} ms, max {r['max_ms']:.2f} ms"
        )
        live_ok = r["received"] == r["sent"] and r["seq_lost"] == 0 and r["p99_ms"] < 5.0
        print(f"target zero loss and p99 < 5 ms: {'met' if live_ok else 'NOT met'}")
    if args.beside_diagnosis is not None and args.live_seconds > 0:
        print(f"\nLive UDP loopback beside `diagnose {args.beside_diagnosis.name}`, {args.live_rate:.0f} msg/s")
        print(f"{'diagnosis niceness':<20}{'lost':>6}{'p50 ms':>9}{'p99 ms':>9}{'max ms':>9}{'p99 < 5 ms':>12}")
        for nice in (0, DIAGNOSIS_NICE):
            r = beside_diagnosis(args.beside_diagnosis, nice, args.live_rate, args.live_seconds)
            lost = r["sent"] - r["received"] + r["seq_lost"]
            ok = lost == 0 and r["p99_ms"] < 5.0
            print(
                f"{nice:<20}{lost:>6}{r['p50_ms']:>9.2f}{r['p99_ms']:>9.2f}{r['max_ms']:>9.2f}"
                f"{'met' if ok else 'NOT met':>12}"
            )
    return 0


def beside_diagnosis(log: Path, nice: int, rate: float, seconds: float) -> dict:
    """The live run while a diagnosis of ``log`` runs at niceness ``nice``, from the end of its triage."""
    with tempfile.TemporaryDirectory() as d:
        proc = subprocess.Popen(
            [sys.executable, "-m", "groundstation", "diagnose", str(log), "--out", d, "--jobs", "1"],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
            preexec_fn=(lambda: os.nice(nice)) if nice else None,
        )
        try:
            assert proc.stdout is not None
            for line in proc.stdout:  # its triage is printed once the log is read
                if line.startswith("triage"):
                    break
            return asyncio.run(live(rate, seconds))
        finally:
            proc.kill()
            proc.wait()


if __name__ == "__main__":
    sys.exit(main())
