"""``groundstation fleet diagnose``: an archive of logs on a real Dask cluster (a LocalCluster of
worker processes, and a dask-scheduler with a dask-worker started as processes on loopback),
resumable, one failed log reported without stopping the rest."""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from .conftest import REPO, free_tcp_port
from .helpers import running

pytestmark = pytest.mark.slow

GS = [sys.executable, "-m", "groundstation"]


def _archive(root: Path) -> Path:
    """Two flights of one quadcopter (its baro thrust coefficient 2.0 then 3.0: a wearing motor's
    wash), a PX4 SITL flight, a DataFlash log cut to its header (corrupt), and a text file."""
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario

    a = root / "archive"
    (a / "quad-1").mkdir(parents=True)
    (a / "px4").mkdir()
    for name, seed, k in (("2026-05-01.tlog", 1, 2.0), ("2026-05-08.tlog", 2, 3.0)):
        run_fast(Scenario.from_args("quad", seed, 25.0, ["range_tilt"], [f"baro_thrust:k={k}"]), a / "quad-1" / name)
    shutil.copy(REPO / "tests" / "fixtures" / "px4_sitl_events.ulg", a / "px4" / "sitl.ulg")
    (a / "quad-1" / "broken.bin").write_bytes(b"\xa3\x95\x80" + b"\x01" * 200)
    (a / "notes.txt").write_text("not a log\n")
    return a


def _fleet(*args, timeout=900):
    return subprocess.run(GS + ["fleet", "diagnose", *map(str, args)], capture_output=True, text=True, timeout=timeout)


def _rows(out: Path) -> list[dict]:
    return list(csv.DictReader(open(out / "fleet.csv")))


def test_fleet_on_a_local_cluster_resumes_and_reports_the_broken_log(tmp_path):
    import pyarrow.parquet as pq

    a, out = _archive(tmp_path), tmp_path / "fleet"
    r = _fleet(a, "--out", out, "--workers", "2")
    assert r.returncode == 1, r.stderr  # one log failed, the rest were diagnosed
    assert "4 logs under" in r.stdout and "a local cluster of 2 workers" in r.stdout
    assert "failed: quad-1/broken.bin: " in r.stdout and "Traceback" not in r.stdout + r.stderr
    err = json.loads((out / "quad-1__broken.bin.diagnosis" / "error.json").read_text())
    assert "broken.bin" in err["error"] and len(err["error"].splitlines()) == 1
    rows = _rows(out)
    assert {r["log"] for r in rows} == {"quad-1/2026-05-01.tlog", "quad-1/2026-05-08.tlog", "px4/sitl.ulg"}
    thrust = {r["log"]: json.loads(r["parameters"])["k"] for r in rows if r["effect"] == "baro_thrust"}
    assert thrust["quad-1/2026-05-01.tlog"] == pytest.approx(2.0, rel=0.25)
    assert thrust["quad-1/2026-05-08.tlog"] == pytest.approx(3.0, rel=0.25)
    assert all(r["vehicle"] == r["log"].split("/")[0] for r in rows)
    table = pq.read_table(out / "fleet.parquet").to_pylist()
    assert [t["log"] for t in table] == [r["log"] for r in rows] and table[0]["duration_s"] > 20
    page = (out / "report.html").read_text()
    assert "quad-1: 2 flights" in page and "baro_thrust" in page and "2 of 2" in page and "<svg" in page
    assert "broken.bin" in page
    stamp = (out / "quad-1__2026-05-01.tlog.diagnosis" / "done.json").stat().st_mtime_ns
    # again: the three done are skipped, the broken one is tried (and fails) again
    r = _fleet(a, "--out", out, "--workers", "2")
    assert r.returncode == 1 and "3 already diagnosed, 1 to do" in r.stdout, r.stdout
    assert (out / "quad-1__2026-05-01.tlog.diagnosis" / "done.json").stat().st_mtime_ns == stamp
    assert len(_rows(out)) == len(rows)


def test_fleet_through_a_scheduler_and_worker_started_as_processes(tmp_path):
    """A scheduler and a worker (``dask scheduler``, ``dask worker``) on loopback, as a lab's
    cluster would run: the logs go to it through ``--scheduler``; both processes are stopped by the
    test, whatever happens."""
    from dask.distributed import Client

    a, out = _archive(tmp_path), tmp_path / "fleet"
    (a / "quad-1" / "broken.bin").unlink()
    port = free_tcp_port()
    addr = f"tcp://127.0.0.1:{port}"
    dask = Path(sys.executable).parent / "dask"
    scheduler = [dask, "scheduler", "--host", "127.0.0.1", "--port", port, "--no-dashboard"]
    worker = [dask, "worker", addr, "--nworkers", "1", "--nthreads", "1", "--no-dashboard"]
    with running(scheduler), running(worker):
        with Client(addr, timeout="60s") as c:
            c.wait_for_workers(1, timeout=60)  # the worker has registered: an event, not a sleep
        r = _fleet(a, "--out", out, "--scheduler", addr)
        assert r.returncode == 0, r.stdout + r.stderr
        assert f"on {addr}" in r.stdout and "3 logs diagnosed, 0 failed" in r.stdout
        assert {r["log"] for r in _rows(out)} == {"quad-1/2026-05-01.tlog", "quad-1/2026-05-08.tlog", "px4/sitl.ulg"}


