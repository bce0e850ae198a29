"""The fast frame walker agrees with pymavlink on every frame, however the bytes arrive."""

import random
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from pymavlink.generator.mavcrc import x25crc

from drivers.mavlink.decode import MavlinkDecoder
from drivers.mavlink.framing import FAST_TYPES
from drivers.mavlink.receiver import MavlinkReceiver

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from ingest import make_stream  # noqa: E402

from tests.helpers import imu_frames  # noqa: E402


def _key(m):
    return (m.t, m.kind, m.instance, tuple(np.round(np.nan_to_num(m.value, nan=-12345.0), 9)))


@pytest.fixture(scope="module", params=[False, True], ids=["px4_fields", "every_field"])
def stream(request):
    return make_stream(3000, seed=7, every_field=request.param)


def test_any_chunking_gives_the_same_result(stream):
    whole = MavlinkReceiver()
    ref = [_key(m) for m in whole.feed(stream, 1.0)]
    rng = random.Random(3)
    pieces = MavlinkReceiver()
    got, i = [], 0
    while i < len(stream):
        n = rng.choice([1, 2, 3, 7, 64, 300, 4096])
        got += [_key(m) for m in pieces.feed(stream[i : i + n], 1.0)]
        i += n
    assert got == ref
    assert pieces.counters.messages == whole.counters.messages == 3000


def test_fast_path_converts_exactly_as_the_pymavlink_object_path(stream):
    mav = mavlink.MAVLink(None)
    objects = mav.parse_buffer(stream)
    assert len(objects) == 3000
    ref_dec = MavlinkDecoder("mav")
    ref = []
    for m in objects:
        ref += [_key(x) for x in ref_dec.decode(m, 1.0)]
    r = MavlinkReceiver("mav")
    got = [_key(x) for x in r.feed(stream, 1.0)]
    assert got == ref
    fast_seen = {t for t in r.counters.by_type if t in FAST_TYPES}
    assert {"HIGHRES_IMU", "ATTITUDE", "SCALED_PRESSURE", "DISTANCE_SENSOR", "SERVO_OUTPUT_RAW"} <= fast_seen


def test_mavlink2_truncated_payload_and_signed_frame():
    enc = mavlink.MAVLink(None, 1, 1)
    # trailing zero fields are trimmed on the wire in MAVLink 2
    frame = enc.attitude_encode(1000, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0).pack(enc)
    assert len(frame) < 12 + 28
    enc.signing.secret_key = bytes(range(32))
    enc.signing.link_id = 1
    enc.signing.sign_outgoing = True
    signed = enc.attitude_encode(2000, 0.25, 0.0, 0.0, 0.0, 0.0, 0.0).pack(enc)
    assert signed[2] & 0x01 and len(signed) == len(frame) + 13
    r = MavlinkReceiver()
    out = r.feed(bytes(frame) + bytes(signed), 1.0)
    att = [m.value[0] for m in out if m.kind.value == "attitude"]
    assert att == pytest.approx([0.5, 0.25]) and r.counters.crc_errors == 0


def test_garbage_and_bad_crc_between_good_frames():
    enc = mavlink.MAVLink(None, 1, 1)
    good = [bytes(enc.attitude_encode(i, 0.1 * i, 0, 0, 0, 0, 0).pack(enc)) for i in range(1, 4)]
    bad = bytearray(good[1])
    bad[-1] ^= 0xFF
    data = b"\x00\x11garbage" + good[0] + bytes(bad) + b"\x13\x37" + good[2]
    r = MavlinkReceiver()
    out = r.feed(data, 1.0)
    assert [round(m.value[0], 3) for m in out if m.kind.value == "attitude"] == [0.1, 0.3]
    assert r.counters.crc_errors == 1 and r.counters.bad_data == 2


