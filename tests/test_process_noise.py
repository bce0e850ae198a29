"""The vertical speed's process noise chosen by the log's likelihood (diagnosis.scoring.noise_match.
match_process_noise), on another generator's lidar flight: an accelerometer bias that steps as the IMU
warms needs more of it than our simulator's flights, and a clean flight keeps the model's."""

import csv

import numpy as np
import pytest

from groundstation.core.imu import ImuSeries
from groundstation.core.measurement import Kind
from groundstation.diagnosis.models import setup
from groundstation.diagnosis.pipeline import _usable_imu
from groundstation.diagnosis.runs.run import hold_zeros, run_model
from groundstation.diagnosis.scoring.noise_match import PROCESS_LEVEL, match_noise, match_process_noise
from groundstation.diagnosis.triage import triage, usable
from groundstation.estimation.logs import load_log
from groundstation.estimation.stated import stated_by

from .conftest import foreign2_file

#: the injected bias [m/s^2] along the body's z, from when the IMU has warmed this much [K]
BIAS, WARMED = 0.3, 3.0


def _flight(bias: float):
    """The lidar flight's setup, its model's run with the sensors' noise matched, the truth (t, height
    up while in flight) and the model's noise as matched; the accelerometer's z offset by ``bias`` from
    the moment the truth's IMU temperature has risen by :data:`WARMED`."""
    p = foreign2_file("clean_range_s1.bin")
    rows = list(csv.DictReader(open(p.with_name(p.stem + "_truth.csv"))))
    tt, z, fl, temp = (np.array([float(r[k]) for r in rows]) for k in ("t", "z", "in_flight", "imu_temp_c"))
    log = load_log(p, imu_columns=True)
    assert log.imu is not None
    if bias:
        for key, s in list(log.imu.series.items()):
            if key[0] is Kind.ACCEL:
                v = s.values().copy()
                v[:, 2] += np.where(np.interp(s.t, tt, temp) > temp[0] + WARMED, bias, 0.0)
                log.imu.series[key] = ImuSeries(s.source, s.t, s.t_rx, v, s.samples)
    tr = triage(log.tables, log.measurements, log.imu)
    ms, _, _ = usable(log.measurements, tr)
    su = setup(ms, imu=_usable_imu(log, tr, keep=False), stated=stated_by(log.tables, log.measurements))
    hold_zeros(su.prep, run_model(su.model, su.prep, su.make))
    model, _, _ = match_noise(su.model, su.prep, su.make)
    flying = fl > 0.5
    return su, model, run_model(model, su.prep, su.make, scores_only=True), (tt[flying], z[flying])


def _height_error(run, truth) -> float:
    t, z = truth
    return float(np.sqrt(np.mean((np.interp(t, run.t, run.x[:, 0]) - z) ** 2)))


@pytest.mark.slow
def test_an_accelerometer_bias_step_raises_the_process_noise_and_the_height_follows_the_lidar():
    """With the model's level the height lags the lidar for seconds after the step (2.96 cm off the
    truth in flight, a plain filter 1.48); the likelihood takes a level 9 times the model's or more,
    and the height comes within 60 % of that error (1.16 cm)."""
    su, model, run, truth = _flight(BIAS)
    with_q, level = match_process_noise(model, su.prep, su.make, run, workers=2)
    assert level is not None
    assert level.sensor == PROCESS_LEVEL and level.ratio >= 3.0 - 1e-9 and level.differs
    i = model.index("vz")
    assert with_q.Qc[i, i] == pytest.approx(level.sigma_data**2)
    chosen = run_model(with_q, su.prep, su.make, scores_only=True)
    assert _height_error(chosen, truth) < 0.6 * _height_error(run, truth)
    assert chosen.loglik > run.loglik
    # the same level on one core as on two
    assert match_process_noise(model, su.prep, su.make, run)[1] == level


@pytest.mark.slow
def test_the_clean_flight_keeps_the_models_process_noise():
    """Without the step no level beats the model's by very strong evidence: nothing changes."""
    su, model, run, _ = _flight(0.0)
    with_q, level = match_process_noise(model, su.prep, su.make, run)
    assert level is None and with_q is model
