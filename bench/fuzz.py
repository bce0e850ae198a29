"""Every log reader against a seeded corpus of mutants, each under a time cap, the whole run under a
memory cap: what a file can do to ``info``, ``triage``, ``replay`` and ``diagnose``, which all read
a log through ``load_log``.

    python bench/fuzz.py [--formats tlog,bin,text,ulg,cf] [--n 200000] [--seed 1] [--memory-mb 1500]
                         [--time-s 5] [--jobs 2] [--json]

Each format has a small valid seed (the project's own writers: a tlog of real frames, a binary and
a text DataFlash log, a ULog, a Crazyflie uSD log), mutated by byte flips, bytes set to the values
parsers trip on (0, 0xFF, a length's extremes), runs inserted, stretches deleted or repeated, and
cuts. A mutant is *read* (the reader returned), *refused* (its one-line error: a ``ValueError`` or
``OSError`` naming the file, one line), or a failure: a *traceback* (any other exception), a *hang*
(over ``--time-s``), a *blow-up* (``MemoryError``, or the process's peak memory growing by more than
``BLOWUP_MB``). The table counts them per format; the first few failures are kept as files under
``--keep`` to reproduce. ``tests/test_fuzz.py`` runs 2,000 a format in ``make test`` and 100,000
a format in ``make soak``, which CI runs.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import resource
import signal
import struct
import sys
import tempfile
import time
import zlib
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from groundstation.estimation.logs import load_log  # noqa: E402

FORMATS = ("tlog", "bin", "text", "ulg", "cf")
#: a mutant that grows the process's peak memory by more than this is a blow-up (the seeds are a
#: few kilobytes: a reader within a small multiple of them stays far below)
BLOWUP_MB = 300.0


class _Hang(BaseException):
    """A reader still at work when its mutant's time limit rang (raised by the alarm's handler). Not an
    ``Exception``: a reader's catch-all would report it as the file refused, and a hang go uncounted."""


def _on_alarm(_sig, _frame):
    raise _Hang


# -- seeds ----------------------------------------------------------------------------------------
def _df_fmt(type_id: int, length: int, name: str, form: str, cols: str) -> bytes:
    return b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", type_id, length, name.encode(), form.encode(), cols.encode())


