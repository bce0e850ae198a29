"""The 3-DOF helicopter's closed loop over the simulator's rig effects: the validation table.

    python bench/rig_diagnosis.py [--seeds 1,2] [--seconds 90]

For each effect the simulator can give the rig (at a realistic size), on the standard flight (take-off
from the table, elevation steps, travel swings; the same manoeuvres for every seed, its noise
differs) and on the large flight (far from the linearisation point, its sizes and periods drawn
from the seed) of each seed: ``diagnose --model heli3dof``'s claims,
the injected parameter found against its truth, and the encoders predicted over 1 s from the motor
voltages, RMS over pitch, elevation and travel, with the lab's model, with the effects found, and
with the truth declared (the oracle: the simulator's full equations and the injected effect at its
true size, nothing fitted); the ratio column is the found model's error over the oracle's.
Then the clean flights: ``small`` (near the linearisation point: nothing to claim) and ``large``
(far from it: the full equations only).
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from groundstation.diagnosis.rig.diagnose import diagnose_rig  # noqa: E402
from groundstation.diagnosis.rig.model import lab_model  # noqa: E402
from groundstation.diagnosis.rig.predict import prediction_error  # noqa: E402
from groundstation.estimation.logs import load_log  # noqa: E402

# (effect, the claim that names it, its parameter, its truth, shown as (unit, factor))
CASES = [
    ("motor_constant:s=0.08", "motor_constant", "K_f", 0.1248 * 1.08, ("N/V", 1.0)),
    ("counterweight:dm=0.02", "equilibrium_voltage", "V_s0", 6.907, ("V", 1.0)),
    ("motor_asymmetry:a=0.04", "motor_asymmetry", "a", 0.04, ("", 1.0)),
    ("viscous_friction:p=0.005,e=0,lambda=0", "viscous_friction(p)", "c_p", 0.005 / 0.044, ("1/s", 1.0)),
    ("viscous_friction:p=0,e=0.05,lambda=0", "viscous_friction(e)", "c_e", 0.05 / 1.03, ("1/s", 1.0)),
    ("viscous_friction:p=0,e=0.2,lambda=0", "viscous_friction(e)", "c_e", 0.2 / 1.03, ("1/s", 1.0)),
    ("viscous_friction:p=0,e=0,lambda=0.08", "viscous_friction(lambda)", "c_l", 0.08 / 1.08, ("1/s", 1.0)),
    ("actuator_lag:tc=0.05", "motor_lag", "tc", 0.05, ("s", 1.0)),
    ("actuator_lag:tc=0.1", "motor_lag", "tc", 0.1, ("s", 1.0)),
    ("encoder_offset:p=1.0,e=-0.8", "encoder_offset", "o_p", math.radians(1.0), ("deg", math.degrees(1.0))),
    ("gyro_bias:x=0.01,y=-0.008,z=0.005", "gyro_bias", "b_gx", 0.01, ("rad/s", 1.0)),
    ("accel_bias:x=0.1,y=-0.08,z=0.15", "accel_bias", "b_az", 0.15, ("m/s^2", 1.0)),
    (
        "imu_misalignment:roll=2,pitch=-1.5,yaw=0",
        "imu_misalignment",
        "m_roll",
        math.radians(2.0),
        ("deg", math.degrees(1.0)),
    ),
]


#: the truth of each case beyond the lab's model, for the oracle (the simulator's own V_s0 is 8.008 V)
TRUTH = {
    "motor_constant:s=0.08": {"K_f": 0.1248 * 1.08, "V_s0": 8.008 / 1.08},
    "counterweight:dm=0.02": {"V_s0": 6.907},
    "motor_asymmetry:a=0.04": {"a": 0.04},
    "viscous_friction:p=0.005,e=0,lambda=0": {"c_p": 0.005 / 0.044},
    "viscous_friction:p=0,e=0.05,lambda=0": {"c_e": 0.05 / 1.03},
    "viscous_friction:p=0,e=0.2,lambda=0": {"c_e": 0.2 / 1.03},
    "viscous_friction:p=0,e=0,lambda=0.08": {"c_l": 0.08 / 1.08},
    "actuator_lag:tc=0.05": {"tc": 0.05},
    "actuator_lag:tc=0.1": {"tc": 0.1},
    "encoder_offset:p=1.0,e=-0.8": {"o_p": math.radians(1.0), "o_e": math.radians(-0.8)},
}


def oracle(effect: str | None) -> dict[str, float]:
    """The model with the truth declared: the full equations, the simulator's V_s0, the effect's size."""
    v = lab_model()
    v.update({"w_e": 1.0, "w_l": 1.0, "V_s0": 8.008})
    v.update(TRUTH.get(effect or "", {}))
    return v


def simulate(folder: Path, flight: str, seed: int, seconds: float, effect: str | None) -> Path:
    log = folder / f"{flight}-{seed}-{(effect or 'clean').split(':')[0]}.tlog"
    cmd = [sys.executable, "-m", "groundstation", "sim", "--vehicle", "heli3dof", "--fast", "--flight", flight]
    cmd += ["--seed", str(seed), "--duration", str(seconds), "--log", str(log)]
    if effect:
        cmd += ["--undeclared", effect]
    subprocess.run(cmd, check=True, capture_output=True)
    return log


def run(path: Path):
    log = load_log(path, tables=False, imu_columns=True)
    t0 = time.perf_counter()
    d = diagnose_rig(log.measurements, log.imu, with_kalman=False)
    return d, time.perf_counter() - t0


def deg_sum(p) -> float:
    return math.degrees(sum(p.rms.values()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="1,2")
    ap.add_argument("--seconds", type=float, default=90.0)
    ap.add_argument("--flights", default="standard,large", help="the flights the effects are injected on")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    print(
        "| flight | injected | claimed | found / truth | prediction (deg RMS, p+e+lambda) lab -> found; oracle "
        "| found / oracle | s |"
    )
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for seed in seeds:
            for flight, (effect, name, param, truth, (unit, k)) in (
                (f, c) for f in args.flights.split(",") for c in CASES
            ):
                d, secs = run(simulate(folder, flight, seed, args.seconds, effect))
                names = [st.name for st in d.search.claimed]
                v = d.search.final.values[param]
                found = f"{v * k:.4g} / {truth * k:.4g} {unit}" if name in names else "-"
                b, a = deg_sum(d.prediction[0]), deg_sum(d.prediction[1])
                o = deg_sum(prediction_error(d.session, oracle(effect)))
                print(
                    f"| {flight} s{seed} | {effect} | {', '.join(names) or '-'} | {found} "
                    f"| {b:.3f} -> {a:.3f}; {o:.3f} | {a / o:.2f} | {secs:.1f} |"
                )
            for flight in ("small", "large"):
                d, secs = run(simulate(folder, flight, seed, args.seconds, None))
                names = [st.name for st in d.search.claimed]
                fin = d.search.final.values
                shares = f"w_e {fin['w_e']:.3f}, w_l {fin['w_l']:.3f}" if names else "-"
                b, a = deg_sum(d.prediction[0]), deg_sum(d.prediction[1])
                o = deg_sum(prediction_error(d.session, oracle(None)))
                print(
                    f"| {flight} s{seed} | - | {', '.join(names) or '-'} | {shares} | {b:.3f} -> {a:.3f}; {o:.3f} | "
                    f"{a / o:.2f} | {secs:.1f} |"
                )


if __name__ == "__main__":
    main()
