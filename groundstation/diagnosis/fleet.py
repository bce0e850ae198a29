"""A season of flights: every log in a folder tree diagnosed as ``diagnose`` does, one task per log,
and what recurs across them.

The work per log is :func:`diagnose_one`, a plain function of paths so that a Dask worker (any
process with this package installed) can run it; the command line (``groundstation fleet
diagnose``) schedules it (:mod:`groundstation.app.fleet_cli`). Each log's reports go to their own
folder under ``out``; ``done.json`` is written last, so a log with one is finished and is skipped
when the run is repeated (resumption), as long as the log's size and modification time are those
recorded; a log that fails writes ``error.json`` instead (its one-line error) and is tried again next
time. :func:`fleet_table` gathers the finished logs into one row per effect found, and
:func:`write_fleet_report` shows per vehicle which effects recur and how their parameters move
from flight to flight (a baro thrust coefficient creeping up as a motor wears).

Logs are recognised by content (tlog, DataFlash, ULog, Crazyflie), not by extension; the vehicle is
the log's first folder under the archive (``archive/quad-3/2026-05-01.bin`` is ``quad-3``), or
``(root)`` for a log at the top.
"""

from __future__ import annotations

import contextlib
import csv
import html
import io
import json
import math
import os
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from drivers.logs.crazyflie import is_crazyflie_log
from drivers.logs.dataflash import is_dataflash
from drivers.logs.ulog import is_ulog
from groundstation.diagnosis.pipeline import run

TABLE_COLUMNS = (
    "log",
    "vehicle",
    "duration_s",
    "effect",
    "parameters",
    "delta_bic",
    "sensor",
    "innovation_rms_before",
    "innovation_rms_after",
    "rmse_before",
    "rmse_after",
    "nees_before",
    "nees_after",
)


@dataclass(frozen=True)
class LogJob:
    path: str  # the log
    rel: str  # its path under the archive (the row's name)
    out: str  # its report folder
    vehicle: str
    model: str


#: a tlog's first record: a big-endian UNIX time [us] between 2000 and 2100, then a MAVLink magic
_TLOG_US = (946_684_800_000_000, 4_102_444_800_000_000)


def _is_tlog(p: Path) -> bool:
    try:
        with open(p, "rb") as f:
            head = f.read(9)
    except OSError:
        return False
    # a damaged start is the reader's to resync over and report: a tlog is named by its first record
    return len(head) == 9 and _TLOG_US[0] <= int.from_bytes(head[:8], "big") <= _TLOG_US[1] and head[8] in (0xFE, 0xFD)


def is_log(p: Path) -> bool:
    """A file a reader of ours takes, by its content."""
    return p.is_file() and (is_dataflash(p) or is_ulog(p) or is_crazyflie_log(p) or _is_tlog(p))


def folder_name(rel: str) -> str:
    """A log's report folder name: its path under the archive, one level."""
    return rel.replace(os.sep, "__") + ".diagnosis"


#: names a log has: a file so named that no reader takes is reported as a failed log, not passed over
LOG_SUFFIXES = frozenset({".tlog", ".bin", ".ulg"})


def find_logs(archive: Path, out: Path, model: str) -> list[LogJob]:
    """Every log under ``archive``, and every file named as one (:data:`LOG_SUFFIXES`), sorted by
    path; the output folder itself is skipped. Folders are walked without following their links (a
    link to a parent folder would walk for ever); a file that is a link is taken as its target, and a
    link that leads nowhere or to itself is a log that fails (a row with its reason), not an error
    of the whole run."""
    jobs = []
    out = out.resolve()
    for p in sorted(_files(archive)):
        try:
            inside_out = out in p.resolve(strict=False).parents
            wanted = is_log(p) or p.suffix.lower() in LOG_SUFFIXES  # (a link to nothing named as a log fails)
        except (OSError, RuntimeError):  # a link loop, a target that cannot be read
            inside_out, wanted = False, p.suffix.lower() in LOG_SUFFIXES or p.is_symlink()
        if inside_out or not wanted:
            continue
        rel = str(p.relative_to(archive))
        parts = Path(rel).parts
        vehicle = parts[0] if len(parts) > 1 else "(root)"
        jobs.append(LogJob(str(p), rel, str(out / folder_name(rel)), vehicle, model))
    return jobs


def _files(archive: Path) -> list[Path]:
    """The non-folder entries under ``archive``, folder links not followed."""
    found = []
    for root, dirs, files in os.walk(archive, followlinks=False):
        found += [Path(root) / f for f in files]
        found += [Path(root) / d for d in dirs if (Path(root) / d).is_symlink() and not (Path(root) / d).is_dir()]
    return found


def _stamp(p: Path) -> dict:
    st = p.stat()
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns}


