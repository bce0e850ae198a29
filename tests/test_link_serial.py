"""The MAVLink link over a real pseudo-terminal opened by pyserial: unplug and replug."""

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers.mavlink.link import LinkState, MavlinkLink
from drivers.transports import TransportError
from groundstation.core.measurement import Kind
from sim_bridge.mavlink_vehicle import MavlinkVehicle
from sim_bridge.pty_port import PtyPort

from .conftest import async_test
from .test_link_udp import _next_state, _take


@async_test(timeout=30)
async def test_serial_link_survives_unplug_and_replug(tmp_path):
    port = PtyPort(tmp_path / "ttyVEHICLE")  # a stable name, like /dev/serial/by-id/...
    port.plug()
    veh = MavlinkVehicle(pty=port)
    await veh.open()
    link = MavlinkLink(f"{port.path},115200", record=tmp_path / "s.tlog", streams={})
    sub, events = link.measurements(), link.events()
    await link.open()
    try:
        veh.heartbeat()
        await _next_state(events, LinkState.ALIVE)
        for i in range(10):
            veh.send(mavlink.MAVLink_distance_sensor_message(1000 + i, 10, 500, 100 + i, 0, 0, 25, 0))
        got = await _take(sub, 11)
        assert [m.value[0] for m in got if m.kind is Kind.RANGE] == pytest.approx([1.0 + 0.01 * i for i in range(10)])
        await veh.wait_for("HEARTBEAT")  # GCS heartbeat came down the serial line

        port.unplug()  # the USB radio is pulled out
        lost = await _next_state(events, LinkState.LOST)
        assert "ttyVEHICLE" in lost.reason or "/dev/pts" in lost.reason
        link.recorder.flush()
        conn = mavutil.mavlink_connection(str(tmp_path / "s.tlog"))
        n = 0
        while conn.recv_match(type="DISTANCE_SENSOR") is not None:
            n += 1
        assert n == 10  # nothing recorded so far is lost

        port.plug()  # ... and plugged back in
        await veh.open()
        veh.start_heartbeat(10.0)  # pyserial flushes input on open
        await _next_state(events, LinkState.ALIVE, timeout=10)
        veh.send(mavlink.MAVLink_distance_sensor_message(2000, 10, 500, 250, 0, 0, 25, 0))
        got = await _take(sub, 2)
        assert any(m.kind is Kind.RANGE and m.value[0] == pytest.approx(2.5) for m in got)
    finally:
        await link.close()
        veh.close()


@async_test()
async def test_missing_serial_port_is_a_clear_error():
    link = MavlinkLink("/dev/ttyDOES_NOT_EXIST,57600")
    with pytest.raises(TransportError, match="no such device"):
        await link.open()
