"""The ground station's control desk: which controllers and feedback a vehicle offers,
and the one :class:`~.commander.Commander` in charge at a time.

A :class:`ControlStation` belongs to one link. Choosing a controller or a
feedback source builds a fresh commander (disarmed: a change never carries an
armed state over); the choice is refused while armed. Measurements, link
events and the fixed-rate ticks go to the commander in charge.

Vehicles and their commands:

* ``heli3dof``: PD (pole placement, omega_0 = 4, zeta = 1), LQR + feed-forward
  (eq. 38), LQR + integral (eq. 44); feedback from the encoders, the Kalman
  filter, the raw IMU or the open-loop predictor; MOTORS frames on the board;
* ``quad``: altitude hold on the thrust-model filter or the altitude filter;
  SET_ATTITUDE_TARGET;
* ``coax``: altitude hold on the altitude filter; MANUAL_CONTROL (collective).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from groundstation.core.broadcast import Broadcast
from groundstation.core.measurement import Measurement
from groundstation.estimation.models.heli3dof_rig import Heli3dofRig
from groundstation.estimation.routing import altitude_estimator, quad_thrust_estimator

from .commander import ArmRefused, Commander
from .controllers import (
    COAX_THRUST,
    QUAD_THRUST,
    AltitudeHold,
    Controller,
    LQRFeedForward,
    LQRIntegral,
    PitchPD,
)
from .feedback import FEEDBACK_3DOF, EstimatorFeedback, Feedback
from .uplink import AttitudeTarget, BoardMotors, ManualControl, Uplink

#: each vehicle's controllers (the 3-DOF rig's take ``rig=``, its own constants)
CONTROLLERS: dict[str, dict[str, Callable[..., Controller]]] = {
    "heli3dof": {"pd": lambda **kw: PitchPD.place(4.0, 1.0, **kw), "lqr": LQRFeedForward, "lqr_i": LQRIntegral},
    "quad": {"altitude_hold": lambda: AltitudeHold(QUAD_THRUST)},
    "coax": {"altitude_hold": lambda: AltitudeHold(COAX_THRUST)},
}
FEEDBACK: dict[str, dict[str, Callable[[], Feedback]]] = {
    "heli3dof": dict(FEEDBACK_3DOF),
    "quad": {
        "altitude": lambda: EstimatorFeedback(altitude_estimator()),
        "quad_thrust": lambda: EstimatorFeedback(quad_thrust_estimator()),
    },
    "coax": {"altitude": lambda: EstimatorFeedback(altitude_estimator())},
}
#: where each reference's slider goes (min, max, step)
REFERENCE_RANGES = {
    "p_c": (-0.5, 0.5, 0.01),
    "e_c": (-0.4, 0.6, 0.01),
    "e_dot_c": (-0.3, 0.3, 0.01),
    "z_c": (0.3, 5.0, 0.05),
}


def default_uplink(vehicle: str, link) -> Uplink:
    if vehicle == "heli3dof":
        return BoardMotors(link)
    if vehicle == "quad":
        return AttitudeTarget(link)
    return ManualControl(link)


class ControlStation:
    def __init__(
        self,
        vehicle: str,
        link,
        *,
        uplink: Uplink | None = None,
        rate: float = 100.0,
        controller: str | None = None,
        feedback: str | None = None,
        on_command: Callable[[Measurement], None] | None = None,
        rig: Heli3dofRig | None = None,
    ) -> None:
        """``rig``: a 3-DOF rig's own constants (a diagnosis's ``heli3dof_rig.json``), which its
        controllers are designed on and fly with."""
        if vehicle not in CONTROLLERS:
            raise ValueError(f"no controllers for vehicle {vehicle!r}; use one of {', '.join(CONTROLLERS)}")
        self.vehicle, self.link, self.rate = vehicle, link, rate
        self.rig = rig if vehicle == "heli3dof" else None
        self.uplink = uplink or default_uplink(vehicle, link)
        self.on_command = on_command
        self.controller_name = controller or next(iter(CONTROLLERS[vehicle]))
        self.feedback_name = feedback or next(iter(FEEDBACK[vehicle]))
        #: every commander's arm and disarm notes, whichever is in charge
        self.notes: Broadcast[str] = Broadcast(1000)
        self.commander = self._build()
        self._changed = asyncio.Event()
        self._stopped = False

    @property
    def controllers(self) -> tuple[str, ...]:
        return tuple(CONTROLLERS[self.vehicle])

    @property
    def feedbacks(self) -> tuple[str, ...]:
        return tuple(FEEDBACK[self.vehicle])

    def _build(self) -> Commander:
        make = CONTROLLERS[self.vehicle][self.controller_name]
        c = make(rig=self.rig) if self.rig is not None else make()
        fb = FEEDBACK[self.vehicle][self.feedback_name]()
        return Commander(
            c, fb, self.uplink, rate=self.rate, link=self.link, on_command=self.on_command, notes=self.notes
        )

    def select(self, *, controller: str | None = None, feedback: str | None = None) -> None:
        """Change controller and/or feedback (refused while armed: disarm first)."""
        if self.commander.armed:
            raise ArmRefused("disarm before changing the controller or the feedback")
        if controller is not None and controller not in CONTROLLERS[self.vehicle]:
            raise ValueError(f"unknown controller {controller!r}; use one of {', '.join(self.controllers)}")
        if feedback is not None and feedback not in FEEDBACK[self.vehicle]:
            raise ValueError(f"unknown feedback {feedback!r}; use one of {', '.join(self.feedbacks)}")
        self.controller_name = controller or self.controller_name
        self.feedback_name = feedback or self.feedback_name
        old = self.commander
        self.commander = self._build()
        self.commander.reference.update({k: v for k, v in old.reference.items() if k in self.commander.reference})
        self._changed.set()

    def feed(self, m: Measurement) -> None:
        self.commander.feed(m)

    async def follow(self, measurements) -> None:
        async for batch in measurements.batches():
            for m in batch:
                self.commander.feed(m)

    async def run(self) -> None:
        """Run whichever commander is in charge (restarted when the choice changes)."""
        while not self._stopped:
            cmd = self.commander
            task = asyncio.create_task(cmd.run())
            self._changed.clear()
            waiter = asyncio.create_task(self._changed.wait())
            try:
                await asyncio.wait({task, waiter}, return_when=asyncio.FIRST_COMPLETED)
            finally:
                if not task.done():
                    cmd.stop()
                    await task
                waiter.cancel()

    def stop(self) -> None:
        self._stopped = True
        self.commander.stop()
        self.notes.close()
