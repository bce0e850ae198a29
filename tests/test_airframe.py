"""The thrust curve read from a log's own accelerometer (groundstation/diagnosis/catalogue/airframe.py): the thrust
model's prior when no vehicle file gives the airframe."""

import math

import numpy as np
import pytest

from drivers.replay import Replay
from groundstation.core.measurement import Kind
from groundstation.diagnosis.catalogue.airframe import thrust_curve
from groundstation.diagnosis.catalogue.thrust_model import lift_off, main_flight, throttle_series
from groundstation.diagnosis.engine import diagnose
from groundstation.diagnosis.live import markdown
from groundstation.diagnosis.models import setup
from groundstation.diagnosis.report.conclusion import conclusion
from groundstation.diagnosis.report.report import as_json
from groundstation.diagnosis.runs.outputs import interval_means
from groundstation.estimation.models.ground import TAU_GROUND
from groundstation.estimation.truth import truth_from
from groundstation.estimation.vehicles import declared_effects
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario
from sim_bridge.vehicles.quad import QuadParams


def _flight(tmp_path, seed, undeclared=()):
    log = tmp_path / f"q{seed}.tlog"
    run_fast(
        Scenario.from_args("quad", seed, 60.0, ["range_tilt"], list(undeclared), flight="thrust_test"),
        log,
        log.with_suffix(".csv"),
    )
    return log, list(Replay(log).iter_measurements())


def _curve(ms, **kw):
    w = main_flight(ms)
    ms = interval_means([m for m in ms if w[0] <= m.t <= w[1] + 5.0])
    th = throttle_series(ms)
    flying = [t for t, v in th if v >= TAU_GROUND]
    return thrust_curve(ms, th, flying[0], lift_off(ms, flying[0]), flying[-1], **kw)


@pytest.mark.parametrize("seed, undeclared", [(1012, ()), (1003, ("actuator_lag:tc=0.1",))])
@pytest.mark.slow
def test_the_accelerometer_reads_the_simulated_quadcopters_thrust_curve(tmp_path, seed, undeclared):
    """alpha, beta and the drag within 3 %, 0.3 m/s^2 and 10 % of the simulator's (22, -1.2, 0.35); the hover
    throttle alone gives 19.8 with beta held at 0. A lag in the motors is fitted along (0.1 s here), as a
    nuisance: held at 0 it flattened the curve (drag read 0.17 /s)."""
    _, ms = _flight(tmp_path, seed, undeclared)
    c = _curve(ms)
    p = QuadParams()
    assert c is not None
    assert c.alpha == pytest.approx(p.alpha, rel=0.03) and abs(c.beta - p.beta) < 0.3, c
    assert c.drag == pytest.approx(p.drag, rel=0.1), c
    assert c.tc == pytest.approx(0.1 if undeclared else 0.0, abs=0.01), c
    assert c.sigma["alpha"] < 0.03 * c.alpha and c.seconds > 15.0


@pytest.mark.slow
def test_a_log_the_curve_cannot_be_read_from_gives_none_and_the_hover_prior_stays(tmp_path):
    """Without an accelerometer (ArduPilot's underpowered.log has none) or with too little flight: None,
    never a guess, and the diagnosis keeps the hover prior. NaN samples are skipped, not propagated."""
    _, ms = _flight(tmp_path, 1018)
    no_imu = [m for m in ms if m.kind is not Kind.ACCEL]
    assert _curve(no_imu) is None
    nan = [
        m._replace(value=np.full_like(m.value, np.nan)) if m.kind is Kind.ACCEL and i % 7 == 0 else m
        for i, m in enumerate(ms)
    ]
    c = _curve(nan)
    assert c is not None and all(math.isfinite(v) for v in (c.alpha, c.beta, c.drag, c.n, c.tc))
    # the first 10 s (the take-off and a hover): too little flight to fit
    w = main_flight(ms)
    short = [m for m in ms if m.t <= 10.5]
    th = throttle_series(short)
    flying = [t for t, v in th if v >= TAU_GROUND]
    assert thrust_curve(short, th, flying[0], lift_off(short, flying[0]), 10.5) is None, w
    su = setup(no_imu, model_name="quad_thrust")
    assert su.airframe is None  # the hover prior: beta held at 0
    assert float(su.model.x0[su.model.index("beta")]) == 0.0


