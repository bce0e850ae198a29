"""The simulated vehicle as a ground station sees it, beyond its telemetry: an ArduPilot-like
HEARTBEAT, parameters, commands with addressed ACKs, modes, arming, its version, ping, the mission
protocol and the guided flight; driven by pymavlink frames over a real UDP socket, and by MAVProxy
itself."""

from __future__ import annotations

import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .conftest import free_udp_port
from .helpers import running, simulated_vehicle

GS = [sys.executable, "-m", "groundstation"]
ME_SYS, ME_COMP = 250, 190  # the test's own MAVLink address: ACKs must name it
HOME = (47.397742, 8.545594)  # the simulator's GPS origin (sim_bridge/sensors.py)


def _recv(c, kind: str, cond=lambda m: True, timeout: float = 10.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        m = c.recv_match(type=kind, blocking=True, timeout=end - time.monotonic())
        if m is not None and cond(m):
            return m
    raise AssertionError(f"no {kind} within {timeout} s")


def _ack(c, command: int):
    return _recv(c, "COMMAND_ACK", lambda m: m.command == command)


@pytest.mark.slow
def test_parameters_commands_and_acks_over_real_frames():
    port = free_udp_port()
    c = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=ME_SYS, source_component=ME_COMP)
    try:
        with simulated_vehicle(port, "--sysid", "7", "--duration", "120"):
            hb = _recv(c, "HEARTBEAT", lambda m: m.get_srcSystem() == 7)
            assert hb.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA and hb.type == mavlink.MAV_TYPE_QUADROTOR
            c.target_system, c.target_component = 7, 1
            # parameters: all of them, one read, one set that changes the running simulation
            c.mav.param_request_list_send(7, 1)
            first = _recv(c, "PARAM_VALUE")
            names = {first.param_id: first.param_value}
            while len(names) < first.param_count:
                m = _recv(c, "PARAM_VALUE")
                names[m.param_id] = m.param_value
            assert names["SYSID_THISMAV"] == 7 and names["SIM_ALPHA"] == pytest.approx(22.0)
            assert {"SIM_S_BARO_SIGMA", "SIM_RATE_IMU"} <= set(names)
            c.mav.param_set_send(7, 1, b"SIM_ALPHA", 23.5, mavlink.MAV_PARAM_TYPE_REAL32)
            assert _recv(c, "PARAM_VALUE", lambda m: m.param_id == "SIM_ALPHA").param_value == pytest.approx(23.5)
            c.mav.param_request_read_send(7, 1, b"SIM_ALPHA", -1)
            assert _recv(c, "PARAM_VALUE", lambda m: m.param_id == "SIM_ALPHA").param_value == pytest.approx(23.5)
            # commands: each ACK names us; the state shows in the next HEARTBEAT
            c.mav.command_long_send(7, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 4, 0, 0, 0, 0, 0)
            ack = _ack(c, mavlink.MAV_CMD_DO_SET_MODE)
            assert ack.result == mavlink.MAV_RESULT_ACCEPTED
            assert (ack.target_system, ack.target_component) == (ME_SYS, ME_COMP)
            _recv(c, "HEARTBEAT", lambda m: m.get_srcSystem() == 7 and m.custom_mode == 4)
            c.mav.command_long_send(7, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            assert _ack(c, mavlink.MAV_CMD_COMPONENT_ARM_DISARM).result == mavlink.MAV_RESULT_ACCEPTED
            _recv(c, "HEARTBEAT", lambda m: m.get_srcSystem() == 7 and m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            c.mav.command_long_send(7, 1, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 2)
            assert _ack(c, mavlink.MAV_CMD_NAV_TAKEOFF).result == mavlink.MAV_RESULT_ACCEPTED
            c.mav.command_long_send(7, 1, mavlink.MAV_CMD_DO_SET_SERVO, 0, 5, 1500, 0, 0, 0, 0, 0)
            assert _ack(c, mavlink.MAV_CMD_DO_SET_SERVO).result == mavlink.MAV_RESULT_UNSUPPORTED
            msgid = mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION
            c.mav.command_long_send(7, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, msgid, 0, 0, 0, 0, 0, 0)
            v = _recv(c, "AUTOPILOT_VERSION")
            assert v.flight_sw_version >> 24 == 4 and v.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            # ping, the mission list, the state and the sensors' health
            c.mav.ping_send(123456, 9, 0, 0)
            pong = _recv(c, "PING", lambda m: m.seq == 9 and m.target_system == ME_SYS)
            assert pong.time_usec == 123456
            c.mav.mission_request_list_send(7, 1)
            assert _recv(c, "MISSION_COUNT").count == 0
            assert _recv(c, "EXTENDED_SYS_STATE").landed_state in (
                mavlink.MAV_LANDED_STATE_ON_GROUND,
                mavlink.MAV_LANDED_STATE_IN_AIR,
            )
            st = _recv(c, "SYS_STATUS")
            want = mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_GPS
            assert st.onboard_control_sensors_health & want == want
    finally:
        c.close()


#: MAVProxy, from the test extras (installed beside this Python by make test)
MAVPROXY = Path(sys.executable).parent / "mavproxy.py"


@pytest.mark.slow
def test_mavproxy_fetches_parameters_sets_one_uploads_a_mission_and_the_vehicle_flies_it(tmp_path):
    """MAVProxy 1.8 (its param, mode, arm, wp, cmdlong and ftp modules) against the simulator's guided
    flight on loopback, scripted through its console: parameters fetched and one set, a mission
    uploaded and listed back, then armed and flown in AUTO until it lands and disarms."""
    port = free_udp_port()
    lines: queue.Queue[str] = queue.Queue()
    seen: list[str] = []

    def until(text: str, timeout: float = 30.0) -> str:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                ln = lines.get(timeout=end - time.monotonic())
            except queue.Empty:
                break
            seen.append(ln)
            if text in ln:
                return ln
        raise AssertionError(f"MAVProxy never said {text!r}:\n" + "".join(seen[-30:]))

    mavproxy = [
        MAVPROXY,
        f"--master=udpin:127.0.0.1:{port}",
        f"--state-basedir={tmp_path}",
        "--default-modules=param,mode,arm,wp,cmdlong,ftp",
    ]
    pipes = {
        "stdin": subprocess.PIPE,
        "stdout": subprocess.PIPE,
        "stderr": subprocess.STDOUT,
        "text": True,
        "bufsize": 1,
    }
    with (
        running(mavproxy, **pipes) as mp,
        simulated_vehicle(port, "--sysid", "7", "--duration", "120", "--flight", "guided"),
    ):
        threading.Thread(target=lambda: [lines.put(ln) for ln in mp.stdout], daemon=True).start()

        def say(cmd: str) -> None:
            mp.stdin.write(cmd + "\n")
            mp.stdin.flush()

        until("Detected vehicle 7:1")
        t0 = time.monotonic()
        n = int(until("Received ").split("Received ")[1].split()[0])
        # MAVProxy asks for the parameter file by MAVFTP first: refused at once, it turns to the
        # parameter protocol (unanswered, it waits out its FTP timeouts: 12 s more here)
        assert n > 30 and time.monotonic() - t0 < 8.0
        say("param set SIM_DRAG 0.4")
        # MAVProxy queues a set for its idle loop and sends a "param fetch" at once, so the first
        # replies may predate the set: ask the vehicle again after each reply until it holds the value
        end = time.monotonic() + 30.0
        while True:
            say("param fetch SIM_DRAG")
            if float(until("SIM_DRAG = ").split("=")[1]) == pytest.approx(0.4):
                break
            assert time.monotonic() < end, "the vehicle never took the set value"
        say("wp list")
        until("Requesting 0 waypoints")
        # a mission in MAVProxy's file format (item 0 home): take off to 3 m, 5 m north, land
        wpl = tmp_path / "mission.txt"
        rows = [(0, 1, 0, 16, 0, HOME[0], HOME[1], 120.0), (1, 0, 3, 22, 0, 0, 0, 3.0),
                (2, 0, 3, 16, 0, HOME[0] + 5 / 111_320, HOME[1], 3.0), (3, 0, 3, 21, 0, 0, 0, 0.0)]  # fmt: skip
        wpl.write_text("QGC WPL 110\n" + "".join(
            f"{i}\t{cur}\t{frame}\t{cmd}\t{p1}\t0\t0\t0\t{lat:.7f}\t{lon:.7f}\t{alt}\t1\n"
            for i, cur, frame, cmd, p1, lat, lon, alt in rows))  # fmt: skip
        say(f"wp load {wpl}")
        until("Loaded 4 waypoints in")
        say("wp list")
        until("Requesting 4 waypoints")
        say("arm throttle")
        until("COMPONENT_ARM_DISARM: ACCEPTED")
        say("mode AUTO")
        until("DO_SET_MODE: ACCEPTED")
        until("waypoint 2")  # the take-off flown, on to the waypoint (MISSION_CURRENT)
        until("waypoint 3", timeout=60)  # the waypoint reached, landing
        until("DISARMED", timeout=60)  # on the ground, the motors stopped: the mission flown
        assert (tmp_path / "mav_7_1.parm").exists()  # MAVProxy saved the parameters it fetched