def is_done(job: LogJob) -> bool:
    """The log was diagnosed, and has not changed since."""
    marker = Path(job.out) / "done.json"
    try:
        done = json.loads(marker.read_text())
        return done.get("stamp") == _stamp(Path(job.path))
    except (OSError, ValueError):
        return False


def diagnose_one(job: LogJob) -> dict:
    """Diagnose one log into its folder; never raises: a log that fails returns (and writes) its
    error in one line. Returns the summary ``done.json`` holds, or ``{"log", "error"}``."""
    out = Path(job.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "error.json").unlink(missing_ok=True)
    (out / "done.json").unlink(missing_ok=True)
    try:
        if not is_log(Path(job.path)):
            raise ValueError("not a log by its content (a MAVLink tlog, DataFlash, ULog or Crazyflie log)")
        r = run(Path(job.path), out, model=job.model)
    except MemoryError:
        return failed(job, "out of memory while diagnosing it")
    except Exception as e:  # any failure of one log is that log's row, never the fleet's end
        return failed(job, _one_line(e))
    summary = {
        "log": job.rel,
        "vehicle": job.vehicle,
        "duration_s": round(r.duration, 3),
        "description": r.description,
        "rows": rows_of(job, r.report, r.duration),
        "triage": [f for f in r.report.get("triage", []) if f["severity"] in ("critical", "error")],
        "stamp": _stamp(Path(job.path)),
    }
    tmp = out / "done.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2, default=float))
    tmp.replace(out / "done.json")  # whole or absent: a killed run leaves no half marker
    return summary


def _one_line(e: BaseException) -> str:
    """An exception as one line: its message, or its type where it has none (a bare KeyError)."""
    text = str(e).splitlines()[0] if str(e) else ""
    return text if isinstance(e, (ValueError, OSError)) and text else f"{type(e).__name__}: {text}".rstrip(": ")


def failed(job: LogJob, reason: str) -> dict:
    """Record that ``job`` failed, for ``reason`` (one line): its ``error.json``, and the row."""
    err = {"log": job.rel, "vehicle": job.vehicle, "error": reason}
    out = Path(job.out)
    with contextlib.suppress(OSError):  # a folder that cannot be written: the row is still returned
        out.mkdir(parents=True, exist_ok=True)
        (out / "error.json").write_text(json.dumps(err, indent=2))
    return err


def _num(x) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def rows_of(job: LogJob, j: dict, duration: float) -> list[dict]:
    """One row per effect found in a report; one row with no effect when none was."""
    before, after = j.get("before", {}), j.get("after", {})
    against_truth = {  # where the log has truth: its error, and whether its sigma is honest (NEES 1)
        "rmse_before": _num(before.get("rmse_vs_truth")),
        "rmse_after": _num(after.get("rmse_vs_truth")),
        "nees_before": _num(before.get("nees")),
        "nees_after": _num(after.get("nees")),
    }
    rows = []
    for e in j.get("effects", []):
        params = {k: v for k, v in e["params"].items() if not k.startswith("sigma_") and _num(v) is not None}
        sensor = e.get("evidence", {}).get("sensor") or e["params"].get("sensor") or ""
        sb = before.get("sensors", {}).get(sensor, {})
        sa = after.get("sensors", {}).get(sensor, {})
        rows.append(
            {
                "log": job.rel,
                "vehicle": job.vehicle,
                "duration_s": round(duration, 3),
                "effect": e["name"],
                "parameters": json.dumps(params, sort_keys=True),
                "delta_bic": _num(e.get("evidence", {}).get("delta_bic")),
                "sensor": sensor,
                "innovation_rms_before": _num(sb.get("innovation_rms")),
                "innovation_rms_after": _num(sa.get("innovation_rms")),
                **against_truth,
            }
        )
    if not rows:
        rows.append(
            {
                "log": job.rel,
                "vehicle": job.vehicle,
                "duration_s": round(duration, 3),
                "effect": "",
                "parameters": "{}",
                "delta_bic": None,
                "sensor": "",
                "innovation_rms_before": None,
                "innovation_rms_after": None,
                **against_truth,
            }
        )
    return rows


def collect(jobs: list[LogJob]) -> tuple[list[dict], list[dict]]:
    """(every finished log's summary, every failed log's error), from their folders."""
    done, failed = [], []
    for job in jobs:
        out = Path(job.out)
        if is_done(job):
            done.append(json.loads((out / "done.json").read_text()))
        elif (out / "error.json").exists():
            failed.append(json.loads((out / "error.json").read_text()))
    return done, failed


def fleet_table(done: list[dict]) -> list[dict]:
    return [row for s in done for row in s["rows"]]


