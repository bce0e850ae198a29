"""``groundstation info LOG``: what a log holds, read through its reader alone (no filter, no
dashboard: it answers as fast as the log is read)."""

from __future__ import annotations

import math
from pathlib import Path

from drivers.logs.crazyflie import is_crazyflie_log
from drivers.logs.dataflash import is_dataflash
from drivers.logs.ulog import is_ulog
from drivers.replay import Replay
from drivers.tlog import TlogIndex
from groundstation.estimation.identity import identify
from groundstation.estimation.logs import load_log


def cmd_info(args) -> int:
    """What a log holds: a tlog's frames, damage and loss (below); any other log (DataFlash, ULog,
    Crazyflie) through its reader: format, duration, the vehicle, what it measured, its records."""
    if not args.file.exists():
        raise OSError(f"{args.file}: cannot read: no such file")
    if is_dataflash(args.file) or is_ulog(args.file) or is_crazyflie_log(args.file):
        return info_of_log(args.file)
    idx = TlogIndex.scan(args.file)
    rp = Replay(args.file, speed=math.inf)
    n = sum(1 for _ in rp.iter_measurements())
    c = rp.receiver.counters
    print(
        f"{args.file}: {len(idx)} records, {idx.duration:.1f} s, "
        f"MAVLink1 {c.mavlink1} / MAVLink2 {c.mavlink2} frames, {n} measurements"
    )
    print(
        f"  CRC errors {c.crc_errors}, garbage {c.bad_data}, unknown ids {c.unknown}, "
        f"sequence loss {c.loss_percent:.2f}%"
    )
    for sysid in sorted({k[0] for k in c.per_source}):
        print(f"  system {sysid}: loss {c.loss_percent_of(sysid):.2f}%")
    damage = rp.skipped_summary()
    if damage:
        print(f"  damage: {damage}")
    for name, count in sorted(c.by_type.items(), key=lambda kv: -kv[1]):
        print(f"  {name:<28} {count:>8}")
    return 0


def info_of_log(path: Path) -> int:
    log = load_log(path, imu_columns=True)
    print(f"{path}: {log.description}")
    v = identify(log.tables)
    print(f"  vehicle: {v.name} ({v.evidence})" + (f"; firmware {log.tables.firmware}" if log.tables.firmware else ""))
    kinds: dict[str, int] = {}
    for m in log.measurements:
        kinds[m.kind.value] = kinds.get(m.kind.value, 0) + 1
    if log.imu is not None:
        for (kind, inst), s in log.imu.series.items():
            kinds[f"{kind.value}[{inst}]"] = len(s)
    print("  measurements by kind: " + ", ".join(f"{k} {n}" for k, n in sorted(kinds.items(), key=lambda kv: -kv[1])))
    print(f"  parameters: {len(log.tables.params)}; records by type:")
    for name, tb in sorted(log.tables.tables.items(), key=lambda kv: -len(kv[1])):
        print(f"  {name:<28} {len(tb):>8}")
    return 0
