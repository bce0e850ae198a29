"""What the autopilot itself said: ArduPilot's ERR, EV and MODE records and its MSG / STATUSTEXT
lines, a MAVLink vehicle's HEARTBEAT modes and states, PX4's ``vehicle_status`` and logged
messages.

ERR subsystem and code numbers are ArduPilot's ``LogErrorSubsystem`` / ``LogErrorCode``
(``libraries/AP_Logger/AP_Logger.h``; ArduCopter 3.x had the same numbers in ``defines.h``);
EV ids its ``LogEvent``; mode numbers ArduCopter's ``Mode::Number``.
"""

from __future__ import annotations

import re

import numpy as np

from drivers.logs.tables import LogTables, Table
from drivers.mavlink.commands import COPTER_MODES

from .finding import DOCS, PX4_DOCS, TriageFinding, runs

#: ERR Subsys -> (finding, what); the failsafes all read "failsafe"
ERR_SUBSYSTEMS = {
    1: ("failsafe", "main loop"),
    2: ("failsafe", "radio"),
    3: ("config_risk", "compass"),
    5: ("failsafe", "radio failsafe"),
    6: ("failsafe", "battery failsafe"),
    7: ("failsafe", "GPS failsafe"),
    8: ("failsafe", "GCS failsafe"),
    9: ("failsafe", "fence breach"),
    11: ("gps_glitch", "GPS"),
    12: ("crash", "crash check"),
    13: ("flip", "flip mode"),
    16: ("ekf_innovation", "EKF check (variance)"),
    17: ("failsafe", "EKF/inertial-navigation failsafe"),
    18: ("failsafe", "barometer"),
    19: ("failsafe", "CPU"),
    22: ("failsafe", "navigation"),
    23: ("failsafe", "terrain failsafe"),
    24: ("lane_switch", "EKF primary changed"),
    25: ("motor_saturation", "thrust loss check"),
    26: ("failsafe", "sensors failsafe"),
    29: ("failsafe", "vibration failsafe"),
    31: ("failsafe", "dead-reckoning failsafe"),
}
ERR_FAILSAFE_GPS = 7
#: (Subsys, ECode) whose code says more than "it happened"
ERR_CODES = {(11, 2): "GPS glitch", (12, 1): "crash detected", (12, 2): "loss of control", (7, 1): "GPS lost"}

#: EV ids that start and end a flight (arming)
EV_ARMED, EV_DISARMED = 10, 11
EV_NOTES = {19: ("gps_glitch", "error", "GPS lost"), 54: ("failsafe", "critical", "motors emergency stopped")}

#: modes a failsafe puts a copter in (a change into one is said with the mode change)
RECOVERY_MODES = {"RTL", "LAND", "SMART_RTL", "AUTO_RTL"}

#: text the autopilot sends, by what it means (ArduPilot's and PX4's wording)
TEXT_PATTERNS = (
    (re.compile(r"crash", re.I), "crash", "critical"),
    (re.compile(r"low battery|battery (failsafe|critical|emergency)|critical battery", re.I), "failsafe", "error"),
    (re.compile(r"radio failsafe|rc (lost|failsafe)|failsafe.*radio|no rc", re.I), "failsafe", "error"),
    (re.compile(r"gps glitch|gps lost|lost gps|gps (failsafe|fix lost)", re.I), "gps_glitch", "error"),
    (re.compile(r"ekf (variance|failsafe)|ekf.*lane switch|ekf primary changed", re.I), "ekf_innovation", "error"),
    (re.compile(r"vibration compensation|high vibration", re.I), "vibration", "warning"),
    (re.compile(r"failsafe", re.I), "failsafe", "error"),
    (re.compile(r"potential thrust loss|thrust loss", re.I), "motor_saturation", "error"),
)


#: MAV_TYPE of copters (quad, coaxial, helicopter, hexa, octo, tri)
COPTER_TYPES = {2, 3, 4, 13, 14, 15}
MAV_AUTOPILOT_INVALID = 8  # a component that is not an autopilot (a camera, a gimbal) sends this
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_STATE_ACTIVE = 4  # MAV_STATE: "system is active and might be already airborne; motors are engaged"


def autopilot_heartbeats(tables: LogTables) -> Table | None:
    """The vehicle's own HEARTBEATs (not its cameras' or gimbals'), as a table."""
    hb = tables.get("HEARTBEAT")
    if hb is None or (ap := hb.numeric("autopilot")) is None:
        return hb
    keep = ap != MAV_AUTOPILOT_INVALID
    return Table(hb.t[keep], {k: v[keep] for k, v in hb.cols.items()})


