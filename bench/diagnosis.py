"""The diagnosis sweep: effect x magnitude x seed, each effect undeclared, on simulated flights.

    python bench/diagnosis.py [--seeds 5] [--effects baro_thrust,sensor_delay] [--jobs 2] [--seconds 60]
                              [--airframe sim_quad] [--baro-flight standard]
    python bench/diagnosis.py --foreign     # the foreign flights' table (bench/foreign.py)
    python bench/diagnosis.py --speed       # every core against one (bench/diagnosis_speed.py)

For every run: a simulated flight (vehicle alternating quad / coax, the seed
changing the flight), the effect acting but not declared, then ``diagnose``
with the altitude model; the barometer's effects on the high flight (a climb
above the range sensor's reach, where the baro carries the height;
``--baro-flight standard`` flies them on the standard flight instead, where the
range hides them from the height); thrust-side effects with the thrust model, on the
quadcopter flying the thrust test flight, and the IMU's own (gyro bias,
mounting) with the attitude model, on the quadcopter. Printed per run: the
true effect's rank, its parameter error, RMSE against truth before/after
(height [m]; roll and pitch [rad] for the attitude model), the affected
sensor's NIS and Ljung-Box p after, and the same test's p on that sensor's own simulated
noise against truth (:func:`sensor_noise`). Then per effect the issue's bars: ranked
first in >= 90 % of runs (beside it, "+k": runs where it was not first but the report gives it as
the first effect's close alternative, ``search.CLOSE_CALL``), parameter within +-15 %, RMSE down >= 50 % (>= 80 %
for tilt and latency), and for the clean runs nothing claimed in >= 95 %; for an effect outside the
catalogue (``OUTSIDE``, the simulator's ``baro_airflow``), how often the regression names it and sizes
it within 30 %. The
truth (the simulator's sidecar) is used for the errors only: ``diagnose``'s
veto of an effect that makes the error against truth worse is off, so what is
measured is the diagnosis from the log's own sensors. ``--airframe sim_quad``
gives the thrust model the simulated quadcopter's thrust curve, drag and
acceleration noise (``groundstation/vehicles/sim_quad.json``, as ``diagnose --vehicle``); without it
they come from the log (the thrust curve from the accelerometer: groundstation/diagnosis/catalogue/airframe.py).
The fast subset is ``tests/test_diagnosis.py``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from groundstation.diagnosis.catalogue.altitude import GEOMETRIC  # noqa: E402

#: effect -> (parameter checked, magnitudes spread over the realistic range, extra spec)
SWEEP = {
    "baro_thrust": ("k", (1.0, 3.0, 6.0), ""),
    "baro_bias_drift": ("rate", (0.03, 0.08, 0.13), ",sigma=0.01"),
    "baro_thermal": ("k", (0.2, 0.5, 1.0), ""),
    "baro_ground_effect": ("A", (-0.8, -1.5, -2.5), ""),
    "sensor_delay": ("seconds", (0.03, 0.06, 0.12), "sensor=range,"),
    "range_tilt": (None, (None,), ""),
    "accel_scale": ("s", (0.01, 0.02, 0.04), ""),
    # outside the catalogue (OUTSIDE): what the sparse regression must name
    "baro_airflow": ("k", (0.1, 0.2, 0.3), ""),
    "clean": (None, (None,), ""),
    "clean_high": (None, (None,), ""),
    # thrust-side: the thrust model (quadcopter only: its document's model)
    "thrust_voltage": ("n", (1.0, 1.5, 2.0), ""),
    "thrust_ground_effect": ("R", (0.1, 0.15, 0.25), ""),
    "actuator_lag": ("tc", (0.05, 0.1, 0.2), ""),
    "clean_thrust": (None, (None,), ""),
    # the IMU's own: the attitude model on the raw IMU (multirotor: the quadcopter)
    "gyro_bias": ("x", (0.005, 0.015, 0.04), ",y=-0.01,z=0"),
    "imu_misalignment": ("roll", (1.0, 2.5, 4.0), ",pitch=-1.5,yaw=0"),
    "clean_attitude": (None, (None,), ""),
    # a vertical accelerometer bias is the altitude model's own state b_acc: "modelled", not added
    "accel_bias": ("z", (0.1, 0.2, 0.4), ",x=0,y=0"),
}
#: effects diagnosed with the thrust model, on the quadcopter, flying the thrust test flight (a
#: low hover in ground effect and throttle steps: sim_bridge/profile.py); the standard flight's
#: lowest hover is 0.6 m and its throttle smooth, and gives ground effect and lag nothing to act on
THRUST = {"thrust_voltage", "thrust_ground_effect", "actuator_lag", "clean_thrust"}
#: effects diagnosed with the attitude model, on the quadcopter
ATTITUDE = {"gyro_bias", "imu_misalignment", "clean_attitude"}
#: barometer effects fly the high flight (sim_bridge/profile.py): a climb to 5-8 m, above the range
#: sensor's 4 m, where the baro alone carries the height. On the standard flight (<= 3.6 m) the range
#: carries it throughout and a baro effect moves the height by a millimetre or less: "RMSE down"
#: measures nothing there
HIGH = {"baro_thrust", "baro_bias_drift", "baro_thermal", "baro_ground_effect", "clean_high", "baro_airflow"}
#: effects outside the diagnosis' catalogue, with the regressor the regression must name (discover.py):
#: "rank" 1 when a discovery on the baro names it, its coefficient the parameter (bar: within 30 %, the
#: raw innovations' fit being short by what the filter absorbed)
OUTSIDE = {"baro_airflow": "vertical speed^2"}
CLEAN = {"clean", "clean_high", "clean_thrust", "clean_attitude"}


def model_for(effect: str) -> str:
    return "quad_thrust" if effect in THRUST else "attitude" if effect in ATTITUDE else "altitude"


def flight_for(effect: str, baro_flight: str = "high") -> str:
    return "thrust_test" if effect in THRUST else baro_flight if effect in HIGH else "standard"


def one(job: tuple) -> dict:
    from drivers.replay import Replay
    from groundstation.diagnosis.engine import diagnose
    from groundstation.estimation.truth import truth_from
    from groundstation.estimation.vehicles import declared_effects
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario

    effect, param, mag, extra, seed, vehicle, seconds, airframe, flight = job
    declared = [] if effect == "range_tilt" else ["range_tilt"]
    model = model_for(effect)
    und = []
    if effect != "range_tilt" and effect not in CLEAN:
        spec = f"{extra}{param}={mag}" if extra.endswith(",") else f"{param}={mag}{extra}"
        und = [f"{effect}:{spec}"]
    with tempfile.TemporaryDirectory() as d:
        log = Path(d) / "s.tlog"
        run_fast(Scenario.from_args(vehicle, seed, seconds, declared, und, flight=flight), log, log.with_suffix(".csv"))
        ms = list(Replay(log).iter_measurements())
        t0 = time.perf_counter()
        dg = diagnose(
            ms,
            model_name=model,
            declared=declared_effects(log.with_suffix(".declared.json")),
            truth=truth_from(ms, log, None),
            veto_with_truth=False,
            vehicle=airframe,
        )
        wall = time.perf_counter() - t0
        sim_truth = np.genfromtxt(log.with_suffix(".csv"), delimiter=",", names=True)
    names = [e.name for e in dg.effects]
    found = dg.effects + dg.modelled  # an effect the base model estimates counts as found
    all_names = names + [e.name for e in dg.modelled]
    rank = all_names.index(effect) + 1 if effect in all_names else 0
    est = found[rank - 1].params.get(param) if rank and param else None
    if effect in OUTSIDE:
        named = [x for x in dg.discoveries if x.sensor == "baro" and OUTSIDE[effect] in x.expression]
        rank, est = (1, named[0].coefficient) if named else (0, None)
    err = abs(est - mag) / abs(mag) if est is not None else None
    rb, ra = (dg.truth.error(r, 8.0, seconds - 10.0) for r in (dg.before, dg.after))
    if effect == "range_tilt":
        # the slant is always simulated: the twin is the same flight with it declared
        floor = clean_twin_rmse(vehicle, seed, seconds, ["range_tilt"], model, flight, airframe)
    else:
        floor = clean_twin_rmse(vehicle, seed, seconds, declared, model, flight, airframe) if und else rb
    sensor = "baro" if effect in OUTSIDE else found[rank - 1].evidence.get("sensor") if rank else None
    if sensor not in {f.sensor for f in dg.findings_after}:  # none, or an input (a lagged throttle)
        sensor = "accel" if model == "attitude" else "range"
    after = {f.test: f for f in dg.findings_after if f.sensor == sensor}
    R = next(
        (float(np.atleast_2d(mm.R)[0, 0]) for mm in dg.after.model.measurements.values() if mm.name == sensor),
        float("nan"),
    )
    noise = sensor_noise(ms, sim_truth, sensor, R, mag if effect == "sensor_delay" else 0.0)
    # the runner-ups the log barely told from the effects it named (search.CLOSE_CALL)
    alternatives = [e.evidence["alternative"]["name"].split("(")[0] for e in dg.effects if "alternative" in e.evidence]
    return {
        "effect": effect,
        "mag": mag,
        "seed": seed,
        "vehicle": vehicle,
        "rank": rank,
        "claimed": names,
        "alternatives": alternatives,
        "discovered": [x.expression for x in dg.discoveries],
        "est": est,
        "err": err,
        "rmse_before": rb,
        "rmse_after": ra,
        "rmse_floor": floor,
        "nis_ok": after["NIS mean"].passed if "NIS mean" in after else None,
        "nis": after["NIS mean"].statistic if "NIS mean" in after else float("nan"),
        "lb_p": after["Ljung-Box whiteness"].statistic if "Ljung-Box whiteness" in after else float("nan"),
        **noise,
        "wall": wall,
    }


def sensor_noise(ms: list, tr: np.ndarray, sensor: str, R: float, delay: float = 0.0) -> dict:
    """The sensor's own simulated noise, judged as its innovations are: its mean square over the
    model's R (the NIS a perfect model would approach) and its Ljung-Box p, ``tr`` the simulator's
    truth table (``*.csv``). The noise is the
    readings minus what the simulator's truth says they should read (the baro: height plus every
    baro effect's error; the range: the true slant range, ``delay`` s earlier for a range delay).
    Each test fails on 5 % of draws of correct noise, and where the noise fails, so do the
    innovations: on 4 baro_thrust flights the innovations' Ljung-Box read
    p = 0.036, 0.018, 0.014, 0.002 and their noise's 0.046, 0.019, 0.019, 0.002; on two clean
    high flights the range's NIS read 0.90 and 1.10 and its noise 0.88 and 1.09.
    The accelerometer (horizontal, the attitude model's measurement): the simulator's record of its
    readings' noise and rounding over each 10 ms truth row, which are the diagnosis' input blocks;
    NIS over both axes at R / samples per block, Ljung-Box on x (the first component, as the
    diagnosis reads it). NaN where the truth has no such column."""
    from scipy.stats import chi2

    from groundstation.core.atmosphere import altitude_at
    from groundstation.core.measurement import Kind
    from groundstation.estimation.whiteness import ljung_box

    if sensor == "baro":
        b = np.array(
            [(m.t, float(altitude_at(m.value[0]))) for m in ms if m.kind is Kind.BARO_PRESSURE and m.instance == 0]
        )
        t, e = b[:, 0], b[:, 1] - np.interp(b[:, 0], tr["t"], tr["h"] + tr["baro_alt_error"])
    elif sensor == "range":
        r = np.array([(m.t, float(m.value[0])) for m in ms if m.kind is Kind.RANGE])
        t, e = r[:, 0], r[:, 1] - np.interp(r[:, 0] - delay, tr["t"], tr["range_true"])
    elif sensor == "accel" and "accel_err_x" in (tr.dtype.names or ()):
        ok = (tr["accel_samples"] > 0) & (tr["t"] >= tr["t"][0] + 5.0)
        ex, ey, k = tr["accel_err_x"][ok], tr["accel_err_y"][ok], tr["accel_samples"][ok]
        nis, (lo, hi) = float(np.mean((ex**2 + ey**2) * k / R)), chi2.ppf([0.025, 0.975], 2 * len(ex)) / len(ex)
        return {"noise_nis": nis, "noise_nis_ok": bool(lo <= nis <= hi), "noise_p": float(ljung_box(ex))}
    else:
        return {"noise_nis": float("nan"), "noise_nis_ok": None, "noise_p": float("nan")}
    e = e[t >= t[0] + 5.0]  # from 5 s in, as the diagnosis scores
    e = e - e.mean()  # the baro's zero is the model's own constant
    nis, (lo, hi) = float(np.mean(e**2) / R), chi2.ppf([0.025, 0.975], len(e)) / len(e)
    return {"noise_nis": nis, "noise_nis_ok": bool(lo <= nis <= hi), "noise_p": float(ljung_box(e))}


def clean_twin_rmse(
    vehicle: str,
    seed: int,
    seconds: float,
    declared: list[str],
    model: str,
    flight: str = "standard",
    airframe: str | None = None,
) -> float:
    """The height RMSE the base model reaches on the same flight without the effect: the floor no
    diagnosis can go below (range noise, the filter's own lag). Where a range sensor carries the
    height, a baro effect adds a few millimetres to a ~3 mm floor, and "RMSE down >= 50 %" is out of
    reach by construction; the share of the effect's own error removed, (before - after) /
    (before - floor), is what the diagnosis controls."""
    from drivers.replay import Replay
    from groundstation.diagnosis.models import setup
    from groundstation.diagnosis.runs.run import run_model
    from groundstation.estimation.truth import truth_from
    from groundstation.estimation.vehicles import declared_effects
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario

    with tempfile.TemporaryDirectory() as d:
        log = Path(d) / "s.tlog"
        run_fast(Scenario.from_args(vehicle, seed, seconds, declared, [], flight=flight), log, log.with_suffix(".csv"))
        ms = list(Replay(log).iter_measurements())
        su = setup(ms, model_name=model, declared=declared_effects(log.with_suffix(".declared.json")), vehicle=airframe)
        r = run_model(su.model, su.prep, su.make)
        return truth_from(ms, log, None).error(r, 8.0, seconds - 10.0)


def noise_too(rs: list[dict]) -> str:
    """Of the runs failing NIS / Ljung-Box after, how many have a sensor noise that fails it too
    ("k/m"), and how many failed where the truth gives no noise (the accelerometer: "+j n/a")."""

    def count(failed: list[dict], has, fails) -> str:
        known = [r for r in failed if has(r)]
        out = f"{sum(fails(r) for r in known)}/{len(known)}"
        return out + (f" +{len(failed) - len(known)} n/a" if len(failed) > len(known) else "")

    return (
        count(
            [r for r in rs if not r["nis_ok"]], lambda r: r["noise_nis_ok"] is not None, lambda r: not r["noise_nis_ok"]
        )
        + ", "
        + count(
            [r for r in rs if not r["lb_p"] > 0.05], lambda r: np.isfinite(r["noise_p"]), lambda r: r["noise_p"] <= 0.05
        )
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--effects", default=",".join(SWEEP))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument(
        "--airframe",
        default=None,
        help="a vehicle file for the thrust model (sim_quad: the simulated "
        "quadcopter's thrust curve, drag and acceleration noise); default: from the log",
    )
    ap.add_argument(
        "--baro-flight",
        choices=("high", "standard"),
        default="high",
        help="the flight of the barometer's effects and clean_high (default: high)",
    )
    ap.add_argument(
        "--foreign",
        action="store_true",
        help="the foreign flights' table instead (bench/foreign.py: another generator's flights, with truth)",
    )
    ap.add_argument(
        "--speed",
        action="store_true",
        help="diagnose on every core against one, on the same logs (bench/diagnosis_speed.py)",
    )
    args = ap.parse_args()
    if args.speed:
        import diagnosis_speed  # bench/diagnosis_speed.py, beside this file

        sys.argv = [sys.argv[0]]
        return diagnosis_speed.main()
    if args.foreign:
        import foreign  # bench/foreign.py, beside this file

        sys.argv = [sys.argv[0], "--jobs", str(args.jobs)]
        return foreign.main()
    jobs = []
    for effect in args.effects.split(","):
        param, mags, extra = SWEEP[effect]
        for mag in mags:
            for s in range(args.seeds):
                seed = 1000 + 17 * s + len(jobs)
                vehicle = "quad" if effect in THRUST | ATTITUDE else ("quad", "coax")[s % 2]
                airframe = args.airframe if model_for(effect) == "quad_thrust" else None
                jobs.append(
                    (
                        effect,
                        param,
                        mag,
                        extra,
                        seed,
                        vehicle,
                        args.seconds,
                        airframe,
                        flight_for(effect, args.baro_flight),
                    )
                )
    print(
        f"{'effect':<20}{'mag':>7}{'seed':>6}{'veh':>6}{'rank':>5}{'param':>10}{'err':>7}"
        f"{'RMSE before':>13}{'after':>9}{'floor':>8}{'NIS':>7}{'noise':>7}{'LB p':>8}{'noise':>7}  claimed",
        flush=True,
    )
    rows = []
    # one BLAS thread each: OpenBLAS's pool does not survive a fork (groundstation/diagnosis/scoring/trials.py)
    with threadpool_limits(limits=1, user_api="blas"), ProcessPoolExecutor(args.jobs) as ex:
        for r in ex.map(one, jobs):
            rows.append(r)
            est = f"{r['est']:.4g}" if r["est"] is not None else "-"
            err = f"{100 * r['err']:.0f}%" if r["err"] is not None else "-"
            mag = f"{r['mag']:g}" if r["mag"] is not None else "-"
            print(
                f"{r['effect']:<20}{mag:>7}{r['seed']:>6}{r['vehicle']:>6}{r['rank']:>5}{est:>10}{err:>7}"
                f"{r['rmse_before']:>13.4f}{r['rmse_after']:>9.4f}{r['rmse_floor']:>8.4f}"
                f"{r['nis']:>6.2f}{' ' if r['nis_ok'] else '*'}{r['noise_nis']:>7.2f}"
                f"{r['lb_p']:>8.3f}{r['noise_p']:>7.3f}  "
                f"{','.join(r['claimed'] + ['discovered:' + x for x in r['discovered']]) or '-'}"
                f"{''.join(' (or ' + a + ')' for a in r['alternatives'])}",
                flush=True,
            )
    print(
        "\nper effect (bars: ranked first, parameter within 15 %, height RMSE down 50 %; 80 % for geometry and timing)"
    )
    print(
        f"{'effect':<20}{'runs':>5}{'first':>8}{'':>3}{'param ok':>10}{'RMSE down (median)':>20}"
        f"{'of its own error':>20}{'NIS ok':>8}{'LB p>0.05':>10}  failing where the noise fails too (NIS, LB)"
    )
    for effect in args.effects.split(","):
        rs = [r for r in rows if r["effect"] == effect]
        if effect in CLEAN:
            quiet = np.mean([not r["claimed"] and not r["discovered"] for r in rs])
            print(
                f"{effect:<20}{len(rs):>5}   nothing claimed in {100 * quiet:.0f} % (bar >= 95 %); NIS ok "
                f"{100 * np.mean([bool(r['nis_ok']) for r in rs]):.0f} %, Ljung-Box "
                f"{100 * np.mean([r['lb_p'] > 0.05 for r in rs]):.0f} %; failing where the noise fails too "
                f"{noise_too(rs)}"
            )
            continue
        if effect in OUTSIDE:
            # named, not added: the model, its height error and its whiteness stay as they were
            named = [r for r in rs if r["rank"] == 1]
            print(
                f"{effect:<20}{len(rs):>5}   outside the catalogue: {OUTSIDE[effect]} named by the regression in "
                f"{100 * len(named) / len(rs):.0f} %, its coefficient within 30 % in "
                f"{100 * np.mean([r['err'] is not None and r['err'] <= 0.3 for r in rs]):.0f} %; a catalogue "
                f"effect claimed in {100 * np.mean([bool(r['claimed']) for r in rs]):.0f} %"
            )
            continue
        first = np.mean([r["rank"] == 1 for r in rs])
        # not first, but given as the first effect's close alternative: the report says it may be this
        alt = sum(r["rank"] != 1 and effect in r["alternatives"][:1] for r in rs)
        tol = 0.3 if effect in OUTSIDE else 0.15
        pok = [r["err"] is not None and r["err"] <= tol for r in rs] if SWEEP[effect][0] else []
        down = np.median([1 - r["rmse_after"] / r["rmse_before"] for r in rs])
        # the share of the effect's own error removed, where the effect moves the height at all
        # (before >= 10 % over the floor: below that the ratio is noise over noise)
        moved = [r for r in rs if r["rmse_before"] > 1.1 * r["rmse_floor"]]
        share = [(r["rmse_before"] - r["rmse_after"]) / (r["rmse_before"] - r["rmse_floor"]) for r in moved]
        own = f"{100 * np.median(share):.0f}% of {len(moved)}" if moved else "- (height unmoved)"
        bar = 0.8 if effect in GEOMETRIC else 0.5
        print(
            f"{effect:<20}{len(rs):>5}{100 * first:>7.0f}%{f'+{alt}' if alt else '':>3}"
            f"{(f'{100 * np.mean(pok):.0f}%' if pok else '-'):>10}"
            f"{100 * down:>13.0f}% (>= {100 * bar:.0f}%){own:>20}"
            f"{100 * np.mean([bool(r['nis_ok']) for r in rs]):>7.0f}%"
            f"{100 * np.mean([r['lb_p'] > 0.05 for r in rs]):>9.0f}%"
            f"  {noise_too(rs)}"
        )
    print(f"\nmedian diagnosis time {np.median([r['wall'] for r in rows]):.1f} s per 60 s flight")
    return 0


if __name__ == "__main__":
    sys.exit(main())
