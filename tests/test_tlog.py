"""The .tlog format: our files open in pymavlink's reader, theirs in ours; damage is survivable."""

import os

import numpy as np
import pytest
from pymavlink import mavutil

from drivers.replay import Replay
from drivers.tlog import TlogError, TlogIndex, TlogWriter

from .conftest import real_file
from .helpers import imu_frames, write_tlog


def test_our_recording_reads_in_pymavlink(tmp_path):
    p = tmp_path / "ours.tlog"
    w = TlogWriter(p)
    frames = imu_frames(50)
    for i, fr in enumerate(frames):
        w.write(fr, 1_700_000_000.0 + i * 0.01)
    w.close()
    conn = mavutil.mavlink_connection(str(p))
    got = []
    while (m := conn.recv_match()) is not None:
        got.append(m)
    assert [m.get_type() for m in got] == ["SCALED_IMU"] * 50
    assert got[10].time_boot_ms == 1100
    assert got[10]._timestamp == pytest.approx(1_700_000_000.1, abs=1e-6)


@pytest.mark.parametrize(
    "name,messages,crc_errors,mavlink2",
    [
        ("dronekit_flight_replay_flight.tlog", 75477, 1314, False),  # MAVProxy, MAVLink 1, radio damage
        ("ardusub_small.tlog", 35912, 4, True),  # QGroundControl, MAVLink 2
    ],
)
def test_their_recordings_read_here_as_pymavlink_reads_them(name, messages, crc_errors, mavlink2):
    p = real_file(f"mavlink_tlog/{name}")
    rp = Replay(p)
    n = sum(1 for _ in rp.iter_measurements())
    c = rp.receiver.counters
    assert c.messages == messages and c.crc_errors == crc_errors
    assert (c.mavlink2 > 0) == mavlink2 and n > 0.5 * messages
    conn = mavutil.mavlink_connection(str(p))
    good = 0
    while (m := conn.recv_match()) is not None:
        good += m.get_type() != "BAD_DATA"
    assert good == messages


def test_truncated_last_record_is_tolerated(tmp_path):
    p = write_tlog(tmp_path / "t.tlog", imu_frames(100))
    data = p.read_bytes()
    p.write_bytes(data[:-7])  # cut into the last frame
    idx = TlogIndex.scan(p)
    assert len(idx) == 99 and idx.truncated_at == len(data) - 8 - len(imu_frames(1)[0])
    rp = Replay(p)
    assert sum(1 for _ in rp.iter_measurements()) == 99 * 3
    assert "truncated" in rp.skipped_summary()


def test_bad_crc_frames_are_counted_and_skipped(tmp_path):
    frames = imu_frames(100)
    bad = bytearray(frames[40])
    bad[12] ^= 0xFF  # payload byte: CRC no longer matches
    frames[40] = bytes(bad)
    p = write_tlog(tmp_path / "c.tlog", frames)
    rp = Replay(p)
    list(rp.iter_measurements())
    assert rp.receiver.counters.crc_errors == 1 and rp.receiver.counters.messages == 99


def test_garbage_between_records_is_resynchronised(tmp_path):
    p = write_tlog(tmp_path / "g.tlog", imu_frames(100))
    data = p.read_bytes()
    rec = len(data) // 100
    junk = os.urandom(333).replace(b"\xfd", b"\x00").replace(b"\xfe", b"\x00")
    p.write_bytes(data[: 50 * rec] + junk + data[50 * rec :])
    idx = TlogIndex.scan(p)
    assert len(idx) == 100 and len(idx.skipped) == 1 and idx.skipped[0][1] == 333


@pytest.mark.parametrize("content", [b"", b"hello, this is a text file\n" * 300, os.urandom(10000)])
def test_not_a_tlog_is_a_clear_error(tmp_path, content):
    p = tmp_path / "not.tlog"
    p.write_bytes(content)
    with pytest.raises(TlogError, match="not.tlog: not a MAVLink tlog"):
        TlogIndex.scan(p)


def test_seek_is_by_time_across_a_recording_gap(tmp_path):
    # 100 records, then a 100 s gap, then 100 more: a byte-fraction seek to
    # the middle of the time span would land at the gap's edge, not in it.
    p = write_tlog(tmp_path / "gap.tlog", imu_frames(200), dt=0.01, gap_after=99, gap=100.0)
    idx = TlogIndex.scan(p)
    assert idx.duration == pytest.approx(101.99, abs=1e-3)
    i = idx.seek(50.0)  # inside the gap: the first record after it
    assert i == 100
    assert idx.seek(101.005) == 101 and idx.seek(0.495) == 50
    assert np.all(np.diff(idx.offset) > 0)


def test_a_lone_damaged_timestamp_takes_the_time_before_it(tmp_path):
    """A bit flipped in one record's timestamp (2^32 us: 72 minutes ahead, within the day a resync
    trusts) neither stretches the log's duration nor moves seeking; it is counted. A real gap of
    the recording (the records after it agree with each other) stays a gap."""
    p = write_tlog(tmp_path / "flip.tlog", imu_frames(100))
    data = bytearray(p.read_bytes())
    rec = len(data) // 100
    data[50 * rec + 3] ^= 0x01  # bit 32 of record 50's big-endian microseconds
    p.write_bytes(bytes(data))
    idx = TlogIndex.scan(p)
    assert len(idx) == 100 and idx.mended_times == 1
    assert idx.duration == pytest.approx(0.99, abs=1e-5) and idx.t[50] == idx.t[49]
    assert idx.seek(0.595) == 60  # (ahead, record 50 took every later seek)
    rp = Replay(p)
    assert sum(1 for _ in rp.iter_measurements()) == 300
    assert "1 record with a damaged timestamp given the time of the one before" in rp.skipped_summary()
    gap = TlogIndex.scan(write_tlog(tmp_path / "gap.tlog", imu_frames(100), gap_after=49, gap=3600.0))
    assert gap.mended_times == 0 and gap.duration == pytest.approx(3600.99, abs=1e-3)
