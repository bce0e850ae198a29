"""What a diagnosis reports of an effect is what its model after holds: the value the error after is
measured with, and the one handed to the vehicle."""

import pytest

from groundstation.diagnosis.engine import diagnose
from groundstation.estimation.logs import load_log
from groundstation.estimation.stated import stated_by

from .conftest import foreign2_file


@pytest.mark.slow
def test_an_effect_is_reported_as_the_model_after_holds_it_once_the_gps_has_its_slow_error():
    """A PX4 flight with rotor wash on the baro and a GPS whose height wanders by most of a metre: the
    effects are traced against the GPS at the floor of its slow error, and the GPS is then given the
    level the log shows, which moves the wash's estimate (0.88 at the floor, 0.93 at 1 m, for a true
    1.02). The size reported, and sent to the vehicle, is the one the model after holds."""
    path = foreign2_file("baro_thrust_s2.ulg")
    log = load_log(path)
    d = diagnose(
        log.measurements,
        source=str(path),
        vehicle=log.vehicle,
        stated=stated_by(log.tables, log.measurements),
        workers=2,
    )
    slow = next(n for n in d.noise if n.sensor == "gps (slow)")
    assert slow.sigma_data >= 0.3, slow  # the level moved from the floor the effects were traced at
    assert [e.name for e in d.effects][:1] == ["baro_thrust"]
    after = d.after.model
    held = float(after.x0[after.index("k_thrust")])
    assert d.effects[0].params["k_tw"] == pytest.approx(held, rel=1e-9)


@pytest.mark.slow
def test_an_effect_the_model_after_holds_near_zero_is_not_claimed():
    """A PX4 flight's GPS height made 0.25 s late: a rotor wash was added first (climbs lead the
    throttle, and the late GPS lags them), then the GPS's delay, which explains what the wash had
    taken. With both in the model the wash read 0.11 +- 0.05 and the height after was 5.3 cm against
    4.5 cm before. An effect claimed on 3 standard errors is claimed only where the model after
    holds it so: the delay alone is named, and the error after is no worse than before."""
    import json

    import numpy as np

    from groundstation.core.measurement import Kind
    from groundstation.diagnosis.runs.run import in_time_order

    path = foreign2_file("clean_s2.ulg")
    meta = json.loads(path.with_name("clean_s2_meta.json").read_text())
    truth = np.genfromtxt(path.with_name("clean_s2_truth.csv"), delimiter=",", names=True)
    log = load_log(path, imu_columns=True)
    late = 0.25
    ms = [m._replace(t=m.t + late, t_rx=m.t_rx + late) if m.kind is Kind.GPS else m for m in log.measurements]
    ms.sort(key=in_time_order)
    d = diagnose(ms, source=str(path), imu=log.imu, vehicle=log.vehicle)
    assert [e.name for e in d.effects] == ["sensor_delay"] and d.effects[0].params["sensor"] == "gps"
    # the height alone late, the fix's vertical velocity on time: PX4's one GPS delay would move both
    assert d.effects[0].evidence["form"] == "height"
    from groundstation.diagnosis.report.autopilot_params import suggest

    assert not [p for p in suggest(d, ms, log.tables.params, "px4") if p.name == "EKF2_GPS_DELAY"]
    wash = [e for e in d.rejected if e.name == "baro_thrust" and "sigma from zero" in e.evidence["reason"]]
    assert wash, [(e.name, e.evidence.get("reason")) for e in d.rejected]

    def error(run) -> float:  # the data README's scoring: in flight, the datum from the pre-arm ground
        fl = truth["in_flight"] > 0.5
        z = run.x[:, run.model.index("z")]
        est = np.interp(truth["t"][fl], run.t, z) - np.median(z[run.t < meta["times"]["arm"]])
        return float(np.sqrt(np.mean((est - truth["z"][fl]) ** 2)))

    assert error(d.after) <= error(d.before) + 1e-4, (error(d.before), error(d.after))


def test_a_parameter_restated_in_another_unit_is_counted_once():
    """A rotor wash in its thrust form is one state, reported per unit thrust over weight (k_tw) and per
    unit of the command (k): 2.34 sigma each is 2.34 sigma, not 3.3 together, and is not claimed. Two
    parameters fitted apart (a gyro bias on two axes) still count together."""
    from groundstation.core.measurement import Kind
    from groundstation.diagnosis.catalogue.altitude import altitude_catalogue
    from groundstation.diagnosis.scoring.holdout import sizes

    wash = {"k": 0.0203, "sigma_k": 0.00867, "k_tw": 0.0625, "sigma_k_tw": 0.0267, "tc": 0.22}
    kinds = {Kind.BARO_PRESSURE, Kind.RANGE, Kind.THROTTLE, Kind.ACCEL}
    thrust_form = next(c for c in altitude_catalogue(kinds) if c.name == "baro_thrust" and c.form == "thrust")
    _, why = sizes(wash, False, thrust_form.fitted)
    assert why is not None and "2.3 sigma" in why, why
    assert sizes(wash, False)[1] is None  # counted twice: 3.3 sigma
    assert sizes({"x": 0.0234, "sigma_x": 0.01, "y": 0.0234, "sigma_y": 0.01}, False)[1] is None
