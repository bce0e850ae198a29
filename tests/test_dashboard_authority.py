"""Control from the dashboard needs authority: the session's token, the dashboard's own page as
origin, and holding control. Through the real dashboard websocket (protocol-level tabs with the
headers a browser sends), the real control station and commander, and the simulated quad on UDP."""

from __future__ import annotations

import asyncio
import math
import subprocess
import sys

import pytest

from drivers.mavlink.link import MavlinkLink
from groundstation.control.station import ControlStation
from sim_bridge.bridge import SimBridge
from sim_bridge.scenario import Scenario
from web.authority import Authority, RemoteRefused
from web.dashboard import Dashboard
from web.probe import ViserProbe, gui_id

from .conftest import async_test, free_udp_port


class _Session:
    """The simulated quad, a link, a control station and a dashboard; all stopped on exit."""

    async def __aenter__(self):
        port = free_udp_port()
        self.bridge = SimBridge(Scenario("quad", seed=6), udp_to=("127.0.0.1", port))
        self.link = MavlinkLink(f"udpin:127.0.0.1:{port}", lost_after=1.0)
        self.station = ControlStation("quad", self.link)
        sub = self.link.measurements()
        await self.link.open()
        await self.bridge.open()
        self.dash = Dashboard(port=0, plot_hz=10.0)
        self.panel = self.dash.add_control(self.station)
        self.tasks = [
            asyncio.create_task(c)
            for c in (self.bridge.run(), self.dash.run(), self.station.follow(sub), self.station.run())
        ]
        self.notes = self.station.notes.subscribe()
        fresh = self.link.measurements()
        k = 0
        async for _ in fresh:  # a live link with fresh estimates
            k += 1
            if k >= 300:
                break
        fresh.close()
        return self

    async def __aexit__(self, *exc):
        self.station.stop()
        self.bridge.close()
        await self.link.close()
        for t in self.tasks[:2]:
            t.cancel()
        await asyncio.gather(*self.tasks, return_exceptions=True)
        self.dash.stop()

    async def press(self, probe: ViserProbe, handle, **updates) -> None:
        await probe.set_gui(gui_id(handle), **(updates or {"value": True}))

    async def settled(self, probe: ViserProbe, text: str) -> None:
        """Until the panel's status says ``text`` (the callbacks run as viser receives them)."""
        await probe.until_markdown(gui_id(self.panel.status_md), text)


@async_test(timeout=60)
async def test_a_page_from_another_origin_cannot_arm_even_with_the_token():
    """What the audit did: a client sending ``Origin: http://evil.example`` (any web page open in the
    operator's browser can) armed ``demo --control`` and raised z_c to 5 m. It is view only now: its
    Take control, ARM and slider are ignored, and the commander never arms."""
    async with _Session() as s:
        async with ViserProbe(s.dash.control_url, origin="http://evil.example") as evil:
            await s.press(evil, s.panel.take)
            await s.settled(evil, "a page from http://evil.example may not command")
            await s.press(evil, s.panel.arm)
            await s.press(evil, s.panel.arm)
            await s.press(evil, s.panel.sliders["z_c"], value=5.0)
            await evil.until_notifications("Not yours to command", 3)  # each handled, and refused
        assert not s.station.commander.armed and s.station.commander.reference["z_c"] == 1.0
        assert s.dash.authority.holder is None and s.station.uplink.sent == 0


@async_test(timeout=60)
async def test_without_the_token_a_tab_views_and_cannot_command():
    async with _Session() as s:
        async with ViserProbe(s.dash.url) as viewer:
            await s.press(viewer, s.panel.take)
            await s.settled(viewer, "view only: open the control address")
            await s.press(viewer, s.panel.arm)
            await s.press(viewer, s.panel.arm)
            await viewer.until_notifications("Not yours to command", 2)  # both presses handled, refused
        assert not s.station.commander.armed and s.station.uplink.sent == 0


