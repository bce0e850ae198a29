"""Fuzzing every reader, bounded and seeded: frames whose CRC is valid but whose contents are not
(random payloads, extreme and non-finite field values, counts past their fields), damaged tlogs,
board streams, DataFlash and Crazyflie logs. Nothing may raise but the reader's own one-line error,
and what gets through must not poison an estimator."""

from __future__ import annotations

import math
import random
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers import board_protocol as bp
from drivers.board import BinaryBoardReceiver, NmeaReceiver
from drivers.logs.crazyflie import CrazyflieLogError, measurements, read_crazyflie
from drivers.logs.dataflash import DataFlashError, read_dataflash
from drivers.logs.ulog_writer import TYPES as C_TYPES
from drivers.mavlink.decode import DECODED_TYPES
from drivers.mavlink.receiver import MavlinkReceiver
from drivers.replay import Replay
from drivers.tlog import TlogError, TlogIndex, TlogWriter
from groundstation.estimation.loop import EstimationLoop
from groundstation.estimation.registry import build_estimator

FIXTURES = Path(__file__).resolve().parent / "fixtures"
EXTREMES = [0, 1, -1, math.nan, math.inf, -math.inf, 1e30, -1e30, 2**31 - 1, -(2**31), 65535, 255]


def _random_value(rng: random.Random, fmt: str):
    """A value of a pymavlink field's struct type: extreme or random."""
    if fmt in "fd":
        return rng.choice([*EXTREMES[:8], rng.uniform(-1e6, 1e6), rng.gauss(0, 10)])
    bits = {"b": 7, "B": 8, "h": 15, "H": 16, "i": 31, "I": 32, "q": 63, "Q": 64}.get(fmt, 8)
    signed = fmt.islower()
    lo, hi = (-(2**bits), 2**bits - 1) if signed else (0, 2**bits - 1)
    return rng.choice([lo, hi, 0, rng.randint(lo, hi)])


def _random_message(rng: random.Random, cls):
    """An instance of a pymavlink message class with every field random (arrays too)."""
    args = []
    for t, length in zip(cls.fieldtypes, cls.array_lengths):
        code = C_TYPES.get(t, "B")  # MAVLink's field types are C's, as ULog's
        if code == "c":
            args.append(bytes(rng.randrange(32, 127) for _ in range(max(length, 1))).decode())
        elif length:
            args.append([_random_value(rng, code) for _ in range(length)])
        else:
            args.append(_random_value(rng, code))
    return cls(*args)


def _frames(seed: int, n: int) -> list[bytes]:
    """Valid-CRC frames: random field values of every decoded type, and random payload bytes of any
    type with the CRC recomputed (what a buggy autopilot or a crafted packet sends)."""
    rng = random.Random(seed)
    enc = mavlink.MAVLink(None, 1, 1)
    classes = [c for c in mavlink.mavlink_map.values() if c.msgname in DECODED_TYPES]
    out = []
    for k in range(n):
        if k % 2 == 0:
            cls = rng.choice(classes)
            try:
                msg = _random_message(rng, cls)
                if cls.msgname == "RC_CHANNELS":
                    msg.chancount = rng.choice([0, 18, 19, 200, 255])
                out.append(bytes(msg.pack(enc)))
            except (struct.error, OverflowError, ValueError, TypeError):
                continue  # a value pymavlink itself cannot pack: not a frame
        else:
            cls = rng.choice(list(mavlink.mavlink_map.values()))
            payload = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 256)))
            hdr = struct.pack(
                "<BBBBBBBHB", 0xFD, len(payload), 0, 0, rng.randrange(256), 1, 1, cls.id & 0xFFFF, cls.id >> 16
            )
            crc = mavlink.x25crc(hdr[1:] + payload)
            crc.accumulate(struct.pack("B", cls.crc_extra))
            out.append(hdr + payload + struct.pack("<H", crc.crc))
        enc.seq = (enc.seq + 1) % 256
    return out


