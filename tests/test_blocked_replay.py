"""A replay at max speed with nothing to watch or export reading by reading takes the log as
columns and its IMU in 10 ms blocks: the same estimate, the same count of measurements, and the
reading-by-reading path wherever the blocks do not hold (several vehicles)."""

from __future__ import annotations

import csv
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from groundstation.estimation.logs import load_blocked
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario

from .helpers import imu_frames, write_tlog


def _replay(log, *extra) -> str:
    r = subprocess.run(
        [sys.executable, "-m", "groundstation", "replay", str(log), "--speed", "max", "--no-web", "--quiet", *extra],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    return r.stdout


def _estimates(path) -> dict[str, np.ndarray]:
    rows = list(csv.DictReader(open(path)))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


@pytest.mark.slow
def test_blocks_give_the_estimate_of_every_sample(tmp_path):
    """A 30 s quad flight with a 1 kHz IMU: the height and its sigma from the blocks against the
    reading-by-reading replay's (asked for by exporting every measurement), after the filter settles."""
    sc = Scenario(vehicle="quad", seed=5, duration=30.0)
    sc.sensors.rates.update({"imu": 1000, "baro": 50, "range": 20})
    log = tmp_path / "q.tlog"
    run_fast(sc, log)
    blocked = _replay(log, "--export", str(tmp_path / "b.csv"))
    each = _replay(log, "--export", str(tmp_path / "e.csv"), "--export-measurements", str(tmp_path / "m.csv"))
    assert "10 ms blocks" in blocked and "ms blocks" not in each
    count = re.compile(r"done: (\d+) measurements")
    assert count.search(blocked).group(1) == count.search(each).group(1)  # every reading counted, not a block
    b, e = _estimates(tmp_path / "b.csv"), _estimates(tmp_path / "e.csv")
    late = e["t"] > e["t"][0] + 5.0
    z_b = np.interp(e["t"][late], b["t"], b["z"])
    sigma_b = np.interp(e["t"][late], b["t"], b["sigma_z"])
    sigma = np.median(e["sigma_z"][late])  # 3.6 mm on the range sensor
    assert np.sqrt(np.mean((z_b - e["z"][late]) ** 2)) < 0.3 * sigma  # measured 0.5 mm
    assert np.median(np.abs(sigma_b / e["sigma_z"][late] - 1.0)) < 0.05


def test_a_log_of_two_vehicles_replays_reading_by_reading(tmp_path):
    """The IMU's columns are per kind and instance, not per vehicle: two vehicles' log is not blocked."""
    one, two = imu_frames(300, sysid=1), imu_frames(300, sysid=2)
    log = write_tlog(tmp_path / "two.tlog", [f for pair in zip(one, two) for f in pair], dt=0.005)
    assert load_blocked(log) is None
    out = _replay(log, "--export", str(tmp_path / "est.csv"))
    assert "ms blocks" not in out and "done: 1800 measurements" in out  # accel, gyro and mag each
    assert (tmp_path / "est.csv").exists() and (tmp_path / "est.sys2.csv").exists()


def test_a_damaged_log_is_blocked_with_its_damage_named(tmp_path):
    """Garbage between records and a cut end: replayed in blocks, the damage on the last line."""
    frames = imu_frames(400)
    log = write_tlog(tmp_path / "d.tlog", frames)
    data = bytearray(log.read_bytes())
    data[3000:3000] = b"\x00garbage\xfe\x01" * 5
    log.write_bytes(bytes(data[:-7]))
    out = _replay(log)
    last = out.strip().splitlines()[-1]
    assert "10 ms blocks" in last and "truncated last record" in last, out


@pytest.mark.slow
def test_ctrl_c_stops_a_batch_replay_with_what_was_estimated_written(tmp_path):
    """A max-speed replay runs outside an event loop: Ctrl-C stops it at once (inside one, the first
    SIGINT only marked the run cancelled and was lost), the estimates so far are in the file, and the
    last line says where it stopped; exit status 130."""
    sc = Scenario(vehicle="quad", seed=2, duration=120.0)
    sc.sensors.rates.update({"imu": 1000, "baro": 50, "range": 20})
    log, est = tmp_path / "q.tlog", tmp_path / "est.csv"
    run_fast(sc, log)
    # as from a terminal: SIGINT at Python's own handler and not blocked (a child inherits an ignored
    # or blocked SIGINT from the test's worker, where an earlier test may have left it so)
    terminal = (
        "import runpy, signal, sys; signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT}); "
        "signal.signal(signal.SIGINT, signal.default_int_handler); sys.argv[0] = 'groundstation'; "
        "runpy.run_module('groundstation', run_name='__main__')"
    )
    cmd = [sys.executable, "-c", terminal, "replay", str(log), "--speed", "max", "--no-web", "--quiet"]
    with subprocess.Popen([*cmd, "--export", str(est)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as p:
        try:
            assert p.stdout is not None and p.stdout.readline().startswith("replaying")  # estimating from here
            deadline = time.monotonic() + 60
            while not (est.exists() and est.stat().st_size > 0) and p.poll() is None and time.monotonic() < deadline:
                time.sleep(0.005)  # until the first estimates reach the file
            p.send_signal(signal.SIGINT)
            out, err = p.communicate(timeout=60)
        finally:
            p.kill()
    assert p.returncode == 130 and "Traceback" not in err, err
    last = out.strip().splitlines()[-1]
    stopped = re.match(r"stopped \(Ctrl-C\) at t ([\d.]+) s: (\d+) of (\d+) measurements", last)
    assert stopped and int(stopped.group(2)) < int(stopped.group(3)), last
    rows = _estimates(est)
    assert 0 < len(rows["t"]) and rows["t"][-1] <= float(stopped.group(1)) + 0.05


def test_ctrl_c_wrapped_by_a_compiled_kernels_loader_is_still_ctrl_c():
    """Ctrl-C that lands while numba unpickles a cached kernel reaches Python as a SystemError caused
    by the KeyboardInterrupt (the timing cannot be caused at will, so the chain is built as numba
    builds it): a stop, exit status 130; a SystemError of any other cause stays an error."""
    from groundstation.app.interrupts import is_interrupt
    from groundstation.app.main import one_line_errors

    def wrapped(_args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as k:
            raise SystemError("<function _numba_unpickle> returned a result with an exception set") from k

    def other(_args):
        raise SystemError("a bug")

    assert one_line_errors(wrapped, None) == 130
    with pytest.raises(SystemError):
        one_line_errors(other, None)
    assert not is_interrupt(ValueError("x")) and is_interrupt(KeyboardInterrupt())


def test_ctrl_c_while_a_command_loads_its_modules_is_a_stop(monkeypatch, capsys):
    """Ctrl-C in the second or so a command spends importing numpy, scipy and the estimators (before
    its own code runs) is exit status 130 without a traceback, as it is later on. The moment cannot
    be hit at will, so the import raises it."""
    from groundstation.app import main as entry

    def interrupted(name):
        raise KeyboardInterrupt

    monkeypatch.setattr(entry, "importlib", SimpleNamespace(import_module=interrupted))
    log = Path(__file__).parent / "fixtures" / "ardusub_small.tlog"
    assert entry.main(["replay", str(log), "--no-web"]) == 130
    assert "Traceback" not in capsys.readouterr().err
