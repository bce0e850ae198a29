"""How a model is declared: states, inputs, continuous dynamics, measurement models.

A :class:`LinearModel` is the continuous-time linear (possibly input-dependent)
system ::

    x_dot = A(u) x + B u + w,    E[w w^T] = Qc delta(t)        (coaxial doc. eq. 9.2, 9.20)
    y     = H(m, ctx) x + h0(m, ctx) + v,  E[v v^T] = R         (eq. 9.3)

with named states and inputs. A nonlinear model (the multirotor attitude) gives
its dynamics ``x_dot = f(x, u)`` and their Jacobian instead of ``A``; the
filter then relinearises at every step, an extended Kalman filter (the
measurement stays linear in the state, ``H(ctx)``). The filter discretises it exactly for each step
(:func:`discretize`, Van Loan's method), so a model is written as its equations
and never as hand-discretised matrices, and it can be **augmented**
(:meth:`LinearModel.augmented`) with extra states, regressors on a
measurement, or changed measurement functions without touching the filter:
the diagnosis adds effects exactly this way.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.linalg import expm

from groundstation.core.atmosphere import altitude_at
from groundstation.core.measurement import Kind, Measurement

from ..context import Context, Zero

#: a measurement model's reader: the measured vector of a record, or None to skip it
Extract = Callable[[Measurement, Context], "np.ndarray | None"]
#: an impulse the model's dynamics lack, read at a record of its kind: the variance [state: added
#: variance] that the event adds to the named states at the filter's time, or None when none happened
Impulse = Callable[[Measurement, Context], "dict[str, float] | None"]


@dataclass
class MeasurementModel:
    """One sensor's measurement equation ``y = H x + offset``.

    ``extract(m, ctx)`` turns a :class:`Measurement` into the measured vector
    (e.g. pressure to pressure altitude) or None to skip it; ``row(ctx)`` gives
    H (it may depend on the context: a tilt, a throttle); ``offset(ctx)`` adds
    a known term; ``R`` is the noise variance (matrix for vector sensors).
    """

    name: str
    kind: Kind
    extract: Extract
    row: Callable[[Context], np.ndarray]
    R: np.ndarray
    offset: Callable[[Context], np.ndarray] | None = None
    instance: int | None = None  # None: any instance
    #: state indices the update may correct; None: all. A constraint that describes an impulse the
    #: model lacks (the ground stopping a touchdown) corrects only the states it acts on, and the
    #: others keep what the data told them: a Schmidt ("consider") update
    corrects: tuple[int, ...] | None = None
    #: with ``corrects``: the update sets those states to the measured value with variance R and
    #: independent of the rest (a reset: the ground holds the vehicle whatever the other states are).
    #: Repeated at every input on the ground, an update's information would pile up instead
    reset: bool = False
    #: a constraint on the state as it is (the ground under a landed vehicle), applied at the
    #: filter's own time: its message's time does not move the filter's clock. A throttle message's
    #: time may lead the sensors' by more than the loop's reorder window (on the live simulated
    #: link SERVO_OUTPUT_RAW led the IMU by 90 ms), and predicted to it, the filter dropped the
    #: IMU blocks after it as out of order: the demo's estimate fell to -1.2 m at the landing
    untimed: bool = False
    #: ``R`` is one raw sample's variance: a measurement averaging n samples (``Measurement.samples``,
    #: an IMU block mean) is updated with R / n. Fixed per block, R had assumed the 500 Hz
    #: simulator's 5-6 samples; a live recording's 250 Hz IMU gives 3, and its attitude diagnosis
    #: read an accelerometer NIS of 3.74 for 2
    per_sample: bool = False

    @property
    def dim(self) -> int:
        return int(np.atleast_2d(self.R).shape[0])


@dataclass
class LinearModel:
    name: str
    states: list[str]
    inputs: list[str]
    A: Callable[[np.ndarray], np.ndarray]  # A(u)
    B: np.ndarray
    Qc: np.ndarray  # continuous process-noise density
    x0: np.ndarray
    P0: np.ndarray
    measurements: dict[str, MeasurementModel]
    doc: str = ""
    #: states whose values cannot be known from the sensors (reported, not guessed)
    notes: list[str] = field(default_factory=list)
    #: nonlinear dynamics x_dot = f(x, u) and their Jacobian df/dx (an EKF; ``A`` unused)
    f: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    jacobian: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    #: the builder's keyword arguments: a model that cannot be :meth:`augmented` (a nonlinear
    #: one) is rebuilt with one more effect from them
    options: dict = field(default_factory=dict)
    #: per record kind, events the continuous dynamics do not hold (the ground letting go of the
    #: vehicle at lift-off): each adds process noise to named states when it happens
    impulses: dict[Kind, tuple[Impulse, ...]] = field(default_factory=dict)
    #: a cheap key of ``A(u)``: inputs with the same key give the same A (None: A itself is its key).
    #: The filter keys its discretisations on it, and holds back the covariance's steps while it stays
    A_key: Callable[[np.ndarray], Hashable] | None = None

    @property
    def n(self) -> int:
        return len(self.states)

    def index(self, state: str) -> int:
        return self.states.index(state)

    def augmented(
        self,
        *,
        states: Sequence[str] = (),
        A_extra: Callable | None = None,
        Qc_extra=(),
        x0_extra=(),
        P0_extra=(),
        coupling: Callable | None = None,
        measurements: dict[str, MeasurementModel] | None = None,
        name: str | None = None,
    ) -> LinearModel:
        """A new model with extra states appended (random walks by default).

        ``coupling(u) -> (n_old x k)`` lets the new states drive the old ones
        (a bias on an input, a thrust factor); ``A_extra(u) -> (k x k)`` is
        their own dynamics; ``measurements`` replaces or adds measurement
        models, whose rows must then have ``n_old + k`` columns (see
        :func:`pad_row` to extend an old row).
        """
        if self.f is not None:
            raise ValueError(f"{self.name}: a nonlinear model is rebuilt from its options, not augmented")
        k = len(states)
        n0 = self.n
        A_old = self.A

        def A(u):
            a = np.zeros((n0 + k, n0 + k))
            a[:n0, :n0] = A_old(u)
            if coupling is not None:
                a[:n0, n0:] = coupling(u)
            if A_extra is not None:
                a[n0:, n0:] = A_extra(u)
            return a

        B = np.vstack([self.B, np.zeros((k, self.B.shape[1]))])
        Qc = np.zeros((n0 + k, n0 + k))
        Qc[:n0, :n0] = self.Qc
        Qc[n0:, n0:] = np.diag(np.asarray(Qc_extra, dtype=float)) if k else 0
        P0 = np.zeros((n0 + k, n0 + k))
        P0[:n0, :n0] = self.P0
        P0[n0:, n0:] = np.diag(np.asarray(P0_extra, dtype=float)) if k else 0
        meas = {}
        for key, mm in self.measurements.items():
            meas[key] = replace(mm, row=padded(mm.row, k))
        meas.update(measurements or {})
        # the old A's key still keys the new A where the new states take no input
        u0 = np.zeros(len(self.inputs))
        keyed = coupling is None and (A_extra is None or np.array_equal(A_extra(u0), A_extra(u0 + 1.0)))
        return LinearModel(
            name or self.name,
            self.states + list(states),
            list(self.inputs),
            A,
            B,
            Qc,
            np.concatenate([self.x0, np.asarray(x0_extra, dtype=float)]),
            P0,
            meas,
            self.doc,
            list(self.notes),
            options=dict(self.options),
            impulses=dict(self.impulses),
            A_key=self.A_key if keyed else None,
        )


def with_measurement_noise(model: LinearModel, noise: dict[str, np.ndarray] | None) -> LinearModel:
    """``model`` with each named sensor's R from ``noise`` (``groundstation noise``'s output: sensor
    -> R). A sensor the model lacks, an R of another size than the sensor's, or one that is not a
    covariance (NaN, not positive definite) is a ValueError: a noise file made for another model must
    not be taken silently as this one's, nor a broken one put into the filter."""
    if not noise:
        return model
    meas = dict(model.measurements)
    for sensor, R in noise.items():
        keys = [k for k, mm in meas.items() if mm.name == sensor]
        if not keys:
            raise ValueError(f"--noise: the {model.name} model has no sensor {sensor!r}")
        R = np.atleast_2d(np.asarray(R, dtype=float))
        if not (np.all(np.isfinite(R)) and np.allclose(R, R.T) and np.all(np.linalg.eigvalsh(R) > 0.0)):
            raise ValueError(f"--noise: {sensor}'s R is not a covariance (finite, symmetric, positive definite)")
        for k in keys:
            if R.shape != np.atleast_2d(meas[k].R).shape:
                raise ValueError(
                    f"--noise: {sensor}'s R is {R.shape[0]}x{R.shape[1]}, the {model.name} model's is "
                    f"{np.atleast_2d(meas[k].R).shape[0]}x{np.atleast_2d(meas[k].R).shape[1]}"
                )
            meas[k] = replace(meas[k], R=R)
    return replace(model, measurements=meas)


