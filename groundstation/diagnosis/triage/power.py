"""Power: a log that stops while the vehicle is armed in the air (a brownout, or the battery
unplugged by a crash), and the flight controller's own supply (VCC).

Thresholds are LogAnalyzer's (ArduPilot ``Tools/LogAnalyzer/tests``): ``TestBrownout`` calls a log
that ends armed above 3 m (CTUN's baro altitude) truncated; ``TestVCC`` warns when the board's
voltage moves by more than 0.3 V and fails below 4.6 V. Only logs the vehicle writes itself
(DataFlash, ULog) can end in a brownout; a tlog ends when the ground station stops recording.
"""

from __future__ import annotations

import numpy as np

from drivers.logs.tables import LogTables

from .events import armed_at_end
from .finding import DOCS, TriageFinding

ALOFT_M = 3.0  # [m] above it, a log that ends armed ended in the air (TestBrownout)
VCC_MIN_V, VCC_SPREAD_V = 4.6, 0.3  # (TestVCC)


def _altitude(tables: LogTables) -> tuple[np.ndarray, np.ndarray] | None:
    """Height above where it armed [m]: CTUN's baro altitude (ArduPilot), the local position (PX4)."""
    ctun = tables.get("CTUN")
    if ctun is not None and (h := ctun.numeric("BAlt", "BarAlt")) is not None:
        return ctun.t, h
    lp = tables.get("vehicle_local_position")
    if lp is not None and (z := lp.numeric("z")) is not None:
        return lp.t, -z
    return None


def _vcc(tables: LogTables) -> tuple[np.ndarray, np.ndarray, str] | None:
    """The board's supply [V]: POWR.Vcc (V), CURR.Vcc (mV in ArduCopter 3.x), PX4 ``system_power``."""
    for name, col in (("POWR", "Vcc"), ("CURR", "Vcc"), ("system_power", "voltage5v_v")):
        tb = tables.get(name)
        if tb is None or (v := tb.numeric(col)) is None:
            continue
        v = v / 1000.0 if np.nanmax(v) > 100 else v
        ok = np.isfinite(v) & (v > 0.5)
        if ok.sum() > 2:
            return tb.t[ok], v[ok], f"{name}.{col}"
    return None


def _last_readings(tables: LogTables) -> str:
    said = []
    vcc = _vcc(tables)
    if vcc is not None:
        said.append(f"VCC {vcc[1][-1]:.2f} V")
    for name, vcol, icol in (
        ("BAT", "Volt", "Curr"),
        ("CURR", "Volt", "Curr"),
        ("battery_status", "voltage_v", "current_a"),
    ):
        tb = tables.get(name)
        if tb is not None and (v := tb.numeric(vcol)) is not None and len(v):
            i = tb.numeric(icol)
            scale = 0.01 if np.nanmax(v) > 100 else 1.0  # CURR: volts x 100 in old logs
            said.append(f"battery {v[-1] * scale:.2f} V" + (f" {i[-1] * scale:.1f} A" if i is not None else ""))
            break
    return ", ".join(said) if said else "no power readings in the log"


def check_power(tables: LogTables, t_end: float, crashed: float = np.inf) -> list[TriageFinding]:
    """``crashed``: when a crash or flip began (a log that then stops armed is that story's end)."""
    out: list[TriageFinding] = []
    alt = _altitude(tables)
    if tables.fmt in ("dataflash", "ulog") and armed_at_end(tables) and alt is not None and len(alt[0]):
        t, h = alt
        if np.isfinite(h[-1]) and h[-1] > ALOFT_M:
            after = np.isfinite(crashed)
            why = (
                f"after the crash at {crashed:.1f} s (the battery torn off by the impact, or a brownout)"
                if after
                else "a power loss (brownout) or the log cut short"
            )
            out.append(
                TriageFinding(
                    "log_ends_in_flight",
                    float(t[-1]),
                    t_end,
                    "warning" if after else "error",
                    f"the log stops while armed at {h[-1]:.1f} m by the baro: {why}; "
                    f"last readings: {_last_readings(tables)}",
                    DOCS["log_ends_in_flight"],
                )
            )
    vcc = _vcc(tables)
    if vcc is not None:
        t, v, src = vcc
        lo, hi = float(np.min(v)), float(np.max(v))
        k = int(np.argmin(v))
        if lo < VCC_MIN_V:
            out.append(
                TriageFinding(
                    "board_voltage",
                    float(t[k]),
                    float(t[k]),
                    "error",
                    f"the flight controller's supply fell to {lo:.2f} V ({src}; below {VCC_MIN_V} V it may brown out)",
                    DOCS["board_voltage"],
                )
            )
        elif hi - lo > VCC_SPREAD_V:
            out.append(
                TriageFinding(
                    "board_voltage",
                    float(t[0]),
                    float(t[-1]),
                    "warning",
                    f"the flight controller's supply moved {hi - lo:.2f} V ({lo:.2f}-{hi:.2f} V, {src}; a steady "
                    f"supply moves less than {VCC_SPREAD_V} V: a weak power module or a servo load on it)",
                    DOCS["board_voltage"],
                )
            )
    return out
