"""The controllers: each reads a named state and reference, returns a saturated command.

3-DOF helicopter (lab document, part 2 and 3), input ``u = (V_s - V_s0, V_d)``
turned into motor voltages ``V_f = (V_s - V_d)/2``, ``V_b = (V_s + V_d)/2``
(eq. 9-10 with ``V_s = V_f + V_b``, ``V_d = V_b - V_f``):

* :class:`PitchPD`: ``V_d = K_pp (p_c - p) - K_pd p_dot`` (sec. 2.1);
* :class:`LQRFeedForward`: ``u = F r - K x``, x = (p, p_dot, e_dot), r = (p_c, e_dot_c) (eq. 33, 37);
* :class:`LQRIntegral`: the same with ``gamma``, ``zeta`` integrating the tracking error (eq. 39-41).

On a rig's own constants (``rig=``, :class:`~groundstation.estimation.models.heli3dof_rig.Heli3dofRig`,
what ``diagnose --model heli3dof`` writes): the gains are designed on its K_f, the lift is held
about its V_s0, the two motors' unlike constants are split for (``V_f = (V_s - V_d) / (2 (1 - a))``,
``V_b = (V_s + V_d) / (2 (1 + a))``, so that the thrusts' sum and difference are the ones asked for),
and where the rig shows the full equations the lift that holds it is ``V_s0 cos(e) / cos(p)``
(eq. 10 at rest) instead of V_s0.

Saturation: each motor takes 0 .. V_max. Lift comes first: V_s is clipped to
0 .. 2 V_max, then V_d to what both motors can still give at that V_s,
``|V_d| <= min(V_s, 2 V_max - V_s)``. The lab's document is silent on it; an
arm that keeps its lift and loses some pitch authority is what the lab's
flight shows when the joystick is pushed hard.

Anti-windup (:class:`LQRIntegral`, :class:`AltitudeHold`): conditional
integration. While the command is saturated the integrators stop, unless the
error would drive them back out of saturation.

Altitude hold (:class:`AltitudeHold`), on the altitude filter's (z, vz): LQR
with integral action on ``z_dd = a`` (the double integrator of the altitude
documents' kinematics), then the thrust model inverted for the collective:
``tau = (g + a - beta) / (alpha cos(roll) cos(pitch))`` (quadcopter document,
eq. 2), or for the coaxial helicopter ``(1 + k_w) k_F i / m = g + a``
(coaxial document, eq. 5.21 and 5.29 at equal inputs).
"""

from __future__ import annotations

import abc
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from groundstation.control import design
from groundstation.estimation.models.heli3dof import V_S0
from groundstation.estimation.models.heli3dof_rig import Heli3dofRig

G = 9.80665
V_MAX = 12.0


def clamp(v: float, lo: float, hi: float) -> float:
    """``v`` held to [lo, hi]; NaN stays NaN (Python's ``min``/``max`` would drop it, and a NaN state
    became a valid-looking command: the commander checks every command for it)."""
    return v if v != v else min(hi, max(lo, v))


@dataclass(frozen=True)
class Output:
    command: np.ndarray  # what is sent: (V_f, V_b) [V], or (collective,) 0..1
    u: np.ndarray  # the controller's own input, after saturation
    saturated: bool


class Controller(abc.ABC):
    """``update(x, r, dt)``: state and reference by name -> :class:`Output`."""

    name = "controller"
    #: the state components it reads
    needs: tuple[str, ...] = ()
    #: reference names and their defaults
    references: dict[str, float] = {}
    #: names of the command components (export and plots)
    command_names: tuple[str, ...] = ()
    #: the plausible range of each state it reads (optional ones too: checked when present); a value
    #: outside it, or not finite, disarms (:class:`~.commander.Commander`)
    state_limits: dict[str, tuple[float, float]] = {}
    #: what each command component may be
    command_limits: tuple[float, float] = (-math.inf, math.inf)

    @abc.abstractmethod
    def update(self, x: Mapping[str, float], r: Mapping[str, float], dt: float) -> Output:
        """One control step of ``dt`` seconds."""

    def reset(self) -> None:
        """Forget integrator state (at arming); a controller without one has nothing to do."""
        return None

    def describe(self) -> dict:
        return {"name": self.name}


# -- 3-DOF helicopter -------------------------------------------------------------------------


