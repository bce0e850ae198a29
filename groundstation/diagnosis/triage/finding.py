"""One triage finding, how findings rank, and the interval arithmetic the checks share."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: worst first; a finding's rank is its severity, then its time
SEVERITIES = ("critical", "error", "warning", "info")

#: where a user reads what the finding means and what to do; ArduPilot's wiki unless PX4's is named
DOCS = {
    "crash": "https://ardupilot.org/copter/docs/crash_check.html",
    "flip": "https://ardupilot.org/copter/docs/common-diagnosing-problems-using-logs.html",
    "failsafe": "https://ardupilot.org/copter/docs/failsafe-landing-page.html",
    "gps_glitch": "https://ardupilot.org/copter/docs/gps-failsafe-glitch-protection.html",
    "logging_gap": "https://ardupilot.org/copter/docs/common-logs.html",
    "vibration": "https://ardupilot.org/copter/docs/common-measuring-vibration.html",
    "clipping": "https://ardupilot.org/copter/docs/common-measuring-vibration.html",
    "imu_mismatch": "https://ardupilot.org/copter/docs/common-prearm-safety-checks.html",
    "motor_imbalance": "https://ardupilot.org/copter/docs/common-diagnosing-problems-using-logs.html",
    "motor_saturation": "https://ardupilot.org/copter/docs/thrust-loss-yaw-imbalance.html",
    "ekf_innovation": "https://ardupilot.org/copter/docs/ekf-inav-failsafe.html",
    "lane_switch": "https://ardupilot.org/copter/docs/common-apm-navigation-extended-kalman-filter-overview.html",
    "config_risk": "https://ardupilot.org/copter/docs/common-prearm-safety-checks.html",
    "battery": "https://ardupilot.org/copter/docs/failsafe-battery.html",
    "mode_change": "https://ardupilot.org/copter/docs/flight-modes.html",
    "estimator_divergence": "https://ardupilot.org/copter/docs/common-apm-navigation-extended-kalman-filter-overview.html",
    "bad_parameter": "https://ardupilot.org/copter/docs/parameters.html",
    "log_ends_in_flight": "https://ardupilot.org/copter/docs/common-diagnosing-problems-using-logs.html",
    "board_voltage": "https://ardupilot.org/copter/docs/common-diagnosing-problems-using-logs.html",
    "nan_in_records": "https://ardupilot.org/copter/docs/common-logs.html",
    "duplicate_data": "https://ardupilot.org/copter/docs/common-logs.html",
    "slow_loops": "https://ardupilot.org/copter/docs/common-diagnosing-problems-using-logs.html",
    "no_flight": "https://ardupilot.org/copter/docs/common-logs.html",
    "lean_angle": "https://ardupilot.org/copter/docs/common-diagnosing-problems-using-logs.html",
    "thrust_margin": "https://ardupilot.org/copter/docs/thrust-loss-yaw-imbalance.html",
    "autotune": "https://ardupilot.org/copter/docs/autotune.html",
    "gps_quality": "https://ardupilot.org/copter/docs/gps-failsafe-glitch-protection.html",
    "compass": "https://ardupilot.org/copter/docs/common-compass-setup-advanced.html",
    "baro_glitch": "https://ardupilot.org/copter/docs/common-diagnosing-problems-using-logs.html",
    "flow_scale": "https://ardupilot.org/copter/docs/common-optical-flow-sensor-setup.html",
}
PX4_DOCS = {
    "vibration": "https://docs.px4.io/main/en/assembly/vibration_isolation.html",
    "clipping": "https://docs.px4.io/main/en/assembly/vibration_isolation.html",
    "ekf_innovation": "https://docs.px4.io/main/en/advanced_config/tuning_the_ecl_ekf.html",
    "failsafe": "https://docs.px4.io/main/en/config/safety.html",
    "config_risk": "https://docs.px4.io/main/en/config/safety.html",
}


@dataclass
class TriageFinding:
    """What happened, when (``t_start``..``t_end`` [s] on the log's clock), how bad, the figures."""

    name: str
    t_start: float
    t_end: float
    severity: str
    evidence: str
    doc: str = ""
    #: the fit cannot use this stretch (the model does not hold there: a crash, a failsafe, clipping)
    cuts: bool = False
    detail: dict = field(default_factory=dict)

    @property
    def rank(self) -> tuple[int, float]:
        return SEVERITIES.index(self.severity), self.t_start

    def as_json(self) -> dict:
        return {
            "name": self.name,
            "t_start": round(self.t_start, 3),
            "t_end": round(self.t_end, 3),
            "severity": self.severity,
            "evidence": self.evidence,
            "doc": self.doc,
            "cuts_fit": self.cuts,
        }

    def line(self) -> str:
        when = f"{self.t_start:.1f} s" if self.t_end - self.t_start < 0.05 else f"{self.t_start:.1f}-{self.t_end:.1f} s"
        return f"{self.severity.upper():8s} {self.name:16s} {when:>16s}  {self.evidence}"


def runs(
    mask: np.ndarray, t: np.ndarray, join: float = 0.0, min_len: float = 0.0
) -> list[tuple[float, float, int, int]]:
    """The stretches where ``mask`` holds, as (t_start, t_end, i_start, i_end inclusive); stretches
    closer than ``join`` [s] are merged, those shorter than ``min_len`` [s] dropped."""
    if not len(mask) or not mask.any():
        return []
    m = np.concatenate([[False], mask.astype(bool), [False]])
    d = np.diff(m.astype(np.int8))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1
    out: list[list] = []
    for a, b in zip(starts, ends):
        if out and t[a] - out[-1][1] <= join:
            out[-1][1], out[-1][3] = t[b], b
        else:
            out.append([t[a], t[b], a, b])
    return [(float(a), float(b), int(i), int(j)) for a, b, i, j in out if b - a >= min_len]


def cell_count(v_full: float) -> int:
    """A lithium pack's cells from its full voltage (4.2 V a cell charged; 4.35 V for LiHV)."""
    return max(1, int(np.ceil(v_full / 4.35 - 0.05)))
