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
