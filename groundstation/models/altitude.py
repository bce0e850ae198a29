"""Altitude with accelerometer bias: coaxial-helicopter document, chapter 9.

State (eq. 9.9): ``x = (z, z_dot, b_acc)``, z up [m], z_dot [m/s], b_acc the
accelerometer bias [m/s^2]. Input: the measured vertical acceleration
``gamma_z`` [m/s^2]. Continuous model (eq. 9.7)::

    z_dot     = z_dot
    z_ddot    = gamma_z - b_acc             (eq. 9.1: gamma_z = z_ddot + b_acc)
    b_acc_dot = 0 (+ noise)                 (eq. 9.6)

    A = [[0, 1, 0], [0, 0, -1], [0, 0, 0]],  B = (0, 1, 0)^T,  Qc = diag(0, G_acc, G_bias)  (9.22)

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
* ``gps``: GPS altitude minus its value at initialisation, ``= z``.

Corrections to the document, made knowingly:

* Below eq. 9.4 the input is written ``u = gamma_z B_gamma``; eq. 9.1 and 9.7
  make it ``gamma_z - B_gamma`` (through A's -1), which is what we use.
* Eq. 9.26 calls R "the standard deviation"; it is the variance sigma^2.
* An accelerometer measures specific force, not acceleration: gamma_z is the
  vertical component of the specific force in the world frame with gravity
  removed, ``gamma_z = -(R_IB f)_down - g``; the document leaves g implicit.
"""
from __future__ import annotations

import numpy as np

from ..measurement import Kind
from .base import LinearModel, MeasurementModel, barometer, relative_to_estimate, slant

G = 9.80665


def altitude_model(*, G_acc: float = 3.0e-5, G_bias: float = 1.0e-8, sigma_range: float = 0.0105,
                   sigma_baro: float = 0.338, sigma_gps: float = 2.0, P0_bias: float = 0.04,
                   range_tilt: bool = False, range_offset: float = 0.0, use_gps: bool = False) -> LinearModel:
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
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0]])
    B = np.array([[0.0], [1.0], [0.0]])
    H = np.array([[1.0, 0.0, 0.0]])

    def range_row(ctx):
        return np.array([[slant(ctx), 0.0, 0.0]])

    meas = {
        "range": MeasurementModel("range", Kind.RANGE, lambda m, ctx: np.array([m.value[0] - range_offset]),
                                  range_row if range_tilt else (lambda ctx: H), np.array([[sigma_range**2]])),
        "gps": MeasurementModel("gps", Kind.GPS, relative_to_estimate(lambda m: float(m.value[2]), "gps_ref", 10),
                                lambda ctx: H, np.array([[sigma_gps**2]])),
        **barometer(lambda ctx: H, np.array([[sigma_baro**2]])),
    }
    if not use_gps:
        # GPS altitude errors are correlated over tens of seconds (2 m over 20 s in the
        # simulator, worse on real receivers): taken as white they fail every whiteness
        # test and add nothing a baro and a range sensor do not already give. ``use_gps``
        # puts them back (the document's GPS update, eq. 9.8's sibling).
        del meas["gps"]
    return LinearModel(
        name="altitude", states=["z", "vz", "b_acc"], inputs=["gamma_z"],
        A=lambda u: A, B=B, Qc=np.diag([0.0, G_acc, G_bias]),
        x0=np.zeros(3), P0=np.diag([0.05**2, 0.05**2, P0_bias]), measurements=meas,
        doc=__doc__)
