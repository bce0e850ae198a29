"""The command line, as a user runs it: exit codes, one-line errors, exports, crash safety."""

import asyncio
import csv
import json
import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundstation.app.session_files import discard_if_empty, session_path
from sim_bridge.mavlink_vehicle import MavlinkVehicle

from .conftest import async_test, free_udp_port, real_file
from .helpers import imu_frames, write_tlog

GS = [sys.executable, "-m", "groundstation"]


def run(*args, timeout=120):
    return subprocess.run(GS + list(args), capture_output=True, text=True, timeout=timeout)


def replay_max(log, *args):
    """``replay LOG`` at full speed, headless and quiet, with ``args``."""
    return run("replay", str(log), "--speed", "max", "--no-web", "--quiet", *args)


def assert_one_line_error(r, text):
    assert r.returncode == 2, r
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("groundstation: error")]
    assert len(lines) == 1 and text in lines[0], r.stderr


@pytest.mark.slow
def test_replay_export_of_a_real_tlog(tmp_path):
    src = real_file("mavlink_tlog/ardusub_small.tlog")
    out = tmp_path / "out.csv"
    est = tmp_path / "est.csv"
    r = run("replay", str(src), "--speed", "max", "--no-web", "--export-measurements", str(out), "--export", str(est))
    assert r.returncode == 0, r.stderr
    header = open(est).readline().strip().split(",")
    assert header == ["t", "z", "vz", "b_acc", "sigma_z", "sigma_vz", "sigma_b_acc"]
    est_rows = list(csv.DictReader(open(est)))
    assert len(est_rows) > 100 and all(float(r["sigma_z"]) > 0 for r in est_rows)
    assert "4 frames with bad CRC skipped" in r.stdout
    rows = list(csv.DictReader(open(out)))
    assert rows[0].keys() == {"t", "kind", "instance", "component", "value", "variance", "source"}
    kinds = {row["kind"] for row in rows}
    assert {"attitude", "baro_pressure", "battery_voltage", "throttle"} <= kinds
    pressures = [float(row["value"]) for row in rows if row["kind"] == "baro_pressure"]
    assert 80_000 < min(pressures) and max(pressures) < 300_000  # Pa (a depth sensor reads > 1 atm)
    ts = [float(row["t"]) for row in rows if row["kind"] == "attitude"]
    assert all(b >= a for a, b in zip(ts, ts[1:]))


@pytest.mark.slow
def test_replay_takes_a_vehicle_file_for_its_estimator(tmp_path):
    """``--vehicle`` gives the live estimator an airframe's constants, as ``diagnose`` and
    ``evaluate`` take them: the simulated quad's thrust curve (alpha 22, beta -1.2) instead of the
    thrust model's defaults. An unknown vehicle is a one-line error naming the known ones, before
    anything starts."""
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario

    log = tmp_path / "q.tlog"
    run_fast(Scenario.from_args("quad", 7, 6.0, ["range_tilt"], []), log)
    first = {}
    for vehicle in (None, "sim_quad"):
        est = tmp_path / f"{vehicle}.csv"
        r = replay_max(
            log,
            "--model",
            "quad_thrust",
            "--export",
            str(est),
            *(["--vehicle", vehicle] if vehicle else []),
        )
        assert r.returncode == 0, r.stderr
        first[vehicle] = next(csv.DictReader(open(est)))
    assert float(first["sim_quad"]["alpha"]) == pytest.approx(22.0, abs=0.5)
    assert float(first["sim_quad"]["beta"]) == pytest.approx(-1.2, abs=0.3)
    assert float(first[None]["alpha"]) == pytest.approx(20.0, abs=0.5)
    assert_one_line_error(
        run("replay", str(log), "--no-web", "--vehicle", "nosuch"), "no vehicle configuration 'nosuch'"
    )


