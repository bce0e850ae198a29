"""The estimators and the closed loop on flights another generator wrote (../shared/data/foreign):
its own physics, rates, noise and take-offs. The full table is ``bench/foreign.py``; here one clean
indoor flight, one clean outdoor flight and one outdoor baro effect, against the same bars."""

import numpy as np
import pytest
from scipy.stats import chi2

from groundstation.core.measurement import Kind
from groundstation.estimation.logs import load_measurements
from groundstation.estimation.loop import EstimationLoop
from groundstation.estimation.registry import build_estimator
from groundstation.estimation.whiteness import effective_size

from .conftest import bench_module, foreign2_file, foreign_file

bench_foreign = bench_module("foreign")


@pytest.mark.slow
@pytest.mark.parametrize("flight", ["clean_s1", "clean_gps_s1", "baro_thermal_s1"])
def test_the_diagnosis_meets_its_bar_on_a_foreign_flight(flight):
    """Clean: nothing claimed. A catalogued effect: named first, the height error after within 1.5 times
    that of the model with the true effect taken out at its true parameters, and not above the error
    before (bench/foreign.py's bars)."""
    tlog = foreign_file(f"{flight}.tlog")
    r = bench_foreign.evaluate(flight, tlog.parent)
    assert r["ok"], (r["why"], r["claimed"], r["rejected"])
    assert r["after"] <= r["before"] + 1e-9
    if not r["hidden"]:
        # the noise came from the log: the baro's is a third of what the model starts from
        baro = next(n for n in r["noise"] if n["sensor"] == "baro")
        assert baro["sigma_data"] < 0.5 * baro["sigma_model"], r["noise"]


def replayed(flight: str):
    """The live altitude estimator over a foreign flight: its measurements, the truth table, and the
    estimate's times, heights and height sigmas."""
    tlog = foreign_file(f"{flight}.tlog")
    truth = np.genfromtxt(tlog.with_name(f"{flight}_truth.csv"), delimiter=",", names=True)
    ms, _, _ = load_measurements(tlog)
    loop = EstimationLoop([build_estimator("altitude")])
    sub = loop.snapshots.subscribe()
    for m in ms:
        loop.push(m)
    snaps = sub.get_nowait()
    t, z, sz = (np.array(v) for v in zip(*((s.t, s.x[0], s.sigma[0]) for s in snaps)))
    return ms, truth, t, z, sz


def test_replayed_the_height_beats_the_raw_range_and_the_take_off_is_consistent():
    """The live estimator over a clean indoor flight: its height error below the range sensor's own,
    and through the take-off (1 s before to 5 s after) the normalised error squared inside its 95 %
    band: the generator's vehicle leaves the ground at 0.5 m/s between two IMU samples."""
    ms, truth, t, z, sz = replayed("clean_s1")
    err = bench_foreign.height_error(t, z, truth, "range")
    rt = np.array([m.t for m in ms if m.kind is Kind.RANGE])
    rv = np.array([m.value[0] for m in ms if m.kind is Kind.RANGE])
    raw = bench_foreign.height_error(rt, rv, truth, "range")
    assert err < raw, (err, raw)
    lift = float(truth["t"][np.flatnonzero(truth["z"] > 0.05)[0]])
    w = (t > lift - 1.0) & (t < lift + 5.0)
    nz = (z[w] - np.interp(t[w], truth["t"], truth["z"])) / sz[w]
    # the mean of correlated NEES values: a chi-square band with as many degrees of freedom as the
    # window's errors are worth as independent samples (their AR(1) effective size; at least one)
    dof = max(effective_size(nz), 1.0)
    lo, hi = chi2.ppf([0.025, 0.975], dof) / dof
    nees = float(np.mean(nz**2))
    assert lo <= nees <= hi, (nees, lo, hi, dof)


