"""MAVLink 2 signing against a simulated vehicle that requires it (real loopback UDP): with the
right key the link is alive and its stream requests are taken; with a wrong key, or none, nothing
gets through either way, and the refusals are counted."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers.mavlink.framing import Framer
from drivers.mavlink.link import MavlinkLink
from drivers.mavlink.signing import SignatureCheck, SigningState, signing_key, timestamp_now
from sim_bridge.bridge import SimBridge
from sim_bridge.scenario import Scenario

from .conftest import async_test, free_udp_port
from .helpers import simulated_vehicle

KEY = signing_key("correct horse battery staple")


async def _session(key: bytes | None, seconds: float):
    link = MavlinkLink("udpin:127.0.0.1:0", ack_timeout=0.3, signing_key=key)
    await link.open()
    br = SimBridge(Scenario("quad", seed=2), udp_to=("127.0.0.1", link.transport.local_address[1]), signing_key=KEY)
    await br.open()
    task = asyncio.get_running_loop().create_task(br.run())
    end = time.monotonic() + seconds
    try:
        while time.monotonic() < end and not (key == KEY and br.sim.sensors.rates["imu"] == 250.0):
            await asyncio.sleep(0.05)
    finally:
        br.close()
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await link.close()
    return link, br


@async_test(timeout=60)
async def test_the_right_key_gets_through_both_ways():
    link, br = await _session(KEY, 20.0)
    assert 1 in link.vehicles and link.counters.signature_refused == 0
    assert br.sim.sensors.rates["imu"] == 250.0  # our signed SET_MESSAGE_INTERVAL was taken
    assert br.signing is not None and br.signing.refused == 0 and br.signature_refused == 0


@pytest.mark.slow
@pytest.mark.parametrize("key", [signing_key("wrong"), None], ids=["wrong key", "no key"])
@async_test(timeout=60)
async def test_a_wrong_key_or_none_is_refused(key):
    link, br = await _session(key, 3.0)
    assert br.sim.sensors.rates["imu"] == 500.0  # nothing we sent was taken
    assert br.received.get("COMMAND_LONG", 0) == 0 and br.signature_refused > 0  # our frames, refused
    if key is not None:  # we check: the vehicle's frames, signed with its key, are refused and counted
        c = link.counters
        assert not link.vehicles and c.messages == 0 and c.signature_refused >= 0.8 * br.frames_sent > 10


def _signed(ts: int, *, link_id: int = 0, sysid: int = 1, key: bytes = KEY, msg=None) -> bytes:
    """A frame signed at timestamp ``ts`` (10 us since 2015) on ``link_id``."""
    enc = mavlink.MAVLink(None, sysid, 1)
    enc.signing.secret_key, enc.signing.sign_outgoing, enc.signing.timestamp = key, True, ts - 1
    enc.signing.link_id = link_id
    return bytes((msg or mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3)).pack(enc))


def test_signature_check_refuses_replays_and_unsigned_frames():
    now = timestamp_now()
    frame = _signed(now)
    check = SignatureCheck(KEY)
    assert check.accept(frame, 0, 1, 1)
    assert not check.accept(frame, 0, 1, 1) and check.replayed == 1  # the same timestamp again: a replay
    plain = bytes(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(mavlink.MAVLink(None, 1, 1)))
    assert not check.accept(plain, 0, 1, 1) and check.unsigned == 1
    radio = bytes(mavlink.MAVLink_radio_status_message(1, 2, 3, 4, 5, 6, 7).pack(mavlink.MAVLink(None, 51, 68)))
    assert check.accept(radio, mavlink.MAVLINK_MSG_ID_RADIO_STATUS, 51, 68)  # a radio cannot sign
    with pytest.raises(ValueError, match="empty passphrase"):
        signing_key("")


def test_a_key_from_a_file(tmp_path):
    """32 raw bytes, or 64 hex digits (a text file); anything else is a one-line error."""
    raw, hexed, bad = tmp_path / "k.bin", tmp_path / "k.hex", tmp_path / "k.txt"
    raw.write_bytes(KEY)
    hexed.write_text(KEY.hex() + "\n")
    bad.write_text("z" * 64)
    assert signing_key(str(raw)) == KEY and signing_key(str(hexed)) == KEY
    with pytest.raises(ValueError, match="not a signing key"):
        signing_key(str(bad))


@pytest.mark.slow
def test_the_commands_take_a_key_and_say_when_frames_are_refused():
    """``groundstation sim --signing`` and ``param --signing``: the right passphrase reads a
    parameter, another says its frames were refused by signing (processes, stopped by the test)."""
    port = free_udp_port()
    gs = [sys.executable, "-m", "groundstation", "param", f"udpin:127.0.0.1:{port}", "--signing"]
    with simulated_vehicle(port, "--signing", "s3cret"):
        r = subprocess.run(gs + ["s3cret", "get", "SIM_ALPHA"], capture_output=True, text=True, timeout=60)
        assert r.stdout.split() == ["SIM_ALPHA", "22"], r.stderr
        r = subprocess.run(gs + ["other", "get", "SIM_ALPHA"], capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and "refused by MAVLink 2 signing" in r.stderr and "Traceback" not in r.stderr


def test_a_new_stream_is_accepted_within_a_minute_of_the_local_time_only():
    """The audit's replays on a new link id, with the right key: an hour old and two years old are
    refused; a frame stamped within the minute is a new stream (mavlink.io, "Accepting signed packets")."""
    now = timestamp_now()
    check = SignatureCheck(KEY)
    assert not check.accept(_signed(now - 3600 * 100_000, link_id=7), 0, 1, 1)
    assert not check.accept(_signed(now - 2 * 365 * 86400 * 100_000, link_id=8), 0, 1, 1)
    assert check.replayed == 2
    assert check.accept(_signed(now - 30 * 100_000, link_id=9), 0, 1, 1)


def test_a_forged_frame_moves_no_timestamp_and_our_own_frames_come_back_refused():
    """One frame with a wrong signature stamped 2^48 - 10 had blocked the vehicle's valid stream; a
    ground station's own signed frames reflected back to it are replays."""
    now = timestamp_now()
    check = SignatureCheck(KEY, own=(255, 190))
    forged = bytearray(_signed(2**48 - 10))
    forged[-1] ^= 0xFF
    assert not check.accept(bytes(forged), 0, 1, 1) and check.bad == 1
    assert check.accept(_signed(now), 0, 1, 1) and check.accept(_signed(now + 1), 0, 1, 1)
    enc = mavlink.MAVLink(None, 255, 190)
    enc.signing.secret_key, enc.signing.sign_outgoing, enc.signing.timestamp = KEY, True, now
    ours = bytes(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(enc))
    assert not check.accept(ours, 0, 255, 190) and check.reflected == 1