def test_frames_that_pass_their_crc_never_raise_and_never_poison_an_estimator():
    rx = MavlinkReceiver("fuzz")
    estimators = [build_estimator(name) for name in ("altitude", "quad_thrust", "horizontal", "attitude")]
    loop = EstimationLoop(estimators, align_clocks=False)
    t = 0.0
    for frame in _frames(1, 6000):
        t += 0.001
        for m in rx.feed(frame, t):
            loop.push(m._replace(t=t) if not math.isfinite(m.t) or abs(m.t - t) > 1e3 else m)
    c = rx.counters
    assert c.messages + c.crc_errors > 5000, c.as_dict()
    for e in estimators:
        assert np.all(np.isfinite(e.filter.x)) and np.all(np.isfinite(e.filter.P)), (e.name, e.counters.skipped)


def test_frames_of_unknown_ids_are_recorded_but_prove_nothing():
    rx = MavlinkReceiver("fuzz")
    frame = bytes.fromhex("fd0400000001010a0f0b") + b"\x01\x02\x03\x04" + b"\x00\x00"  # id 0x0b0f0a: unknown
    rx.feed(frame * 3, 0.0)
    assert rx.counters.unknown == 3 and rx.counters.messages == 0 and not rx.counters.per_source


@pytest.mark.parametrize("seed", range(6))
def test_damaged_tlogs_replay_what_they_can_or_say_in_one_line_why_not(tmp_path, seed):
    rng = random.Random(seed)
    src = (FIXTURES / ("dronekit_flight.tlog" if seed % 2 else "ardusub_small.tlog")).read_bytes()
    data = bytearray(src[: 200_000 + rng.randrange(200_000)])
    for _ in range(rng.randint(1, 40)):
        op = rng.random()
        i = rng.randrange(len(data))
        if op < 0.5:
            data[i] = rng.randrange(256)
        elif op < 0.8:
            data[i:i] = bytes([rng.choice([0xFD, 0xFE, 0x00, 0xFF])]) * rng.randrange(1, 2000)
        else:
            del data[i : i + rng.randrange(1, 500)]
    p = tmp_path / "damaged.tlog"
    p.write_bytes(bytes(data))
    try:
        rp = Replay(p)
    except TlogError as e:
        assert str(e).startswith(str(p)) and "\n" not in str(e)
        return
    n = sum(1 for _ in rp.iter_measurements())
    assert n > 0 and isinstance(rp.skipped_summary(), str)


def test_board_streams_of_random_bytes_and_valid_crc_frames_never_raise():
    rng = random.Random(5)
    board, nmea = BinaryBoardReceiver("fuzz"), NmeaReceiver("fuzz")
    for k in range(3000):
        if k % 3 == 0:
            msg_id = rng.choice(list(bp.PAYLOADS))
            payload = bytes(rng.randrange(256) for _ in range(rng.choice([0, 4, bp.PAYLOADS[msg_id][1].size, 64])))
            chunk = bp.frame(msg_id, rng.randrange(256), payload)
        elif k % 3 == 1:
            chunk = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 200)))
        else:
            body = ",".join(
                rng.choice(["GPGGA", "GPRMC", "", "nan", "inf", "99999999", "-", "E", "W", "N", "1"])
                for _ in range(rng.randrange(1, 16))
            )
            cs = 0
            for ch in body.encode():
                cs ^= ch
            chunk = f"${body}*{cs:02X}\r\n".encode()
        board.feed(chunk, k * 0.01)
        nmea.feed(chunk, k * 0.01)


