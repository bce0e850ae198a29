"""The dashboard's Vehicle panel, through the real dashboard websocket (protocol-level tabs with
the headers a browser sends), the real link and the simulated quad's guided flight on UDP: mode,
arming and takeoff from the tab holding control (arming and takeoff pressed twice), a parameter
read by anyone and set by the holder only, and nothing from another tab."""

from __future__ import annotations

import asyncio
import subprocess

import pytest

from drivers.mavlink.link import MavlinkLink
from sim_bridge.bridge import SimBridge
from sim_bridge.scenario import Scenario
from web.dashboard import Dashboard
from web.probe import CAMERA_REPORT, ViserProbe, gui_id

from .browser import CHROMIUM, Browser
from .conftest import async_test, free_udp_port
from .helpers import until


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


class _ForeignPage:
    """A page served from another origin (another port of this machine) whose script opens the
    dashboard's control websocket, token and all, and sends viser's own messages: a camera report,
    then ``presses`` (each a GuiUpdateMessage, msgpack-encoded here and carried as base64)."""

    def __init__(self, websocket_url: str, presses: list[dict]) -> None:
        import base64
        import http.server
        import json
        import threading

        import msgspec
        import viser

        frames = [base64.b64encode(msgspec.msgpack.encode(m)).decode() for m in (CAMERA_REPORT, *presses)]
        page = f"""<!doctype html><title>elsewhere</title><script>
const ws = new WebSocket({json.dumps(websocket_url)}, ["viser-v{viser.__version__}"]);
ws.onopen = () => {{
  for (const f of {json.dumps(frames)}) ws.send(Uint8Array.from(atob(f), c => c.charCodeAt(0)));
  document.title = "sent";
}};
</script>""".encode()

        class Serve(http.server.BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 - http.server's name
                self.send_response(200)
                self.send_header("Content-Type", "text/html")
                self.end_headers()
                self.wfile.write(page)

            def log_message(self, *args) -> None:
                """Each request unprinted: the test's output is its assertions."""

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Serve)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    def __enter__(self) -> _ForeignPage:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.server.shutdown()
        self.server.server_close()
        self.thread.join()


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (make test installs it)")
@async_test(timeout=120)
async def test_in_chromium_a_view_only_tab_and_a_page_from_elsewhere_command_nothing():
    """The audit's attacks in a real browser. A view-only tab (the dashboard's page without the
    token) presses ARM and moves the takeoff slider with the keyboard, as a user would: told "Not
    yours to command" and "Not changed" in the page, the slider's value goes back to the holder's.
    A page from another origin that knows the token opens the control websocket itself and presses
    ARM twice and sends a 30 m takeoff height: refused as a page from elsewhere. The vehicle stays
    disarmed and the holder's 2 m stands."""
    async with _Session() as s:
        guided = s.bridge.protocol.guided
        async with ViserProbe(s.dash.control_url) as a:
            await s.press(a, s.panel.take)
            await s.said(a, "control held by tab")
            await s.press(a, s.panel.altitude, value=2.0)
            await until(lambda: s.panel.accepted["altitude"] == 2.0, 30.0, "the holder's 2 m accepted")

            async with Browser() as b:
                await b.goto(s.dash.url)
                await b.wait_for_text("TAKEOFF")
                await b.click_button("ARM")
                await b.wait_for_text("Not yours to command")
                thumb = '[role="slider"][aria-valuemax="30"]'  # the takeoff height's, 1-30 m
                assert await b.evaluate(f"document.querySelector('{thumb}').getAttribute('aria-valuenow')") == "2"
                await b.key_on(thumb, "ArrowRight", 39)
                await b.wait_for_text("Not changed")
                assert s.panel.altitude.value == 2.0 and s.panel.accepted["altitude"] == 2.0

                ws_url = s.dash.control_url.partition("websocket=")[2]
                presses = [
                    {"type": "GuiUpdateMessage", "uuid": gui_id(s.panel.arm), "updates": {"value": True}},
                    {"type": "GuiUpdateMessage", "uuid": gui_id(s.panel.arm), "updates": {"value": True}},
                    {"type": "GuiUpdateMessage", "uuid": gui_id(s.panel.altitude), "updates": {"value": 30.0}},
                ]
                before = s.panel.refused
                with _ForeignPage(ws_url, presses) as elsewhere:
                    await b.goto(elsewhere.url)
                    await until(lambda: s.panel.refused == before + 3, 30.0, "the page's three presses refused")
                    await s.said(a, f"a page from {elsewhere.url.rstrip('/')} may not command this vehicle")
            assert f"{before + 3} refused to tabs without control" in s.panel.status_md.content  # the holder is told
            assert not guided.armed
            assert s.panel.altitude.value == 2.0 and s.panel.accepted["altitude"] == 2.0


