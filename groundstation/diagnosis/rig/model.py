"""The rig's model as the fit sees it: the constants of
:class:`~groundstation.estimation.models.heli3dof_rig.Heli3dofRig` (the lab's linear model and what a
rig adds to it; its docstring has the equations) as a flat set of numbers, and the residuals of a
session's columns under them.

The residual groups: the three accelerations the encoders show against the equations of motion,
and the gyro's and the accelerometer's axes against what the encoders say the IMU on the arm reads
(:func:`~groundstation.estimation.models.heli3dof_rig.imu_frame`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from groundstation.estimation.models.heli3dof_rig import Heli3dofRig, imu_frame

from .session import RigSession

#: every parameter of the fit, its value in the lab's model, and its typical size (the fit's scale)
PARAMETERS: dict[str, tuple[float, float]] = {
    "K_f": (Heli3dofRig.K_f, 0.01),
    "V_s0": (Heli3dofRig.V_s0, 0.5),
    "a": (0.0, 0.02),
    "w_e": (0.0, 0.5),
    "w_l": (0.0, 0.5),
    "c_p": (0.0, 0.1),
    "c_e": (0.0, 0.05),
    "c_l": (0.0, 0.05),
    "tc": (0.0, 0.05),
    "b_gx": (0.0, 0.005),
    "b_gy": (0.0, 0.005),
    "b_gz": (0.0, 0.005),
    "b_ax": (0.0, 0.05),
    "b_ay": (0.0, 0.05),
    "b_az": (0.0, 0.05),
    "m_roll": (0.0, 0.02),
    "m_pitch": (0.0, 0.02),
    "m_yaw": (0.0, 0.02),
    "o_p": (0.0, 0.01),
    "o_e": (0.0, 0.01),
}
#: bounds where physics sets them; the rest are free
BOUNDS: dict[str, tuple[float, float]] = {
    "tc": (0.0, 1.0),  # a lag is not negative
    "K_f": (1e-3, 10.0),
    "a": (-0.5, 0.5),
    "c_p": (0.0, np.inf),  # friction takes energy out
    "c_e": (0.0, np.inf),
    "c_l": (0.0, np.inf),
}
GYRO = ("gyro_x", "gyro_y", "gyro_z")
ACCEL = ("accel_x", "accel_y", "accel_z")


def rig_of(v: dict[str, float]) -> Heli3dofRig:
    return Heli3dofRig(
        K_f=v["K_f"],
        V_s0=v["V_s0"],
        a=v["a"],
        w_e=v["w_e"],
        w_l=v["w_l"],
        c_p=v["c_p"],
        c_e=v["c_e"],
        c_l=v["c_l"],
        tc=v["tc"],
        gyro_bias=(v["b_gx"], v["b_gy"], v["b_gz"]),
        accel_bias=(v["b_ax"], v["b_ay"], v["b_az"]),
        imu_mounting=(v["m_roll"], v["m_pitch"], v["m_yaw"]),
        encoder_offset=(v["o_p"], v["o_e"]),
    )


def values_of(rig: Heli3dofRig) -> dict[str, float]:
    """The fit's numbers of a rig's constants (a vehicle file's, or the lab's)."""
    (bgx, bgy, bgz), (bax, bay, baz) = rig.gyro_bias, rig.accel_bias
    (mr, mp, my), (op, oe) = rig.imu_mounting, rig.encoder_offset
    return {
        "K_f": rig.K_f, "V_s0": rig.V_s0, "a": rig.a, "w_e": rig.w_e, "w_l": rig.w_l,
        "c_p": rig.c_p, "c_e": rig.c_e, "c_l": rig.c_l, "tc": rig.tc,
        "b_gx": bgx, "b_gy": bgy, "b_gz": bgz, "b_ax": bax, "b_ay": bay, "b_az": baz,
        "m_roll": mr, "m_pitch": mp, "m_yaw": my, "o_p": op, "o_e": oe,
    }  # fmt: skip


def lagged(s: RigSession, tc: float) -> tuple[np.ndarray, np.ndarray]:
    """(V_f, V_b) through the motors' first-order lag ``tc`` (the voltage the thrust follows)."""
    if tc <= 1e-9:
        return s.V_f, s.V_b
    alpha = math.exp(-s.dt / tc)
    V_f, V_b = (lfilter([1 - alpha], [1, -alpha], v, zi=[alpha * v[0]])[0] for v in (s.V_f, s.V_b))
    return V_f, V_b


@dataclass
class Columns:
    """The session's columns at the rows a fit reads (a lag runs over the whole voltage first)."""

    rows: np.ndarray
    s: RigSession

    def __post_init__(self) -> None:
        s, r = self.s, self.rows
        self.p_enc, self.e_enc = s.angle["p"][r], s.angle["e"][r]
        self.pd, self.ed, self.ld = s.rate["p"][r], s.rate["e"][r], s.rate["lambda"][r]
        self.pdd, self.edd, self.ldd = s.accel["p"][r], s.accel["e"][r], s.accel["lambda"][r]
        self.gyro = s.gyro[r] if s.gyro is not None else None
        self.f = s.specific_force[r] if s.specific_force is not None else None
        self._lagged: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def voltages(self, tc: float) -> tuple[np.ndarray, np.ndarray]:
        key = round(tc, 9)
        if key not in self._lagged:
            if len(self._lagged) > 64:
                self._lagged.clear()
            V_f, V_b = lagged(self.s, tc)
            self._lagged[key] = (V_f[self.rows], V_b[self.rows])
        return self._lagged[key]


def residuals(v: dict[str, float], c: Columns) -> dict[str, np.ndarray]:
    """Measured minus modelled, per group (the IMU's only where the session has one)."""
    rig = rig_of(v)
    p, e = c.p_enc - v["o_p"], c.e_enc - v["o_e"]
    V_f, V_b = c.voltages(v["tc"])
    pdd, edd, ldd = rig.accelerations(p, e, c.pd, c.ed, c.ld, V_f, V_b)
    out = {"p": c.pdd - pdd, "e": c.edd - edd, "lambda": c.ldd - ldd}
    if c.gyro is not None and c.f is not None:
        C = rig.mounting()
        w, f = imu_frame(p, e, c.pd, c.ed, c.ld, c.edd, c.ldd)
        gyro = c.gyro - w @ C.T - np.asarray(rig.gyro_bias)
        acc = c.f - f @ C.T - np.asarray(rig.accel_bias)
        for i in range(3):
            out[GYRO[i]], out[ACCEL[i]] = gyro[:, i], acc[:, i]
    return out


def lab_model() -> dict[str, float]:
    """The lab's linear model: every parameter at its Table value or zero."""
    return values_of(Heli3dofRig())