def _dataflash_bin(rng: random.Random) -> bytes:
    """A small binary DataFlash log: FMT records, parameters, and IMU, BARO, CTUN and GPS records."""

    def fmt(type_id, length, name, form, cols):
        return b"\xa3\x95\x80" + struct.pack(
            "<BB4s16s64s", type_id, length, name.encode(), form.encode(), cols.encode()
        )

    recs = {
        "IMU": (129, "QffffffI", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG"),
        "BARO": (130, "Qffc", "TimeUS,Alt,Press,Temp"),
        "CTUN": (131, "Qfff", "TimeUS,ThrOut,BarAlt,SonAlt"),
        "PARM": (132, "QNf", "TimeUS,Name,Value"),
        "GPS": (133, "QBLLf", "TimeUS,Status,Lat,Lng,Alt"),
    }
    out = bytearray(fmt(128, 89, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns"))
    sizes = {}
    for name, (tid, form, cols) in recs.items():
        size = 3 + struct.calcsize("<" + form.replace("N", "16s").replace("L", "i").replace("c", "h"))
        sizes[name] = size
        out += fmt(tid, size, name, form, cols)
    out += b"\xa3\x95\x84" + struct.pack("<Q16sf", 0, b"RNGFND_MIN_CM", 20.0)
    for k in range(400):
        t = k * 10_000
        out += b"\xa3\x95\x81" + struct.pack("<QffffffI", t, 0, 0, 0, 0, 0, -9.8, 0)
        if k % 5 == 0:
            out += b"\xa3\x95\x82" + struct.pack("<Qffh", t, rng.gauss(1, 0.1), 101000.0, 2500)
            out += b"\xa3\x95\x83" + struct.pack("<Qfff", t, 0.5, 1.0, 1.0)
            out += b"\xa3\x95\x85" + struct.pack("<QBiif", t, 3, 474000000, -1220000000, 10.0)
    return bytes(out)


@pytest.mark.parametrize("seed", range(8))
def test_damaged_dataflash_logs_are_read_as_far_as_they_go_or_refused_in_one_line(tmp_path, seed):
    rng = random.Random(seed)
    binary = _dataflash_bin(rng)
    text = "\n".join(
        [
            "FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns",
            "FMT, 129, 23, PARM, Nf, Name,Value",
            "FMT, 130, 40, BARO, Iffc, TimeMS,Alt,Press,Temp",
            "PARM, SONAR_TYPE, 0",
        ]
        + [f"BARO, {10 * k}, {rng.gauss(1, 0.1):.2f}, 101000.0, 25.00" for k in range(300)]
    ).encode()
    for name, data in (("fuzz.bin", binary), ("fuzz.log", text)):
        b = bytearray(data)
        for _ in range(rng.randint(1, 25)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        p = tmp_path / name
        p.write_bytes(bytes(b))
        try:
            log = read_dataflash(p)
        except DataFlashError as e:
            assert str(e).startswith(str(p)) and "\n" not in str(e)
            continue
        assert all(math.isfinite(m.t) or math.isnan(m.t) for m in log.measurements)


def _crazyflie(rng: random.Random) -> bytes:
    defs = [
        (1, "estAcceleration", ["acc.x(f)", "acc.y(f)", "acc.z(f)"]),
        (2, "estTOF", ["range.zrange(H)"]),
        (3, "estPose", [f"{v}(f)" for v in ("locSrv.x", "locSrv.y", "locSrv.z", "qx", "qy", "qz", "qw")]),
    ]
    out = bytearray(struct.pack("<BHH", 0xBC, 2, len(defs)))
    for eid, name, variables in defs:
        out += struct.pack("<H", eid) + name.encode() + b"\0" + struct.pack("<H", len(variables))
        out += b"".join(v.encode() + b"\0" for v in variables)
    for k in range(500):
        t = k * 1000
        out += struct.pack("<HQfff", 1, t, 0.0, 0.0, 1.0)
        if k % 40 == 0:
            out += struct.pack("<HQH", 2, t, 1000 + rng.randrange(100))
            out += struct.pack("<HQfffffff", 3, t, 0, 0, 1, 0, 0, 0, 1)
    return bytes(out) + struct.pack("<I", zlib.crc32(bytes(out)))


@pytest.mark.parametrize("seed", range(8))
def test_damaged_crazyflie_logs_are_read_as_far_as_they_go_or_refused_in_one_line(tmp_path, seed):
    rng = random.Random(seed)
    b = bytearray(_crazyflie(rng))
    for _ in range(rng.randint(1, 10)):
        b[rng.randrange(150) if rng.random() < 0.6 else rng.randrange(len(b))] = rng.randrange(256)
    p = tmp_path / "cf"
    p.write_bytes(bytes(b))
    try:
        log = read_crazyflie(p)
    except CrazyflieLogError as e:
        assert str(e).startswith(str(p)) and "\n" not in str(e)
        return
    ms = measurements(log)
    assert all(np.asarray(m.value).ndim == 1 for m in ms)


def test_a_tlog_resyncs_over_a_long_run_of_magic_bytes_in_linear_time(tmp_path):
    """A 640 KB run of 0xFD: each candidate's next magic byte was searched for anew, to the file's end."""
    import time

    src = (FIXTURES / "dronekit_flight.tlog").read_bytes()
    p = tmp_path / "run.tlog"
    p.write_bytes(src[:100_000] + b"\xfd" * 640_000 + src[100_000:])
    t0 = time.process_time()
    idx = TlogIndex.scan(p)
    assert time.process_time() - t0 < 3.0  # 9 s quadratic; about 0.5 s linear, with room for a loaded CI
    assert len(idx.skipped) == 1 and idx.skipped[0][1] >= 640_000


def test_a_recorder_clock_step_of_days_starts_a_segment_instead_of_dropping_the_rest(tmp_path):
    idx0 = TlogIndex.scan(FIXTURES / "dronekit_flight.tlog")
    data = bytearray((FIXTURES / "dronekit_flight.tlog").read_bytes())
    mid = len(idx0) // 2
    for o in idx0.offset[mid:]:
        ts = struct.unpack_from(">Q", data, int(o))[0]
        struct.pack_into(">Q", data, int(o), ts + 2 * 86_400 * 10**6)
    p = tmp_path / "step.tlog"
    p.write_bytes(bytes(data))
    idx = TlogIndex.scan(p)
    assert len(idx) >= len(idx0) - 2 and len(idx.clock_steps) == 1
    assert idx.duration == pytest.approx(idx0.duration, abs=1.0)  # the step is not time that passed
    assert "clock stepped" in Replay(p).skipped_summary()


def test_a_recording_written_through_a_clock_step_reads_back_whole(tmp_path):
    p = tmp_path / "w.tlog"
    w = TlogWriter(p)
    frames = _frames(3, 50)
    for k, fr in enumerate(frames):
        w.write(fr, 1.7e9 + k * 0.01 + (0 if k < 25 else 5 * 86_400))
    w.close()
    assert len(TlogIndex.scan(p)) >= len(frames) - 1


def _ulog(formats: list[str], topics: list[tuple[int, str]], records: list[tuple[int, bytes]], cut: int = 0) -> bytes:
    """A ULog file (docs.px4.io's ULog format): header, flag bits, format definitions, subscriptions
    (msg_id, name) and data records (msg_id, payload); ``cut`` bytes taken off its end."""

    def msg(kind: str, payload: bytes) -> bytes:
        return struct.pack("<HB", len(payload), ord(kind)) + payload

    out = bytearray(b"ULog\x01\x12\x35\x01" + struct.pack("<Q", 0))
    out += msg("B", bytes(16) + bytes(24))
    for f in formats:
        out += msg("F", f.encode())
    for mid, name in topics:
        out += msg("A", struct.pack("<BH", 0, mid) + name.encode())
    for mid, payload in records:
        out += msg("D", struct.pack("<H", mid) + payload)
    return bytes(out[: len(out) - cut] if cut else out)


def _read_ulog_or_one_line(p: Path):
    from drivers.logs.ulog import ULogError, read_ulog

    try:
        return read_ulog(p)
    except ULogError as e:
        assert str(e).startswith(str(p)) and "\n" not in str(e)
        return str(e)


def test_ulog_reproducers_give_one_line_or_a_counted_skip(tmp_path):
    """The audit's ULog cases, rebuilt: a topic without a timestamp (a KeyError), formats nested in
    themselves or multiplying their arrays (163 bytes had grown to 2.67 GB), a file cut inside its
    definitions (pyulog read on for minutes), a data section cut inside a message."""
    baro = "baro_t:uint64_t timestamp;float pressure"
    good = [(1, struct.pack("<Qf", k * 100_000, 101000.0)) for k in range(50)]
    cases = {
        "untimed": _ulog([baro, "notime:float x;float y"], [(1, "baro_t"), (2, "notime")], [*good, (2, bytes(8))]),
        "self_nested": _ulog(["a:uint64_t timestamp;a inner"], [(1, "a")], []),
        "multiplying": _ulog(
            ["a:uint64_t timestamp;b[1000] x", "b:c[1000] y", "c:d[1000] z", "d:double w"], [(1, "a")], []
        ),
        "unknown_type": _ulog(["a:uint64_t timestamp;nosuch x"], [(1, "a")], []),
        "cut_in_definitions": _ulog([baro, "other:uint64_t timestamp;" + "float f;" * 50], [], [])[:-30],
        "cut_in_data": _ulog([baro], [(1, "baro_t")], good, cut=3),
    }
    got = {}
    for name, data in cases.items():
        p = tmp_path / f"{name}.ulg"
        p.write_bytes(data)
        got[name] = _read_ulog_or_one_line(p)
    assert not isinstance(got["untimed"], str) and got["untimed"].skipped["topic_without_timestamp"] == 1
    assert "contains itself" in got["self_nested"]
    assert "larger than a message can carry" in got["multiplying"]
    assert "unknown type" in got["unknown_type"]
    assert "cut inside its definitions" in got["cut_in_definitions"]
    cut = got["cut_in_data"]
    assert not isinstance(cut, str) and "cut at offset" in cut.damage
    assert len(cut.tables["baro_t"]) == 49  # every whole record before the cut


def test_pyulog_seeking_back_past_a_short_read_lands_where_it_meant():
    """pyulog skips a header it takes for damage by ``seek(-2 - size, 1)`` after reading ``size`` bytes; at
    the end of a file the read is short, and the seek must still land one byte past the header (it
    landed at the file's start, and pyulog read the same bytes for ever). Any other loop runs out of
    reads."""
    from drivers.logs.ulog_source import ULogLoopError, ULogSource

    f = ULogSource(b"xxxxx" + struct.pack("<HB", 20_000, 0) + bytes(10))
    f.seek(5)
    assert len(f.read(3)) == 3 and len(f.read(20_000)) == 10
    assert f.seek(-2 - 20_000, 1) == 6
    f.seek(5)
    f.read(3)
    f.read(20_000)
    assert f.seek(-(3 + 20_000), 1) == 5  # back to the header: a message to read again
    f = ULogSource(bytes(100))
    with pytest.raises(ULogLoopError):
        while True:
            f.seek(0)
            f.read(3)


def test_the_fuzzers_ulog_mutants_that_kept_pyulog_reading_are_read_at_once(tmp_path):
    """Mutants 1 and 258 of the fuzzer's ULog share (seed 7000): each kept pyulog 1.3 reading until
    the fuzzer's alarm, which its reader then reported as the file refused."""
    import time

    from .conftest import bench_module

    fuzz = bench_module("fuzz")
    rng, base = random.Random(7000), fuzz.seed_ulg()
    mutants = [fuzz.mutate(base, rng) for _ in range(259)]
    for k in (1, 258):
        p = tmp_path / f"mutant{k}.ulg"
        p.write_bytes(mutants[k])
        t0 = time.process_time()
        _read_ulog_or_one_line(p)
        assert time.process_time() - t0 < 1.0, k


@pytest.mark.parametrize("seed", range(4))
def test_damaged_ulogs_are_read_as_far_as_they_go_or_refused_in_one_line(tmp_path, seed):
    rng = random.Random(seed)
    b = bytearray((FIXTURES / "px4_sample_log_small.ulg").read_bytes()[:150_000])
    for _ in range(rng.randint(1, 30)):
        op = rng.random()
        i = rng.randrange(len(b))
        if op < 0.6:
            b[i] = rng.randrange(256)
        elif op < 0.8:
            del b[i : i + rng.randrange(1, 300)]
        else:
            b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 50)))
    p = tmp_path / "damaged.ulg"
    p.write_bytes(bytes(b))
    _read_ulog_or_one_line(p)


def test_a_dataflash_fmt_of_length_zero_is_damage_not_a_loop(tmp_path):
    """189 bytes: an FMT record declaring a length of 0 made the walker step by 0 while its list grew
    (1.6 GB in 108 s). Its type's records are now resynced over as damage."""
    from drivers.logs.bulk import walk_dataflash

    def fmt(type_id, length, name, form, cols):
        return b"\xa3\x95\x80" + struct.pack(
            "<BB4s16s64s", type_id, length, name.encode(), form.encode(), cols.encode()
        )

    data = fmt(128, 89, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns") + fmt(129, 0, "IMU", "Qf", "TimeUS,AccX")
    data += b"\xa3\x95\x81" + bytes(8)
    assert len(data) == 189
    walk = walk_dataflash(data)
    assert 129 not in walk.fmts and walk.skipped
    p = tmp_path / "fmt0.bin"
    p.write_bytes(data)
    log = read_dataflash(p)
    assert not log.measurements and "damaged FMT" in log.damage


def test_an_fmt_header_inside_a_records_data_is_data(tmp_path):
    """The three bytes of an FMT record's header (0xA3 0x95 0x80) inside a record's fields, as another
    generator's 5.9 MB log had them once in a float: data, not a damaged FMT. Read as an FMT, two
    bytes of the record were zeroed and the log was said to be damaged."""
    from drivers.logs.bulk import walk_dataflash
    from drivers.logs.dataflash import clean_binary_formats

    def fmt(type_id, length, name, form, cols):
        return b"\xa3\x95\x80" + struct.pack(
            "<BB4s16s64s", type_id, length, name.encode(), form.encode(), cols.encode()
        )

    data = fmt(128, 89, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns") + fmt(129, 15, "TST", "Qf", "TimeUS,Val")
    stamps = [1_000_000 * k for k in range(1, 20)]
    stamps[3] = int.from_bytes(b"\x00\xa3\x95\x80\x00\x00\x00\x00", "little")  # the header in a field
    for us in stamps:
        data += b"\xa3\x95\x81" + struct.pack("<Qf", us, 1.5)
    assert data.count(b"\xa3\x95\x80") == 3 and len(data) - data.rfind(b"\xa3\x95\x80") >= 89
    walk = walk_dataflash(data)
    assert len(walk.offsets[128]) == 2 and not walk.skipped  # two FMT records; the third header is data
    assert clean_binary_formats(data, walk) == (data, 0)
    p = tmp_path / "inside.bin"
    p.write_bytes(data)
    log = read_dataflash(p)
    assert log.damage == "" and log.counts["TST"] == len(stamps)
    assert log.tables.tables["TST"].cols["TimeUS"].tolist() == [float(us) for us in stamps]


def _mutants_give_no_traceback_hang_or_blowup(tmp_path, per_format: int, jobs: int) -> None:
    """bench/fuzz.py in a process of its own, capped at 1.5 GB, each mutant at 5 s: ``per_format``
    mutants of each of the five formats (tlog, binary and text DataFlash, ULog, Crazyflie) through
    ``load_log``, the reading ``info``, ``triage``, ``replay`` and ``diagnose`` all do."""
    import json
    import subprocess
    import sys

    from .conftest import REPO

    r = subprocess.run(
        [
            sys.executable,
            str(REPO / "bench" / "fuzz.py"),
            "--n",
            str(per_format),
            "--jobs",
            str(jobs),
            "--json",
            "--seed",
            "7",
            "--keep",
            str(tmp_path / "failing"),
        ],
        capture_output=True,
        text=True,
        timeout=3600,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    rows = json.loads(r.stdout.splitlines()[-1])
    assert sum(row["n"] for row in rows) == 5 * per_format
    for row in rows:
        assert row["traceback"] == row["hang"] == row["blowup"] == 0, row
        assert row["read"] > 0 and row["read"] + row["refused"] == row["n"], row


@pytest.mark.slow
def test_ten_thousand_mutants_of_the_five_formats_give_no_traceback_hang_or_blowup(tmp_path):
    _mutants_give_no_traceback_hang_or_blowup(tmp_path, 2_000, 1)


@pytest.mark.soak
def test_half_a_million_mutants_of_the_five_formats_give_no_traceback_hang_or_blowup(tmp_path):
    """100,000 a format, on every core (the benchmark runs 200,000 a format)."""
    from groundstation.core.cores import available_cores

    _mutants_give_no_traceback_hang_or_blowup(tmp_path, 100_000, available_cores())
