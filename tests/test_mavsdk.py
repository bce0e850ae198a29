"""MAVSDK-Python against the simulated vehicle on loopback: a peer nobody here wrote connects,
sees health, position and home, arms, takes off, lands, and sees the vehicle disarm itself.

MAVSDK is pinned in the test extras at the last release whose wheel ships ``mavsdk_server``
(2.x; 3.x and later load a C library instead); the test starts that server itself, so that it
is stopped with the test, and skips with the reason where the binary cannot run here.
"""

from __future__ import annotations

import asyncio
import contextlib
import subprocess
from pathlib import Path

import pytest

from .conftest import async_test, free_tcp_port, free_udp_port
from .helpers import running, simulated_vehicle

mavsdk = pytest.importorskip("mavsdk", reason="MAVSDK-Python is a test extra (pip install -e .[test])")
SERVER = Path(mavsdk.__file__).parent / "bin" / "mavsdk_server"


def _server_runs() -> str | None:
    """Why mavsdk_server cannot run here (None: it can)."""
    if not SERVER.exists():
        return f"this MAVSDK ({mavsdk.__name__}) ships no mavsdk_server; the test extras pin 2.8.0"
    try:
        out = subprocess.run([SERVER, "--help"], capture_output=True, text=True, timeout=10)
    except OSError as e:  # another architecture, or a missing loader
        return f"mavsdk_server cannot run on this machine: {e}"
    return None if "Usage" in out.stdout + out.stderr else f"mavsdk_server --help said: {out.stderr[:200]}"


async def _first(stream, cond, what: str, timeout: float = 30.0):
    """The first value of a MAVSDK telemetry stream that meets ``cond``."""

    async def first():
        async with contextlib.aclosing(stream) as values:  # closed here, not by the collector later
            async for v in values:
                if cond(v):
                    return v
        raise AssertionError(f"the stream of {what} ended")

    done, _ = await asyncio.wait([asyncio.ensure_future(first())], timeout=timeout)
    if not done:
        raise AssertionError(f"not within {timeout} s: {what}")
    return done.pop().result()


# aiogrpc's stream iterators end their executor from its own thread when collected, which raises
# inside their __del__ ("cannot join current thread"), not this test: github.com/mavlink/MAVSDK-Python/issues/698
@pytest.mark.filterwarnings("ignore:Exception ignored in.*WrappedIterator:pytest.PytestUnraisableExceptionWarning")
@pytest.mark.slow
def test_mavsdk_connects_sees_health_and_position_arms_takes_off_and_lands():
    reason = _server_runs()
    if reason is not None:
        pytest.skip(reason)
    port, grpc = free_udp_port(), free_tcp_port()
    sim = ("--flight", "guided", "--sysid", "1", "--duration", "120")
    server = [SERVER, "-p", str(grpc), f"udp://:{port}"]
    with simulated_vehicle(port, *sim), running(server):
        _fly(grpc)  # async_test: on its own event loop, bounded in time


@async_test(timeout=120)
async def _fly(grpc: int) -> None:
    from mavsdk import System

    drone = System(mavsdk_server_address="127.0.0.1", port=grpc)
    await drone.connect()
    await _first(drone.core.connection_state(), lambda s: s.is_connected, "a connection")
    health = await _first(
        drone.telemetry.health(),
        lambda h: h.is_global_position_ok and h.is_home_position_ok and h.is_armable,
        "health: global position, home, armable",
    )
    assert health.is_gyrometer_calibration_ok and health.is_accelerometer_calibration_ok
    home = await _first(drone.telemetry.home(), lambda p: True, "home")
    assert home.latitude_deg == pytest.approx(47.397742, abs=1e-6)
    on_ground = await _first(drone.telemetry.landed_state(), lambda s: True, "the landed state")
    assert on_ground.name == "ON_GROUND"
    await drone.action.arm()
    await drone.action.set_takeoff_altitude(3.0)
    await drone.action.takeoff()
    await _first(drone.telemetry.in_air(), bool, "in the air")
    p = await _first(drone.telemetry.position(), lambda p: p.relative_altitude_m > 2.7, "3 m up")
    assert p.absolute_altitude_m == pytest.approx(home.absolute_altitude_m + p.relative_altitude_m, abs=0.05)
    await drone.action.land()
    await _first(drone.telemetry.in_air(), lambda a: not a, "landed")
    await _first(drone.telemetry.armed(), lambda a: not a, "disarmed after the landing")
