"""Bulk loading into numpy arrays agrees with pymavlink value for value, and reports damage by offset."""

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.generator.mavcrc import x25crc

from drivers.logs.bulk import BulkError, crc_mcrf4xx_rows, load, walk_dataflash
from drivers.logs.dataflash import read_dataflash

from .conftest import REPO, real_file

FIXTURES = REPO / "tests" / "fixtures"


def pymavlink_by_type(path):
    conn = mavutil.mavlink_connection(str(path))
    out = {}
    while (m := conn.recv_match()) is not None:
        out.setdefault(m.get_type(), []).append(m)
    return out


def assert_same_values(bulk, ref, skip=("BAD_DATA", "FMT", "FMTU", "UNIT", "MULT")):
    # pymavlink hands out neither BAD_DATA nor DataFlash's own format records; bulk keeps the latter
    assert set(bulk.messages) - set(skip) == set(ref) - set(skip)
    for name, arr in bulk.messages.items():
        if name in skip:
            continue
        msgs = ref[name]
        assert len(arr) == len(msgs), name
        for col in arr.names:
            if col not in msgs[0].__dict__:  # an extension field the frame did not carry
                continue
            got, want = arr[col], [getattr(m, col) for m in msgs]
            if got.dtype.kind == "S":
                # raw bytes here; pymavlink gives str decoded with errors="replace"
                text = [g.decode("utf-8", "replace").split("\0")[0] for g in got]
                want = [(w.decode("utf-8", "replace") if isinstance(w, bytes) else str(w)).split("\0")[0] for w in want]
                assert text == want, (name, col)
            else:
                np.testing.assert_allclose(
                    np.asarray(got, float), np.asarray(want, float), rtol=1e-6, err_msg=f"{name}.{col}"
                )


def test_vectorised_crc_is_mavlinks_x25():
    rng = np.random.default_rng(3)
    rows = rng.integers(0, 256, size=(50, 37), dtype=np.uint8)
    got = crc_mcrf4xx_rows(rows, 124)
    want = [x25crc(bytes(r) + bytes([124])).crc for r in rows]
    assert got.tolist() == want


def test_tlog_matches_pymavlink_message_for_message():
    p = FIXTURES / "ardusub_small.tlog"
    bulk = load(p)
    ref = pymavlink_by_type(p)
    assert_same_values(bulk, ref)
    assert sum(bulk.crc_errors.values()) == len(ref["BAD_DATA"])  # the same 4 damaged frames
    imu = bulk["SCALED_IMU2"] if "SCALED_IMU2" in bulk else bulk["RAW_IMU"]
    assert np.all(np.diff(imu.t) >= -1.0)  # receive times, in file order


def test_tlog_with_damage_counts_crc_errors_and_keeps_the_rest():
    p = FIXTURES / "dronekit_flight.tlog"
    bulk = load(p)
    assert sum(bulk.crc_errors.values()) == 1314  # as mavutil counts them
    assert bulk.count == 75_477
    assert "truncated at offset 2723821" in bulk.damage_summary()


def test_dataflash_bin_matches_dfreader():
    p = real_file("ardupilot_dataflash/pyflightcoach_pilot_0004.BIN")
    bulk = load(p)
    assert_same_values(bulk, pymavlink_by_type(p))
    assert np.all(np.diff(bulk["ATT"].t) > 0) and 90 < bulk["ATT"].t[-1] - bulk["ATT"].t[0] < 110


@pytest.mark.slow
def test_damaged_dataflash_names_the_offset_and_keeps_data_on_both_sides(tmp_path):
    raw = real_file("ardupilot_dataflash/erle_pxf_copter_Loiter_RTL.bin").read_bytes()
    bad = tmp_path / "bad.bin"
    bad.write_bytes(raw[:400_000] + b"\xff" * 100 + raw[400_100:])
    bulk = load(bad)
    clean = load(real_file("ardupilot_dataflash/erle_pxf_copter_Loiter_RTL.bin"))
    assert bulk.skipped and 400_000 <= bulk.skipped[0][0] < 400_100  # the first bad header is in the hole
    assert clean.count - 10 < bulk.count < clean.count  # only the records hit are lost
    log = read_dataflash(bad)
    assert f"{bad}: " in log.damage and f"at offset {bulk.skipped[0][0]}" in log.damage
    assert log.duration == pytest.approx(257.9, abs=0.5)  # data after the damage is kept too

    cut = tmp_path / "cut.bin"
    starts = sorted(o for offs in walk_dataflash(raw).offsets.values() for o in offs)
    at = starts[int(np.searchsorted(starts, 300_000))]
    cut.write_bytes(raw[: at + 5])  # mid-record
    log = read_dataflash(cut)
    assert f"last record truncated at offset {at}" in log.damage and 50 < log.duration < 278


def test_foreign_file_is_one_line_error(tmp_path):
    p = tmp_path / "x.tlog"
    p.write_bytes(b"hello, world\n" * 1000)
    with pytest.raises(ValueError, match="x.tlog: not a MAVLink tlog"):
        load(p)
    with pytest.raises(BulkError, match="cannot read"):
        load(tmp_path / "missing.bin")