@async_test(timeout=90)
async def test_one_tab_holds_control_arm_asks_twice_and_a_nan_reference_is_refused():
    """Tab A takes control; one press of ARM arms nothing, the second arms. Tab B (also with the
    token) sees that A holds control and its DISARM is ignored until it takes control over, which
    the panel says. A NaN slider value from the holder is refused: the reference and the armed
    commander's commands stay finite."""
    async with _Session() as s:
        async with ViserProbe(s.dash.control_url) as a, ViserProbe(s.dash.control_url) as b:
            await s.press(a, s.panel.take)
            await s.settled(a, "control held by tab")
            holder = s.dash.authority.holder
            await s.press(a, s.panel.arm)
            await s.settled(a, "press ARM again")
            assert not s.station.commander.armed
            await s.press(a, s.panel.arm)
            assert (await asyncio.wait_for(s.notes.__anext__(), 5.0)).startswith("armed")

            await s.press(a, s.panel.sliders["z_c"], value=math.nan)
            await s.settled(a, "must be a finite number")
            assert s.station.commander.reference["z_c"] == 1.0 and s.station.commander.armed
            for crafted in (1e9, -1e9, 20.0):  # the audit's: a slider of 0.3-5.0 sent anything
                await s.press(a, s.panel.sliders["z_c"], value=crafted)
                await s.settled(a, f"z_c = {crafted:g} is outside 0.3 to 5")
                assert s.station.commander.reference["z_c"] == 1.0

            await s.press(b, s.panel.disarm)
            await s.settled(b, f"tab {holder} holds control; press Take control first")
            assert s.station.commander.armed
            await s.press(b, s.panel.take)
            await s.settled(b, f"took control over from tab {holder}")
            await s.press(b, s.panel.disarm)
            assert (await asyncio.wait_for(s.notes.__anext__(), 5.0)).startswith("disarmed: by the user")
        records = s.station.commander.records.subscribe()
        assert all(math.isfinite(float(r.command[0])) for r in records.get_nowait())


def test_a_dashboard_on_the_network_needs_allow_remote():
    with pytest.raises(RemoteRefused, match="pass --allow-remote"):
        Dashboard(host="0.0.0.0", port=0)
    auth = Authority("0.0.0.0", 8080, allow_remote=True)
    assert auth.control_url.endswith(f"/control/{auth.token}") and len(auth.token) >= 24
    # another session's token, a host the dashboard does not serve on (DNS rebinding): refused
    assert "token" in Authority("127.0.0.1", 8080).refusal(f"/control/{auth.token}", {"Host": "127.0.0.1:8080"})
    local = Authority("127.0.0.1", 8080)
    assert "not this dashboard's address" in local.refusal(f"/control/{local.token}", {"Host": "evil.example:8080"})
    assert (
        local.refusal(f"/control/{local.token}", {"Host": "localhost:8080", "Origin": "http://localhost:8080"}) is None
    )


def test_the_command_line_refuses_a_network_dashboard_in_one_line(tmp_path):
    """Said from the arguments, before anything starts: no recording begun (the demo's own file)."""
    r = subprocess.run(
        [sys.executable, "-m", "groundstation", "demo", "--host", "0.0.0.0", "--duration", "1"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("groundstation: error: dashboard on 0.0.0.0")
    assert not (tmp_path / "out").exists()


def test_a_request_naming_its_host_or_origin_twice_is_refused_in_words():
    """A duplicate Host header had given a traceback in the request check and dropped the press."""
    from websockets.datastructures import Headers

    auth = Authority("127.0.0.1", 8080)
    path = f"/control/{auth.token}"
    twice = Headers([("Host", "127.0.0.1:8080"), ("Host", "evil.example:8080")])
    assert "a header named twice" in (auth.refusal(path, twice) or "")
    origins = Headers([("Host", "127.0.0.1:8080"), ("Origin", "http://127.0.0.1:8080"), ("Origin", "http://x")])
    assert "a header named twice" in (auth.refusal(path, origins) or "")
    assert auth.refusal(path, Headers([("Host", "127.0.0.1:8080"), ("Origin", "http://127.0.0.1:8080")])) is None


def test_panel_work_runs_on_the_sessions_loop_not_on_vipers():
    """viser awaits GUI callbacks on its own loop, in its server's thread: what they hand the session
    (web/session_loop.py) runs on the session's loop, and its result and exceptions come back."""
    import threading

    from web.session_loop import SessionLoop

    session = SessionLoop()
    seen: list[tuple[int, asyncio.AbstractEventLoop]] = []

    async def on_loop(x):
        seen.append((threading.get_ident(), asyncio.get_running_loop()))
        if x < 0:
            raise ValueError("refused")
        return 2 * x

    async def main():
        session.bind()
        other = asyncio.new_event_loop()  # viser's, in its thread
        box: dict = {}

        def viser_thread():
            async def callback():
                box["result"] = await session.call(on_loop, 21)
                try:
                    await session.call(on_loop, -1)
                except ValueError as e:
                    box["error"] = str(e)

            other.run_until_complete(callback())
            other.close()

        t = threading.Thread(target=viser_thread)
        t.start()
        await asyncio.to_thread(t.join)  # the session's loop stays free to run what is handed it
        return box, threading.get_ident(), asyncio.get_running_loop()

    box, ident, loop = asyncio.run(main())
    assert box == {"result": 42, "error": "refused"}
    assert seen and all(s == (ident, loop) for s in seen)
