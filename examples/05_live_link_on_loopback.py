"""A live MAVLink link, MAVSDK-style: the simulated quadcopter on loopback UDP, its measurements
as an ``async for`` stream, and the altitude filter estimating as they arrive.

    python examples/05_live_link_on_loopback.py [--seconds 10]

The link listens on a free port (``udpin:127.0.0.1:0``), the simulated vehicle sends to it in
real time, the link asks it for its streams (SET_MESSAGE_INTERVAL), and the estimation loop
attaches to the link's receive path. What a real vehicle or SITL on ``udpin:0.0.0.0:14550`` gives,
without hardware.
"""

import argparse
import asyncio
import contextlib
from collections import Counter

from drivers.mavlink.link import MavlinkLink
from groundstation.estimation.loop import EstimationLoop
from groundstation.estimation.registry import build_estimator
from sim_bridge.bridge import SimBridge
from sim_bridge.scenario import Scenario


async def main(seconds: float) -> None:
    async with MavlinkLink("udpin:127.0.0.1:0") as link:
        loop = EstimationLoop([build_estimator("altitude", declared=[{"name": "range_tilt"}])])
        loop.attach_link(link)
        port = link.transport.local_address[1]
        bridge = SimBridge(Scenario("quad", seed=1, duration=seconds), udp_to=("127.0.0.1", port))
        await bridge.open()
        flying = asyncio.create_task(bridge.run(seconds))
        kinds: Counter = Counter()
        measurements = link.measurements()

        async def count():
            async for m in measurements:
                kinds[m.kind.value] += 1

        counting = asyncio.create_task(count())
        try:
            await flying
        finally:
            bridge.close()
            counting.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await counting
    snap = loop.latest.get("altitude")
    print(
        f"{link.counters.messages} messages, loss {link.counters.loss_percent:.1f} %, streams via "
        f"{link.stream_method.get(1, 'none')}"
    )
    print("measurements by kind: " + ", ".join(f"{k} {n}" for k, n in kinds.most_common(8)))
    if snap is not None:
        print(f"altitude at t = {snap.t:.2f} s: z = {snap.x[0]:+.3f} ± {snap.sigma[0]:.3f} m")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    asyncio.run(main(ap.parse_args().seconds))
