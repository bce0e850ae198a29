"""The tlog reader (IMU as columns) gives what the replay's receive path gives, record for record."""

import random

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers.logs.tlog_reader import read_tlog
from drivers.replay import Replay
from groundstation.core.imu import ImuColumns
from groundstation.core.measurement import Kind

from .helpers import imu_frames, write_tlog

FIXTURES = __import__("pathlib").Path(__file__).parent / "fixtures"


def assert_same_as_replay(path):
    rp = Replay(path)
    ms, imu = ImuColumns.split(rp.iter_measurements())
    got = read_tlog(path)
    assert got.damage == rp.skipped_summary()
    assert len(got.measurements) == len(ms)
    for a, b in zip(ms, got.measurements):
        assert (a.t, a.kind, a.source, a.instance) == (b.t, b.kind, b.source, b.instance)
        assert a.t_rx == b.t_rx and np.array_equal(a.value, b.value, equal_nan=True)
    assert list(got.imu.series) == list(imu.series)
    for key, s in imu.series.items():
        q = got.imu.series[key]
        assert q.source == s.source, key
        for name in ("t", "t_rx", "value", "samples"):
            assert np.array_equal(getattr(q, name), getattr(s, name)), (key, name)
        # float32 only where that is what was sent: widened, the receiver's float64 to the bit
        assert q.values().dtype == np.float64 and np.array_equal(q.values(), s.value), key
    return got


def _highres(enc, t_us, upd, k, inst=0):
    msg = mavlink.MAVLink_highres_imu_message(
        t_us, 0.1 * k, -0.2, -9.8 + 0.001 * k, 0.01, -0.02 * k, 0.03, 0.2, 0.0, 0.4, 1013.0, 0.0, 0.0, 25.0, upd, inst
    )
    return bytes(msg.pack(enc))


def _mixed_frames():
    """Two vehicles' HIGHRES_IMU at 1 kHz beside other messages: every case the columns leave to
    the receiver (magnetometer and pressure bits, zero and UNIX times, untimed messages before the
    first time, a second instance, MAVLink 1 SCALED_IMU) among plain accelerometer + gyro frames."""
    a, b = mavlink.MAVLink(None, 1, 1), mavlink.MAVLink(None, 2, 1)
    gcs = mavlink.MAVLink(None, 255, 190)  # a ground station's heartbeat, once: it waits for a clock for good
    frames = [bytes(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(gcs))]
    frames += [bytes(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(a))]  # untimed, before any time
    frames += [bytes(mavlink.MAVLink_vfr_hud_message(0, 0, 0, 50, 1.0, 0.0).pack(a))]
    rnd = random.Random(7)
    for k in range(3000):
        enc = a if k % 5 else b
        upd = rnd.choice([0x3F, 0x3F, 0x3F, 0x07, 0x38, 0x1FF, 0x23F, 0])
        t_us = 2_000_000 + 1000 * k
        if k % 397 == 0:
            t_us = 0  # no time: the aligned clock's
        elif k % 401 == 0:
            t_us = 1_700_000_000_000_000 + k  # a UNIX time: as absent
        frames.append(_highres(enc, t_us, upd, k, inst=k % 7 == 0))
        if k % 20 == 0:
            frames.append(bytes(mavlink.MAVLink_vfr_hud_message(0, 0, 0, 50, 1.0, 0.0).pack(enc)))
        if k % 50 == 0:
            frames.append(
                bytes(mavlink.MAVLink_scaled_pressure_message(2000 + k, 1013.0 - k * 1e-3, 0.0, 2500).pack(a))
            )
        enc.seq = (enc.seq + 1) % 256
    frames += imu_frames(30, mavlink1=True)
    return frames


def test_mixed_vehicles_and_flags(tmp_path):
    got = assert_same_as_replay(write_tlog(tmp_path / "mixed.tlog", _mixed_frames(), dt=0.001))
    assert len(got.imu) > 4000


def test_accelerometer_and_gyro_of_the_same_frames_share_their_times(tmp_path):
    """Frames that carry both (as PX4 sends them) give the two series one array of times, one of
    receive times and one of sample counts, not a copy each; the series are the replay's still."""
    a = mavlink.MAVLink(None, 1, 1)
    frames = []
    for k in range(500):
        frames.append(_highres(a, 2_000_000 + 1000 * k, 0x3F, k))
        a.seq = (a.seq + 1) % 256
    got = assert_same_as_replay(write_tlog(tmp_path / "plain.tlog", frames, dt=0.001))
    acc, gyro = got.imu.get(Kind.ACCEL), got.imu.get(Kind.GYRO)
    assert acc is not None and gyro is not None and len(acc) == len(gyro) == 500
    assert gyro.t is acc.t and gyro.t_rx is acc.t_rx and gyro.samples is acc.samples
    assert not np.shares_memory(gyro.value, acc.value)
    # cut as the triage cuts a stretch: still shared, and each series as masking it alone gives
    cut = got.imu.masked(lambda s: (s.t < 2.1) | (s.t > 2.3))
    c_acc, c_gyro = cut.get(Kind.ACCEL), cut.get(Kind.GYRO)
    assert c_acc is not None and c_gyro is not None and 250 < len(c_acc) < 500
    assert c_gyro.t is c_acc.t and c_gyro.t_rx is c_acc.t_rx and c_gyro.samples is c_acc.samples
    for q, s in ((c_acc, acc), (c_gyro, gyro)):
        alone = s.masked((s.t < 2.1) | (s.t > 2.3))
        for name in ("t", "t_rx", "value", "samples"):
            assert np.array_equal(getattr(q, name), getattr(alone, name)), name


def test_damaged_file(tmp_path):
    """Flipped bits (bad CRCs, broken lengths), garbage, a run of start markers, a cut last record."""
    clean = write_tlog(tmp_path / "clean.tlog", _mixed_frames(), dt=0.001).read_bytes()
    d = bytearray(clean)
    rnd = random.Random(3)
    for _ in range(60):
        d[rnd.randrange(len(d))] ^= 1 << rnd.randrange(8)
    d[len(d) // 3 : len(d) // 3] = bytes(rnd.randrange(256) for _ in range(700))
    d[len(d) // 2 : len(d) // 2] = b"\xfd" * 90
    (tmp_path / "bad.tlog").write_bytes(bytes(d[:-5]))
    got = assert_same_as_replay(tmp_path / "bad.tlog")
    assert "bad CRC" in got.damage and "truncated" in got.damage


@pytest.mark.parametrize("name", ["ardusub_small.tlog", pytest.param("dronekit_flight.tlog", marks=pytest.mark.slow)])
def test_recorded_logs(name):
    assert_same_as_replay(FIXTURES / name)