#: longest the held attitude is carried forward by its rates (a dropout holds it instead)
ATTITUDE_HOLD_MAX = 0.1


def tilt_now(ctx: Context) -> tuple[float, float]:
    """Roll and pitch at the measurement's time ``ctx.t``: the latest attitude message
    carried forward by its body rates (first order; an autopilot sends attitude at 10-50 Hz
    and a range sensor reads in between). Held as it came, a 50 Hz attitude is on average
    10 ms old. Held so, and with the IMU blocks stamped at their first sample, the range of clean
    simulated flights looked 5.5 ms early (with both as here, 2.5 ms), and a true 30 ms range
    delay was measured as 22-28 ms."""
    roll, pitch = ctx.roll, ctx.pitch
    t_att = ctx.attitude_t
    if t_att is not None and ctx.roll_rate is not None and ctx.pitch_rate is not None and ctx.t is not None:
        dt = min(max(ctx.t - t_att, 0.0), ATTITUDE_HOLD_MAX)
        roll += ctx.roll_rate * dt
        pitch += ctx.pitch_rate * dt
    return roll, pitch


def slant(ctx: Context) -> float:
    """1 / (cos(roll) cos(pitch)): a body-z range sensor's reading per metre of height (tilt <= 78 deg)."""
    roll, pitch = tilt_now(ctx)
    return 1.0 / max(math.cos(roll) * math.cos(pitch), 0.2)