@pytest.mark.slow
@async_test(timeout=150)
async def test_a_plain_connect_prints_its_control_address_and_its_vehicle_panel_commands():
    """``groundstation connect`` with its dashboard and nothing else said: the control address is
    printed, and the tab opened there takes control and sets the simulated vehicle's mode, which
    the vehicle accepts; a tab at the printed dashboard address views only."""
    import re
    import sys

    from .conftest import free_tcp_port
    from .helpers import running, simulated_vehicle

    port, web = free_udp_port(), free_tcp_port()
    connect = [sys.executable, "-m", "groundstation", "connect", f"udpin:127.0.0.1:{port}", "--port", str(web)]
    connect += ["--no-record"]
    with running(connect, stdout=subprocess.PIPE, text=True) as gs, simulated_vehicle(port, "--flight", "guided"):
        lines: list[str] = []
        while not any(line.startswith("control: ") for line in lines):
            line = await asyncio.wait_for(asyncio.to_thread(gs.stdout.readline), 30)
            assert line, f"connect ended before it printed a control address: {lines}"
            lines.append(line)
        (control,) = [re.match(r"control: (\S+)", line)[1] for line in lines if line.startswith("control: ")]
        (page,) = [re.match(r"dashboard: (\S+)", line)[1] for line in lines if line.startswith("dashboard: ")]
        assert control.startswith(f"{page}/?websocket=")
        async with ViserProbe(control) as a, ViserProbe(page) as viewer:
            (panel, shown), (seen, _) = await _vehicle_panel(a), await _vehicle_panel(viewer)
            assert seen == panel  # the same panel in every tab
            if "vehicle 1: **disarmed**" not in shown:  # not heard yet when the tab opened
                await a.until_markdown(panel["status"], "vehicle 1: **disarmed**", timeout=60)
            await a.set_gui(panel["Take control"], value=True)
            await a.until_markdown(panel["status"], "control held by tab", timeout=30)
            await viewer.set_gui(panel["ARM"], value=True)
            await viewer.until_notifications("Not yours to command", 1)
            await a.set_gui(panel["mode"], value="GUIDED")
            await a.set_gui(panel["Set mode"], value=True)
            await a.until_markdown(panel["status"], "mode GUIDED: accepted by vehicle 1", timeout=30)


async def _vehicle_panel(probe: ViserProbe, timeout: float = 30.0) -> tuple[dict[str, str], str]:
    """The Vehicle panel's elements as a tab receives them from a dashboard in another process:
    each one's label -> its id, and ``status``: the panel's markdown; and that markdown's text as
    it stood when the panel had come (later changes come as updates)."""
    await probe.announce_camera()

    async def read() -> tuple[dict[str, str], str]:
        folder, found, shown = None, {}, ""
        async for _, messages in probe.frames():
            for m in messages:
                props = m.get("props") or {}
                if m["type"] == "GuiFolderMessage" and props.get("label") == "Vehicle":
                    folder = m["uuid"]
                elif m["type"] == "GuiUpdateMessage" and m.get("uuid") == found.get("status"):
                    shown = m["updates"].get("_markdown", shown)
                elif folder is not None and m.get("container_uuid") == folder:
                    if m["type"] == "GuiMarkdownMessage":
                        found["status"], shown = m["uuid"], props.get("_markdown", "")
                    else:
                        found[props.get("label")] = m["uuid"]
            if "Set" in found:  # the panel's last element
                return found, shown
        raise AssertionError(f"the dashboard closed before its Vehicle panel came: {found}")

    return await asyncio.wait_for(read(), timeout)