def write_table(rows: list[dict], out: Path) -> None:
    """fleet.csv and fleet.parquet (pyarrow), one row per effect per log."""
    import pyarrow as pa  # the fleet's own dependencies, imported where they are used
    import pyarrow.parquet as pq

    with open(out / "fleet.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=TABLE_COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: "" if r[k] is None else r[k] for k in TABLE_COLUMNS})
    schema = pa.schema(
        [
            (
                c,
                pa.float64()
                if c in ("duration_s", "delta_bic") or c.startswith(("innovation", "rmse", "nees"))
                else pa.string(),
            )
            for c in TABLE_COLUMNS
        ]
    )
    pq.write_table(
        pa.Table.from_pylist([{c: r[c] for c in TABLE_COLUMNS} for r in rows], schema=schema), out / "fleet.parquet"
    )


def write_fleet_report(done: list[dict], failed: list[dict], out: Path) -> None:
    """report.html: per vehicle, each effect's share of its flights and its parameters flight by
    flight (in the logs' path order, which for dated names is time order), with a plot of each
    parameter found in two flights or more; then the logs that failed."""
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>fleet diagnosis</title>"
        "<style>body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto}"
        "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px;font-size:13px}"
        "</style></head><body>",
        f"<h1>Fleet diagnosis: {len(done)} logs diagnosed, {len(failed)} failed</h1>",
    ]
    vehicles = sorted({s["vehicle"] for s in done})
    for v in vehicles:
        logs = [s for s in done if s["vehicle"] == v]
        parts.append(
            f"<h2>{html.escape(v)}: {len(logs)} flights, {sum(s['duration_s'] for s in logs) / 60:.1f} min</h2>"
        )
        effects = sorted({r["effect"] for s in logs for r in s["rows"] if r["effect"]})
        if not effects:
            parts.append("<p>No effect found in any flight.</p>")
        rows_html, figures = [], []
        for e in effects:
            n = sum(any(r["effect"] == e for r in s["rows"]) for s in logs)
            series: dict[str, list[tuple[int, float]]] = {}
            for k, s in enumerate(logs):
                for r in s["rows"]:
                    if r["effect"] == e:
                        for p, val in json.loads(r["parameters"]).items():
                            series.setdefault(p, []).append((k, float(val)))
            drift = "; ".join(f"{p}: " + ", ".join(f"{val:.3g}" for _, val in pts) for p, pts in sorted(series.items()))
            rows_html.append(
                f"<tr><td>{html.escape(e)}</td><td>{n} of {len(logs)}</td><td>{html.escape(drift)}</td></tr>"
            )
            figures += [
                _drift_svg(f"{v}: {e} {p} by flight", pts, logs) for p, pts in sorted(series.items()) if len(pts) > 1
            ]
        if effects:
            parts.append("<table><tr><th>effect</th><th>flights</th><th>parameters, flight by flight</th></tr>")
            parts += rows_html
            parts.append("</table>")
            parts += figures
        crit = [(s["log"], f) for s in logs for f in s.get("triage", [])]
        if crit:
            parts.append("<h3>Triage: crashes, failsafes and faults</h3><ul>")
            parts += [
                f"<li>{html.escape(log)}: {html.escape(f['name'])} at {f['t_start']:.1f} s: "
                f"{html.escape(f['evidence'])}</li>"
                for log, f in crit
            ]
            parts.append("</ul>")
    if failed:
        parts.append("<h2>Failed</h2><ul>")
        parts += [f"<li>{html.escape(f['log'])}: {html.escape(f['error'])}</li>" for f in failed]
        parts.append("</ul>")
    parts.append("</body></html>")
    (out / "report.html").write_text("\n".join(parts))


def _drift_svg(title: str, pts: list[tuple[int, float]], logs: list[dict]) -> str:
    """One parameter flight by flight, as an inline SVG (matplotlib, the reports' plotting library)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5, 1.8))
    ax = fig.add_subplot()
    ax.plot([k for k, _ in pts], [val for _, val in pts], "o-")
    ax.set_xticks(range(len(logs)), [Path(s["log"]).name[:12] for s in logs], rotation=30, fontsize=6)
    ax.set_title(title, fontsize=8)
    fig.tight_layout()
    buf = io.StringIO()
    fig.savefig(buf, format="svg")
    svg = buf.getvalue()
    return svg[svg.index("<svg") :]


def summary_line(done: list[dict], failed: list[dict]) -> str:
    counts = Counter(r["effect"] for s in done for r in s["rows"] if r["effect"])
    common = ", ".join(f"{n} ({c})" for n, c in counts.most_common(5))
    return f"{len(done)} logs diagnosed, {len(failed)} failed" + (f"; effects found: {common}" if common else "")