def test_payload_longer_than_the_definition_reads_the_known_fields():
    """A newer dialect's extension fields (more payload than ours defines) are passed over, as
    pymavlink passes over them."""
    enc = mavlink.MAVLink(None, 1, 1)
    frame = bytearray(enc.attitude_encode(1000, 0.5, 0.25, 0.125, 0.1, 0.2, 0.3).pack(enc))
    payload = frame[10:-2] + b"\x01\x02\x03\x04"  # four bytes of a field this dialect lacks
    body = bytes([frame[0], len(payload)]) + bytes(frame[2:10]) + payload
    crc = x25crc(body[1:])
    crc.accumulate(bytes([mavlink.MAVLink_attitude_message.crc_extra]))
    longer = body + struct.pack("<H", crc.crc)
    ref = mavlink.MAVLink(None).parse_buffer(longer)
    r = MavlinkReceiver()
    out = r.feed(longer, 1.0)
    att = next(m.value for m in out if m.kind.value == "attitude")
    assert list(att) == pytest.approx([0.5, 0.25, 0.125])
    assert (ref[0].roll, ref[0].pitch, ref[0].yaw) == pytest.approx(tuple(att))
    assert r.counters.crc_errors == 0 and r.counters.messages == 1


def test_counters_of_a_mixed_read_are_those_of_its_frames_one_by_one():
    """Counted once a read: the same totals as frame by frame, whatever else the read holds."""
    v1 = imu_frames(5, sysid=1, mavlink1=True)
    enc = mavlink.MAVLink(None, 1, 1)
    enc.seq = 5
    v2 = imu_frames(5, sysid=1, t0_ms=1050, enc=enc)  # the same sender, now on MAVLink 2
    other = imu_frames(4, sysid=7)
    unknown = bytes.fromhex("fd0400000001010a0f0b") + b"\x01\x02\x03\x04" + b"\x00\x00"
    bad = bytearray(other[0])
    bad[-1] ^= 0xFF
    data = b"".join(v1[:3] + other[:2] + [unknown] + v1[3:] + [bytes(bad)] + v2[1:] + other[2:])
    whole, single = MavlinkReceiver(), MavlinkReceiver()
    whole.feed(data, 1.0)
    for i in range(len(data)):
        single.feed(data[i : i + 1], 1.0)
    for r in (whole, single):
        c = r.counters
        assert (c.messages, c.mavlink1, c.mavlink2, c.unknown, c.crc_errors) == (13, 5, 8, 1, 1)
        assert c.by_type["SCALED_IMU"] == 13 and sum(c.by_type.values()) == 14
        # sender 1 skipped v2[0]: one lost; sender 7 lost none (the damaged frame is no sequence number)
        assert c.per_source == {(1, 1): [9, 1], (7, 1): [4, 0]}
        assert r.peer_mavlink1 == {(1, 1): False, (7, 1): False}


def test_a_message_the_decoder_fails_on_is_counted_and_leaves_no_part_behind():
    """A conversion that raises half-way (a fault no real message here causes: the decoder's
    handler is replaced) gives none of that message's records; the read goes on."""
    enc = mavlink.MAVLink(None, 1, 1)
    frames = [bytes(enc.attitude_encode(1000 * i, 0.1 * i, 0, 0, 0, 0, 0).pack(enc)) for i in (1, 2, 3)]
    r = MavlinkReceiver()
    cls = mavlink.MAVLink_attitude_message
    handler, *rest = r.decoder._handlers[cls]

    def half_then_fail(m, t, t_rx, source, instance, out):
        handler(m, t, t_rx, source, instance, out)
        if m[0] == 2000:  # time_boot_ms, the first of the fields in wire order
            raise ValueError("roll out of range")

    r.decoder._handlers[cls] = (half_then_fail, *rest)
    out = r.feed(b"".join(frames), 1.0)
    assert [round(m.t, 3) for m in out if m.kind.value == "attitude"] == [1.0, 3.0]
    assert len(out) == 4  # attitude and rate of the two good messages, none of the failed one
    assert r.counters.undecodable == 1 and r.counters.last_undecodable == "ATTITUDE: roll out of range"
    assert r.counters.messages == 3
