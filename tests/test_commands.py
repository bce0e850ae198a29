"""``groundstation command``: arm, mode, takeoff, land against the simulated vehicle (a process on
loopback UDP), each with the vehicle's ACK as one line; the motors start only with --yes."""

from __future__ import annotations

import subprocess
import sys

import pytest

from .conftest import free_udp_port
from .helpers import simulated_vehicle


@pytest.mark.slow
def test_commands_and_their_one_line_results():
    port = free_udp_port()
    gs = [sys.executable, "-m", "groundstation", "command", f"udpin:127.0.0.1:{port}"]

    def run(*args):
        return subprocess.run(gs + list(args), capture_output=True, text=True, timeout=60)

    with simulated_vehicle(port, "--sysid", "4", "--duration", "600"):  # stopped by the test: not a deadline
        r = run("arm")
        assert r.returncode == 2 and "arm starts the motors: add --yes to confirm" in r.stderr
        assert run("arm", "--yes").stdout.strip() == "arm: accepted by vehicle 4"
        assert run("mode", "guided").stdout.strip() == "mode guided: accepted by vehicle 4"
        r = run("mode", "POSITION")
        assert r.returncode == 2 and "not an ArduCopter mode" in r.stderr and "Traceback" not in r.stderr
        assert run("takeoff", "2.5", "--yes").stdout.strip() == "takeoff 2.5: accepted by vehicle 4"
        r = run("takeoff", "500", "--yes")
        assert r.returncode == 2 and "an altitude in (0, 120] m" in r.stderr
        assert run("land").stdout.strip() == "land: accepted by vehicle 4"
        r = run("arm", "--yes", "--sysid", "9")  # nobody is vehicle 9
        assert r.returncode == 2 and "no heartbeat from vehicle 9" in r.stderr
