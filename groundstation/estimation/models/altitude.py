"""Altitude with accelerometer bias: coaxial-helicopter document, chapter 9.

State (eq. 9.9): ``x = (z, z_dot, b_acc)``, z up [m], z_dot [m/s], b_acc the
accelerometer bias along the body's up axis (-z FRD) [m/s^2]. Inputs: the measured vertical
acceleration ``gamma_z`` [m/s^2] and ``cos_tilt`` = cos(roll) cos(pitch), the body z axis's
share of the vertical. Continuous model (eq. 9.7, with the bias in the body frame)::

    z_dot     = z_dot
    z_ddot    = gamma_z - cos_tilt b_acc    (eq. 9.1: gamma_z = z_ddot + b_acc, level)
    b_acc_dot = 0 (+ noise)                 (eq. 9.6)

    A = [[0, 1, 0], [0, 0, -cos_tilt], [0, 0, 0]],  B = [(0, 1, 0)^T, 0],  Qc = diag(0, G_acc, G_bias)  (9.22)

discretised exactly (Phi = e^{AT}, eq. 9.14; G, eq. 9.16; Q_k, eq. 9.24: the
test suite checks our numerical discretisation against those closed forms).

Measurement models, one per sensor (eq. 9.8 is the range sensor's):

* ``range``: ``d = z`` (H = (1, 0, 0)), the document's eq. 9.8; with
  ``range_tilt=True`` (the catalogue effect, when declared or found) the slant
  ``d = z / (cos(roll) cos(pitch))``, H = (1 / (cos(roll) cos(pitch)), 0, 0);
  with a mounting offset ``range_offset = o`` [m] (catalogue ``range_offset``,
  the simulator's ``d_meas = d + o``) the reading is corrected to ``d - o``;
* ``baro``: pressure altitude (ISA, or the log's own baro altitude) minus its
  value at initialisation, ``= z``; each has its own zero, and a log that gives
  both for one sample (DataFlash BARO) is read once, from the pressure;
* ``gps``: GPS altitude minus its value at initialisation, ``= z``;
* ``gps_vz`` (``gps_velocity=True``, with ``use_gps``): the fix's own vertical velocity, ``= z_dot``
  (H = (0, 1, 0)): what both autopilots' height filters take from a receiver.

Corrections to the document, made knowingly:

* Below eq. 9.4 the input is written ``u = gamma_z B_gamma``; eq. 9.1 and 9.7
  make it ``gamma_z - B_gamma`` (through A's -1), which is what we use.
* Eq. 9.26 calls R "the standard deviation"; it is the variance sigma^2.
* An accelerometer measures specific force, not acceleration: gamma_z is the
  vertical component of the specific force in the world frame with gravity
  removed, ``gamma_z = -(R_IB f)_down - g``; the document leaves g implicit.
* The document's b_acc sits on the vertical (its helicopter hovers level). An
  accelerometer's bias is in the sensor's own frame, and the rotation into the
  world carries it: along the vertical it is cos_tilt b_acc. Held on the vertical,
  the bias left b (1 - cos_tilt) in the input whenever the vehicle tilted: on a
  simulated standard flight with a body-z bias of 0.4 m/s^2 the range innovations
  failed NIS (1.19) and Ljung-Box (p 0.000), and the diagnosis named the low-passed
  tilt; in the body frame, 1.01 and p 0.08 (the horizontal axes' biases look like a
  tilt and stay unmodelled: the attitude model's docstring). A is the document's at
  level, and the discretisation (eq. 9.14-9.24) holds for each held input.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from groundstation.core.measurement import Kind

from .base import LinearModel, MeasurementModel, barometer, pad_row, relative_to_estimate, slant

G = 9.80665


#: cos_tilt's step in A: the filter caches each distinct A's discretisation and sums the covariance's
#: steps while A stays the same (filters.ModelFilter._apply_pending). Half a step of 0.4 m/s^2 of bias
#: is 2e-4 m/s^2, under a hundredth of the accelerometer's noise over a 10 ms step (0.055 m/s^2); a
#: step of 1e-4 changed A at 45 % of the steps on a logged 400 Hz IMU (another generator's .bin)
COS_TILT_STEP = 1e-3


def transition(u) -> np.ndarray:
    """A(u): the document's, with the bias's coupling -cos_tilt; level for ``A(None)`` (the
    closed-form tests). A filter's inputs start at zero, so until the first accelerometer
    sample it predicts no acceleration at all, the bias's share included."""
    c = 1.0 if u is None or len(u) < 2 else tilt_key(u) * COS_TILT_STEP
    return np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -c], [0.0, 0.0, 0.0]])


def tilt_key(u) -> int:
    """A(u)'s key (``LinearModel.A_key``): cos_tilt in steps of :data:`COS_TILT_STEP`."""
    return round(float(u[1]) / COS_TILT_STEP)