def test_replayed_a_throttle_cut_in_the_air_is_a_fall_not_a_landing():
    """The generator ends its outdoor flights with the motors cut at several metres and a fall, braked
    just above the ground. Motors stopped is not landed while nothing holds the vehicle up (the
    accelerometer's upward specific force below g/2): held at vz = 0 there, the estimate stood still
    while the vehicle fell, and was 1.7 m off; falling with it, it stays within the GPS's metre."""
    _, truth, t, z, _ = replayed("clean_gps_s2")
    cut = (truth["throttle"] < 0.05) & (truth["z"] > 0.5)
    assert cut.any(), "the flight has its throttle cut in the air"
    # the outdoor scoring: estimate and truth zeroed on the ground before take-off
    a, b = bench_foreign.GROUND
    g, gt = (t > a) & (t < b), (truth["t"] > a) & (truth["t"] < b)
    e = (z - z[g].mean()) - (np.interp(t, truth["t"], truth["z"]) - truth["z"][gt].mean())
    fall = (t > truth["t"][cut][0] - 0.5) & (t < truth["t"][cut][-1] + 2.5)  # the cut, the fall, the braking
    assert np.abs(e[fall]).max() < 0.3, np.abs(e[fall]).max()
    assert bench_foreign.height_error(t, z, truth, "gps") < 0.1


def test_replayed_a_touchdown_stops_the_estimate_on_the_floor():
    """The generator's vehicle lands at 0.2 m/s and stops between two IMU samples, below the range
    sensor's 2 cm minimum: the ground's impulse is not in the accelerometer's blocks. Held at the
    descent's vertical speed by the range's centimetres of flight, the estimate sank 3.4 cm below
    the floor while the ground's constraints, piling up, said 5 mm; the touchdown lets go of vz as
    the lift-off does, and the estimate stays on the floor."""
    _, truth, t, z, sz = replayed("accel_scale_s1")
    up = truth["z"] > 0.05
    first_up = truth["t"][np.flatnonzero(up)[0]]
    # on the ground after a flight: a landing, and the time to the next lift-off
    down = (truth["t"] > first_up) & (truth["z"] < 0.005) & (truth["throttle"] < 0.15)
    assert down.any(), "the flight lands before its end"
    # half a second after each touchdown on: the constraint on z waits for the range to go quiet
    landed_for = np.interp(t, truth["t"], _time_since_start_of(down, truth["t"]))
    settled = landed_for > 0.5
    assert settled.any()
    err = np.abs(z[settled] - np.interp(t[settled], truth["t"], truth["z"]))
    assert np.median(err) < 0.005 and err.max() < 0.015, (np.median(err), err.max())


def _time_since_start_of(flag: np.ndarray, t: np.ndarray) -> np.ndarray:
    """For each sample, how long ``flag`` has been true (0 where it is false)."""
    out = np.zeros_like(t)
    start = None
    for i, f in enumerate(flag):
        start = (t[i] if start is None else start) if f else None
        out[i] = t[i] - start if start is not None else 0.0
    return out


def test_a_baro_error_added_as_the_log_is_read_moves_its_heights_and_pressures_alike():
    """bench/foreign.py --baro-error: the error added to each baro height, and the pressure that height
    is (dp = -rho g dh) taken from each baro pressure, at each reading's own time; other kinds as read."""
    from groundstation.core.measurement import Measurement
    from groundstation.core.readings import Readings

    ms = []
    for k in range(20):
        t = 0.1 * k
        ms.append(Measurement(t, Kind.BARO_ALTITUDE, np.array([10.0]), "baro"))
        ms.append(Measurement(t + 0.01, Kind.BARO_PRESSURE, np.array([100000.0]), "baro"))
        ms.append(Measurement(t + 0.02, Kind.RANGE, np.array([2.0]), "lidar"))
    out = list(bench_foreign.with_baro_error(Readings.of(ms), lambda t: 0.5 * t))
    assert [m.t for m in out] == [m.t for m in ms]
    for a, b in zip(ms, out):
        if a.kind is Kind.BARO_ALTITUDE:
            assert b.value[0] == pytest.approx(10.0 + 0.5 * a.t)
        elif a.kind is Kind.BARO_PRESSURE:
            assert b.value[0] == pytest.approx(100000.0 - bench_foreign.rho_g(ms) * 0.5 * a.t)
        else:
            assert b.value[0] == 2.0


def _imu_log(n: int, dt: float):
    """A log of ``n`` accelerometer and gyro readings ``dt`` apart, each (1, 2, -9.8), as records and
    as columns."""
    from groundstation.core.imu import ImuColumns
    from groundstation.core.measurement import Measurement
    from groundstation.core.readings import Readings
    from groundstation.estimation.logs import LoadedLog

    ms = [
        Measurement(dt * k, kind, np.array([1.0, 2.0, -9.8]), "imu")
        for k in range(n)
        for kind in (Kind.ACCEL, Kind.GYRO)
    ]
    _, imu = ImuColumns.split(ms)
    return LoadedLog(measurements=Readings.of(ms), description="", vehicle=None, imu=imu)