def relative_to_estimate(value_of: Callable[[Measurement], float], key: str, n_cal: int):
    """An extractor for an absolute altitude (baro, GPS) made relative to the
    ground station's zero: its first ``n_cal`` readings are averaged against the
    estimate of z (no update meanwhile: the extractor returns None), so the zero
    carries 1/sqrt(n_cal) of one reading's noise instead of all of it. ``key`` names the
    zero in the context's :attr:`~.Context.zeros`."""

    def extract(m: Measurement, ctx: Context) -> np.ndarray | None:
        v = value_of(m)
        zero = ctx.zeros.get(key, Zero())
        ref = zero.ref
        if ref is None:
            total, n = zero.total + v - ctx.z, zero.n + 1
            if n < n_cal:
                ctx.zeros[key] = Zero(total, n, None, zero.held)
                return None
            ref = total / n if zero.held is None else zero.held
            ctx.zeros[key] = Zero(total, n, ref, zero.held)
        return np.array([v - ref])

    return extract


def barometer(row: Callable[[Context], np.ndarray], R: np.ndarray) -> dict[str, MeasurementModel]:
    """A barometer's two forms, as a height relative to the ground station's zero: a pressure
    (MAVLink SCALED_PRESSURE, ``baro``; the standard atmosphere's altitude) and an altitude (DataFlash
    BARO.Alt, Crazyflie baro.asl, ``baro_alt``), both named ``baro``. One barometer, one update: a
    log that gives the same sample as a pressure and as an altitude (DataFlash BARO: Press and Alt)
    is read from the pressure."""
    from_pressure = relative_to_estimate(lambda m: altitude_at(float(m.value[0])), "baro_ref", 50)
    from_altitude = relative_to_estimate(lambda m: float(m.value[0]), "baro_alt_ref", 25)

    def baro_pressure(m, ctx):
        ctx.baro_has_pressure = True
        return from_pressure(m, ctx)

    def baro_altitude(m, ctx):
        return None if ctx.baro_has_pressure else from_altitude(m, ctx)

    return {
        "baro": MeasurementModel("baro", Kind.BARO_PRESSURE, baro_pressure, row, R),
        "baro_alt": MeasurementModel("baro", Kind.BARO_ALTITUDE, baro_altitude, row, R),
    }


def unit_row(n: int, i: int) -> np.ndarray:
    """H for a measurement of state i alone, of an n-state model."""
    r = np.zeros((1, n))
    r[0, i] = 1.0
    return r


def state_row(n: int, i: int) -> Callable[[Context], np.ndarray]:
    """H(ctx) of a measurement of state i alone, of an n-state model."""
    return lambda ctx: unit_row(n, i)


def padded(row: Callable[[Context], np.ndarray], k: int) -> Callable[[Context], np.ndarray]:
    """H(ctx) of ``row`` extended with k zero columns (for augmented states). A row that returns the
    same array each time (a constant H: no one writes into an H) gets the same padded array back,
    made once: a filter reads its rows at every update."""
    last: list = [None, None]  # (row's last H, held so its id stays its own; that H padded)

    def padded_row(ctx: Context) -> np.ndarray:
        r = row(ctx)
        if r is not last[0]:
            last[0], last[1] = r, pad_row(r, k)
        return last[1]

    return padded_row


