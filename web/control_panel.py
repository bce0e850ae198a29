"""The dashboard's control panel: who holds control, arm/disarm, controller and feedback,
references, plots.

Built on a :class:`groundstation.control.station.ControlStation`, behind the dashboard's
:class:`~web.authority.Authority`:

* a status line: armed or why not, the last arming note, and which tab holds control;
* ``Take control``: a tab that connected with the session's token, from the dashboard's own page,
  holds control from then on (taking it over from another tab is allowed, and said);
* ARM, which asks to be pressed again within :data:`CONFIRM_S` seconds, and DISARM: from the tab
  that holds control only;
* controller and feedback dropdowns (refused while armed: the dropdown goes back) and one slider
  per reference of the controller in charge, likewise from the holder only;
* a plot of one reference (chosen), the state it tracks and the command (V_d for the 3-DOF rig,
  the collective otherwise) over the last ``window_s`` seconds.

A control action from any other tab is ignored, and that tab is told why in a notification. A
reference is range-checked here, on the server, against the limits its slider shows (a crafted tab
can send a slider any number). What the commander does runs on the session's event loop
(:class:`~web.session_loop.SessionLoop`), where it flies the vehicle. A gamepad is not wired:
viser's GUI offers no Gamepad API hook, and the sliders give the same references.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable

import numpy as np

from groundstation.control.commander import ArmRefused
from groundstation.control.station import REFERENCE_RANGES, ControlStation

from .authority import Authority
from .session_loop import SessionLoop

#: what the plot shows per reference: the state it tracks
TRACKS = {"p_c": "p", "e_c": "e", "e_dot_c": "e_dot", "z_c": "z"}
#: seconds within which ARM must be pressed a second time
CONFIRM_S = 5.0


class ControlPanel:
    def __init__(
        self,
        gui,
        station: ControlStation,
        authority: Authority,
        refusal: Callable[[int | None], str | None],
        *,
        window_s: float = 20.0,
        clock: Callable[[], float] = time.monotonic,
        session: SessionLoop | None = None,
    ) -> None:
        """``refusal(client_id)``: why that tab may not command (the dashboard reads its request),
        or None; ``session``: the loop the commander runs on (default: the caller's)."""
        self.station, self.window_s = station, window_s
        self.session = session or SessionLoop()
        self.authority, self.refusal, self.clock = authority, refusal, clock
        self.message = ""
        self._arm_pending: tuple[int, float] | None = None  # (client id, when ARM was first pressed)
        self._rows: deque = deque()
        self._records = station.commander.records.subscribe(lossy=True, maxlen=5000)
        with gui.add_folder("Control"):
            self.status_md = gui.add_markdown(self._status())
            self.take = gui.add_button("Take control")
            self.arm = gui.add_button("ARM", color="red")
            self.disarm = gui.add_button("DISARM")
            self.controller = gui.add_dropdown(
                "controller", options=station.controllers, initial_value=station.controller_name
            )
            self.feedback = gui.add_dropdown("feedback", options=station.feedbacks, initial_value=station.feedback_name)
            self.sliders = {}
            for name in REFERENCE_RANGES:
                lo, hi, step = REFERENCE_RANGES[name]
                s = gui.add_slider(
                    name, min=lo, max=hi, step=step, initial_value=0.0 if lo < 0 < hi else lo + step, visible=False
                )
                s.on_update(self._reference_changed(name))
                self.sliders[name] = s
            refs = tuple(station.commander.reference)
            self.plot_choice = gui.add_dropdown("plot", options=refs, initial_value=refs[0])
            self.plot = gui.add_uplot(
                data=(np.zeros(2, np.float32),) * 4,
                series=(
                    {"label": "t [s]"},
                    {"label": "reference", "stroke": "green"},
                    {"label": "state", "stroke": "blue"},
                    {"label": "command", "stroke": "red"},
                ),
                scales={"x": {"time": False}},
                legend={"show": True},
                aspect=2.0,
            )
        self._show_references()

        # async callbacks: viser runs them on the event loop (plain ones go to a thread
        # pool), so the commander is only ever touched from the loop it runs on
        @self.take.on_click
        async def _(e) -> None:
            why = self.refusal(e.client_id)
            if why is not None:
                self._tell(e, "View only", why)
            else:
                self.message = self.authority.take(e.client_id)
            self._refresh()

        @self.arm.on_click
        async def _(e) -> None:
            if self._allowed(e):
                await self._arm(e.client_id)

        @self.disarm.on_click
        async def _(e) -> None:
            if self._allowed(e):
                await self.session.call(self.station.commander.disarm, f"by the user (dashboard, tab {e.client_id})")
                self._arm_pending = None
                self.arm.label = "ARM"
            self._refresh()

        @self.plot_choice.on_update
        async def _(_e) -> None:
            self._rows.clear()

        @self.controller.on_update
        async def _(e) -> None:
            if self.controller.value == self.station.controller_name:
                return
            if self._allowed(e):
                await self._select(controller=self.controller.value)
            else:
                self.controller.value = self.station.controller_name

        @self.feedback.on_update
        async def _(e) -> None:
            if self.feedback.value == self.station.feedback_name:
                return
            if self._allowed(e):
                await self._select(feedback=self.feedback.value)
            else:
                self.feedback.value = self.station.feedback_name

    # -- who ---------------------------------------------------------------------------------------
    def _allowed(self, e) -> bool:
        """Whether the tab behind event ``e`` may command now; if not it is told why."""
        why = self.authority.command_refusal(self.refusal(e.client_id), e.client_id)
        if why is not None:
            self._tell(e, "Not yours to command", why)
            self._refresh()
            return False
        return True

    def _tell(self, e, title: str, body: str) -> None:
        self.message = f"tab {e.client_id}: {body}"
        if e.client is not None:
            e.client.add_notification(title, body, auto_close_seconds=6.0, color="yellow")

    def client_left(self, client_id: int) -> None:
        self.authority.left(client_id)
        self._refresh()

    # -- user actions ------------------------------------------------------------------------------
    async def _arm(self, client_id: int) -> None:
        """First press asks for a second within :data:`CONFIRM_S` s; the second arms."""
        now = self.clock()
        pending = self._arm_pending
        if pending is None or pending[0] != client_id or now - pending[1] > CONFIRM_S:
            self._arm_pending = (client_id, now)
            self.arm.label = "CONFIRM ARM"
            self.message = f"press ARM again within {CONFIRM_S:g} s to arm"
            self._refresh()
            return
        self._arm_pending = None
        self.arm.label = "ARM"
        try:
            await self.session.call(self.station.commander.arm)
            self.message = ""
        except ArmRefused as e:
            self.message = f"arming refused: {e}"
        self._refresh()

    async def _select(self, **choice) -> None:
        try:
            await self.session.call(lambda: self.station.select(**choice))
            self._records.close()
            self._records = self.station.commander.records.subscribe(lossy=True, maxlen=5000)
            self._rows.clear()
            self.message = ""
        except (ArmRefused, ValueError) as e:
            self.message = str(e)
            self.controller.value = self.station.controller_name
            self.feedback.value = self.station.feedback_name
        self._show_references()
        self._refresh()

    def _reference_changed(self, name):
        async def cb(e) -> None:
            cmd = self.station.commander
            if name not in cmd.reference or float(self.sliders[name].value) == cmd.reference[name]:
                return
            if self._allowed(e):
                try:
                    value = float(self.sliders[name].value)
                    lo, hi, _ = REFERENCE_RANGES[name]
                    if not math.isfinite(value):
                        raise ValueError(f"reference {name} must be a finite number, not {value!r}")
                    if not lo <= value <= hi:  # a value no slider gives (a crafted tab's)
                        raise ValueError(f"reference {name} = {value:g} is outside {lo:g} to {hi:g}")
                    await self.session.call(lambda: cmd.set_reference(**{name: value}))
                    return
                except (ValueError, TypeError) as err:  # (NaN too: set_reference refuses it)
                    self._tell(e, "Reference refused", str(err))
                    self._refresh()
            self.sliders[name].value = cmd.reference[name]  # back to what is flown

        return cb

    def _show_references(self) -> None:
        ref = self.station.commander.reference
        if tuple(ref) != self.plot_choice.options:
            self.plot_choice.options = tuple(ref)
            self.plot_choice.value = next(iter(ref))
        for name, s in self.sliders.items():
            s.visible = name in ref
            if name in ref:
                s.value = min(s.max, max(s.min, ref[name]))

    # -- pushing -------------------------------------------------------------------------------------
    def _refresh(self) -> None:
        self.status_md.content = self._status()

    def _status(self) -> str:
        c = self.station.commander
        head = "**ARMED**" if c.armed else "**disarmed**"
        held = self.authority.holder
        who = f"control held by tab {held}" if held is not None else "nobody holds control"
        text = (
            f"{head} · {c.controller.name} on {c.feedback.name} · {who} · "
            f"{self.station.uplink.sent} commands sent\n\n{c.status}"
        )
        return text + (f"\n\n{self.message}" if self.message else "")

    def update(self) -> None:
        """Status and plot (called at the dashboard's panel rate)."""
        if self._arm_pending is not None and self.clock() - self._arm_pending[1] > CONFIRM_S:
            self._arm_pending = None
            self.arm.label = "ARM"
        self._refresh()
        for rec in self._records.get_nowait():
            ref_name = self.plot_choice.value if self.plot_choice.value in rec.reference else next(iter(rec.reference))
            state = rec.state.get(TRACKS.get(ref_name, ""), np.nan)
            cmd = float(rec.command[-1] - rec.command[0]) if len(rec.command) > 1 else float(rec.command[0])
            self._rows.append((rec.t, rec.reference[ref_name], state, cmd))
        while self._rows and self._rows[0][0] < self._rows[-1][0] - self.window_s:
            self._rows.popleft()
        if len(self._rows) > 1:
            a = np.array(self._rows, dtype=np.float32)
            step = max(1, len(a) // 400)
            a = a[::step]
            self.plot.data = (a[:, 0], a[:, 1], a[:, 2], a[:, 3])