def motor_voltages(
    u_s: float, V_d: float, V_s0: float = V_S0, V_max: float = V_MAX, a: float = 0.0
) -> tuple[np.ndarray, np.ndarray, bool]:
    """(V_f, V_b), the applied (V_s - V_s0, V_d), and whether anything was clipped; ``a``: the
    motors' asymmetry (module docstring), split for."""
    V_s = V_s0 + u_s
    V_s_c = clamp(V_s, 0.0, 2 * V_max)
    lim = min(V_s_c, 2 * V_max - V_s_c)
    V_d_c = clamp(V_d, -lim, lim)
    sat = V_s_c != V_s or V_d_c != V_d
    if a == 0.0:
        return (np.array([(V_s_c - V_d_c) / 2, (V_s_c + V_d_c) / 2]), np.array([V_s_c - V_s0, V_d_c]), sat)
    V_f = clamp((V_s_c - V_d_c) / (2 * (1 - a)), 0.0, V_max)
    V_b = clamp((V_s_c + V_d_c) / (2 * (1 + a)), 0.0, V_max)
    sat = sat or V_f != (V_s_c - V_d_c) / (2 * (1 - a)) or V_b != (V_s_c + V_d_c) / (2 * (1 + a))
    return np.array([V_f, V_b]), np.array([V_s_c - V_s0, V_d_c]), sat


#: the 3-DOF rig's angles stay within a quarter turn, its rates within 10 rad/s
HELI3DOF_LIMITS = {
    "p": (-math.pi / 2, math.pi / 2),
    "e": (-math.pi / 2, math.pi / 2),
    "p_dot": (-10.0, 10.0),
    "e_dot": (-10.0, 10.0),
    "lambda_dot": (-10.0, 10.0),
}


class _Heli3dof(Controller):
    command_names = ("V_f", "V_b")
    state_limits = HELI3DOF_LIMITS

    def __init__(self, *, V_s0: float = V_S0, V_max: float = V_MAX, rig: Heli3dofRig | None = None) -> None:
        self.rig = rig
        self.V_s0, self.V_max = (rig.V_s0 if rig is not None else V_s0), V_max
        self.a = rig.a if rig is not None else 0.0
        self.command_limits = (0.0, V_max)

    @staticmethod
    def motor_constant(K_f: float, rig: Heli3dofRig | None) -> float:
        """The K_f the gains are designed on: the rig's own where it is given."""
        return rig.K_f if rig is not None else K_f

    def _out(self, u_s: float, V_d: float, x: Mapping[str, float] | None = None) -> Output:
        V_s0 = self.V_s0
        rig = self.rig
        if rig is not None and rig.w_e > 0 and x is not None and "e" in x and "p" in x:
            # the lift that holds the rig where it is (eq. 10 at rest, in the rig's share of it)
            ce, cp = 1 + rig.w_e * (math.cos(x["e"]) - 1), 1 + rig.w_e * (math.cos(x["p"]) - 1)
            V_s0 = V_s0 * ce / max(cp, 0.5)
        cmd, u, sat = motor_voltages(u_s + V_s0 - self.V_s0, V_d, self.V_s0, self.V_max, self.a)
        return Output(cmd, u, sat)


class PitchPD(_Heli3dof):
    """PD on pitch by pole placement (lab sec. 2.1-2.3, eq. 21-27).

    The lab flew elevation by hand with the joystick's V_s; here a PD on
    elevation (its own pole pair, on K2) stands in for the operator, so a
    pitch step can be flown hands-off.
    """

    name = "pd"
    needs = ("p", "p_dot", "e", "e_dot")
    references = {"p_c": 0.0, "e_c": 0.0}

    def __init__(
        self,
        K_pp: float,
        K_pd: float,
        *,
        K_ep: float | None = None,
        K_ed: float | None = None,
        K_f: float = design.K_F,
        **kw,
    ) -> None:
        super().__init__(**kw)
        self.K_pp, self.K_pd = K_pp, K_pd
        _, K2 = design.k1_k2(self.motor_constant(K_f, self.rig))
        # elevation: a critically damped pair at 2 rad/s unless given
        self.K_ep = K_ep if K_ep is not None else 4.0 / K2
        self.K_ed = K_ed if K_ed is not None else 4.0 / K2

    @classmethod
    def place(cls, omega0: float, zeta: float, *, K_f: float = design.K_F, **kw) -> PitchPD:
        """Gains for omega_0 and zeta on the plant with motor constant K_f (eq. 25-26)."""
        K_f = cls.motor_constant(K_f, kw.get("rig"))
        K1, _ = design.k1_k2(K_f)
        return cls(*design.pd_gains(K1, omega0, zeta), K_f=K_f, **kw)

    @classmethod
    def from_poles(cls, l1: complex, l2: complex, *, K_f: float = design.K_F, **kw) -> PitchPD:
        K_f = cls.motor_constant(K_f, kw.get("rig"))
        K1, _ = design.k1_k2(K_f)
        return cls(*design.pd_from_poles(K1, l1, l2), K_f=K_f, **kw)

    def update(self, x, r, dt):
        V_d = self.K_pp * (r["p_c"] - x["p"]) - self.K_pd * x["p_dot"]  # sec. 2.1
        u_s = self.K_ep * (r["e_c"] - x["e"]) - self.K_ed * x["e_dot"]
        return self._out(u_s, V_d, x)

    def describe(self):
        return {"name": self.name, "K_pp": self.K_pp, "K_pd": self.K_pd, "K_ep": self.K_ep, "K_ed": self.K_ed}


