"""The lab's control findings, reproduced on the simulated 3-DOF helicopter.

    python bench/control.py [--seconds 60] [--json OUT.json]

Every flight runs the ground station's own controller, feedback and commander
against the simulated rig, bytes both ways through the board protocol, the
simulator stepped as fast as it goes (:mod:`groundstation.control.offline`).
The rig starts resting on the table, as in the lab; control is armed at 0.5 s,
the elevation is lifted to level, and the pitch reference steps at 6 s.

1. **Table 2, pole placement.** For each of the lab's nine trials: the gains
   the lab computed (its K1 = 13.5, from K_f = 3.4) flown on the rig, whose K1
   is 0.496 (K_f = 0.1248, see ``groundstation.control.design``); and gains
   placed with the corrected K1. Each response is named as the lab names it
   (:func:`groundstation.control.response.classify`).
2. **Feedback sources**: the LQR with feed-forward (the lab's eq. 92 weights)
   fed by the encoders, the Kalman filter, the raw IMU and the open-loop
   predictor, for ``--seconds``: pitch tracking error, elevation-rate tracking
   error, noise on the command (RMS of its step-to-step change), and whether
   it stayed up (pitch within its limits and off the table).
3. **The lab's Q and R** (eq. 38, 44, 92): gains and closed-loop poles on the
   corrected model, and the step each gives.

4. **The closed loop felt by the controller.** A rig unlike Table 1 (a heavier
   counterweight, stronger and unlike motors: ``RIG_EFFECTS``) flies a session
   on its own; ``diagnose --model heli3dof`` finds its constants; the PD and the
   LQR with integral action, designed on the lab's constants and then on the
   rig's, each fly a pitch step: overshoot, 2 % settling time, and the pitch's
   and elevation's steady-state errors.

Baseline for the ratios: the lab's own observation (Table 2/3) for part 1;
encoder feedback for part 2; the lab's constants for part 4.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from groundstation.app.offline_flight import fly  # noqa: E402
from groundstation.control import design  # noqa: E402
from groundstation.control.controllers import LQRFeedForward, LQRIntegral, PitchPD  # noqa: E402
from groundstation.control.feedback import FEEDBACK_3DOF  # noqa: E402
from groundstation.control.response import classify, step_fit  # noqa: E402
from groundstation.diagnosis.rig.diagnose import diagnose_rig  # noqa: E402
from groundstation.estimation.logs import load_log  # noqa: E402
from sim_bridge.effects import parse_effect  # noqa: E402
from sim_bridge.scenario import Scenario  # noqa: E402

#: Table 2: poles, theory, what the lab observed
TABLE2 = [
    ((-1, -1), "critically damped", "unstable"),
    ((-2, -2), "critically damped", "unstable"),
    ((-3, -3), "critically damped", "underdamped"),
    ((-4, -4), "critically damped", "underdamped"),
    ((-20, -20), "critically damped", "unstable"),
    ((-5.2j, 5.2j), "undamped", "undamped"),
    ((-0.7 - 7.3j, -0.7 + 7.3j), "underdamped", "undamped"),
    ((-6.8 - 2.9j, -6.8 + 2.9j), "underdamped", "underdamped -> critically damped"),
    ((-17.1, -3.2), "overdamped", "overdamped"),
]
T_STEP, P_STEP = 6.0, 0.3


def pitch_trial(ctrl, seconds):
    f = fly(
        Scenario("heli3dof", seed=11),
        ctrl,
        FEEDBACK_3DOF["encoders"](),
        seconds=seconds,
        reference=lambda t: {"p_c": P_STEP if t >= T_STEP else 0.0, "e_c": 0.0},
    )
    name = classify(f.t, f.truth["p"], T_STEP, 0.0, P_STEP, limit=1.15)
    if name != "unstable" and np.min(f.truth["e"][f.t > T_STEP]) <= -0.49:
        name = "unstable"  # it fell back onto the table
    sat = float(np.mean([r.saturated for r in f.records if r.t >= T_STEP])) if f.records else 0.0
    try:
        w, z, _ = step_fit(f.t, f.truth["p"], T_STEP, 0.0, P_STEP) if name != "unstable" else (np.nan,) * 3
    except ValueError:
        w, z = np.nan, np.nan
    return name, w, z, sat


def part1(seconds):
    K1_lab, _ = design.k1_k2(design.LAB_K_F)
    K1, _ = design.k1_k2()
    rows = []
    print("\n## 1. Table 2: pole placement (pitch step 0.3 rad from level; encoders)\n")
    print(
        "| trial | poles | theory | lab observed | lab gains (K_pp, K_pd) | on the rig: omega_0, zeta "
        "| rig shows | corrected gains | rig shows | saturated |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for i, (poles, theory, observed) in enumerate(TABLE2, 1):
        lab = PitchPD.from_poles(*poles, K_f=design.LAB_K_F)
        w_real, z_real = design.omega_zeta(K1, lab.K_pp, lab.K_pd)
        name_lab, *_ = pitch_trial(lab, seconds)
        ours = PitchPD.from_poles(*poles)
        name_ours, w, z, sat = pitch_trial(ours, seconds)
        ps = ", ".join(f"{p:g}" for p in poles)
        print(
            f"| {i} | {ps} | {theory} | {observed} | {lab.K_pp:.2f}, {lab.K_pd:.2f} | {w_real:.2f}, {z_real:.2f} "
            f"| {name_lab} | {ours.K_pp:.1f}, {ours.K_pd:.1f} | {name_ours} | {sat:.0%} |"
        )
        rows.append(
            {
                "trial": i,
                "poles": [str(p) for p in poles],
                "theory": theory,
                "lab": observed,
                "lab_gains": [lab.K_pp, lab.K_pd],
                "lab_gains_real_omega_zeta": [w_real, z_real],
                "rig_with_lab_gains": name_lab,
                "corrected_gains": [ours.K_pp, ours.K_pd],
                "rig_with_corrected_gains": name_ours,
                "fitted_omega_zeta": [w, z],
                "saturated": sat,
            }
        )
    print(
        f"\nlab K1 = {K1_lab:.2f} (K_f = {design.LAB_K_F}), rig K1 = {K1:.3f} (K_f = {design.K_F}); "
        "'saturated': share of control ticks after the step with a motor at its limit."
    )
    return rows


def _reference(t, truth):
    """The lab's joystick, scripted: pitch steps of +-0.2 rad every 5 s; the operator
    holds elevation by eye through the elevation-rate reference (eq. 33's e_dot_c)."""
    p = 0.0 if t < 6.0 else 0.2 * (1 if int((t - 6.0) // 5.0) % 2 == 0 else -1)
    u = t % 40.0
    e_target = 0.0 if u < 20.0 else (0.15 if u < 30.0 else -0.1)
    ed = max(-0.15, min(0.15, 0.8 * (e_target - truth["e"])))
    return {"p_c": p, "e_dot_c": ed}


def part2(seconds):
    print(f"\n## 2. Feedback sources: LQR + feed-forward (eq. 92 weights), {seconds:g} s of scripted joystick\n")
    print(
        "| feedback | its p error [rad] | its e_dot error [rad/s] | pitch tracking RMS [rad] | ratio "
        "| e_dot tracking RMS [rad/s] | command noise [V] | ratio | stayed up | wall [s] |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    rows, base = [], None
    for name, cls in FEEDBACK_3DOF.items():
        t0 = time.perf_counter()
        f = fly(
            Scenario("heli3dof", seed=12),
            LQRFeedForward(design.LAB_Q_KF, design.LAB_R_KF),
            cls(),
            seconds=seconds,
            reference=_reference,
        )
        wall = time.perf_counter() - t0
        m = f.t >= T_STEP
        ref_p = np.array([r.reference["p_c"] for r in f.records])
        ref_ed = np.array([r.reference["e_dot_c"] for r in f.records])
        k = len(f.records)
        m = m[-k:] if k else m
        tp, ted = f.truth["p"][-k:], f.truth["e_dot"][-k:]
        ep = float(np.sqrt(np.mean((tp[m] - ref_p[m]) ** 2)))
        eed = float(np.sqrt(np.mean((ted[m] - ref_ed[m]) ** 2)))
        cmd = f.command()
        noise = float(np.sqrt(np.mean(np.diff(cmd[:, 1] - cmd[:, 0]) ** 2))) if len(cmd) > 2 else np.nan
        e = f.truth["e"][f.t >= T_STEP]
        up = bool(
            np.all(np.abs(f.truth["p"][f.t >= T_STEP]) < 1.15) and np.all((e > -0.49) & (e < 0.99)) and f.armed[-1]
        )
        # what the controller was told against the truth at the same tick
        fp = np.array([r.state["p"] for r in f.records]) - tp
        fed = np.array([r.state["e_dot"] for r in f.records]) - ted
        sp, sed = float(np.sqrt(np.mean(fp[m] ** 2))), float(np.sqrt(np.mean(fed[m] ** 2)))
        if base is None:
            base = (ep, noise)
        print(
            f"| {name} | {sp:.4f} | {sed:.4f} | {ep:.4f} | {ep / base[0]:.2f} | {eed:.4f} | {noise:.3f} "
            f"| {noise / base[1]:.2f} | {'yes' if up else 'no'} | {wall:.1f} |"
        )
        rows.append(
            {
                "feedback": name,
                "state_p_error": sp,
                "state_e_dot_error": sed,
                "pitch_rms": ep,
                "e_dot_rms": eed,
                "command_noise": noise,
                "stayed_up": up,
            }
        )
    return rows


def part3(seconds):
    print("\n## 3. The lab's Q and R on the corrected model (step 0.2 rad, encoders)\n")
    print("| weights | K | closed-loop poles | rig shows | omega_0, zeta fitted |")
    print("|---|---|---|---|---|")
    rows = []
    cases = [
        ("eq. 38", LQRFeedForward(design.LAB_Q_FF, design.LAB_R_FF)),
        ("eq. 92", LQRFeedForward(design.LAB_Q_KF, design.LAB_R_KF)),
        ("eq. 44 (integral)", LQRIntegral(design.LAB_Q_I, design.LAB_R_I)),
    ]
    for label, c in cases:
        A, B, _ = design.integral_model() if isinstance(c, LQRIntegral) else design.pitch_model()
        poles = np.linalg.eigvals(A - B @ c.K)
        f = fly(
            Scenario("heli3dof", seed=13),
            c,
            FEEDBACK_3DOF["encoders"](),
            seconds=min(seconds, 25.0),
            reference=lambda t: {"p_c": 0.2 if t >= T_STEP else 0.0, "e_dot_c": 0.0},
        )
        name = classify(f.t, f.truth["p"], T_STEP, 0.0, 0.2, limit=1.15)
        w, z, _ = step_fit(f.t, f.truth["p"], T_STEP, 0.0, 0.2)
        ps = ", ".join(f"{p.real:.2f}{p.imag:+.2f}j" if abs(p.imag) > 1e-9 else f"{p.real:.2f}" for p in poles)
        print(f"| {label} | {np.round(c.K, 2).tolist()} | {ps} | {name} | {w:.2f}, {z:.2f} |")
        rows.append(
            {"weights": label, "K": c.K.tolist(), "poles": [str(p) for p in poles], "rig": name, "omega_zeta": [w, z]}
        )
    return rows


#: the rig of part 4: its V_s0 about 1.6 V under the lab's, its K_f 10 % over, its motors 5 % apart
RIG_EFFECTS = ["counterweight:dm=0.03", "motor_constant:s=0.1", "motor_asymmetry:a=0.05"]


def step_metrics(f, ref: float) -> dict:
    """Overshoot [%], 2 % settling time [s] after the step, the pitch's and the elevation's mean error
    over the last 3 s [rad] (elevation held at 0)."""
    t, p, e = f.t, f.truth["p"], f.truth["e"]
    after = t >= T_STEP
    over = max(0.0, float(np.max(p[after]) - ref) / ref * 100.0)
    outside = np.flatnonzero(after & (np.abs(p - ref) > 0.02 * ref))
    settle = float(t[outside[-1]] - T_STEP) if len(outside) else 0.0
    last = t >= t[-1] - 3.0
    return {
        "overshoot_pct": over,
        "settling_s": settle,
        "pitch_error": float(np.mean(p[last]) - ref),
        "elevation_error": float(np.mean(e[last])),
    }


def _pitch_step(t):
    """The PD's reference: level, then the pitch step; its own loop holds the elevation."""
    return {"p_c": P_STEP if t >= T_STEP else 0.0, "e_c": 0.0}


def _pitch_step_level_by_eye(t, truth):
    """The LQR's: the pitch step, the elevation held level by the operator through the
    elevation-rate reference (as in part 2)."""
    return {"p_c": P_STEP if t >= T_STEP else 0.0, "e_dot_c": max(-0.15, min(0.15, -0.8 * truth["e"]))}


def part4(seconds):
    print("\n## 4. The controllers on the lab's constants and on the rig's (pitch step 0.3 rad, encoders)\n")
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "rig.tlog"
        cmd = [sys.executable, "-m", "groundstation", "sim", "--vehicle", "heli3dof", "--fast", "--flight", "large"]
        cmd += ["--seed", "21", "--duration", "90", "--log", str(log)]
        for e in RIG_EFFECTS:
            cmd += ["--undeclared", e]
        subprocess.run(cmd, check=True, capture_output=True)
        loaded = load_log(log, tables=False, imu_columns=True)
        d = diagnose_rig(loaded.measurements, loaded.imu, with_kalman=False)
    rig = d.after
    print(
        f"rig: {', '.join(RIG_EFFECTS)}; found {', '.join(st.name for st in d.search.claimed)}: K_f {rig.K_f:.4f} N/V, "
        f"V_s0 {rig.V_s0:.3f} V, a {rig.a:.4f}, w_e {rig.w_e:.2f}\n"
    )
    print("| controller | constants | overshoot | settling [s] | pitch error [rad] | elevation error [rad] |")
    print("|---|---|---|---|---|---|")
    scenario = lambda: Scenario("heli3dof", seed=22, undeclared=[parse_effect(e) for e in RIG_EFFECTS])  # noqa: E731
    rows = []
    for label, make in (
        ("PD (omega_0 4, zeta 1)", lambda **kw: PitchPD.place(4.0, 1.0, **kw)),
        ("LQR + I (eq. 44)", lambda **kw: LQRIntegral(design.LAB_Q_I, design.LAB_R_I, **kw)),
    ):
        for which, kw in (("lab's", {}), ("rig's", {"rig": rig})):
            c = make(**kw)
            f = fly(
                scenario(),
                c,
                FEEDBACK_3DOF["encoders"](),
                seconds=min(seconds, 25.0),
                reference=_pitch_step if "e_c" in c.references else _pitch_step_level_by_eye,
            )
            m = step_metrics(f, P_STEP)
            print(
                f"| {label} | {which} | {m['overshoot_pct']:.1f} % | {m['settling_s']:.2f} | {m['pitch_error']:+.4f} "
                f"| {m['elevation_error']:+.4f} |"
            )
            rows.append({"controller": label, "constants": which, **m})
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="length of the feedback-source flights")
    ap.add_argument("--trial-seconds", type=float, default=20.0, help="length of each pole-placement trial")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--parts", default="1,2,3,4", help="which parts to run")
    a = ap.parse_args()
    parts = {int(x) for x in a.parts.split(",")}
    out = {}
    if 1 in parts:
        out["table2"] = part1(a.trial_seconds)
    if 2 in parts:
        out["feedback"] = part2(a.seconds)
    if 3 in parts:
        out["weights"] = part3(a.seconds)
    if 4 in parts:
        out["rig"] = part4(a.seconds)
    if a.json:
        a.json.write_text(json.dumps(out, indent=2, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
