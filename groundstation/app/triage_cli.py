"""``groundstation triage LOG``: what the log says happened, worst first, in about a second: it
loads the log's reader and the triage's checks, not the diagnosis's filters."""

from __future__ import annotations

import json

from groundstation.diagnosis.triage import triage
from groundstation.estimation.logs import load_log


def cmd_triage(args) -> int:
    if not args.file.exists():
        raise OSError(f"{args.file}: cannot read: no such file")
    log = load_log(args.file, imu_columns=True)
    tr = triage(log.tables, log.measurements, log.imu)
    if args.json:
        print(json.dumps({"source": str(args.file), "clock": tr.clock, "findings": tr.as_json()}, indent=2))
        return 0
    print(f"{args.file}: {log.description}")
    print(tr.summary(limit=1000))
    return 0