def pad_row(row: np.ndarray, k: int) -> np.ndarray:
    """Extend measurement rows with k zero columns (for augmented states)."""
    r = np.atleast_2d(row)
    out = np.zeros((r.shape[0], r.shape[1] + k))
    out[:, : r.shape[1]] = r
    return out


def discretize(
    A: np.ndarray, B: np.ndarray, Qc: np.ndarray, dt: float, *, with_q: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Exact zero-order-hold discretisation (coaxial doc. eq. 9.11, 9.15, 9.23).

    Phi = e^{A dt}, G = int_0^dt e^{A s} ds B, Q_k = int_0^dt e^{A s} Qc e^{A^T s} ds,
    all from matrix exponentials of block matrices (Van Loan, 1978), so the
    closed forms of eq. (9.14), (9.16), (9.24) come out for the altitude model
    and no model needs them written by hand. ``with_q=False``: Phi and G alone (Q_k None), for a
    step of the state whose covariance is propagated later, over a longer stretch.
    """
    n, m = A.shape[0], B.shape[1]
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A * dt
    M[:n, n:] = B * dt
    E = expm(M)
    Phi, G = E[:n, :n], E[:n, n:]
    if not with_q:
        return Phi, G, None
    V = np.zeros((2 * n, 2 * n))
    V[:n, :n] = -A * dt
    V[:n, n:] = Qc * dt
    V[n:, n:] = A.T * dt
    F = expm(V)
    Qk = Phi @ F[:n, n:]
    return Phi, G, 0.5 * (Qk + Qk.T)


def discretize_series(
    A: np.ndarray, B: np.ndarray, Qc: np.ndarray, dt: float, halvings: int = 0, *, with_q: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The integrals of :func:`discretize` by their Taylor series to fourth order in ``A dt``
    (for steps that each have their own A or dt, where the exponentials would dominate)::

        Phi = sum_{k=0..4} (A T)^k / k!
        G   = sum_{k=0..3} A^k T^{k+1} / (k+1)!  B
        Q_k = sum_{k=0..3} T^{k+1} / (k+1)!  sum_j C(k, j) A^j Qc A^T^{k-j}

    Truncation error ~ (|A| T)^5 / 120: below 3e-6 of the step's terms for |A| T < 0.2.

    ``halvings`` s: the series over T = dt / 2^s, then s doublings, each exact (two equal steps of
    one A are one step of twice the length; the scaling and squaring of Moler and Van Loan, 2003)::

        Phi(2T) = Phi(T)^2,  G(2T) = G(T) + Phi(T) G(T),  Q_k(2T) = Q_k(T) + Phi(T) Q_k(T) Phi(T)^T

    so a longer step (a 10 Hz log's, a fast rotor's) keeps the series' accuracy at a few small
    products per doubling, where the exponentials of the block matrices cost twenty times more.
    ``with_q=False``: Phi and G alone, as :func:`discretize`'s.
    """
    if halvings:
        Phi, G, Qk = discretize_series(A, B, Qc, dt / 2**halvings, with_q=with_q)
        for _ in range(halvings):
            G = G + Phi @ G
            if Qk is not None:
                Qk = Qk + Phi @ Qk @ Phi.T
            Phi = Phi @ Phi
        return Phi, G, 0.5 * (Qk + Qk.T) if Qk is not None else None
    eye = np.eye(A.shape[0])
    AT = A * dt
    # Gamma = I + AT/2 + (AT)^2/6 + (AT)^3/24 in Horner's form; then Phi = I + AT Gamma, G = Gamma B T
    Gam = eye + AT @ (eye + AT @ (eye + AT / 4) / 3) / 2
    Phi = eye + AT @ Gam
    G = Gam @ B * dt
    if not with_q:
        return Phi, G, None
    # the covariance integral's series: M_k = A M_{k-1} + M_{k-1} A^T, M_0 = Qc (each M_k symmetric)
    M1 = A @ Qc
    M1 = M1 + M1.T
    M2 = A @ M1
    M2 = M2 + M2.T
    M3 = A @ M2
    M3 = M3 + M3.T
    Qk = Qc * dt + M1 * dt**2 / 2 + M2 * dt**3 / 6 + M3 * dt**4 / 24
    return Phi, G, 0.5 * (Qk + Qk.T)


def observability_rank(A: np.ndarray, C: np.ndarray) -> int:
    """Rank of [C; CA; ...; CA^{n-1}] (continuous-time observability)."""
    n = A.shape[0]
    blocks, M = [], np.atleast_2d(C)
    for _ in range(n):
        blocks.append(M)
        M = M @ A
    return int(np.linalg.matrix_rank(np.vstack(blocks)))