class LQRFeedForward(_Heli3dof):
    """u = F r - K x (eq. 33), K from LQR on (A, B) of eq. 31, F from eq. 37."""

    name = "lqr"
    needs = ("p", "p_dot", "e_dot")
    references = {"p_c": 0.0, "e_dot_c": 0.0}

    def __init__(
        self, Q: np.ndarray = design.LAB_Q_FF, R: np.ndarray = design.LAB_R_FF, *, K_f: float = design.K_F, **kw
    ) -> None:
        super().__init__(**kw)
        A, B, C = design.pitch_model(self.motor_constant(K_f, self.rig))
        self.Q, self.R = np.asarray(Q, float), np.asarray(R, float)
        self.K = design.lqr(A, B, self.Q, self.R)
        self.F = design.reference_feedforward(A, B, C, self.K)

    def update(self, x, r, dt):
        xs = np.array([x["p"], x["p_dot"], x["e_dot"]])
        u = self.F @ np.array([r["p_c"], r["e_dot_c"]]) - self.K @ xs
        return self._out(u[0], u[1], x)

    def describe(self):
        return {
            "name": self.name,
            "Q": np.diag(self.Q).tolist(),
            "R": np.diag(self.R).tolist(),
            "K": self.K.round(4).tolist(),
            "F": self.F.round(4).tolist(),
        }


class LQRIntegral(_Heli3dof):
    """LQR on the augmented model of eq. 41; u = F r - K (x, gamma, zeta).

    ``gamma_dot = p - p_c``, ``zeta_dot = e_dot - e_dot_c`` (eq. 39), integrated
    with the controller's own step. F: see :mod:`.design` (eq. 43 leaves it free).
    """

    name = "lqr_i"
    needs = ("p", "p_dot", "e_dot")
    references = {"p_c": 0.0, "e_dot_c": 0.0}

    def __init__(
        self,
        Q: np.ndarray = design.LAB_Q_I,
        R: np.ndarray = design.LAB_R_I,
        *,
        K_f: float = design.K_F,
        integral_limit: float = 5.0,
        anti_windup: bool = True,
        **kw,
    ) -> None:
        super().__init__(**kw)
        self.anti_windup = anti_windup
        K_f = self.motor_constant(K_f, self.rig)
        A, B, _ = design.integral_model(K_f)
        A3, B3, C3 = design.pitch_model(K_f)
        self.Q, self.R = np.asarray(Q, float), np.asarray(R, float)
        self.K = design.lqr(A, B, self.Q, self.R)
        self.F = design.reference_feedforward(A3, B3, C3, self.K[:, :3])
        self.integral_limit = integral_limit
        self.z = np.zeros(2)  # gamma, zeta

    def reset(self):
        self.z = np.zeros(2)

    def update(self, x, r, dt):
        xs = np.array([x["p"], x["p_dot"], x["e_dot"]])
        ref = np.array([r["p_c"], r["e_dot_c"]])
        err = np.array([xs[0] - ref[0], xs[2] - ref[1]])  # eq. 39
        u = self.F @ ref - self.K @ np.concatenate([xs, self.z])
        out = self._out(u[0], u[1], x)
        # conditional integration: stop while saturated, unless the error unwinds it
        dz = err * dt
        if out.saturated and self.anti_windup:
            excess = u - out.u  # how far past the limits, per input
            push = -(self.K[:, 3:] @ dz)  # what integrating would add to u
            if np.any(excess * push > 0):
                dz = np.zeros(2)
        self.z = np.clip(self.z + dz, -self.integral_limit, self.integral_limit)
        return out

    def describe(self):
        return {
            "name": self.name,
            "Q": np.diag(self.Q).tolist(),
            "R": np.diag(self.R).tolist(),
            "K": self.K.round(4).tolist(),
            "F": self.F.round(4).tolist(),
        }


