"""The dashboard's control panel: arm/disarm, controller and feedback, references, plots.

Built on a :class:`groundstation.control.station.ControlStation`:

* a status line (armed or why not, the last arming note);
* ARM and DISARM buttons (arming refused shows its one-line reason);
* controller and feedback dropdowns (changing either disarms nothing: it is
  refused while armed, and the dropdown goes back);
* one slider per reference of the controller in charge;
* a plot of one reference (chosen), the state it tracks and the command (V_d
  for the 3-DOF rig, the collective otherwise) over the last ``window_s`` seconds.

A gamepad is not wired: viser's GUI offers no Gamepad API hook, and the
sliders give the same references.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from groundstation.control.commander import ArmRefused
from groundstation.control.station import REFERENCE_RANGES, ControlStation

#: what the plot shows per reference: the state it tracks
TRACKS = {"p_c": "p", "e_c": "e", "e_dot_c": "e_dot", "z_c": "z"}


class ControlPanel:
    def __init__(self, gui, station: ControlStation, *, window_s: float = 20.0) -> None:
        self.station, self.window_s = station, window_s
        self.message = ""
        self._rows: deque = deque()
        self._records = station.commander.records.subscribe(lossy=True, maxlen=5000)
        with gui.add_folder("Control"):
            self.status_md = gui.add_markdown(self._status())
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
        @self.arm.on_click
        async def _(_e) -> None:
            self._arm()

        @self.disarm.on_click
        async def _(_e) -> None:
            self.station.commander.disarm("by the user (dashboard)")
            self.status_md.content = self._status()

        @self.plot_choice.on_update
        async def _(_e) -> None:
            self._rows.clear()

        @self.controller.on_update
        async def _(_e) -> None:
            if self.controller.value != self.station.controller_name:
                self._select(controller=self.controller.value)

        @self.feedback.on_update
        async def _(_e) -> None:
            if self.feedback.value != self.station.feedback_name:
                self._select(feedback=self.feedback.value)

    # -- user actions ------------------------------------------------------------------------------
    def _arm(self) -> None:
        try:
            self.station.commander.arm()
            self.message = ""
        except ArmRefused as e:
            self.message = f"arming refused: {e}"
        self.status_md.content = self._status()

    def _select(self, **choice) -> None:
        try:
            self.station.select(**choice)
            self._records.close()
            self._records = self.station.commander.records.subscribe(lossy=True, maxlen=5000)
            self._rows.clear()
            self.message = ""
        except (ArmRefused, ValueError) as e:
            self.message = str(e)
            self.controller.value = self.station.controller_name
            self.feedback.value = self.station.feedback_name
        self._show_references()
        self.status_md.content = self._status()

    def _reference_changed(self, name):
        async def cb(_e) -> None:
            cmd = self.station.commander
            if name in cmd.reference:
                cmd.set_reference(**{name: float(self.sliders[name].value)})

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
    def _status(self) -> str:
        c = self.station.commander
        head = "**ARMED**" if c.armed else "**disarmed**"
        text = (
            f"{head} · {c.controller.name} on {c.feedback.name} · "
            f"{self.station.uplink.sent} commands sent\n\n{c.status}"
        )
        return text + (f"\n\n{self.message}" if self.message else "")

    def update(self) -> None:
        """Status and plot (called at the dashboard's panel rate)."""
        self.status_md.content = self._status()
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