def test_a_vehicle_file_with_a_name_its_model_does_not_take_is_a_one_line_error(tmp_path, monkeypatch):
    """A misspelt key in a vehicle file (alhpa0) is a one-line error naming it and what the model
    takes, in replay and in diagnose alike, not a TypeError from deep in the model's factory."""
    import json

    from groundstation.estimation import registry as estimators
    from groundstation.estimation import vehicles

    (tmp_path / "typo.json").write_text(json.dumps({"quad_thrust": {"alhpa0": 22.0, "drag": 0.35}}))
    monkeypatch.setattr(vehicles, "VEHICLE_CONFIGS", tmp_path)
    with pytest.raises(ValueError, match="quad_thrust takes no 'alhpa0'; it takes .*alpha0"):
        estimators.vehicle_config("typo", "quad_thrust")
    assert estimators.vehicle_config("typo", "altitude") == {}
    monkeypatch.undo()
    for name in ("sim_quad", "apm2_sonar", "crazyflie"):  # the shipped files all read
        for model in ("altitude", "quad_thrust", "attitude"):
            estimators.vehicle_config(name, model)


@pytest.mark.parametrize(
    "case,content,text",
    [
        ("text", b"just some notes, not telemetry\n" * 500, "not a MAVLink tlog"),
        ("empty", b"", "not a MAVLink tlog"),
        ("garbage", None, "not a MAVLink tlog"),
    ],
)
def test_replay_of_a_file_that_is_not_a_tlog(tmp_path, case, content, text):
    p = tmp_path / f"{case}.tlog"
    p.write_bytes(content if content is not None else os.urandom(20000))
    assert_one_line_error(run("replay", str(p), "--no-web"), text)


def test_replay_of_a_missing_file():
    assert_one_line_error(run("replay", "/nonexistent/x.tlog", "--no-web"), "No such file")


def test_replay_of_a_truncated_file_keeps_what_is_there(tmp_path):
    p = write_tlog(tmp_path / "t.tlog", imu_frames(100))
    p.write_bytes(p.read_bytes()[:-10])
    r = run("replay", str(p), "--speed", "max", "--no-web", "--export-measurements", str(tmp_path / "o.csv"))
    assert r.returncode == 0 and "truncated last record" in r.stdout
    assert "297 measurements" in r.stdout


@pytest.mark.parametrize(
    "url,text",
    [
        ("/dev/ttyNO_SUCH_PORT,57600", "no such device"),
        ("bogus:thing", "unknown connection"),
        ("udpin:127.0.0.1:99999", "out of range"),
        ("udpin:203.0.113.7:14550", "cannot open"),  # an address this machine does not have
    ],
)
def test_connect_errors_are_one_line(url, text):
    assert_one_line_error(run("connect", url, "--no-web", "--no-record"), text)