# -- altitude hold ----------------------------------------------------------------------------


@dataclass(frozen=True)
class ThrustMap:
    """Collective -> vertical specific force along the body axis: ``a_T = gain * c + offset``."""

    gain: float
    offset: float
    limit: tuple[float, float] = (0.0, 1.0)

    def collective(self, a_T: float) -> float:
        return (a_T - self.offset) / self.gain


#: quadcopter document eq. 2 with the simulated airframe's coefficients (alpha, beta)
QUAD_THRUST = ThrustMap(22.0, -1.2)
#: coaxial document: (1 + k_w) k_F i / m with k_F = 4.4 N (5.21), k_w = 0.84 (5.29), m = 0.5 kg
COAX_THRUST = ThrustMap((1 + 0.84) * 4.4 / 0.5, 0.0)


#: height error, vertical speed, integral: a loop of about 1.2 rad/s
HOLD_Q = np.diag([2.0, 1.0, 0.5])
HOLD_R = np.array([[1.0]])


class AltitudeHold(Controller):
    """Height hold on the altitude filter's state: LQR + integral on z_dd = a, thrust model inverted.

    States ``(z - z_c, vz, integral of z - z_c)``; Q, R default to a loop of about
    1.2 rad/s, gentle enough for the altitude filter's few-cm noise. When the
    feedback carries the thrust filter's own ``alpha`` and ``beta`` (quadcopter
    model), those replace the nominal thrust map: the loop adapts as the
    battery sags.
    """

    name = "altitude_hold"
    needs = ("z", "vz")
    references = {"z_c": 1.0}
    command_names = ("collective",)
    #: a small rotorcraft's flight: beyond a quarter turn of tilt it is upside down, and a thrust
    #: curve outside these is no estimate to fly on
    state_limits = {
        "z": (-10.0, 1000.0),
        "vz": (-30.0, 30.0),
        "roll": (-math.pi / 2, math.pi / 2),
        "pitch": (-math.pi / 2, math.pi / 2),
        "alpha": (1.0, 200.0),
        "beta": (-50.0, 50.0),
    }
    command_limits = (0.0, 1.0)

    def __init__(
        self,
        thrust: ThrustMap = QUAD_THRUST,
        *,
        Q=HOLD_Q,
        R=HOLD_R,
        a_limit: float = 0.5 * G,
        integral_limit: float = 3.0,
    ) -> None:
        A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
        B = np.array([[0.0], [1.0], [0.0]])
        self.Q, self.R = np.asarray(Q, float), np.asarray(R, float)
        self.K = design.lqr(A, B, self.Q, self.R)[0]
        self.thrust, self.a_limit, self.integral_limit = thrust, a_limit, integral_limit
        self.i = 0.0

    def reset(self):
        self.i = 0.0

    def update(self, x, r, dt):
        e = x["z"] - r["z_c"]
        a = -float(self.K @ np.array([e, x["vz"], self.i]))
        a_c = clamp(a, -self.a_limit, self.a_limit)
        tilt = clamp(math.cos(x.get("roll", 0.0)) * math.cos(x.get("pitch", 0.0)), 0.5, 1.0)
        gain = x.get("alpha", self.thrust.gain)
        offset = x.get("beta", self.thrust.offset)
        c = (G + a_c - offset) / (gain * tilt)
        lo, hi = self.thrust.limit
        c_c = clamp(c, lo, hi)
        sat = a_c != a or c_c != c
        # conditional integration: while saturated, only what unwinds it
        excess = (a - a_c) if a_c != a else (c - c_c)
        push = -self.K[2] * e * dt
        if not sat or excess * push <= 0:
            self.i = clamp(self.i + e * dt, -self.integral_limit, self.integral_limit)
        return Output(np.array([c_c]), np.array([a_c]), sat)

    def describe(self):
        return {"name": self.name, "K": self.K.round(4).tolist(), "thrust": [self.thrust.gain, self.thrust.offset]}
