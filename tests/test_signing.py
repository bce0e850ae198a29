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

from drivers.mavlink.link import MavlinkLink
from drivers.mavlink.signing import SignatureCheck, signing_key
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
    assert br._parser.signing.goodsig_count > 0 and br._parser.signing.badsig_count == 0


@pytest.mark.parametrize("key", [signing_key("wrong"), None], ids=["wrong key", "no key"])
@async_test(timeout=60)
async def test_a_wrong_key_or_none_is_refused(key):
    link, br = await _session(key, 3.0)
    assert br.sim.sensors.rates["imu"] == 500.0  # nothing we sent was taken
    assert br.received.get("COMMAND_LONG", 0) == 0 and br.signature_refused > 0  # our frames, refused
    if key is not None:  # we check: the vehicle's frames, signed with its key, are refused and counted
        c = link.counters
        assert not link.vehicles and c.messages == 0 and c.signature_refused >= 0.8 * br.frames_sent > 10


def test_signature_check_refuses_replays_and_unsigned_frames():
    enc = mavlink.MAVLink(None, 1, 1)
    enc.signing.secret_key, enc.signing.sign_outgoing, enc.signing.timestamp = KEY, True, 1000
    frame = bytes(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(enc))
    check = SignatureCheck(KEY)
    assert check.accept(frame, 0, 1, 1)
    assert not check.accept(frame, 0, 1, 1) and check.bad == 1  # the same timestamp again: a replay
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
