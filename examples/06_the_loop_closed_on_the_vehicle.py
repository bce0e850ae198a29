"""The mission's loop closed on a vehicle: fly, download the log, diagnose it, load the parameters,
fly again, and see the vehicle's own height estimate improve.

    python examples/06_the_loop_closed_on_the_vehicle.py [--seconds 40] [--speed 5]

The simulated quadcopter (its guided flight, as ArduCopter SITL flies it) has a barometer that
reads the rotor wash (``baro_thrust``, k = 3 m per unit throttle), told to nobody. Its autopilot
estimates its height from that barometer (``sim_bridge/onboard_height.py``, as ArduCopter's EKF3
does by default), so its own estimate, what it sends as GLOBAL_POSITION_INT, is wrong in flight.
Every step goes over real MAVLink on loopback UDP, as it would with a vehicle:

1. arm, take off, climb and descend, land (``drivers.mavlink.commands``);
2. download the flight's DataFlash log (MAVLink's log protocol, ``drivers.mavlink.log_transfer``);
3. ``groundstation diagnose`` the log: it names the effect and writes ``params_ardupilot.param``;
4. load the parameters into the vehicle (the parameter protocol, each set confirmed);
5. fly the same flight again.

Printed: the vehicle's own height error against the simulator's truth on each flight (RMS over the
flight, from GLOBAL_POSITION_INT), the effect found and the parameters loaded.
"""

import argparse
import asyncio
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from drivers.mavlink.commands import run_command
from drivers.mavlink.link import MavlinkLink
from drivers.mavlink.log_transfer import LogClient
from drivers.mavlink.params import ParamClient, load
from groundstation.core.measurement import Kind
from sim_bridge.bridge import SimBridge
from sim_bridge.scenario import Scenario


class HeightError:
    """The vehicle's reported height (GLOBAL_POSITION_INT's relative altitude) against the
    simulator's truth at the same vehicle time."""

    def __init__(self, link: MavlinkLink, bridge: SimBridge) -> None:
        self.truth: list[tuple[float, float]] = []
        self.errors: list[float] = []
        bridge.truth_sink = lambda row: self.truth.append((row["t"], row["h"]))
        self._positions = link.measurements()
        self.task = asyncio.create_task(self._read())

    async def _read(self) -> None:
        async for m in self._positions:
            if m.kind is not Kind.GLOBAL_POSITION or len(self.truth) < 2:
                continue
            ts, hs = zip(*self.truth[-300:], strict=True)
            if ts[0] <= m.t <= ts[-1]:
                self.errors.append(float(m.value[3]) - float(np.interp(m.t, ts, hs)))

    def take(self) -> tuple[float, int]:
        """The RMS error since the last take [m], and of how many estimates."""
        e, self.errors = np.asarray(self.errors), []
        return (float(np.sqrt(np.mean(e**2))) if e.size else float("nan")), int(e.size)


async def until(cond, timeout: float = 120.0) -> None:
    async def wait():
        while not cond():
            await asyncio.sleep(0.02)

    await asyncio.wait_for(wait(), timeout)


async def fly(link: MavlinkLink, bridge: SimBridge, seconds: float) -> None:
    """Arm, take off to 3 m, climb to 8 m, down to 2 m, up to 5 m, land: ``seconds`` in the air."""
    sim, guided = bridge.sim, bridge.protocol.guided
    await run_command(link, 1, 1, "mode", "GUIDED")
    await run_command(link, 1, 1, "arm")
    start = sim.t
    await until(lambda: sim.t > start + 2.0)  # idling on the ground: the log's still stretch
    await run_command(link, 1, 1, "takeoff", 3.0)
    leg = seconds / 4
    for height in (8.0, 2.0, 5.0):
        t0 = sim.t
        await until(lambda t0=t0: sim.t > t0 + leg)
        await run_command(link, 1, 1, "takeoff", height)  # in the air: climb or descend to it
    t0 = sim.t
    await until(lambda: sim.t > t0 + leg)
    await run_command(link, 1, 1, "land")
    await until(lambda: not guided.armed)  # landed: disarmed, the log closed


async def main(seconds: float, speed: float) -> None:
    out = Path(tempfile.mkdtemp(prefix="gs-loop-"))
    scenario = Scenario.from_args("quad", 11, 3600.0, [], ["baro_thrust:k=3"], flight="guided")
    async with MavlinkLink("udpin:127.0.0.1:0") as link:
        bridge = SimBridge(scenario, udp_to=("127.0.0.1", link.transport.local_address[1]), speed=speed)
        await bridge.open()
        running = asyncio.create_task(bridge.run())
        try:
            await until(lambda: 1 in link.vehicles, 10.0)
            err = HeightError(link, bridge)
            await fly(link, bridge, seconds)
            before, n = err.take()
            print(f"flight 1: the vehicle's own height error {100 * before:.1f} cm RMS ({n} estimates)")

            logs = LogClient(link, 1)
            entry = (await logs.list())[-1]
            log = out / f"flight{entry.id}.bin"
            log.write_bytes(await logs.download(entry))
            logs.close()
            print(f"downloaded log {entry.id}: {entry.size:,d} bytes")

            report = out / "diagnosis"
            r = subprocess.run(
                [sys.executable, "-m", "groundstation", "diagnose", str(log), "--out", str(report)],
                capture_output=True,
                text=True,
            )
            if r.returncode != 0:
                raise SystemExit(f"diagnose failed: {r.stderr.strip()}")
            said = (r.stdout + r.stderr).splitlines()
            print("diagnosis: " + (", ".join(ln.strip() for ln in said if ln.strip().startswith("added")) or "nothing"))
            param_file = report / "params_ardupilot.param"
            wanted = load(param_file) if param_file.exists() else {}  # nothing to set: nothing written
            if not wanted:
                print("nothing to load: the diagnosis wrote no parameter")
            params = ParamClient(link, 1)
            for name, value in wanted.items():
                await params.set(name, value)
                print(f"loaded {name} = {value:g} (confirmed by the vehicle)")
            params.close()

            await fly(link, bridge, seconds)
            after, n = err.take()
            print(f"flight 2: the vehicle's own height error {100 * after:.1f} cm RMS ({n} estimates)")
            err.task.cancel()
            print(f"the vehicle's own height error: {100 * before:.1f} cm before, {100 * after:.1f} cm after")
        finally:
            bridge.close()
            running.cancel()
            await asyncio.gather(running, return_exceptions=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=40.0, help="time in the air a flight [s]")
    ap.add_argument("--speed", type=float, default=5.0, help="the simulated world's speed (x real time)")
    args = ap.parse_args()
    asyncio.run(main(args.seconds, args.speed))
