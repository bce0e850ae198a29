"""The held-out check counts each sensor's gain at its innovations' effective sample size
(groundstation/diagnosis/scoring/holdout.py): a sensor whose innovations carry a slow error the model
leaves in them does not outvote the sensors an effect acts on, and a white sensor's loss still does."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from groundstation.core.measurement import Kind
from groundstation.diagnosis.catalogue.altitude import sensor_delay
from groundstation.diagnosis.runs.run import SETTLE_S, Run, SensorTrace
from groundstation.diagnosis.scoring import holdout
from groundstation.estimation.models.altitude import altitude_model

#: three blocks of 60 updates a sensor, one update a second
N_BLOCK = 60


def trace(nis: np.ndarray) -> SensorTrace:
    """A scalar sensor's innovations at unit variance with the given NIS, one a second from SETTLE_S."""
    n = len(nis)
    return SensorTrace(
        t=SETTLE_S + np.arange(n, dtype=float),
        nu=np.sqrt(nis)[:, None],
        S=np.ones((n, 1, 1)),
        nis=nis,
        z=np.zeros((n, 1)),
    )


def run(baro_gain: float, gps_gain: tuple[float, float, float], gps_colour: float) -> Run:
    """A run whose baro gains ``baro_gain`` on each block over the base's and whose GPS gains
    ``gps_gain[k]`` on block k, spread evenly over its updates; its GPS innovations' n / n_eff
    ``gps_colour``."""
    one = np.ones(N_BLOCK)
    baro = np.concatenate([one - 2.0 * baro_gain / N_BLOCK] * 3)
    gps = np.concatenate([one - 2.0 * g / N_BLOCK for g in gps_gain])
    return Run(
        model=None,  # type: ignore[arg-type]
        sensors={"baro": trace(baro), "gps": trace(gps)},
        t=np.zeros(0),
        x=np.zeros((0, 1)),
        covariance=np.zeros((0, 1, 1)),
        loglik=0.0,
        n_scored=0,
        ctx=None,  # type: ignore[arg-type]
        inflation={"baro": 1.0, "gps": gps_colour},
    )


def check(gps_colour: float) -> holdout.Holdout:
    """A delay on the baro, the log's first two blocks for it on both sensors, its last against it on
    the GPS by twice what the baro gains there (a slow GPS error moving with the descent)."""
    base = run(0.0, (0.0, 0.0, 0.0), gps_colour)
    late = run(30.0, (10.0, 10.0, -60.0), gps_colour)
    prep = SimpleNamespace(t0=0.0, t1=SETTLE_S + 3 * N_BLOCK - 1e-6, kinds={Kind.BARO_PRESSURE})
    return holdout.check(
        sensor_delay("baro", (0.0, 0.2)),
        SimpleNamespace(f=None, n=3),  # type: ignore[arg-type]
        late,
        {"seconds": 0.2, "sigma_seconds": 0.01},
        altitude_model(use_gps=True),
        base,
        prep,  # type: ignore[arg-type]
        None,
        [],
        {0.0: base, 0.2: late},
    )


def test_a_coloured_sensors_loss_is_counted_at_its_effective_size():
    """With GPS innovations worth one in eight, its loss of 60 on the last block counts 7.5: the
    baro's delay holds out (gains 40 + 1.25 on the first two blocks, 30 - 7.5 on the last)."""
    h = check(gps_colour=8.0)
    assert h.holds, h.reason
    assert h.gain_by_sensor["gps"] == pytest.approx((10.0 + 10.0 - 60.0) / 8.0)
    assert h.gain_by_sensor["baro"] == pytest.approx(90.0)
    assert math.isclose(h.gain, 90.0 - 5.0)


def test_a_white_sensors_loss_still_turns_the_effect_away():
    """The same losses on white GPS innovations: the GPS is 40 worse on the held-out blocks, and the
    delay is not claimed."""
    h = check(gps_colour=1.0)
    assert not h.holds
    assert "gps" in (h.reason or ""), h.reason
    assert h.gain_by_sensor["gps"] == pytest.approx(-40.0)


@pytest.mark.slow
def test_a_late_baro_on_another_generators_outdoor_dataflash_flight_is_named_as_its_delay():
    """Another generator's outdoor .bin flight with its baro readings 0.2 s late: named as the baro's
    delay within 0.06 s, handed back as ``EK3_HGT_DELAY``, and the height after is nearer the truth.
    Counted update by update, the GPS heights' held-out loss (their slow wander rising through the
    descent) would turn it away."""
    from groundstation.diagnosis.engine import diagnose
    from groundstation.diagnosis.report.autopilot_params import suggest
    from groundstation.estimation.logs import load_log
    from groundstation.estimation.truth import truth_from

    from .conftest import foreign2_file

    path = foreign2_file("clean_s1.bin")
    log = load_log(path, imu_columns=True)
    late = 0.2
    ms = log.measurements.shifted((Kind.BARO_PRESSURE, Kind.BARO_ALTITUDE), -late).in_time_order()
    d = diagnose(
        ms, source=str(path), imu=log.imu, vehicle=log.vehicle, truth=truth_from(ms, path, None), veto_with_truth=False
    )
    assert [(e.name, e.params["sensor"]) for e in d.effects] == [("sensor_delay", "baro")]
    assert abs(d.effects[0].params["seconds"] - late) < 0.06, d.effects[0].params
    (p,) = [p for p in suggest(d, ms, log.tables.params, "ardupilot") if p.name == "EK3_HGT_DELAY"]
    assert p.value == round(1000 * d.effects[0].params["seconds"]), p
    before, after = (d.truth.error(r, r.t[0] + 3.0, r.t[-1] - 3.0) for r in (d.before, d.after))
    assert after < 0.5 * before, (before, after)
