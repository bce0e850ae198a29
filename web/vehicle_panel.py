"""The dashboard's Vehicle panel: what a user opens MAVProxy for, in the browser.

For the vehicle the dashboard shows (its picker, or the link's only vehicle): its flight mode
and armed state as its heartbeat says; mode change, ARM and TAKEOFF (each asking to be pressed
again within :data:`~web.control_panel.CONFIRM_S` seconds, as the Control panel's ARM does),
DISARM and LAND, each a COMMAND_LONG sent until acknowledged (:mod:`drivers.mavlink.commands`);
and one parameter at a time: Get reads it from the vehicle, Set writes it and waits for the
vehicle's echo (:class:`~drivers.mavlink.params.ParamClient`). The result, or why not, in one
line under the buttons.

Behind the dashboard's :class:`~web.authority.Authority`, as the Control panel: only the tab
holding control commands (reading a parameter is open to every tab); any other is told why.

The panel's inputs (mode, take-off height, parameter name and value) are shown to every tab alike
(viser keeps one value for all), so the values a command is sent with are the ones the tab holding
control set, kept here as :attr:`VehiclePanel.accepted`: a change from any other tab is undone at
once and that tab told why, and the holder's own is range-checked here, on the server, against
the limits the panel shows (a crafted tab can send a slider any number). Commands run on the
session's event loop (:class:`~web.session_loop.SessionLoop`), where the link lives.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from drivers.mavlink.commands import COPTER_MODES, CommandError, run_command
from drivers.mavlink.params import ParamClient, ParamError

from .authority import Authority
from .control_panel import CONFIRM_S
from .session_loop import SessionLoop

#: the modes offered (ArduCopter's that a ground station switches to)
MODES = ("STABILIZE", "ALT_HOLD", "LOITER", "POSHOLD", "GUIDED", "AUTO", "RTL", "LAND")
#: [m] the take-off heights the panel offers
TAKEOFF_RANGE = (1.0, 30.0)


def _mode(v: object) -> str | None:
    return None if v in MODES else f"mode {str(v)[:20]!r} is not one offered ({', '.join(MODES)})"


def _within(limits: tuple[float, float], what: str, unit: str) -> Callable[[object], str | None]:
    def check(v: object) -> str | None:
        try:
            x = float(v)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            return f"{what} {str(v)[:20]!r} is not a number"
        if not limits[0] <= x <= limits[1]:
            return f"{what} {x:g} {unit} is outside {limits[0]:g}-{limits[1]:g} {unit}"
        return None

    return check


def _param_name(v: object) -> str | None:
    name = str(v).strip()
    return None if len(name) <= 16 and name.isascii() else "a parameter name is at most 16 ASCII characters"


def _finite(v: object) -> str | None:
    try:
        return None if math.isfinite(float(v)) else f"{v} is not a number to set"  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return f"{str(v)[:20]!r} is not a number"


class VehiclePanel:
    def __init__(
        self,
        gui,
        link,
        authority: Authority,
        refusal: Callable[[int | None], str | None],
        sysid: Callable[[], int | None],
        *,
        take_button: bool = True,
        clock: Callable[[], float] = time.monotonic,
        session: SessionLoop | None = None,
    ) -> None:
        """``link``: the :class:`~drivers.mavlink.link.MavlinkLink`; ``sysid()``: the vehicle shown
        (None: none heard yet); ``take_button``: offer Take control here (the Control panel has its
        own when it is there); ``session``: the loop commands run on (default: the caller's)."""
        self.link, self.authority, self.refusal, self.sysid, self.clock = link, authority, refusal, sysid, clock
        self.session = session or SessionLoop()
        self.message = ""
        self.busy = False
        #: presses and input changes refused to tabs without control, told to the holder (someone
        #: else is trying to command this vehicle)
        self.refused = 0
        self._pending: tuple[str, int, float] | None = None  # (action, client id, first press)
        self._params: dict[int, ParamClient] = {}
        with gui.add_folder("Vehicle"):
            self.status_md = gui.add_markdown(self._status())
            self.take = gui.add_button("Take control", visible=take_button)
            self.mode = gui.add_dropdown("mode", options=MODES, initial_value="LOITER")
            self.set_mode = gui.add_button("Set mode")
            self.arm = gui.add_button("ARM", color="red")
            self.disarm = gui.add_button("DISARM")
            self.altitude = gui.add_slider(
                "takeoff [m]", min=TAKEOFF_RANGE[0], max=TAKEOFF_RANGE[1], step=0.5, initial_value=3.0
            )
            self.takeoff = gui.add_button("TAKEOFF", color="red")
            self.land = gui.add_button("LAND")
            self.param_name = gui.add_text("parameter", initial_value="")
            self.param_value = gui.add_number("value", initial_value=0.0)
            self.param_get = gui.add_button("Get")
            self.param_set = gui.add_button("Set")
        #: the inputs' values as the tab holding control set them: what commands are sent with
        self.accepted: dict[str, float | str] = {
            "mode": "LOITER",
            "altitude": 3.0,
            "param_name": "",
            "param_value": 0.0,
        }
        for key, handle, check in (
            ("mode", self.mode, _mode),
            ("altitude", self.altitude, _within(TAKEOFF_RANGE, "takeoff height", "m")),
            ("param_name", self.param_name, _param_name),
            ("param_value", self.param_value, _finite),
        ):
            handle.on_update(self._input(key, handle, check))

        # async callbacks: viser runs them on the event loop, where the link lives
        @self.take.on_click
        async def _(e) -> None:
            why = self.refusal(e.client_id)
            self.refused += why is not None
            self.message = self.authority.take(e.client_id) if why is None else f"tab {e.client_id}: {why}"
            self._refresh()

        @self.set_mode.on_click
        async def _(e) -> None:
            if self._allowed(e):
                await self._command("mode", str(self.accepted["mode"]))

        @self.arm.on_click
        async def _(e) -> None:
            if self._allowed(e) and self._confirmed("arm", e.client_id):
                await self._command("arm")

        @self.takeoff.on_click
        async def _(e) -> None:
            if self._allowed(e) and self._confirmed("takeoff", e.client_id):
                await self._command("takeoff", float(self.accepted["altitude"]))

        @self.disarm.on_click
        async def _(e) -> None:
            if self._allowed(e):
                await self._command("disarm")

        @self.land.on_click
        async def _(e) -> None:
            if self._allowed(e):
                await self._command("land")

        @self.param_get.on_click
        async def _(_e) -> None:
            await self._param(None)

        @self.param_set.on_click
        async def _(e) -> None:
            if self._allowed(e):
                await self._param(float(self.accepted["param_value"]))

    # -- who ---------------------------------------------------------------------------------------
    def _input(self, key: str, handle, check: Callable[[object], str | None]):
        """The callback of one input: the holder's value, range-checked, is accepted; any other
        tab's, or one out of range, is undone (the value every tab sees goes back) and that tab told
        why."""

        async def cb(e) -> None:
            value = handle.value
            if value == self.accepted[key]:
                return
            refused = self.authority.command_refusal(self.refusal(e.client_id), e.client_id)
            self.refused += refused is not None
            why = refused or check(value)
            if why is None:
                self.accepted[key] = value
                return
            handle.value = self.accepted[key]
            self.message = f"tab {e.client_id}: {why}"
            if e.client is not None:
                e.client.add_notification("Not changed", why, auto_close_seconds=6.0, color="yellow")
            self._refresh()

        return cb

    def _allowed(self, e) -> bool:
        why = self.authority.command_refusal(self.refusal(e.client_id), e.client_id)
        if why is None:
            return True
        self.refused += 1
        self.message = f"tab {e.client_id}: {why}"
        if e.client is not None:
            e.client.add_notification("Not yours to command", why, auto_close_seconds=6.0, color="yellow")
        self._refresh()
        return False

    def _confirmed(self, action: str, client_id: int) -> bool:
        """The second press of ``action`` by the same tab within :data:`CONFIRM_S` s."""
        now, pending = self.clock(), self._pending
        if pending is not None and pending[:2] == (action, client_id) and now - pending[2] <= CONFIRM_S:
            self._pending = None
            return True
        self._pending = (action, client_id, now)
        self.message = f"press {action.upper()} again within {CONFIRM_S:g} s to {action}"
        self._refresh()
        return False

    # -- what it does --------------------------------------------------------------------------------
    def _vehicle(self) -> tuple[int, int] | None:
        sysid = self.sysid()
        if sysid is None or sysid not in self.link.vehicles:
            self.message = "no vehicle heard yet"
            self._refresh()
            return None
        return sysid, self.link.vehicles[sysid]

    async def _command(self, what: str, arg: float | str | None = None) -> None:
        target = self._vehicle()
        if target is None or self.busy:
            return
        self.busy = True
        self.message = f"{what}{f' {arg}' if arg is not None else ''}: sent to vehicle {target[0]}…"
        self._refresh()
        try:
            self.message = await self.session.call(run_command, self.link, *target, what, arg)
        except CommandError as err:
            self.message = str(err)
        finally:
            self.busy = False
        self._refresh()

    async def _param(self, value: float | None) -> None:
        """Get (``value`` None) or set the named parameter, as the vehicle confirms it."""
        target = self._vehicle()
        name = str(self.accepted["param_name"]).strip().upper()
        if target is None or self.busy:
            return
        if not name or len(name) > 16:
            self.message = "parameter: a name of 1-16 characters"
            self._refresh()
            return
        if value is not None and not math.isfinite(value):
            self.message = f"parameter {name}: {value} is not a number to set"
            self._refresh()
            return
        client = self._params.get(target[0])
        if client is None:  # made on the session's loop: it listens to the link there
            client = self._params[target[0]] = await self.session.call(ParamClient, self.link, *target)
        self.busy = True
        try:
            if value is None:
                got = await self.session.call(client.get, name)
                self.param_value.value = self.accepted["param_value"] = got
                self.message = f"{name} = {got:g} (vehicle {target[0]})"
            else:
                got = await self.session.call(client.set, name, value)
                self.message = f"{name} set to {got:g}, confirmed by vehicle {target[0]}"
        except ParamError as err:
            self.message = str(err)
        finally:
            self.busy = False
        self._refresh()

    # -- pushing -------------------------------------------------------------------------------------
    def _status(self) -> str:
        sysid = self.sysid()
        state = self.link.vehicle_state.get(sysid) if sysid is not None else None
        if state is None:
            head = "no vehicle heard yet" if sysid is None else f"vehicle {sysid}"
        else:
            armed, mode = state
            head = f"vehicle {sysid}: **{'ARMED' if armed else 'disarmed'}** · {COPTER_MODES.get(mode, mode)}"
        held = self.authority.holder
        who = f"control held by tab {held}" if held is not None else "nobody holds control"
        if self.refused:
            who += f" · {self.refused} refused to tabs without control"
        return f"{head} · {who}" + (f"\n\n{self.message}" if self.message else "")

    def _refresh(self) -> None:
        self.status_md.content = self._status()

    def update(self) -> None:
        """Called at the dashboard's panel rate."""
        if self._pending is not None and self.clock() - self._pending[2] > CONFIRM_S:
            self._pending = None
        self._refresh()

    def close(self) -> None:
        for client in self._params.values():
            client.close()