def seed_bin() -> bytes:
    out = bytearray(_df_fmt(128, 89, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns"))
    # each record's length is its header and its fields (DFReader's sizes: N is 16 characters)
    out += _df_fmt(129, 3 + 36, "IMU", "QffffffI", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG")
    out += _df_fmt(130, 3 + 18, "BARO", "Qffh", "TimeUS,Alt,Press,Temp")
    out += _df_fmt(131, 3 + 28, "PARM", "QNf", "TimeUS,Name,Value")
    out += _df_fmt(132, 3 + 14, "RFND", "QfBB", "TimeUS,Dist,Stat,Orient")
    out += b"\xa3\x95\x83" + struct.pack("<Q16sf", 0, b"RNGFND1_MIN_CM", 20.0)
    for k in range(60):
        t = k * 10_000
        out += b"\xa3\x95\x81" + struct.pack("<QffffffI", t, 0, 0, 0, 0, 0, -9.8, 0)
        if k % 5 == 0:
            out += b"\xa3\x95\x82" + struct.pack("<Qffh", t, 1.0, 101000.0, 2500)
            out += b"\xa3\x95\x84" + struct.pack("<QfBB", t, 1.5, 4, 25)
    return bytes(out)


def seed_text() -> bytes:
    lines = [
        "ArduCopter V3.1 (5c6503e2)",
        "FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns",
        "FMT, 129, 23, PARM, Nf, Name,Value",
        "FMT, 130, 40, BARO, Iffc, TimeMS,Alt,Press,Temp",
        "FMT, 131, 40, CTUN, hhhhhhh, ThrIn,SonAlt,BarAlt,WPAlt,NavThr,AngBst,CRate",
        "PARM, SONAR_TYPE, 0",
    ]
    for k in range(60):
        lines.append(f"BARO, {10 * k}, 1.00, 101000.0, 25.00")
        lines.append(f"CTUN, 500, 120, 100, 100, 0, 0, {k % 7}")
    return ("\n".join(lines) + "\n").encode()


def seed_ulg() -> bytes:
    def msg(kind: str, payload: bytes) -> bytes:
        return struct.pack("<HB", len(payload), ord(kind)) + payload

    out = bytearray(b"ULog\x01\x12\x35\x01" + struct.pack("<Q", 0))
    out += msg("B", bytes(40))
    out += msg("I", struct.pack("<B", len("char[3] sys_name")) + b"char[3] sys_name" + b"PX4")
    for f in (
        "vehicle_air_data:uint64_t timestamp;float baro_alt_meter;float baro_temp_celcius;float baro_pressure_pa",
        "sensor_combined:uint64_t timestamp;float[3] gyro_rad;float[3] accelerometer_m_s2",
        "distance_sensor:uint64_t timestamp;float min_distance;float max_distance;float current_distance;"
        "uint8_t signal_quality;uint8_t orientation",
    ):
        out += msg("F", f.encode())
    out += msg("P", struct.pack("<B", len("float EKF2_MIN_RNG")) + b"float EKF2_MIN_RNG" + struct.pack("<f", 0.05))
    for mid, name in ((1, "vehicle_air_data"), (2, "sensor_combined"), (3, "distance_sensor")):
        out += msg("A", struct.pack("<BH", 0, mid) + name.encode())
    for k in range(40):
        t = 1_000_000 + k * 20_000
        out += msg("D", struct.pack("<HQfff", 1, t, 100.0, 25.0, 101000.0))
        out += msg("D", struct.pack("<HQ6f", 2, t, 0, 0, 0, 0, 0, -9.8))
        out += msg("D", struct.pack("<HQfffBB", 3, t, 0.1, 12.0, 1.5, 100, 25))
    return bytes(out)


def seed_cf() -> bytes:
    defs = [
        (1, "estAcceleration", ["acc.x(f)", "acc.y(f)", "acc.z(f)"]),
        (2, "estTOF", ["range.zrange(H)"]),
        (3, "estBarometer", ["baro.asl(f)"]),
    ]
    out = bytearray(struct.pack("<BHH", 0xBC, 2, len(defs)))
    for eid, name, variables in defs:
        out += struct.pack("<H", eid) + name.encode() + b"\0" + struct.pack("<H", len(variables))
        out += b"".join(v.encode() + b"\0" for v in variables)
    for k in range(120):
        t = k * 1000
        out += struct.pack("<HQfff", 1, t, 0.0, 0.0, 1.0)
        if k % 10 == 0:
            out += struct.pack("<HQH", 2, t, 1000 + k)
            out += struct.pack("<HQf", 3, t, 170.0)
    return bytes(out) + struct.pack("<I", zlib.crc32(bytes(out)))


def seed_tlog() -> bytes:
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    enc = mavlink.MAVLink(None, 1, 1)
    out = bytearray()
    t_us = 1_700_000_000_000_000
    for k in range(80):
        t_us += 10_000
        msgs = [mavlink.MAVLink_highres_imu_message(k * 10_000, 0, 0, -9.8, 0, 0, 0, 0, 0, 0, 101000.0, 0, 0, 25, 0)]
        if k % 10 == 0:
            msgs.append(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3))
            msgs.append(mavlink.MAVLink_distance_sensor_message(k * 10, 10, 1200, 150, 0, 0, 25, 0))
        for m in msgs:
            out += struct.pack(">Q", t_us) + bytes(m.pack(enc))
    return bytes(out)


SEEDS = {"tlog": seed_tlog, "bin": seed_bin, "text": seed_text, "ulg": seed_ulg, "cf": seed_cf}
SUFFIX = {"tlog": ".tlog", "bin": ".bin", "text": ".log", "ulg": ".ulg", "cf": ""}


# -- mutation -------------------------------------------------------------------------------------
INTERESTING = (0x00, 0xFF, 0x7F, 0x80, 0x01, 0xFE, 0xFD, 0xA3, 0x95)


def mutate(data: bytes, rng: random.Random) -> bytes:
    b = bytearray(data)
    for _ in range(rng.randint(1, 8)):
        if not b:
            break
        i = rng.randrange(len(b))
        op = rng.random()
        if op < 0.35:
            b[i] ^= 1 << rng.randrange(8)
        elif op < 0.55:
            b[i] = rng.choice(INTERESTING)
        elif op < 0.65:
            b[i : i + 2] = rng.choice((b"\x00\x00", b"\xff\xff", b"\xff\x7f", b"\x01\x00"))
        elif op < 0.75:
            b[i:i] = bytes([rng.choice(INTERESTING)]) * rng.randrange(1, 300)
        elif op < 0.85:
            del b[i : i + rng.randrange(1, 200)]
        elif op < 0.93:
            j = rng.randrange(len(b))
            b[i:i] = b[j : j + rng.randrange(1, 200)]
        else:
            del b[i:]
    return bytes(b)


# -- one worker's share ---------------------------------------------------------------------------
def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_share(fmt: str, seed: int, n: int, time_s: float, memory_mb: float, keep: str | None) -> dict:
    """Read ``n`` mutants of ``fmt`` (this process capped at ``memory_mb``); the counts."""
    if memory_mb > 0:
        limit = int(memory_mb * 1024 * 1024)
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    signal.signal(signal.SIGALRM, _on_alarm)
    rng = random.Random(seed)
    base = SEEDS[fmt]()
    counts = {"read": 0, "refused": 0, "traceback": 0, "hang": 0, "blowup": 0}
    examples: list[str] = []
    folder = Path(tempfile.mkdtemp(prefix=f"fuzz-{fmt}-"))
    path = folder / f"mutant{SUFFIX[fmt]}"
    start_peak = None
    for k in range(n):
        data = mutate(base, rng)
        path.write_bytes(data)
        outcome, why = "read", ""
        signal.setitimer(signal.ITIMER_REAL, time_s)
        try:
            load_log(path, imu_columns=True)
        except _Hang:
            outcome, why = "hang", f"over {time_s} s"
        except MemoryError:
            outcome, why = "blowup", "MemoryError"
        except (ValueError, OSError) as e:
            text = str(e)
            if text.startswith(str(path)) and "\n" not in text:
                outcome = "refused"
            else:
                outcome, why = "traceback", f"{type(e).__name__}: {text[:200]}"
        except Exception as e:  # noqa: BLE001 - what the fuzzing is for
            outcome, why = "traceback", f"{type(e).__name__}: {str(e)[:200]}"
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
        peak = _peak_mb()
        if start_peak is None:
            start_peak = peak  # after the first read: the libraries are loaded
        elif outcome in ("read", "refused") and peak - start_peak > BLOWUP_MB:
            outcome, why = "blowup", f"peak memory {peak:.0f} MB"
            start_peak = peak
        counts[outcome] += 1
        if outcome not in ("read", "refused") and len(examples) < 5:
            examples.append(f"{fmt} seed {seed} mutant {k}: {why}")
            if keep:
                Path(keep).mkdir(parents=True, exist_ok=True)
                (Path(keep) / f"{fmt}-{seed}-{k}{SUFFIX[fmt]}").write_bytes(data)
    path.unlink(missing_ok=True)
    folder.rmdir()
    return {"format": fmt, "n": n, **counts, "examples": examples, "peak_mb": round(_peak_mb(), 1)}


def run(formats, n: int, seed: int, time_s: float, memory_mb: float, jobs: int, keep: str | None) -> list[dict]:
    """Each format's ``n`` mutants spread over ``jobs`` processes; one row per format."""
    shares = []
    for fmt in formats:
        per = max(1, n // jobs)
        for j in range(jobs):
            shares.append((fmt, seed * 1000 + j, per if j < jobs - 1 else n - per * (jobs - 1)))
    with ProcessPoolExecutor(jobs) as pool:
        results = list(
            pool.map(
                run_share,
                [s[0] for s in shares],
                [s[1] for s in shares],
                [s[2] for s in shares],
                [time_s] * len(shares),
                [memory_mb] * len(shares),
                [keep] * len(shares),
            )
        )
    rows = []
    for fmt in formats:
        mine = [r for r in results if r["format"] == fmt]
        row = {"format": fmt, "n": sum(r["n"] for r in mine)}
        for k in ("read", "refused", "traceback", "hang", "blowup"):
            row[k] = sum(r[k] for r in mine)
        row["examples"] = [e for r in mine for e in r["examples"]][:5]
        row["peak_mb"] = max(r["peak_mb"] for r in mine)
        rows.append(row)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--formats", default=",".join(FORMATS))
    ap.add_argument("--n", type=int, default=200_000, help="mutants a format (default 200,000: 1M in all)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--time-s", type=float, default=5.0)
    ap.add_argument("--memory-mb", type=float, default=1500.0)
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--keep", help="a folder to keep the failing mutants in")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    t0 = time.perf_counter()
    rows = run(a.formats.split(","), a.n, a.seed, a.time_s, a.memory_mb, a.jobs, a.keep)
    if a.json:
        print(json.dumps(rows))
        return 0
    head = ("mutants", "read", "refused", "trace", "hang", "blowup", "peak MB")
    print(f"{'format':6s} " + " ".join(f"{h:>8s}" for h in head))
    for r in rows:
        print(
            f"{r['format']:6s} {r['n']:8d} {r['read']:8d} {r['refused']:8d} {r['traceback']:6d} {r['hang']:5d} "
            f"{r['blowup']:6d} {r['peak_mb']:8.0f}"
        )
        for e in r["examples"]:
            print(f"    {e}")
    print(f"{sum(r['n'] for r in rows)} mutants in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