def heartbeat_armed(hb: Table) -> np.ndarray | None:
    """Armed at each HEARTBEAT: the base mode's SAFETY_ARMED bit, or the system state ACTIVE, which
    MAVLink defines as "motors are engaged" and ArduPilot and PX4 send exactly while armed. Either
    alone is not enough: a vehicle (or another generator's log) may state its arming by one of them
    only, and a flight read as "never armed" is reported as a log with nothing flown."""
    bm = hb.numeric("base_mode")
    if bm is None:
        return None
    armed = (bm.astype(int) & MAV_MODE_FLAG_SAFETY_ARMED) > 0
    st = hb.numeric("system_status")
    return armed | (st == MAV_STATE_ACTIVE) if st is not None else armed


def is_copter(tables: LogTables) -> bool:
    hb = autopilot_heartbeats(tables)
    if hb is not None and (ty := hb.numeric("type")) is not None and len(ty):
        return int(np.bincount(ty.astype(int)).argmax()) in COPTER_TYPES
    msg = tables.get("MSG")
    if msg is not None and "Message" in msg and any("Copter" in str(m) for m in msg["Message"]):
        return True
    return "WPNAV_SPEED" in tables.params


def flights(tables: LogTables, t_end: float) -> list[tuple[float, float]]:
    """The armed stretches [s]: EV ARMED..DISARMED or ARM.ArmState (ArduPilot), HEARTBEAT's armed bit (MAVLink),
    ``vehicle_status.arming_state`` (PX4); empty when the log does not say (callers then take the
    whole log as one flight)."""
    ev = tables.get("EV")
    if ev is not None and (ids := ev.numeric("Id")) is not None:
        out, start = [], None
        for t, i in zip(ev.t, ids):
            if i == EV_ARMED and start is None:
                start = t
            elif i == EV_DISARMED and start is not None:
                out.append((float(start), float(t)))
                start = None
        if start is not None:
            out.append((float(start), t_end))
        if out:
            return out
    arm = tables.get("ARM")  # ArduPilot 4.x: a record at each arming and disarming
    if arm is not None and (state := arm.numeric("ArmState")) is not None:
        t = np.append(arm.t, t_end)
        return [(float(t[i]), float(t[i + 1])) for i in range(len(state)) if state[i] == 1]
    hb = autopilot_heartbeats(tables)
    if hb is not None and (armed := heartbeat_armed(hb)) is not None:
        return [(a, b) for a, b, _, _ in runs(armed, hb.t, join=3.0)]
    vs = tables.get("vehicle_status")
    if vs is not None and (st := vs.numeric("arming_state")) is not None:
        return [(a, b) for a, b, _, _ in runs(st == 2, vs.t)]
    return []


def armed_at_end(tables: LogTables) -> bool | None:
    """Whether the last arming state the log states is armed (None: it states none)."""
    ev = tables.get("EV")
    if ev is not None and (ids := ev.numeric("Id")) is not None:
        last = ids[np.isin(ids, (EV_ARMED, EV_DISARMED))]
        if len(last):
            return bool(last[-1] == EV_ARMED)
    arm = tables.get("ARM")
    if arm is not None and (state := arm.numeric("ArmState")) is not None and len(state):
        return bool(state[-1] == 1)
    hb = autopilot_heartbeats(tables)
    if hb is not None and (armed := heartbeat_armed(hb)) is not None and len(armed):
        return bool(armed[-1])
    vs = tables.get("vehicle_status")
    if vs is not None and (st := vs.numeric("arming_state")) is not None and len(st):
        return bool(st[-1] == 2)
    return None


