"""The dashboard's Vehicle panel, through the real dashboard websocket (protocol-level tabs with
the headers a browser sends), the real link and the simulated quad's guided flight on UDP: mode,
arming and takeoff from the tab holding control (arming and takeoff pressed twice), a parameter
read by anyone and set by the holder only, and nothing from another tab."""

from __future__ import annotations

import asyncio

import pytest

from drivers.mavlink.link import MavlinkLink
from sim_bridge.bridge import SimBridge
from sim_bridge.scenario import Scenario
from web.dashboard import Dashboard
from web.probe import ViserProbe, gui_id

from .conftest import async_test, free_udp_port


class _Session:
    async def __aenter__(self):
        port = free_udp_port()
        self.bridge = SimBridge(Scenario("quad", seed=6, flight="guided", duration=600), udp_to=("127.0.0.1", port))
        self.link = MavlinkLink(f"udpin:127.0.0.1:{port}", ack_timeout=0.3)
        await self.link.open()
        await self.bridge.open()
        self.dash = Dashboard(port=0, plot_hz=10.0)
        self.panel = self.dash.add_vehicle_panel(self.link)
        self.tasks = [asyncio.create_task(c) for c in (self.bridge.run(), self.dash.run())]
        while 1 not in self.link.vehicles:  # its first heartbeat
            await asyncio.sleep(0.05)
        return self

    async def __aexit__(self, *exc):
        self.bridge.close()
        await self.link.close()
        for t in self.tasks:
            t.cancel()
        await asyncio.gather(*self.tasks, return_exceptions=True)
        self.dash.stop()

    async def press(self, probe: ViserProbe, handle, **updates) -> None:
        await probe.set_gui(gui_id(handle), **(updates or {"value": True}))

    async def said(self, probe: ViserProbe, text: str) -> None:
        """Until the panel's status says ``text``."""
        await probe.until_markdown(gui_id(self.panel.status_md), text)


@pytest.mark.slow
@async_test(timeout=90)
async def test_the_holder_sets_the_mode_arms_and_takes_off_and_another_tab_cannot():
    async with _Session() as s:
        guided = s.bridge.protocol.guided
        async with ViserProbe(s.dash.control_url) as a, ViserProbe(s.dash.url) as viewer:
            await s.press(viewer, s.panel.arm)
            await s.said(viewer, "nobody holds control")
            await s.press(a, s.panel.take)
            await s.said(a, "control held by tab")
            await s.press(viewer, s.panel.take)  # without the token: view only
            await s.said(viewer, "view only")
            await s.press(a, s.panel.mode, value="GUIDED")
            await s.press(a, s.panel.set_mode)
            await s.said(a, "mode GUIDED: accepted by vehicle 1")
            await s.press(a, s.panel.arm)
            await s.said(a, "press ARM again")
            assert not guided.armed
            await s.press(a, s.panel.arm)
            await s.said(a, "arm: accepted by vehicle 1")
            await s.said(a, "**ARMED** · GUIDED")  # as the vehicle's heartbeat says
            await s.press(a, s.panel.altitude, value=2.0)
            await s.press(a, s.panel.takeoff)
            await s.press(a, s.panel.takeoff)
            await s.said(a, "takeoff 2.0: accepted by vehicle 1")
            assert guided.flying

            await s.press(a, s.panel.param_name, value="SIM_DRAG")
            await s.press(viewer, s.panel.param_get)  # reading is open: the parameter the holder named
            await s.said(viewer, "SIM_DRAG = 0.35")
            await s.press(viewer, s.panel.param_value, value=0.45)  # the inputs are the holder's
            await viewer.until_notifications("Not changed", 1)
            await s.press(viewer, s.panel.param_set)  # setting is the holder's
            await viewer.until_notifications("Not yours to command", 1)
            await s.press(a, s.panel.param_value, value=0.45)
            await s.press(a, s.panel.param_set)
            await s.said(a, "SIM_DRAG set to 0.45, confirmed by vehicle 1")
            assert abs(s.bridge.sim.vehicle.p.drag - 0.45) < 1e-6
            await s.press(a, s.panel.param_name, value="NO_SUCH_PARAM")
            await s.press(a, s.panel.param_get)
            await s.said(a, "parameter NO_SUCH_PARAM: no answer")


@async_test(timeout=90)
async def test_a_view_only_tab_cannot_change_what_the_holder_sends():
    """The audit's attack: a view-only tab rewrote the panel's inputs (the holder picked LOITER and
    sent LAND; asked 2 m and took off to 30 m). Its every change is undone on the server and it is
    told; the holder's own values, range-checked there, are what is sent."""
    async with _Session() as s:
        guided = s.bridge.protocol.guided
        async with ViserProbe(s.dash.control_url) as a, ViserProbe(s.dash.url) as viewer:
            await s.press(a, s.panel.take)
            await s.said(a, "control held by tab")
            await s.press(a, s.panel.mode, value="GUIDED")
            await s.press(a, s.panel.altitude, value=2.0)
            await s.press(viewer, s.panel.mode, value="LAND")
            await viewer.until_notifications("Not changed", 1)
            await s.press(viewer, s.panel.altitude, value=30.0)
            await viewer.until_notifications("Not changed", 1)
            assert (s.panel.mode.value, s.panel.altitude.value) == ("GUIDED", 2.0)  # undone for every tab
            await s.press(a, s.panel.altitude, value=1e9)  # a crafted value from the holder's own tab
            await s.said(a, "outside 1-30 m")
            assert s.panel.accepted["altitude"] == 2.0
            await s.press(a, s.panel.set_mode)
            await s.said(a, "mode GUIDED: accepted by vehicle 1")
            await s.press(a, s.panel.arm)
            await s.press(a, s.panel.arm)
            await s.said(a, "arm: accepted by vehicle 1")
            await s.press(a, s.panel.takeoff)
            await s.press(a, s.panel.takeoff)
            await s.said(a, "takeoff 2.0: accepted by vehicle 1")
            assert guided.flying
