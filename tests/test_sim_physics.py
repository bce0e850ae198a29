"""The simulator's physics against the design documents' analytic answers."""

import math

import numpy as np
import pytest

from groundstation.core.frames import a_ib, euler_from_matrix
from sim_bridge.vehicles.base import G
from sim_bridge.vehicles.coax import Coax, CoaxCommand, CoaxParams, G_ab
from sim_bridge.vehicles.heli3dof import Heli3dof, Heli3dofCommand, Heli3dofParams
from sim_bridge.vehicles.quad import Quad, QuadCommand, QuadParams


def test_rotor_step_reaches_63_percent_at_T():
    v = Coax()
    dt, step = 1e-3, 0.6
    for _ in range(int(round(v.p.T / dt))):
        v.step(dt, CoaxCommand(i_L=step, i_U=0.0))
    assert v.F_L == pytest.approx((1 - math.exp(-1)) * v.p.k_F * step, rel=1e-3)
    assert v.T_L == pytest.approx((1 - math.exp(-1)) * v.p.k_T * step, rel=1e-3)


def test_flapping_direction_matches_eq_4_7():
    np.testing.assert_allclose(G_ab(0, 0), [0, 0, -1])
    g = G_ab(0.1, 0.2)
    assert np.linalg.norm(g) == pytest.approx(1.0)
    assert math.atan2(g[0], g[2]) == pytest.approx(math.atan2(-math.sin(0.1), -math.cos(0.1)))  # tan a = Fx/Fz


def test_coax_hovers_at_the_documented_step_input():
    p = CoaxParams()
    assert p.hover_input == pytest.approx(0.6, abs=0.01)  # the document's test input


def test_newton_euler_free_fall():
    v = Coax()
    v.kin.pos = np.array([0.0, 0.0, -100.0])
    v.on_ground = False
    dt, n = 1e-3, 2000
    for _ in range(n):
        v.step(dt, CoaxCommand())
    t = n * dt
    assert v.kin.pos[2] == pytest.approx(-100 + 0.5 * G * t * t, rel=1e-3)
    assert v.kin.vel[2] == pytest.approx(G * t, rel=1e-6)
    np.testing.assert_allclose(v.kin.specific_force, 0.0, atol=1e-9)  # free fall: accelerometer reads 0


def test_newton_euler_pure_yaw_spin():
    v = Coax()
    v.kin.pos = np.array([0.0, 0.0, -100.0])
    v.on_ground = False
    w0 = 2.0
    v.kin.omega = np.array([0.0, 0.0, w0])
    dt, n = 1e-3, 1000
    for _ in range(n):
        v.step(dt, CoaxCommand())
    roll, pitch, yaw = euler_from_matrix(v.kin.R)
    assert yaw == pytest.approx(w0 * n * dt, rel=1e-9)
    assert abs(roll) < 1e-12 and abs(pitch) < 1e-12
    np.testing.assert_allclose(v.kin.omega, [0, 0, w0], atol=1e-12)


def test_coax_torque_spin_up_is_T_over_I():
    v = Coax()
    v.kin.pos = np.array([0.0, 0.0, -100.0])
    v.on_ground = False
    v.T_U = 0.01  # hold a pure yaw torque by hand
    v.p.T = 1e9  # (no decay of the rotor state)
    for _ in range(100):
        v.step(1e-3, CoaxCommand(i_U=0.0))
    assert v.kin.omega[2] == pytest.approx(0.01 / v.p.inertia[2] * 0.1, rel=1e-3)


def test_quad_hovers_at_g_minus_beta_over_alpha():
    p = QuadParams()
    v = Quad(p)
    v.place(2.0)
    for _ in range(2000):
        v.step(1e-3, QuadCommand(throttle=(G - p.beta) / p.alpha))
    assert abs(v.kin.vel[2]) < 1e-9 and v.kin.pos[2] == pytest.approx(-2.0)
    assert v.kin.specific_force[2] == pytest.approx(-G)


def test_quad_thrust_tilts_with_attitude():
    v = Quad()
    v.place(2.0)
    for _ in range(3000):
        v.step(1e-3, QuadCommand(throttle=0.6, pitch=-0.2))  # nose down: accelerates north
    assert v.theta == pytest.approx(-0.2, abs=1e-3) and v.kin.vel[0] > 0.5


def test_quad_battery_sags_with_current():
    v = Quad()
    v0 = v.voltage
    v.step(1e-3, QuadCommand(throttle=0.5))
    assert v.voltage == pytest.approx(v0 - v.p.r_int * (v.p.i_idle + v.p.i_max * 0.25) + 0.0, abs=0.01)