def test_an_accelerometer_scale_added_as_the_log_is_read_scales_body_z_alone():
    """bench/foreign.py --accel-scale: each accelerometer's body-z reading 1 + s times what it was, as
    columns and as records; x, y and the gyro as read."""
    out = bench_foreign.with_accel_scale(_imu_log(10, 0.01), 0.05)
    for m in out.measurements:
        want = [1.0, 2.0, -9.8 * 1.05] if m.kind is Kind.ACCEL else [1.0, 2.0, -9.8]
        assert np.allclose(m.value, want)
    assert out.imu is not None
    accel, gyro = out.imu.get(Kind.ACCEL), out.imu.get(Kind.GYRO)
    assert accel is not None and gyro is not None
    assert np.allclose(accel.values(), [1.0, 2.0, -9.8 * 1.05])
    assert np.allclose(gyro.values(), [1.0, 2.0, -9.8])


def test_an_accelerometer_bias_step_added_as_the_log_is_read_moves_body_z_from_each_step():
    """bench/foreign.py --accel-bias step=: body z raised by the step after each third of the way from
    lift-off to landing, as records and as columns; x, y and the gyro as read."""
    step = bench_foreign.ACCEL_BIASES["step"]
    times = {"liftoff": 0.0, "land_complete": 3.0}
    out = bench_foreign.with_accel_bias(_imu_log(30, 0.1), lambda t: step(t, None, times, 0.3))
    for m in out.measurements:
        steps = int(m.t >= 1.0) + int(m.t >= 2.0)
        want = [1.0, 2.0, -9.8 + 0.3 * steps] if m.kind is Kind.ACCEL else [1.0, 2.0, -9.8]
        assert np.allclose(m.value, want), (m.t, m.value)
    assert out.imu is not None
    accel, gyro = out.imu.get(Kind.ACCEL), out.imu.get(Kind.GYRO)
    assert accel is not None and gyro is not None
    assert np.allclose(accel.values()[:, 2], -9.8 + 0.3 * np.searchsorted([1.0, 2.0], accel.t, side="right"))
    assert np.allclose(gyro.values(), [1.0, 2.0, -9.8])


@pytest.mark.slow
def test_replayed_without_a_rangefinder_the_baro_noise_comes_from_the_still_stretch():
    """The second generator's clean .bin flight without a rangefinder: its baro's noise, read from the
    still stretch before the arming, is a fraction of the model's, and the live estimate with it is
    well under the model's level's and within the issue's 1.3 times a plain filter's (bench/plain_kf.py)."""
    import json

    from groundstation.estimation import still_noise
    from groundstation.estimation.logs import load_blocked

    log = foreign2_file("clean_s1.bin")
    meta = json.loads(log.with_name("clean_s1_meta.json").read_text())
    truth = np.genfromtxt(log.with_name("clean_s1_truth.csv"), delimiter=",", names=True)
    blocked = load_blocked(log)
    assert blocked is not None

    def run(noise):
        est = build_estimator("altitude", noise=noise, vehicle=blocked.vehicle, stated=blocked.stated)
        loop = EstimationLoop([est], reorder_s=0.0)
        sub = loop.snapshots.subscribe()
        for m in blocked.measurements:
            loop.push(m)
        snaps = sub.get_nowait()
        t, z = np.array([s.t for s in snaps]), np.array([s.x[0] for s in snaps])
        return bench_foreign.flight_error(t, z, truth, meta), est

    still, est = run(None)
    model_r = float(est.model.measurements["baro"].R[0, 0])
    levels = [v for k in still_noise.HEIGHT_OF if (v := still_noise.level(k, est.filter.ctx)) is not None]
    assert levels and max(levels) < model_r / still_noise.DIFFERS**2, (levels, model_r)
    assert "used in flight" in est.still_noise_note, est.still_noise_note
    kept, _ = run({"baro": [[model_r]]})
    plain_kf = bench_module("plain_kf")
    plain = bench_foreign.flight_error(*plain_kf.run(plain_kf.read(log), meta["times"]["arm"]), truth, meta)
    assert still < 0.7 * kept and still < 1.3 * plain, (still, kept, plain)