def test_fleet_errors_are_one_line(tmp_path):
    r = _fleet(tmp_path / "nope", "--out", tmp_path / "o")
    assert r.returncode == 2 and "not a folder" in r.stderr and "Traceback" not in r.stderr
    (tmp_path / "empty").mkdir()
    r = _fleet(tmp_path / "empty", "--out", tmp_path / "o")
    assert r.returncode == 2 and "no log in it" in r.stderr


def test_a_file_named_as_a_log_that_is_none_is_a_failed_log_not_passed_over(tmp_path):
    """A garbage ``.tlog`` (a transfer cut to noise) is reported with its error; a text file is no log."""
    from groundstation.diagnosis import fleet

    a = tmp_path / "archive"
    (a / "quad-2").mkdir(parents=True)
    (a / "quad-2" / "junk.tlog").write_bytes(bytes(range(256)) * 40)
    (a / "quad-2" / "notes.txt").write_text("not a log\n")
    jobs = fleet.find_logs(a, tmp_path / "out", "altitude")
    assert [j.rel for j in jobs] == ["quad-2/junk.tlog"]
    err = fleet.diagnose_one(jobs[0])
    assert err["error"].startswith("not a log by its content") and err["log"] == "quad-2/junk.tlog"
    assert json.loads((Path(jobs[0].out) / "error.json").read_text())["error"] == err["error"]


def test_a_row_carries_the_error_and_whether_the_sigma_is_honest_against_truth(tmp_path):
    """Where a log has truth, each row of the table has its height error and NEES before and after
    (report.json's); without truth they are empty, not zero; and the Parquet file keeps them as numbers."""
    import pyarrow.parquet as pq

    from groundstation.diagnosis import fleet

    job = fleet.LogJob("f.tlog", "quad-1/f.tlog", str(tmp_path), "quad-1", "altitude")
    report = {
        "before": {
            "rmse_vs_truth": 0.42,
            "nees": 48.2,
            "within_2sigma": 0.03,
            "sensors": {"baro": {"innovation_rms": 0.5}},
        },
        "after": {
            "rmse_vs_truth": 0.053,
            "nees": 0.96,
            "within_2sigma": 1.0,
            "sensors": {"baro": {"innovation_rms": 0.1}},
        },
        "effects": [
            {
                "name": "baro_thrust",
                "params": {"k": 2.1, "sigma_k": 0.1},
                "evidence": {"sensor": "baro", "delta_bic": -300.0},
            }
        ],
    }
    (row,) = fleet.rows_of(job, report, 90.0)
    assert (row["rmse_before"], row["rmse_after"], row["nees_before"], row["nees_after"]) == (0.42, 0.053, 48.2, 0.96)
    assert row["innovation_rms_before"] == 0.5 and json.loads(row["parameters"]) == {"k": 2.1}
    (bare,) = fleet.rows_of(job, {"before": {"sensors": {}}, "after": {"sensors": {}}}, 90.0)
    assert bare["effect"] == "" and bare["nees_before"] is None and bare["rmse_after"] is None
    fleet.write_table([row, bare], tmp_path)
    table = pq.read_table(tmp_path / "fleet.parquet").to_pylist()
    assert table[0]["nees_after"] == 0.96 and table[1]["nees_after"] is None
    assert _rows(tmp_path)[0]["nees_before"] == "48.2" and _rows(tmp_path)[1]["nees_before"] == ""


def test_a_hostile_archive_gives_a_row_per_failure_and_never_stops_the_walk(tmp_path):
    """A file link to itself (``Symlink loop`` had ended the whole run), a folder link to its parent (a
    walk for ever), a link to nothing, and a garbage log beside a good one: each failure is a row
    with its reason, and the good log is found."""
    import os

    from groundstation.diagnosis import fleet

    a = tmp_path / "archive"
    (a / "quad").mkdir(parents=True)
    shutil.copy(REPO / "tests" / "fixtures" / "px4_sitl_events.ulg", a / "quad" / "good.ulg")
    os.symlink("loop.bin", a / "quad" / "loop.bin")
    os.symlink("..", a / "quad" / "up")
    os.symlink(tmp_path / "nowhere.tlog", a / "quad" / "gone.tlog")
    (a / "quad" / "junk.ulg").write_bytes(b"ULog\x01\x12\x35" + bytes(5))
    jobs = fleet.find_logs(a, tmp_path / "out", "auto")
    assert sorted(j.rel for j in jobs) == ["quad/gone.tlog", "quad/good.ulg", "quad/junk.ulg", "quad/loop.bin"]
    for j in jobs:
        if j.rel != "quad/good.ulg":
            err = fleet.diagnose_one(j)
            assert err["log"] == j.rel and len(err["error"].splitlines()) == 1, err


def test_any_exception_of_one_log_is_its_row(tmp_path, monkeypatch):
    """A failure no reader names (a bare KeyError from a library, say) is that log's row with its
    type, not the fleet's end. (The fault is made by replacing the pipeline: no log here causes one.)"""
    from groundstation.diagnosis import fleet

    a = tmp_path / "archive"
    a.mkdir()
    shutil.copy(REPO / "tests" / "fixtures" / "px4_sitl_events.ulg", a / "one.ulg")
    job = fleet.find_logs(a, tmp_path / "out", "auto")[0]

    def boom(*_a, **_k):
        raise KeyError("timestamp")

    monkeypatch.setattr(fleet, "run", boom)
    err = fleet.diagnose_one(job)
    assert err["error"] == "KeyError: 'timestamp'"
    assert json.loads((Path(job.out) / "error.json").read_text()) == err