@pytest.mark.slow
def test_from_the_log_alone_a_005_s_lag_is_found_and_sized(tmp_path):
    """No vehicle file: the thrust curve from the accelerometer (alpha 22.47, beta -1.44 here). With the
    hover prior (alpha 19.8, beta held at 0, G_acc 0.006) this lag was found on none of three flights, and
    0.1 s read 0.084-0.086 s. The report gives the curve it started from."""
    log, ms = _flight(tmp_path, 1000, ["actuator_lag:tc=0.05"])
    d = diagnose(
        ms,
        model_name="quad_thrust",
        declared=declared_effects(log.with_suffix(".declared.json")),
        truth=truth_from(ms, log, None),
        veto_with_truth=False,
    )
    assert [e.name for e in d.effects][:1] == ["actuator_lag"], [e.name for e in d.effects]
    assert d.effects[0].params["tc"] == pytest.approx(0.05, rel=0.15)
    assert d.vehicle is None and d.airframe["source"] == "accelerometer"
    assert d.airframe["alpha"] == pytest.approx(22.0, rel=0.03)
    before, after = (d.truth.error(r, 8.0, 50.0) for r in (d.before, d.after))
    assert after < 0.5 * before, (before, after)
    # the conclusion sets the accelerometer's own reading of the lag beside the filter's
    text = conclusion(d, as_json(d))
    assert "from the accelerometer" in text and "for actuator_lag's 0.0" in text, text
    assert "thrust curve from the accelerometer (α 22." in markdown(as_json(d), 60.0)  # the dashboard's panel


@pytest.mark.slow
def test_with_a_vehicle_file_the_accelerometers_curve_is_read_beside_it(tmp_path):
    """``--vehicle sim_quad``: the file's curve is the model's, and the accelerometer's is read beside it
    (22.2 here for the file's 22), for the report to say when a file is not the log's airframe."""
    log, ms = _flight(tmp_path, 1012)
    su = setup(
        ms, model_name="quad_thrust", declared=declared_effects(log.with_suffix(".declared.json")), vehicle="sim_quad"
    )
    a = su.airframe
    assert a is not None and a["used"] is False and a["file_alpha"] == 22.0, a
    assert a["alpha"] == pytest.approx(22.0, rel=0.05)
    assert float(su.model.x0[su.model.index("alpha")]) == 22.0  # the file's, not the fit's


@pytest.mark.slow
def test_a_vehicle_file_that_is_not_the_logs_airframe_is_named_in_the_conclusion(tmp_path, monkeypatch):
    """A vehicle file written for another airframe (alpha 17 where the simulated quadcopter's is 22: other
    propellers, or a heavier battery): the conclusion says the log's accelerometer reads another curve,
    and that the effects are sized against the file's."""
    import json

    from groundstation.estimation import vehicles

    (tmp_path / "other_quad.json").write_text(json.dumps({"quad_thrust": {"alpha0": 17.0, "beta0": 0.0}}))
    monkeypatch.setattr(vehicles, "VEHICLE_CONFIGS", tmp_path)
    log, ms = _flight(tmp_path, 1012)
    d = diagnose(
        ms, model_name="quad_thrust", declared=declared_effects(log.with_suffix(".declared.json")), vehicle="other_quad"
    )
    text = conclusion(d, as_json(d))
    assert "The vehicle file's thrust curve (alpha = 17, beta = 0 m/s^2) is not this log's" in text, text
    assert "reads alpha = 22." in text, text