def test_frames_captured_before_a_restart_are_refused_after_it(tmp_path):
    """The timestamps are kept across restarts (SigningState): 400 frames captured from a stream are
    all refused by a freshly started check, though each was within the minute of the clock."""
    now = timestamp_now()
    captured = [_signed(now + k, link_id=3) for k in range(400)]
    first = SignatureCheck(KEY, state=SigningState(KEY, tmp_path))
    assert all(first.accept(f, 0, 1, 1) for f in captured)
    first.state.save()
    again = SignatureCheck(KEY, state=SigningState(KEY, tmp_path))  # a new process, the same store
    assert not any(again.accept(f, 0, 1, 1) for f in captured) and again.replayed == 400
    assert again.state.local() >= now + 398  # (pymavlink stamps the timestamp it was given, then counts on)
    assert again.accept(_signed(now + 1000, link_id=3), 0, 1, 1)  # the stream going on is accepted
    (tmp_path / "junk").mkdir()
    bad = tmp_path / SigningState(KEY, tmp_path).path.name
    bad.write_text("{not json")
    assert "not read" in SigningState(KEY, tmp_path).warning  # one line, the check starts from the clock


def test_unsigned_frames_of_unknown_ids_never_get_past_a_signed_link():
    """600,000 distinct unknown ids had been recorded regardless of signing (and grown the counters)."""
    got, refused = [], []
    framer = Framer(lambda *a: got.append(a), lambda *a: got.append(a), lambda: None, lambda: None)
    framer.signing = SignatureCheck(KEY)
    framer.on_refused = lambda: refused.append(1)
    unknown = bytes.fromhex("fd0400000001010a0f0b") + b"\x01\x02\x03\x04" + b"\x00\x00"
    framer.feed(unknown * 50)
    assert not got and len(refused) == 50


@async_test(timeout=60)
async def test_the_simulated_vehicle_answers_its_peer_not_whoever_sends_a_datagram():
    """Any datagram, even an unsigned refused one, had redirected all the vehicle's telemetry to its
    sender; it answers the address it was given, from a socket bound to loopback."""
    import socket

    port = free_udp_port()
    link = MavlinkLink(f"udpin:127.0.0.1:{port}", ack_timeout=0.3, signing_key=KEY)
    await link.open()
    br = SimBridge(Scenario("quad", seed=2), udp_to=("127.0.0.1", port), signing_key=KEY)
    await br.open()
    task = asyncio.get_running_loop().create_task(br.run())
    attacker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    attacker.bind(("127.0.0.1", 0))
    try:
        assert br._sock is not None and br._sock.getsockname()[0] == "127.0.0.1"
        attacker.sendto(
            bytes(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(mavlink.MAVLink(None, 9, 9))),
            br._sock.getsockname(),
        )
        before = link.counters.messages
        async for _ in link.measurements():  # telemetry keeps coming to the ground station
            if link.counters.messages > before + 200:
                break
        assert br.udp_to == ("127.0.0.1", port) and br.signature_refused >= 1
    finally:
        attacker.close()
        br.close()
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await link.close()


@async_test(timeout=60)
async def test_the_simulated_vehicle_refuses_after_a_restart_a_command_captured_before_it():
    """A signed COMMAND_LONG captured off the air: taken once, and refused by the same vehicle started
    again (its signing timestamps are stored on close and read at start)."""
    import socket

    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.setblocking(False)  # (the loop's sock_recv needs it)
    cmd = mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0)
    captured = _signed(timestamp_now(), sysid=255, msg=cmd)
    try:
        for attempt in ("first", "after a restart"):
            br = SimBridge(Scenario("quad", seed=2), udp_to=gcs.getsockname(), signing_key=KEY)
            await br.open()
            assert br._sock is not None
            loop = asyncio.get_running_loop()
            task = loop.create_task(br.run())
            gcs.sendto(captured, br._sock.getsockname())
            while br.received.get("COMMAND_LONG", 0) + br.signature_refused == 0:
                await loop.sock_recv(gcs, 4096)  # its telemetry, at hundreds a second, until it has read ours
            taken = br.received.get("COMMAND_LONG", 0)
            br.close()
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            assert (taken, br.signature_refused) == ((1, 0) if attempt == "first" else (0, 1)), attempt
    finally:
        gcs.close()