def check_events(tables: LogTables, t_end: float) -> list[TriageFinding]:
    out: list[TriageFinding] = []
    docs = PX4_DOCS if tables.autopilot == "px4" else {}
    err = tables.get("ERR")
    if err is not None and (sub := err.numeric("Subsys")) is not None and (code := err.numeric("ECode")) is not None:
        open_at: dict[int, int] = {}
        for t, s, c in zip(err.t, sub.astype(int), code.astype(int)):
            if s not in ERR_SUBSYSTEMS:
                continue
            if c == 0 and s in open_at:  # resolved: closes the finding it opened
                out[open_at.pop(s)].t_end = float(t)
                continue
            if c == 0:
                continue
            name, what = ERR_SUBSYSTEMS[s]
            what = ERR_CODES.get((s, c), what)
            sev = "critical" if name in ("crash", "flip") else "error"
            f = TriageFinding(
                name,
                float(t),
                t_end,
                sev,
                f"ERR: {what} (Subsys {s}, ECode {c})",
                DOCS[name],
                cuts=name != "gps_glitch",
            )
            if s == ERR_FAILSAFE_GPS and not _had_gps_fix(tables):
                # ArduCopter raises it at boot on a vehicle that has no GPS: a configuration, not an event
                f.name, f.severity, f.cuts, f.doc = "config_risk", "warning", False, DOCS["config_risk"]
                f.evidence += ": the log has no GPS fix at all (no GPS fitted or enabled?)"
            if name == "crash":
                f.t_end = end_of_flight(tables, float(t), t_end)
            open_at[s] = len(out)
            out.append(f)
    ev = tables.get("EV")
    if ev is not None and (ids := ev.numeric("Id")) is not None:
        for t, i in zip(ev.t, ids.astype(int)):
            if i in EV_NOTES:
                name, sev, what = EV_NOTES[i]
                out.append(TriageFinding(name, float(t), float(t), sev, f"EV: {what} (Id {i})", DOCS[name]))
    out += _texts(tables, docs, t_end)
    out += _modes(tables)
    vs = tables.get("vehicle_status")
    if vs is not None and (fs := vs.numeric("failsafe")) is not None:
        for a, b, _, _ in runs(fs > 0, vs.t):
            out.append(
                TriageFinding(
                    "failsafe", a, b, "error", "vehicle_status: failsafe set", docs.get("failsafe", ""), cuts=True
                )
            )
    return out


def _had_gps_fix(tables: LogTables) -> bool:
    for name, col in (("GPS", "Status"), ("GPS_RAW_INT", "fix_type"), ("vehicle_gps_position", "fix_type")):
        tb = tables.get(name)
        if tb is not None and (fix := tb.numeric(col)) is not None and (fix >= 3).any():
            return True
    return False


def end_of_flight(tables: LogTables, t: float, t_end: float) -> float:
    """The end of the flight a crash happened in: the next disarm, or the end of the log."""
    for a, b in flights(tables, t_end):
        if a <= t <= b:
            return b
    return t_end


def _texts(tables: LogTables, docs: dict, t_end: float) -> list[TriageFinding]:
    out = []
    for name, col in (("MSG", "Message"), ("STATUSTEXT", "text"), ("logged_messages", "text")):
        tb = tables.get(name)
        if tb is None or col not in tb:
            continue
        seen: dict[str, TriageFinding] = {}
        for t, text in zip(tb.t, tb[col]):
            text = str(text).strip()
            for pattern, finding, sev in TEXT_PATTERNS:
                if pattern.search(text):
                    if text in seen:  # repeated: one finding, its last time, a count
                        f = seen[text]
                        f.t_end = float(t)
                        f.detail["n"] += 1
                        f.evidence = f'{name}: "{text}" ({f.detail["n"]} times)'
                    else:
                        f = TriageFinding(
                            finding, float(t), float(t), sev, f'{name}: "{text}"', docs.get(finding, DOCS[finding])
                        )
                        if finding == "crash":  # the autopilot's own crash check: the rest of that flight
                            f.t_end, f.cuts = end_of_flight(tables, float(t), t_end), True
                        f.detail["n"] = 1
                        seen[text] = f
                        out.append(f)
                    break
    return out


def _modes(tables: LogTables) -> list[TriageFinding]:
    """Mode changes, one finding each; a mode toggled back and forth within a second is one."""
    changes: list[tuple[float, str]] = []
    names = COPTER_MODES if is_copter(tables) else {}
    mode = tables.get("MODE")
    hb = autopilot_heartbeats(tables)
    seq: list[tuple[float, object]] = []
    if mode is not None and "Mode" in mode:
        seq = list(zip(mode.t.tolist(), mode["Mode"]))
    elif hb is not None and (cm := hb.numeric("custom_mode")) is not None and tables.autopilot == "ardupilot":
        seq = list(zip(hb.t.tolist(), cm))
    for t, m in seq:
        label = m if isinstance(m, str) else names.get(int(m), f"mode {int(m)}")  # type: ignore[call-overload]
        if not changes or changes[-1][1] != label:
            changes.append((float(t), label))
    out: list[TriageFinding] = []
    i = 0
    while i < len(changes):
        j = i
        while j + 1 < len(changes) and changes[j + 1][0] - changes[j][0] < 1.0:
            j += 1
        t, name = changes[j]
        if j > i:
            among = " / ".join(dict.fromkeys(n for _, n in changes[i : j + 1]))
            text = (
                f"mode toggled {j - i + 1} times within {changes[j][0] - changes[i][0]:.1f} s ({among}), "
                f"ending in {name}"
            )
        else:
            text = f"mode {name}"
        sev = "warning" if name in RECOVERY_MODES or j > i else "info"
        out.append(TriageFinding("mode_change", changes[i][0], t, sev, text, DOCS["mode_change"]))
        i = j + 1
    return out