def test_a_drained_pack_stays_empty_and_is_sent_as_zero_percent():
    """Flown past its capacity (a one-hour flight on a 2.2 Ah pack), the state of charge stops at 0
    and SYS_STATUS says 0 %: negative, it overflowed MAVLink's int8 and the simulator stopped."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from sim_bridge.mavlink_out import MavlinkEncoder
    from sim_bridge.simulator import Sample

    v = Quad(QuadParams(capacity_ah=1e-4))
    for _ in range(2000):
        v.step(1e-3, QuadCommand(throttle=0.6))
    assert v.soc == 0.0 and v.voltage > 0.0
    enc = MavlinkEncoder("quad")
    frames = enc.encode(Sample(2.0, "battery", (v.voltage, v.current, v.soc)))
    frames.append(enc.battery_status(v.voltage, v.current, v.soc))
    msgs = mavlink.MAVLink(None).parse_buffer(b"".join(frames))
    assert msgs and [m.battery_remaining for m in msgs] == [0, 0]


def test_3dof_holds_elevation_at_V_s0():
    p = Heli3dofParams()
    assert p.V_s0 == pytest.approx(8.0, abs=0.01)
    v = Heli3dof(p, e0=0.0)
    for _ in range(5000):  # 10 s at 500 Hz
        v.step(0.002, Heli3dofCommand(V_f=p.V_s0 / 2, V_b=p.V_s0 / 2))
    assert abs(v.x[2]) < 1e-9 and abs(v.x[0]) < 1e-12 and abs(v.x[4]) < 1e-12


def test_3dof_nonlinear_model_departs_from_the_linear_one_at_large_pitch():
    p = Heli3dofParams()
    v = Heli3dof(p, e0=0.0)
    v.x[0] = 0.6  # 34 deg of pitch
    for _ in range(500):
        v.step(0.002, Heli3dofCommand(V_f=p.V_s0 / 2, V_b=p.V_s0 / 2))
    # linear model: e stays 0 (V_s = V_s0); the full one sinks (cos p < 1 loses lift)
    assert v.x[2] < -0.05
    # and the travel acceleration is K3 * p in the linear model; here l_h F sin p / J
    assert v.x[5] > 0


def test_3dof_imu_reads_gravity_on_the_table():
    v = Heli3dof()
    f = v.kin.specific_force
    assert np.linalg.norm(f) == pytest.approx(9.81, rel=1e-6)


@pytest.mark.parametrize("seed", [3, 1001])
def test_the_thrust_test_flight_hovers_in_ground_effect_without_touching_down(seed):
    """flight="thrust_test": a low hover (0.15-0.3 m) reached without touching the ground (a step
    to it, or a ramp without feed-forward, overshot into the ground), then throttle steps."""
    from sim_bridge.profile import FlightProfile
    from sim_bridge.scenario import Scenario
    from sim_bridge.simulator import Simulator

    sim = Simulator(Scenario("quad", seed=seed, duration=60.0, flight="thrust_test"))
    prof = sim.profile
    samples = list(sim.run(34.0))
    truth = [r for r in sim.truth_rows if 6.0 <= r["t"] <= 33.0]  # take-off done, before the tilts
    low = [r["h"] for r in truth if 27.0 <= r["t"] <= 30.0]  # the low hover's settled part
    assert min(r["h"] for r in truth) > 0.08  # airborne throughout
    assert abs(np.median(low) - prof.h_ground) < 0.03 and 0.15 <= prof.h_ground <= 0.3
    # and the ToF reads it there, above the 0.1 m below which the thrust model ignores the range
    tof = [s.values[0] for s in samples if s.sensor == "range" and 27.0 <= s.t <= 30.0]
    assert len(tof) > 50 and np.percentile(tof, 5) > 0.1
    thr = np.array([r["throttle"] for r in truth if 30.0 <= r["t"] <= 33.0])
    assert thr.max() - thr.min() > 0.1  # the steps move the throttle
    # the standard flight's draws are unchanged by the thrust test's (drawn after them)
    a, b = FlightProfile(seed, 60.0), FlightProfile(seed, 60.0, "thrust_test")
    assert (a.h1, a.h_hi, a.h_lo, a.tilt) == (b.h1, b.h_hi, b.h_lo, b.tilt)
    assert a(20.0) == b(20.0) and a(23.0) != b(23.0)


@pytest.mark.slow
@pytest.mark.parametrize("vehicle,seed", [("quad", 8), ("coax", 7)])
def test_the_high_flight_climbs_above_the_range_sensor_and_the_driver_drops_its_readings(tmp_path, vehicle, seed):
    """flight="high": 10 s and more above the range sensor's 4 m, where DISTANCE_SENSOR reports
    out-of-range readings that the driver drops (the baro alone carries the height there), then
    back down, and a landing from a hover (no climb starts before it)."""
    import csv

    from drivers.replay import Replay
    from groundstation.core.measurement import Kind
    from sim_bridge.fast import run_fast
    from sim_bridge.profile import FlightProfile
    from sim_bridge.scenario import Scenario

    log = tmp_path / "h.tlog"
    run_fast(Scenario.from_args(vehicle, seed, 60.0, ["range_tilt"], [], flight="high"), log, log.with_suffix(".csv"))
    rows = [{k: float(v) for k, v in r.items()} for r in csv.DictReader(open(log.with_suffix(".csv")))]
    above = [r["t"] for r in rows if r["range_true"] > 4.05]
    assert len(above) * 0.01 >= 10.0 and max(r["h"] for r in rows) > 5.0
    ranges = [m.t for m in Replay(log).iter_measurements() if m.kind == Kind.RANGE]
    assert not [t for t in ranges if above[0] + 0.1 < t < above[-1] - 0.1]  # none while out of reach
    assert [t for t in ranges if t > above[-1] + 1.0]  # and back after
    assert max(r["h"] for r in rows if r["t"] > 58.0) < 0.01  # landed
    prof = FlightProfile(seed, 60.0, "high")
    assert all(prof(t).height == prof.h1 for t in np.arange(45.0, 53.0, 0.5))  # the repeat hovers
    a = FlightProfile(seed, 60.0)  # the standard's draws unchanged
    assert (a.h1, a.h_hi, a.h_lo, a.tilt) == (prof.h1, prof.h_hi, prof.h_lo, prof.tilt)


@pytest.mark.slow
@pytest.mark.parametrize("vehicle,imu_hz", [("quad", 250.0), ("quad", 500.0), ("coax", 500.0)])
def test_the_imu_reads_the_touchdown_the_truth_goes_through(vehicle, imu_hz):
    """Through the landing, the noiseless IMU's vertical specific force integrates to the truth's
    change of vertical velocity, and the truth's height to the integral of its velocity. The
    damper used to engage at h = 0 with the position held there (the vehicle stopped 1.7 cm
    before its IMU did), the last 2 cm/s were zeroed unread, and a 250 Hz IMU over 500 Hz
    physics read one step of two: the live filter's estimate sank 5-9 cm on the ground."""
    from sim_bridge.scenario import Scenario
    from sim_bridge.simulator import Simulator

    sc = Scenario(vehicle, seed=3, duration=60.0)
    sc.sensors.rates["imu"] = imu_hz
    sc.sensors.accel_sigma = sc.sensors.gyro_sigma = 0.0
    sim = Simulator(sc)
    imu = [(s.t, s.values[:3]) for s in sim.run(60.0) if s.sensor == "imu"]
    tr = {k: np.array([r[k] for r in sim.truth_rows]) for k in ("t", "h", "vd", "roll", "pitch")}
    airborne = tr["t"][tr["h"] > 0.01]
    td = airborne[airborne > 30.0][-1]
    t0, t1 = td - 0.3, td + 0.5
    assert np.interp(t1, tr["t"], tr["vd"]) == 0.0  # at rest by then
    dv = 0.0
    for (ta, f), (tb, _) in zip(imu, imu[1:]):
        if t0 < tb <= t1:  # a sample stands for the interval ending at it
            phi, theta = np.interp(tb, tr["t"], tr["roll"]), np.interp(tb, tr["t"], tr["pitch"])
            f_d = a_ib(phi, theta, 0.0)[2] @ np.asarray(f)  # the down row does not depend on yaw
            dv += (f_d + G) * (tb - ta)
    dv_truth = np.interp(t1, tr["t"], tr["vd"]) - np.interp(t0, tr["t"], tr["vd"])
    assert abs(dv - dv_truth) < 0.005, (dv, dv_truth)
    k = (tr["t"] >= t0) & (tr["t"] <= t1)
    dh = -np.trapezoid(tr["vd"][k], tr["t"][k])
    assert abs((tr["h"][k][-1] - tr["h"][k][0]) - dh) < 0.002, (tr["h"][k][-1] - tr["h"][k][0], dh)
