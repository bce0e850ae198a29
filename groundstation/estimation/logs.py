"""Any supported log in, measurements out: a tlog through the live receive path, an ArduPilot
DataFlash log or a Crazyflie uSD log through their readers (the Crazyflie's tilt derived from
its gyro, :mod:`.derived`). Recognised by content, not by extension."""

from __future__ import annotations

from pathlib import Path

from drivers.logs.crazyflie import is_crazyflie_log, read_crazyflie
from drivers.logs.crazyflie import measurements as cf_measurements
from drivers.logs.dataflash import is_dataflash, read_dataflash
from drivers.replay import Replay
from groundstation.core.counts import counted
from groundstation.core.measurement import Measurement

from .derived import with_attitude


def _reader_skipped(skipped) -> str:
    """The reader's counted skips of readings (not the streams it does not convert)."""
    text = counted({k: n for k, n in skipped.items() if not k.startswith("not_converted:")})
    return f"; the reader skipped {text}" if text else ""


def load_measurements(path: Path) -> tuple[list[Measurement], str, str | None]:
    """Any supported log -> (measurements in time order, a one-line description,
    the vehicle configuration it implies)."""
    if is_crazyflie_log(path):
        log = read_crazyflie(path)
        ms = list(with_attitude(cf_measurements(log)))
        desc = f"Crazyflie uSD log, {log.duration:.1f} s, {len(ms)} measurements" + (
            f"; {log.damage}" if log.damage else ""
        )
        return ms, desc + _reader_skipped(log.skipped), "crazyflie"
    if is_dataflash(path):
        df = read_dataflash(path)
        return (
            df.measurements,
            (
                f"ArduPilot DataFlash log, {df.duration:.1f} s, {len(df.measurements)} "
                f"measurements (clock: {df.clock})"
                + (f"; {df.damage}" if df.damage else "")
                + _reader_skipped(df.skipped)
            ),
            None,
        )
    rp = Replay(path)
    ms = list(rp.iter_measurements())
    damage = rp.skipped_summary()
    return ms, f"MAVLink tlog, {rp.duration:.1f} s" + (f"; {damage}" if damage else ""), None
