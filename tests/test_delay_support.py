"""A late sensor's evidence is counted over the updates its delay acts on (scoring/trace.py): a late
reading differs from an on-time one only while what it measures changes, so a delay's gain per update
is spread over where its run's innovations differ from the base run's (the participation ratio that
counts an effect on the input), not over every reading of a flight that mostly hovers."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from groundstation.core.measurement import Kind
from groundstation.diagnosis.catalogue.altitude import RANGE_DELAYS, sensor_delay
from groundstation.diagnosis.runs.run import SETTLE_S, Run, SensorTrace
from groundstation.diagnosis.scoring import trace
from groundstation.diagnosis.scoring.scored import MATERIAL, scored

#: range updates after the settling time, and how many of them fall in the climbs and descents
N, MOVING = 3000, 200


def _run(nu: np.ndarray, loglik: float) -> Run:
    n = len(nu)
    return Run(
        model=None,  # type: ignore[arg-type]
        sensors={
            "range": SensorTrace(
                t=SETTLE_S + 0.05 * np.arange(n), nu=nu[:, None], S=np.ones((n, 1, 1)), nis=nu * nu, z=np.zeros((n, 1))
            )
        },
        t=np.zeros(0),
        x=np.zeros((0, 1)),
        covariance=np.zeros((0, 1, 1)),
        loglik=loglik,
        n_scored=n,
        ctx=None,  # type: ignore[arg-type]
        loglik_by={"range": loglik},
    )


def test_a_delays_gain_is_counted_where_its_readings_move():
    """A range delay that gains 30 in log-likelihood, all of it in the 200 updates where the height
    changes: 0.15 per update there, material; spread over all 3,000 readings it would be 0.01."""
    rng = np.random.default_rng(3)
    nu = rng.normal(size=N)
    moved = nu.copy()
    moved[1000 : 1000 + MOVING] -= 0.5  # the readings the delay shifts: a climb
    base, late = _run(nu, 0.0), _run(moved, 30.0)
    cand = sensor_delay("range", RANGE_DELAYS, {Kind.RANGE})
    s = scored(cand, None, late, base, N, {"sensor": "range", "seconds": 0.1}, [])  # type: ignore[arg-type]
    assert s.delta_bic == pytest.approx(-60.0 + math.log(N))
    s = trace._supported(s, base, SimpleNamespace(t0=0.0), SETTLE_S)  # type: ignore[arg-type]
    assert s.support == MOVING
    assert s.gain_per_update == pytest.approx(30.0 / MOVING) and s.accepted
    assert 30.0 / N < MATERIAL  # what counting every reading gave: not material


@pytest.mark.slow
def test_a_late_lidar_on_another_generators_indoor_flight_is_named_as_its_delay():
    """Another generator's indoor .bin flight (ALT_HOLD, mostly hovering) with its lidar readings
    0.1 s late: named as the range's delay within 0.02 s, and the height after is nearer the truth.
    Counted over all its readings, the delay's gain was 0.0076 per update, below materiality."""
    from groundstation.diagnosis.engine import diagnose
    from groundstation.estimation.logs import load_log
    from groundstation.estimation.truth import truth_from

    from .conftest import foreign2_file

    path = foreign2_file("clean_range_s1.bin")
    log = load_log(path, imu_columns=True)
    late = 0.1
    ms = log.measurements.shifted((Kind.RANGE,), -late).in_time_order()
    d = diagnose(
        ms, source=str(path), imu=log.imu, vehicle=log.vehicle, truth=truth_from(ms, path, None), veto_with_truth=False
    )
    assert [(e.name, e.params["sensor"]) for e in d.effects] == [("sensor_delay", "range")]
    assert abs(d.effects[0].params["seconds"] - late) < 0.02, d.effects[0].params
    assert d.effects[0].evidence["support"] < 0.1 * len(d.before.sensors["range"].t)
    before, after = (d.truth.error(r, r.t[0] + 3.0, r.t[-1] - 3.0) for r in (d.before, d.after))
    assert after < 0.8 * before, (before, after)


@pytest.mark.parametrize(
    ("by_sensor", "holds"),
    [
        ({"baro": 11.0, "range": 27.2}, True),  # a lidar 0.1 s late on another generator's indoor .ulg
        ({"baro": 0.6, "gps": 9.0, "gps_vz": 2.4}, False),  # a baro reading high with the airspeed squared
    ],
)
def test_a_delay_holds_out_on_the_readings_it_moves(by_sensor, holds):
    """A sensor's delay moves that sensor's readings alone: at least a quarter of its held-out gain
    is on them, or it fits something the other sensors see (holdout.py, rule 4)."""
    from groundstation.diagnosis.scoring.holdout import Holdout, _not_on_own_sensor
    from groundstation.estimation.models.altitude import altitude_model

    model = altitude_model(use_gps=True, gps_velocity=True)
    sensor = "range" if "range" in by_sensor else "baro"
    cand = sensor_delay(sensor, RANGE_DELAYS)
    h = Holdout(gain_by_block=[sum(by_sensor.values())], gain_by_sensor=by_sensor)
    reason = _not_on_own_sensor(cand, model, h)
    assert (reason is None) is holds, reason


def test_a_late_gps_fix_counts_its_velocity_as_its_own_readings():
    """The whole fix late moves the receiver's vertical velocity with its height: both are its own."""
    from groundstation.diagnosis.catalogue.altitude import gps_delays
    from groundstation.diagnosis.scoring.holdout import Holdout, _not_on_own_sensor
    from groundstation.estimation.models.altitude import altitude_model

    model = altitude_model(use_gps=True, gps_velocity=True)
    fix, height = gps_delays({Kind.GPS, Kind.GPS_VD})
    h = Holdout(gain_by_block=[30.0], gain_by_sensor={"baro": 5.0, "gps": 5.0, "gps_vz": 20.0})
    assert _not_on_own_sensor(fix, model, h) is None
    assert _not_on_own_sensor(height, model, h) is not None


def test_each_sensors_delay_grid_reaches_two_steps_past_what_its_autopilots_can_be_told():
    """A delay at the end of its grid is not located (scoring.trace: the profile still rising there is
    "at the edge of the search range", not a finding), so each sensor's grid runs two steps past the
    largest delay its autopilots' parameters take (their documented ranges): a delay as late as an
    autopilot can be told is found, sized between grid values, and written back."""
    from drivers.mavlink.param_ranges import DOCUMENTED
    from groundstation.diagnosis.catalogue import altitude, thrust

    told = {
        "range": ["EKF2_RNG_DELAY"],
        "baro": ["EK3_HGT_DELAY", "EKF2_BARO_DELAY"],
        "gps": ["GPS_DELAY_MS", "EKF2_GPS_DELAY"],
    }
    grids = {
        "range": [altitude.RANGE_DELAYS, thrust.RANGE_DELAYS],
        "baro": [altitude.BARO_DELAYS],
        "gps": [altitude.GPS_DELAYS],
    }
    for sensor, names in told.items():
        most = max(DOCUMENTED[n][1] for n in names) / 1000.0
        for grid in grids[sensor]:
            step = grid[1] - grid[0]
            assert grid[0] == 0.0 and np.allclose(np.diff(grid), step), grid  # profile_sigma reads one step
            assert grid[-1] >= most + 2 * step - 1e-9, (sensor, grid, most)