def altitude_model(
    *,
    G_acc: float = 3.0e-5,
    G_bias: float = 1.0e-8,
    sigma_range: float = 0.0105,
    sigma_baro: float = 0.338,
    sigma_gps: float = 2.0,
    P0_bias: float = 0.04,
    range_tilt: bool = False,
    range_offset: float = 0.0,
    use_gps: bool = False,
    gps_error: tuple[float, float] | None = None,
    gps_velocity: bool = False,
    sigma_gps_vz: float = 0.3,
) -> LinearModel:
    """The document's 3-state filter with our default noise densities.

    ``G_acc`` [(m/s^2)^2 / Hz]: accelerometer white noise (0.08 m/s^2 at
    500 Hz is 1.3e-5) and what the input model misses (attitude error in the
    rotation), tuned so that NEES sits in its chi-square band on simulated
    flights; ``G_bias`` [(m/s^2)^2 / s]: how fast the bias may wander (IMU bias
    instability); ``sigma_*``: the sensors' noise (range: 1 cm plus 1 cm
    quantisation; baro: 4 Pa plus 1.2 Pa steps, sqrt(4^2 + 1.2^2 / 12) = 4.015 Pa,
    at 0.0842 m/Pa near 120 m: 0.338 m. It was 0.345, which put a correct model's
    baro NIS at (0.338 / 0.345)^2 = 0.96, and the NIS test, whose band over a
    60 s flight's 2 700 readings is [0.95, 1.05], failed on a fifth of the
    simulated flights with the model otherwise right).
    """
    B = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]])
    H = np.array([[1.0, 0.0, 0.0]])
    H_VZ = np.array([[0.0, 1.0, 0.0]])

    def range_row(ctx):
        return np.array([[slant(ctx), 0.0, 0.0]])

    meas = {
        "range": MeasurementModel(
            "range",
            Kind.RANGE,
            lambda m, ctx: np.array([m.value[0] - range_offset]),
            range_row if range_tilt else (lambda ctx: H),
            np.array([[sigma_range**2]]),
        ),
        "gps": MeasurementModel(
            "gps",
            Kind.GPS,
            relative_to_estimate(lambda m: float(m.value[2]), "gps_ref", 10),
            lambda ctx: H,
            np.array([[sigma_gps**2]]),
        ),
        **barometer(lambda ctx: H, np.array([[sigma_baro**2]])),
    }
    if use_gps and gps_velocity:
        # the fix's own vertical velocity (ArduPilot's GPS VZ, PX4's vel_d_m_s), as both autopilots'
        # height filters take it (EK3_SRC1_VELZ, EKF2_GPS_CTRL): v_up = -v_down, H = (0, 1, 0). A
        # receiver's velocity comes from its carrier's Doppler, 0.1-0.3 m/s, with no slow wander: it
        # ties the accelerometer's integral between the baro's samples, and its timing is the fix's
        meas["gps_vz"] = MeasurementModel(
            "gps_vz",
            Kind.GPS_VD,
            lambda m, ctx: np.array([-float(m.value[0])]),
            lambda ctx: H_VZ,
            np.array([[sigma_gps_vz**2]]),
        )
    if not use_gps:
        # GPS altitude errors are correlated over tens of seconds (2 m over 20 s in the
        # simulator, worse on real receivers): taken as white they fail every whiteness
        # test and add nothing a baro and a range sensor do not already give. ``use_gps``
        # puts them back (the document's GPS update, eq. 9.8's sibling), ``gps_error`` with
        # their correlated part as a state (:func:`with_gps_error`).
        del meas["gps"]
    model = LinearModel(
        name="altitude",
        states=["z", "vz", "b_acc"],
        inputs=["gamma_z", "cos_tilt"],
        A=transition,
        B=B,
        Qc=np.diag([0.0, G_acc, G_bias]),
        x0=np.zeros(3),
        P0=np.diag([0.05**2, 0.05**2, P0_bias]),
        measurements=meas,
        doc=__doc__,
        A_key=tilt_key,
    )
    return with_gps_error(model, *gps_error) if use_gps and gps_error is not None else model


def with_gps_error(model: LinearModel, sigma: float, tau: float) -> LinearModel:
    """GPS altitude with its correlated error as a first-order Gauss-Markov state, as
    :mod:`.horizontal` does for position: ``b_gps_dot = -b_gps / tau + w``, ``E[w^2] = 2 sigma^2 / tau``,
    and ``y_gps = z + b_gps + v`` (v white, the model's ``sigma_gps``). Taken as white, a receiver's
    slow vertical wander would be averaged to centimetres; with the state, GPS pins the height to
    about ``sigma`` over ``tau`` and carries it over minutes, where a baro drifts with temperature
    and rotor wash. The error starts at zero: the GPS zero is taken against the estimate."""
    n = model.n
    meas = dict(model.measurements)
    gps = meas["gps"]
    old = gps.row

    def row(ctx, old=old):
        r = pad_row(old(ctx), 1)
        r[0, n] = 1.0
        return r

    augmented = model.augmented(
        states=["b_gps"],
        A_extra=lambda u: np.array([[-1.0 / tau]]),
        Qc_extra=[2.0 * sigma**2 / tau],
        x0_extra=[0.0],
        P0_extra=[sigma**2],
    )
    augmented.measurements["gps"] = replace(augmented.measurements["gps"], row=row)
    return augmented
