"""The parameter protocol from the ground station's side, against the simulated vehicle over real
loopback UDP: every parameter fetched over a link that loses a fifth of the vehicle's frames, a
set confirmed by the vehicle's echo, and the files MAVProxy and QGroundControl write."""

from __future__ import annotations

import asyncio
import subprocess
import sys

import pytest

from drivers.mavlink.link import MavlinkLink
from drivers.mavlink.params import ParamClient, ParamError, load, save
from sim_bridge.bridge import LinkFaults, SimBridge
from sim_bridge.scenario import Scenario

from .conftest import async_test, free_udp_port
from .helpers import simulated_vehicle


@pytest.mark.slow
@async_test(timeout=60)
async def test_fetch_all_set_and_get_at_twenty_percent_loss(tmp_path):
    link = MavlinkLink("udpin:127.0.0.1:0", streams={})
    await link.open()
    br = SimBridge(
        Scenario("quad", seed=3), udp_to=("127.0.0.1", link.transport.local_address[1]), faults=LinkFaults(loss=0.2)
    )
    await br.open()
    task = asyncio.get_running_loop().create_task(br.run())
    try:
        while 1 not in link.vehicles:  # the vehicle's first heartbeat
            await asyncio.sleep(0.02)
        client = ParamClient(link, 1, timeout=0.5)
        seen = []
        values = await client.fetch_all(lambda n, total: seen.append((n, total)))
        assert len(values) == client.count == len(br.protocol.params) and br.frames_dropped > 0
        assert values["SIM_ALPHA"] == pytest.approx(22.0) and seen[-1][0] == seen[-1][1]
        assert await client.set("SIM_DRAG", 0.42) == pytest.approx(0.42)
        assert br.sim.vehicle.p.drag == pytest.approx(0.42)  # the running simulation took it
        assert await client.get("SIM_DRAG") == pytest.approx(0.42)
        with pytest.raises(ParamError, match="NO_SUCH_PARAM: no answer"):
            await client.get("NO_SUCH_PARAM")
        assert await client.set("BARO1_THST_SCALE", -35.5) == pytest.approx(-35.5)  # what a diagnosis writes
        assert br.autopilot["BARO1_THST_SCALE"] == pytest.approx(-35.5)
        with pytest.raises(ParamError, match=r"BARO1_THST_SCALE: set to 500 not confirmed \(the vehicle says -35.5"):
            await client.set("BARO1_THST_SCALE", 500.0)  # outside ArduPilot's documented -300..300: refused
        for qgc in (False, True):
            f = tmp_path / f"p{qgc}.params"
            save(f, values, qgc=qgc, types=client.types)
            assert load(f) == pytest.approx(values)
        client.close()
    finally:
        br.close()
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await link.close()


def test_a_file_that_is_not_parameters_is_a_one_line_error(tmp_path):
    f = tmp_path / "x.param"
    f.write_text("SIM_ALPHA 22\nthis is not\n")
    with pytest.raises(ParamError, match=r"x.param:2: not a parameter line"):
        load(f)
    mp = tmp_path / "mp.param"  # Mission Planner's commas
    mp.write_text("# Mission Planner\nSIM_ALPHA,22.5\nSIM_DRAG,0.3\n")
    assert load(mp) == {"SIM_ALPHA": 22.5, "SIM_DRAG": 0.3}


@pytest.mark.slow
def test_param_command_fetches_to_a_file_and_loads_it_back(tmp_path):
    """``groundstation param`` against ``groundstation sim`` (two processes on loopback, both
    stopped by the test)."""
    port = free_udp_port()
    gs = [sys.executable, "-m", "groundstation", "param", f"udpin:127.0.0.1:{port}"]
    with simulated_vehicle(port, "--sysid", "3", "--duration", "60"):
        out = tmp_path / "v.params"
        r = subprocess.run(gs + ["fetch", "--out", str(out), "--qgc"], capture_output=True, text=True, timeout=60)
        assert r.returncode == 0 and "parameters of vehicle 3 written" in r.stdout, r.stderr
        rows = [ln.split("\t") for ln in out.read_text().splitlines() if not ln.startswith("#")]
        assert all(row[0] == "3" and row[1] == "1" for row in rows) and "SIM_ALPHA" in {row[2] for row in rows}
        edited = tmp_path / "edited.param"
        edited.write_text("SIM_ALPHA 21.5\nSIM_DRAG 0.33\n")
        r = subprocess.run(gs + ["load", str(edited)], capture_output=True, text=True, timeout=60)
        assert r.returncode == 0 and "2 parameters set and confirmed" in r.stdout, r.stderr
        r = subprocess.run(gs + ["get", "SIM_ALPHA", "SIM_DRAG"], capture_output=True, text=True, timeout=60)
        assert r.stdout.split() == ["SIM_ALPHA", "21.5", "SIM_DRAG", "0.33"], r.stderr