def test_a_connection_that_never_opens_leaves_no_session_file(tmp_path):
    """Recording by default (``sessions/``), a device that is not there: the one-line error, and no
    empty tlog or folder left behind."""
    r = subprocess.run(
        GS + ["connect", "/dev/ttyNO_SUCH_PORT,57600", "--no-web"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    assert_one_line_error(r, "no such device")
    assert list(tmp_path.iterdir()) == []


def test_sessions_begun_in_the_same_second_each_take_a_file_of_their_own(tmp_path):
    """Eight threads asking for a session's file at once (as two vehicles' sessions or two demos
    begun together): eight names, each file there, none shared."""
    with ThreadPoolExecutor(8) as pool:
        paths = list(pool.map(lambda _: session_path(str(tmp_path / "sessions"), "s-"), range(8)))
    assert len(set(paths)) == 8 and all(p.is_file() and p.stat().st_size == 0 for p in paths)
    discard_if_empty(paths[0])
    assert not paths[0].exists() and (tmp_path / "sessions").is_dir()  # the others keep the folder


@async_test(timeout=60)
async def test_sigkill_loses_at_most_the_last_second(tmp_path):
    port = free_udp_port()
    rec = tmp_path / "killed.tlog"
    proc = await asyncio.create_subprocess_exec(
        *GS,
        "connect",
        f"udpin:127.0.0.1:{port}",
        "--no-web",
        "--quiet",
        "--record",
        str(rec),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    veh = MavlinkVehicle(udp_to=("127.0.0.1", port))
    try:
        line = await asyncio.wait_for(proc.stdout.readline(), 20)
        assert b"link open" in line
        await veh.open()
        sent_at = []
        for i in range(50):
            veh.send(mavlink.MAVLink_attitude_message(1000 + 20 * i, 0.01 * i, 0, 0, 0, 0, 0))
            sent_at.append(time.monotonic())
        # Every frame reaches the file within a second without any shutdown.
        deadline = sent_at[-1] + 1.0

        def recorded():
            if not rec.exists():
                return 0
            conn = mavutil.mavlink_connection(str(rec))
            n = 0
            while conn.recv_match(type="ATTITUDE") is not None:
                n += 1
            return n

        while recorded() < 50 and time.monotonic() < deadline + 0.5:
            await asyncio.sleep(0.05)
        assert recorded() == 50
        assert time.monotonic() <= deadline + 0.5
        proc.send_signal(signal.SIGKILL)
        await proc.wait()
        assert recorded() == 50  # a SIGKILLed session's file is intact and readable
    finally:
        veh.close()
        if proc.returncode is None:
            proc.kill()
            await proc.wait()


@async_test(timeout=60)
async def test_connect_records_until_sigint(tmp_path):
    port = free_udp_port()
    rec = tmp_path / "s.tlog"
    out = tmp_path / "m.csv"
    proc = await asyncio.create_subprocess_exec(
        *GS,
        "connect",
        f"udpin:127.0.0.1:{port}",
        "--no-web",
        "--record",
        str(rec),
        "--export-measurements",
        str(out),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    veh = MavlinkVehicle(udp_to=("127.0.0.1", port))
    try:
        assert b"link open" in await asyncio.wait_for(proc.stdout.readline(), 20)
        await veh.open()
        veh.heartbeat()
        await veh.wait_for("HEARTBEAT", timeout=10)  # the GCS answered: it is running
        for i in range(20):
            veh.send(mavlink.MAVLink_scaled_pressure_message(1000 + 40 * i, 1000.0, 0.0, 2000, 0))
        await veh.wait_for("COMMAND_LONG", timeout=10)  # and it asked for streams
        proc.send_signal(signal.SIGINT)
        stdout, stderr = await asyncio.wait_for(proc.communicate(), 20)
        assert proc.returncode == 0, stderr
        assert b"Traceback" not in stderr and b"closed:" in stdout
    finally:
        veh.close()
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    rows = list(csv.DictReader(open(out)))
    assert sum(r["kind"] == "baro_pressure" for r in rows) == 20


@pytest.mark.slow
def test_sim_fast_writes_log_truth_and_declared(tmp_path):
    log, truth = tmp_path / "s.tlog", tmp_path / "s.csv"
    r = run(
        "sim",
        "--vehicle",
        "quad",
        "--seed",
        "3",
        "--fast",
        "--duration",
        "10",
        "--log",
        str(log),
        "--truth",
        str(truth),
        "--effect",
        "baro_thrust:k=2",
        "--undeclared",
        "accel_bias:z=0.2",
    )
    assert r.returncode == 0, r.stderr
    assert "x real time" in r.stdout
    assert log.stat().st_size > 100_000 and truth.exists() and (tmp_path / "s.declared.json").exists()
    info = run("info", str(log))
    assert "HIGHRES_IMU" in info.stdout and "CRC errors 0" in info.stdout


def test_sim_lists_its_effects():
    r = run("sim", "--list-effects")
    assert r.returncode == 0
    for name in ("accel_bias", "baro_thrust", "range_tilt", "sensor_delay", "thrust_voltage", "vibration"):
        assert f"`{name}`" in r.stdout


@pytest.mark.parametrize(
    "args,text",
    [
        (["--effect", "warp_drive:k=1"], "unknown effect 'warp_drive'"),
        (["--effect", "accel_bias:q=1"], "unknown parameter"),
        (["--effect", "accel_bias:z=lots"], "not a number"),
        (["--undeclared", "sensor_delay:sensor=radar"], "sensor must be one of"),
        (["--vehicle", "blimp"], "invalid choice"),
        (["--vehicle", "heli3dof", "--flight", "guided"], "flies no guided flight"),
    ],
)
def test_sim_bad_arguments_are_one_line(tmp_path, args, text):
    r = run("sim", "--fast", "--log", str(tmp_path / "x.tlog"), *args)
    assert r.returncode == 2 and "Traceback" not in r.stderr and text in r.stderr


@pytest.mark.parametrize("rate", ["-5", "nan"])
def test_a_real_time_sims_bad_stream_rate_is_one_line(rate):
    r = run("sim", "--udp", "none", "--duration", "1", "--unasked-rate", rate)
    assert_one_line_error(r, "--unasked-rate")


def _demo(cwd: Path) -> tuple[int, str]:
    """`make demo`'s command for 2 s, headless, in ``cwd``: the messages it counted and its file."""
    r = subprocess.run(
        GS + ["demo", "--duration", "2", "--no-web"], capture_output=True, text=True, timeout=120, cwd=cwd
    )
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    summary = r.stdout.strip().splitlines()[-1]
    assert summary.startswith("demo: ") and "loss 0.00%" in summary, r.stdout
    return int(summary.split()[1]), summary.rsplit("recorded ", 1)[1]


def _holds_one_run(tlog: Path, messages: int) -> None:
    """The file holds one run: its records about that run's messages (two runs' would be twice as
    many), over at least a second of the 2 s flown (however loaded the machine, and so however long
    the run took)."""
    info = run("info", str(tlog))
    assert info.returncode == 0, info.stderr
    records = int(info.stdout.split(": ", 1)[1].split(" records")[0])
    seconds = float(info.stdout.split(" records, ")[1].split(" s")[0])
    assert messages <= records < 1.5 * messages and seconds > 1.0, (messages, info.stdout)


@pytest.mark.slow
def test_demo_runs_and_records_a_fresh_file_per_run(tmp_path):
    """`make demo`'s command, twice, headless: exit 0, messages without loss, and each run in a
    file of its own (a tlog appended run after run would read as one flight with hours of gaps);
    two started in the same second, each in its own too."""
    runs = [_demo(tmp_path) for _ in range(2)]
    assert runs[0][1] != runs[1][1]
    (tmp_path / "at-once").mkdir()
    with ThreadPoolExecutor(2) as pool:
        runs += list(pool.map(_demo, [tmp_path / "at-once"] * 2))
    assert runs[2][1] != runs[3][1]
    for (messages, rec), cwd in zip(runs, [tmp_path] * 2 + [tmp_path / "at-once"] * 2, strict=True):
        _holds_one_run(cwd / rec, messages)


def _sigma_line(stdout: str) -> tuple[float, float]:
    """``evaluate``'s share within 2 sigma and NEES."""
    line = next(ln for ln in stdout.splitlines() if ln.startswith("its sigma: "))
    return float(line.split()[2].rstrip("%")) / 100, float(line.split("NEES ")[1].split()[0])


@pytest.mark.slow
def test_evaluate_scores_against_a_named_truth_file_or_says_why_not(tmp_path):
    """``evaluate --truth`` reads a truth CSV by any name (a foreign flight's NAME_truth.csv is found
    beside its log); a missing or unreadable one is a one-line error."""
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario

    log, sidecar = tmp_path / "f.tlog", tmp_path / "f.csv"
    run_fast(Scenario.from_args("quad", 3, 20.0, [], []), log, sidecar)
    named = tmp_path / "elsewhere.csv"
    sidecar.rename(named)
    r = run("evaluate", str(log))
    assert r.returncode == 0, r.stderr
    assert "- (no truth)" in r.stdout and "its sigma" not in r.stdout
    r = run("evaluate", str(log), "--truth", str(named))
    assert r.returncode == 0, r.stderr
    est = next(ln for ln in r.stdout.splitlines() if ln.startswith("estimate"))
    assert "(truth: truth file elsewhere.csv)" in est
    assert 0.0 < float(est.split()[1]) < 0.5  # m
    honest = _sigma_line(r.stdout)
    # a truth 1 m off: the same estimate's sigma cannot hold it
    rows = named.read_text().splitlines()
    col = rows[0].split(",").index("h")
    shifted = tmp_path / "shifted.csv"
    lines = [rows[0]] + [
        ",".join(f"{float(v) + 1.0!r}" if i == col else v for i, v in enumerate(ln.split(","))) for ln in rows[1:]
    ]
    shifted.write_text("\n".join(lines) + "\n")
    off = _sigma_line(run("evaluate", str(log), "--truth", str(shifted)).stdout)
    assert off[0] < 0.05 < 0.5 < honest[0] and off[1] > 25.0 > honest[1], (honest, off)
    # a model with no height (the 3-DOF rig's, whose first state is its pitch) is not scored on one
    r = run("evaluate", str(log), "--truth", str(named), "--model", "heli3dof")
    assert r.returncode == 0, r.stderr
    assert "- (no height state)" in r.stdout and "its sigma" not in r.stdout, r.stdout
    assert_one_line_error(run("evaluate", str(log), "--truth", str(tmp_path / "none.csv")), "no such truth file")
    bad = tmp_path / "bad.csv"
    bad.write_text("t,h\n0.0,1.0\n0.1,oops\n")
    assert_one_line_error(run("evaluate", str(log), "--truth", str(bad)), "bad.csv: not a truth CSV")
    bad.write_text("time,height\n0.0,1.0\n")
    assert_one_line_error(run("evaluate", str(log), "--truth", str(bad)), "bad.csv: no truth in it")
    bad.write_bytes(bytes(range(256)) * 4)  # not text at all
    assert_one_line_error(run("evaluate", str(log), "--truth", str(bad)), "bad.csv: not a truth CSV")


@pytest.mark.slow
def test_noise_of_the_altitude_model_before_the_arming_and_replay_takes_it(tmp_path):
    """``noise`` reads its still window up to the log's arming (the simulated quad arms at 2 s) and
    gives the baro's R, whose zero it must calibrate within that window; ``replay --noise`` runs the
    altitude model with it (a range sensor of 1 m noise: the height's sigma in flight is the baro's,
    not the range's), and a noise file of another model's sensors is a one-line error, not a file
    silently ignored."""
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario

    log = tmp_path / "f.tlog"
    run_fast(Scenario.from_args("quad", 3, 20.0, [], []), log)
    noise = tmp_path / "n.json"
    r = run("noise", str(log), "--out", str(noise))
    assert r.returncode == 0, r.stderr
    assert "baro (" in r.stdout and "0-1.8 s" in r.stdout, r.stdout
    d = json.loads(noise.read_text())
    assert d["baro"]["n"] > 40 and 0.338 / 1.3 < d["baro"]["R"][0][0] ** 0.5 < 0.338 * 1.3  # the sim's baro

    def sigma_in_flight(noise_file):
        out = tmp_path / "est.csv"
        r = replay_max(log, "--noise", str(noise_file), "--export", str(out))
        assert r.returncode == 0, r.stderr
        return max(float(row["sigma_z"]) for row in csv.DictReader(open(out)) if 10.0 < float(row["t"]) < 15.0)

    d["range"] = {"R": [[1.0]], "n": 0, "mean": [0.0]}
    noisy = tmp_path / "noisy.json"
    noisy.write_text(json.dumps(d))
    assert sigma_in_flight(noisy) > 10.0 * sigma_in_flight(noise)
    other = tmp_path / "heli.json"
    assert run("noise", str(log), "--model", "heli3dof", "--out", str(other)).returncode == 0
    r = replay_max(log, "--noise", str(other))
    assert_one_line_error(r, "the altitude model has no sensor")
    for bad in ("NaN", "-1.0"):
        broken = tmp_path / "broken.json"
        broken.write_text('{"baro": {"R": [[' + bad + "]]}}")
        assert_one_line_error(replay_max(log, "--noise", str(broken)), "baro's R is not a covariance")
