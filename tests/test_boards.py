"""Serial sensor boards: the binary frame protocol and NMEA GPS, against the spec and over a pty."""

import asyncio
import math
import random
import struct

import numpy as np
import pytest

from drivers import board_protocol as bp
from drivers.board import BinaryBoardReceiver, BoardLink, NmeaReceiver
from drivers.link_state import LinkState
from groundstation.core.measurement import Kind
from sim_bridge.board_out import BinaryFramer
from sim_bridge.bridge import SimBridge
from sim_bridge.pty_port import PtyPort
from sim_bridge.scenario import Scenario

from .conftest import async_test


def test_crc_is_ccitt_false():
    assert bp.crc16_ccitt(b"123456789") == 0x29B1  # the catalogue's check value


def test_a_frame_built_by_hand_from_the_spec_decodes():
    payload = struct.pack("<I6f", 2_000_000, 0.5, -0.25, -9.75, 0.01, 0.02, -0.03)
    body = bytes([1, 0x01, 7, len(payload)]) + payload
    frame = b"\xa5\x5a" + body + struct.pack("<H", bp.crc16_ccitt(body))
    sim = BinaryFramer()
    sim.seq = 7
    assert sim.frame(0x01, payload) == frame  # the simulator's firmware agrees byte for byte
    r = BinaryBoardReceiver()
    out = r.feed(frame, 0.0)
    acc = [m for m in out if m.kind is Kind.ACCEL][0]
    assert acc.t == 2.0 and acc.value == pytest.approx([0.5, -0.25, -9.75])
    assert r.counters.frames == 1 and r.counters.crc_errors == 0


def _stream(n=300, seed=1):
    f = BinaryFramer()
    rng = random.Random(seed)
    out = b""
    for i in range(n):
        t = i * 2000
        if i % 3 == 0:
            out += f.frame(0x04, struct.pack("<I3iH", t, i, -i, 2 * i, 4096))
        else:
            out += f.frame(0x01, struct.pack("<I6f", t, *[rng.uniform(-1, 1) for _ in range(6)]))
    return out


def test_any_chunking_and_damage_is_survived():
    data = _stream()
    ref = BinaryBoardReceiver().feed(data, 0.0)
    r = BinaryBoardReceiver()
    got, i, rng = [], 0, random.Random(5)
    while i < len(data):
        n = rng.choice([1, 3, 17, 64, 500])
        got += r.feed(data[i : i + n], 0.0)
        i += n
    assert [(m.t, m.kind) for m in got] == [(m.t, m.kind) for m in ref]
    # garbage, a flipped bit and an unknown message id
    bad = bytearray(data)
    bad[100] ^= 0x10
    junk = b"\x00\xa5\x13garbage\xa5"
    unknown = BinaryFramer().frame(0x7E, b"\x00" * 4)
    r2 = BinaryBoardReceiver()
    out = r2.feed(junk + bytes(bad) + unknown, 0.0)
    assert r2.counters.crc_errors == 1 and r2.counters.unknown == 1 and r2.counters.garbage_bytes >= len(junk) - 1
    assert len(out) >= len(ref) - 2


def test_encoder_counts_become_radians_and_the_clock_unwraps():
    f = BinaryFramer()
    r = BinaryBoardReceiver()
    a = r.feed(f.frame(0x04, struct.pack("<I3iH", 0xFFFFF000, 1024, -2048, 0, 4096)), 0.0)
    b = r.feed(f.frame(0x04, struct.pack("<I3iH", 0x00000800, 0, 0, 0, 4096)), 0.0)
    assert a[0].kind is Kind.ENCODERS and a[0].value == pytest.approx([math.pi / 2, -math.pi, 0.0])
    assert b[0].t - a[0].t == pytest.approx((0x1000 + 0x800) * 1e-6)  # across the uint32 wrap


def test_nmea_gga_and_rmc_textbook_sentences():
    n = NmeaReceiver()
    data = (
        b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A\r\n"
        b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n"
    )
    out = n.feed(data[:50], 0.0) + n.feed(data[50:], 0.0)
    vel, gps = out
    assert gps.kind is Kind.GPS and gps.value == pytest.approx([48.1173, 11.516666666, 545.4])
    assert gps.t == 764426119.0  # 1994-03-23 12:35:19 UTC
    assert gps.variance[2] == pytest.approx((1.5 * 0.9 * 2.5) ** 2)
    sog = 22.4 * 0.514444
    assert vel.value[:2] == pytest.approx([sog * math.cos(math.radians(84.4)), sog * math.sin(math.radians(84.4))])
    assert math.isnan(vel.value[2])


def test_nmea_bad_checksum_garbage_and_no_fix_are_counted():
    n = NmeaReceiver()
    out = n.feed(
        b"\xff\x00junk$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*48\r\n"
        b"$GPGGA,123520,,,,,0,00,,,M,,M,,*61\r\n$GPGSV,1,1,00*79\r\n",
        0.0,
    )
    assert out == [] and n.counters.crc_errors == 1 and n.counters.no_fix == 1
    assert n.counters.garbage_bytes == 6 and n.counters.unknown == 1


@async_test(timeout=40)
async def test_3dof_board_over_a_pty_with_unplug_and_replug(tmp_path):
    board = PtyPort(tmp_path / "ttyBOARD")
    bridge = SimBridge(Scenario("heli3dof", seed=1), udp_to=None, board=board, speed=1.0)
    await bridge.open()
    link = BoardLink(f"{board.path},921600", "binary", lost_after=0.3)
    sub, events = link.measurements(), link.events()
    await link.open()
    runner = asyncio.create_task(bridge.run(30.0))
    try:
        got = []
        async for m in sub:
            got.append(m)
            if len(got) >= 600:
                break
        enc = [m for m in got if m.kind is Kind.ENCODERS]
        ts = np.array([m.t for m in enc])
        assert len(enc) > 150 and np.diff(ts) == pytest.approx(0.002, abs=1e-6)  # 500 Hz
        assert enc[0].value[1] == pytest.approx(-0.5, abs=0.01)  # resting on the table
        board.unplug()
        async for ev in events:
            if ev.state is LinkState.LOST:
                break
        board.plug()
        async for ev in events:
            if ev.state is LinkState.ALIVE:
                break
        assert link.counters.crc_errors == 0
    finally:
        bridge.close()
        await runner
        await link.close()


@async_test(timeout=40)
async def test_quad_nmea_gps_board(tmp_path):
    board = PtyPort()
    bridge = SimBridge(Scenario("quad", seed=2), udp_to=None, board=board, speed=4.0)
    await bridge.open()
    link = BoardLink(f"{board.path},9600", "nmea")
    sub = link.measurements()
    await link.open()
    runner = asyncio.create_task(bridge.run(30.0))
    try:
        got = []
        async for m in sub:
            got.append(m)
            if len(got) >= 20:
                break
        gps = [m for m in got if m.kind is Kind.GPS]
        assert gps and gps[0].value[0] == pytest.approx(47.397742, abs=1e-4)
        assert link.counters.crc_errors == 0
    finally:
        bridge.close()
        await runner
        await link.close()
