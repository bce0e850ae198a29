"""The dashboard in a real browser (Debian's headless Chromium): screenshots kept in artifacts/."""

import asyncio
import contextlib
import math
import os
import re
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario
from web.dashboard import frd_quat_to_view, ned_to_view

from .browser import CHROMIUM, Browser
from .conftest import async_test, free_tcp_port, real_file

ARTIFACTS = Path(__file__).resolve().parents[1] / "artifacts"


def test_ned_maps_to_a_right_handed_z_up_view():
    np.testing.assert_allclose(ned_to_view([1.0, 2.0, -3.0]), [1.0, -2.0, 3.0])  # 3 m up is +z
    assert frd_quat_to_view((1.0, 0.0, 0.0, 0.0)) == (1.0, 0.0, 0.0, 0.0)
    # a yaw of +90 deg (nose east, NED) becomes a turn to -y (east is -y in the view)
    c = np.sqrt(0.5)
    assert frd_quat_to_view((c, 0.0, 0.0, c)) == pytest.approx((c, 0.0, 0.0, -c))


def non_white(img: np.ndarray) -> float:
    return float(np.mean(img.min(axis=2) < 235))


def dark_pixels(img: np.ndarray) -> int:
    """Text and axes; a blank control panel has only its header's (~300)."""
    return int(np.sum(img.max(axis=2) < 120))


@contextlib.asynccontextmanager
async def _dashboard_of(*command: str):
    """``groundstation COMMAND --port P`` in its own process, and its dashboard's address once the
    process announces it; the process is stopped on the way out, whatever happened."""
    port = free_tcp_port()
    proc = await asyncio.create_subprocess_exec(
        *(sys.executable, "-m", "groundstation", *command, "--port", str(port)),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    try:
        url = None
        while url is None:  # wait for the server's own announcement
            line = (await proc.stdout.readline()).decode()
            assert line, (await proc.stderr.read()).decode()
            if line.startswith("dashboard: "):
                url = line.split()[1]
        yield url
    finally:
        if proc.returncode is None:
            proc.terminate()
            await proc.wait()


#: the state panel's line scoring the height against truth: RMS [cm], share within 2 sigma [%], NEES
AGAINST_TRUTH = re.compile(r"height ([0-9.]+) cm RMS, within 2σ ([0-9]+)% \(95 % if σ is honest\), NEES ([0-9.]+)")


async def _against_truth(url: str) -> str:
    """The state panel's line against truth, once a browser shows it."""
    async with Browser() as b:
        await b.goto(url)
        await b.wait_for_text("against truth, last 60 s: height", timeout=60.0)
        r = await b.call("Runtime.evaluate", expression="document.body.innerText", returnByValue=True)
    return next(ln for ln in r["result"]["value"].splitlines() if "against truth" in ln)


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (make test installs it)")
@async_test(timeout=150)
async def test_dashboard_draws_the_scene_and_the_plots_and_they_change(tmp_path):
    ARTIFACTS.mkdir(exist_ok=True)
    # 60 s at real speed: whenever the tab gets ready (a loaded machine takes 5-30 s), a height
    # step or the sine is still ahead (seed 2: steps at 11, 16 and 51 s, sine 21-33 s, landing at 53 s)
    run_fast(Scenario.from_args("quad", 2, 60.0, ["range_tilt"], []), tmp_path / "q.tlog")
    async with _dashboard_of("replay", str(tmp_path / "q.tlog"), "--speed", "1", "--quiet") as url:
        async with Browser() as b:
            await b.goto(url)
            await b.wait_for_text("NIS and its 95 % band")  # the panels have arrived
            await b.wait_for_text("bias / parameter state")
            await b.wait_for_text("±")  # the state table is live
            a = await _drawn(b, ARTIFACTS / "dashboard_1.png")
            t_first, z_first = await _replay_state(b)
            t, z = t_first, z_first
            while not abs(z - z_first) >= 0.3:  # until the vehicle has visibly moved
                assert t < 52.0, f"the replay reached t = {t} s (first screenshot at {t_first} s) with no 0.3 m move"
                await asyncio.sleep(0.1)
                t, z = await _replay_state(b)
            await asyncio.sleep(0.3)  # a few scene frames (30 Hz) later
            c = await _drawn(b, ARTIFACTS / "dashboard_2.png")
        # the vehicle (a blue 35 cm box) is drawn where the estimate puts it: a move of >= 0.3 m in
        # height (with the horizontal filter's drift beside it) moves it on the screen by tens of
        # pixels with the dashboard's camera; a frozen scene leaves it where it was
        (ya, xa), (yc, xc) = _vehicle_on_screen(a), _vehicle_on_screen(c)
        assert math.hypot(yc - ya, xc - xa) > 8, (
            f"the vehicle stayed at ({xa:.0f}, {ya:.0f}) -> ({xc:.0f}, {yc:.0f}) px while the estimate went "
            f"from z = {z_first:+.2f} m at t = {t_first} s to {z:+.2f} m at t = {t} s"
        )
        for img in (a, c):
            assert dark_pixels(img[:, -380:]) > 1000  # panels: text, tables, plot axes


def _vehicle_on_screen(img: np.ndarray) -> tuple[float, float]:
    """(row, column) of the vehicle's blue box in the 3D view: the only blue there (the covariance is
    orange, the trail grey, the ray red), also under the covariance's 25 % veil. Without the view's
    bottom-left corner, where viser draws its axes gizmo (a blue z axis)."""
    rows, cols = _blue(img)
    assert len(rows) > 50, f"no vehicle in the view ({len(rows)} blue pixels)"
    return float(np.median(rows)), float(np.median(cols)) + 120


def _blue(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    view = _scene(img)[:, 120:]
    r, g, b = view[..., 0], view[..., 1], view[..., 2]
    return np.nonzero((b > 140) & (b - r > 60) & (b - g > 30))


def _scene(img: np.ndarray) -> np.ndarray:
    """The 3D view: left of the panel, below viser's "software WebGL" notice (it may fade)."""
    return img[160:, :860]


async def _drawn(b: Browser, path: Path, *, vehicle: bool = True, within: float = 60.0) -> np.ndarray:
    """A screenshot once the 3D view shows its grid and the vehicle and the panels their contents:
    software WebGL fades the canvas in over several seconds (a frame at a time; on a loaded machine
    the grid was there while the box was still too pale to read as blue), and the panel's folders
    are painted some frames after their text is in the page (a screenshot taken as soon as the text
    was there showed the panel's frame empty: 283 dark pixels)."""
    deadline = time.monotonic() + within
    while (
        non_white(_scene(img := await b.screenshot(path))) < 0.01
        or dark_pixels(img[:, -380:]) <= 1000
        or (vehicle and len(_blue(img)[0]) <= 50)
    ) and time.monotonic() < deadline:
        await asyncio.sleep(0.2)
    return img


async def _replay_state(b: Browser) -> tuple[float, float]:
    """The replay position the link panel shows ('t 12.3 / 40.0 s') and the state table's z."""
    r = await b.call("Runtime.evaluate", expression="document.body.innerText", returnByValue=True)
    text = r["result"]["value"]
    t = re.search(r"t ([0-9.]+) / [0-9.]+ s", text)
    z = re.search(r"\nz\s+([+-]?[0-9.]+)", text)
    return (float(t.group(1)) if t else -1.0), (float(z.group(1)) if z else math.nan)


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (make test installs it)")
@async_test(timeout=90)
async def test_dashboard_panels_and_plots_are_drawn(tmp_path):
    ARTIFACTS.mkdir(exist_ok=True)
    port = free_tcp_port()
    code = (
        f"import sys, time; sys.path.insert(0, {str(Path(__file__).resolve().parents[1])!r})\n"
        "from web.dashboard import Dashboard\n"
        f"d = Dashboard(port={port}); d.update_panels(); print('ready', flush=True); time.sleep(60)\n"
    )
    proc = await asyncio.create_subprocess_exec(sys.executable, "-c", code, stdout=asyncio.subprocess.PIPE)
    try:
        while (line := (await proc.stdout.readline()).decode()) and line.strip() != "ready":
            pass  # viser's banner comes first
        assert line.strip() == "ready"
        async with Browser() as b:
            await b.goto(f"http://127.0.0.1:{port}")
            await b.wait_for_text("No diagnosis has been run")
            img = await _drawn(b, ARTIFACTS / "dashboard_panels.png", vehicle=False)
        assert dark_pixels(img[:, -380:]) > 1000  # folders, tables and uPlot axes
    finally:
        if proc.returncode is None:
            proc.terminate()
            await proc.wait()


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (make test installs it)")
@async_test(timeout=120)
async def test_a_replay_with_motion_capture_shows_the_height_against_it():
    """A Crazyflie log with Vicon in it, replayed: the browser's state panel scores the height
    against the motion capture as the replay goes."""
    log = real_file("crazyflie_util/0422-log00")
    async with _dashboard_of("replay", str(log), "--speed", "1", "--quiet") as url:
        line = await _against_truth(url)
    assert AGAINST_TRUTH.search(line), line


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (make test installs it)")
@async_test(timeout=120)
async def test_the_demo_shows_the_simulators_truth_and_scores_the_height_against_it():
    """``demo``: the simulator's truth reaches the dashboard as motion capture would (never an
    estimator), and the state panel scores the height against it; the filter, tuned on this
    simulator, holds it (NEES under 3)."""
    async with _dashboard_of("demo", "--duration", "40") as url:
        line = await _against_truth(url)
    m = AGAINST_TRUTH.search(line)
    assert m and float(m.group(1)) < 10.0 and float(m.group(3)) < 3.0, line


@pytest.mark.slow
@async_test(timeout=60)
async def test_websocket_updates_arrive_at_the_configured_rates():
    """What a tab receives, at the protocol level: the scene at scene_hz, the plots at plot_hz,
    however fast the estimates come (here 200 Hz)."""
    import time

    from groundstation.estimation.loop import Snapshot
    from web.dashboard import Dashboard
    from web.probe import ViserProbe, gui_id

    d = Dashboard(port=0, scene_hz=20.0, plot_hz=5.0)
    pusher = asyncio.create_task(d.run())

    async def estimates():
        k = 0
        while True:
            k += 1
            d.feed_snapshot(
                Snapshot(
                    k * 0.005,
                    "altitude",
                    ("z", "vz", "b_acc"),
                    np.array([1.0 + 1e-3 * k, 0, 0]),
                    np.eye(3) * 1e-4,
                    None,
                    time.monotonic(),
                )
            )
            await asyncio.sleep(0.005)

    feeder = asyncio.create_task(estimates())
    try:
        scene, plot = [], []
        plot_id = gui_id(d.plot_z)
        async with ViserProbe(d.url) as probe:
            t_end = None
            async for t, messages in probe.frames():
                for m in messages:
                    if m["type"] == "SetPositionMessage" and m["name"] == "/vehicle":
                        scene.append(t)
                    elif m["type"] == "GuiUpdateMessage" and m.get("uuid", m.get("id")) == plot_id:
                        plot.append(t)
                if scene and t_end is None:
                    t_end = scene[0] + 4.0  # four seconds after the first update
                if t_end is not None and t > t_end:
                    break
        scene_hz = (len(scene) - 1) / (scene[-1] - scene[0])
        plot_hz = (len(plot) - 1) / (plot[-1] - plot[0])
        assert 0.9 * 20.0 <= scene_hz <= 1.05 * 20.0, scene_hz
        assert 0.9 * 5.0 <= plot_hz <= 1.05 * 5.0, plot_hz
    finally:
        feeder.cancel()
        pusher.cancel()
        await asyncio.gather(feeder, pusher, return_exceptions=True)
        d.stop()


@pytest.mark.slow
@async_test(timeout=400)
async def test_live_diagnosis_panel_names_the_undeclared_effect(tmp_path):
    """The dashboard's Diagnosis panel, pressed by a tab: the last 60 s of a session with an
    undeclared rotor-wash baro error, diagnosed in a worker process while the page stays live
    (its text arrives as the markdown's ``_markdown`` property), from what the session's
    estimator was given: its declared slant and its airframe file (sim_quad's constants are the
    thrust model's; the altitude model's diagnosis is the same with or without them)."""
    from drivers.replay import Replay
    from groundstation.diagnosis.live import DIAGNOSIS_NICE
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario
    from web.dashboard import Dashboard
    from web.probe import ViserProbe, gui_id

    log = tmp_path / "s.tlog"
    run_fast(Scenario.from_args("quad", 7, 40.0, ["range_tilt"], ["baro_thrust:k=4"]), log)
    d = Dashboard(port=0)
    d.attach_session(model="altitude", declared=[{"name": "range_tilt"}], vehicle="sim_quad")
    pusher = asyncio.create_task(d.run())
    try:
        for m in Replay(log).iter_measurements():
            d.feed_measurement(m)
        md_id = gui_id(d.diagnosis_md)
        async with ViserProbe(d.url) as viewer:  # a view-only tab starts nothing that costs
            await viewer.set_gui(gui_id(d.diagnose_button), value=True)
            await viewer.until_notifications("Not yours to start", 1)
            assert d.last_diagnosis is None and not d._diagnosing
        async with ViserProbe(d.control_url) as probe:
            await probe.set_gui(gui_id(d.diagnosis_window), value=40.0)
            await probe.set_gui(gui_id(d.diagnose_button), value=True)
            async for _, messages in probe.frames():
                texts = [
                    m["updates"].get("_markdown", "")
                    for m in messages
                    if m["type"] == "GuiUpdateMessage" and m.get("uuid") == md_id
                ]
                if any("baro_thrust" in t for t in texts):
                    assert any("model altitude, vehicle sim_quad" in t for t in texts), texts
                    break
        assert d.last_diagnosis["vehicle"] == "sim_quad"
        assert d.last_diagnosis["effects"][0]["name"] == "baro_thrust"
        # the worker yields the CPU to the link and the estimation loop
        (worker,) = d._pool._processes
        nice = os.getpriority(os.PRIO_PROCESS, worker) - os.getpriority(os.PRIO_PROCESS, 0)
        assert nice == min(DIAGNOSIS_NICE, 19 - os.getpriority(os.PRIO_PROCESS, 0))
        assert 3.0 < d.last_diagnosis["effects"][0]["params"]["k"] < 5.0
    finally:
        pusher.cancel()
        await asyncio.gather(pusher, return_exceptions=True)
        d.stop()


def test_the_state_panel_lists_what_the_estimator_skipped():
    """A replay of underpowered.log skips its sonar's echoes on the ground: the state panel says so
    under the table, as the replay's last line does (not a calibration's or the ground's non-uses)."""
    from groundstation.estimation.estimator import EstimatorCounters
    from groundstation.estimation.loop import Snapshot
    from web.dashboard import Dashboard

    dash = Dashboard(port=0)
    try:
        counters = EstimatorCounters(skipped={"range_on_ground": 310, "baro_not_used": 49, "landed_not_used": 9})
        dash.attach_session(model="altitude", declared=[], counters=counters)
        dash.feed_snapshot(Snapshot(1.0, "altitude", ("z", "vz", "b_acc"), np.zeros(3), np.eye(3) * 1e-4, None, 0.0))
        dash.update_panels()
        assert dash.state_md.content.endswith("\n\nskipped: 310 range_on_ground"), dash.state_md.content
        counters.skipped.clear()
        dash.update_panels()
        assert "skipped" not in dash.state_md.content
    finally:
        dash.stop()


def test_the_state_panel_scores_the_height_against_a_truth_in_the_stream():
    """Motion capture in the stream (TRUTH_POSE, NED): the state panel gives the height's error against
    it and whether the sigma drawn holds it; without truth it says nothing of it."""
    from groundstation.core.measurement import Kind, Measurement
    from groundstation.estimation.loop import Snapshot
    from web.dashboard import Dashboard

    rng = np.random.default_rng(5)
    dash = Dashboard(port=0)
    try:
        dash.attach_session(model="altitude", declared=[])
        P = np.diag([0.01**2, 1e-4, 1e-4])
        for k in range(1000):  # 10 s: truth at 100 Hz, the estimate at 50 Hz just after it, 1 cm sigma
            t = 0.01 * k
            h = 1.0 + 0.5 * math.sin(t)
            dash.feed_measurement(Measurement(t, Kind.TRUTH_POSE, np.array([0.0, 0.0, -h, 1.0, 0, 0, 0]), "mocap"))
            if k % 2 == 1:
                z = 1.0 + 0.5 * math.sin(t - 0.004) + rng.normal(0.0, 0.01)
                dash.feed_snapshot(
                    Snapshot(t - 0.004, "altitude", ("z", "vz", "b_acc"), np.array([z, 0, 0]), P, None, 0.0)
                )
        dash.update_panels()
        line = dash.state_md.content.split("\n\n")[-1]
        assert line.startswith("against truth, last 60 s: height 1.0 cm RMS, within 2σ 9"), line
        nees = float(line.split("NEES ")[1])
        assert 0.8 < nees < 1.2, line
        dash.clear_view()
        dash.feed_snapshot(Snapshot(11.0, "altitude", ("z", "vz", "b_acc"), np.zeros(3), P, None, 0.0))
        dash.update_panels()
        assert "against truth" not in dash.state_md.content
    finally:
        dash.stop()


def test_the_vehicle_follows_the_estimate_once_a_session_is_attached():
    """The 3D view's vehicle is placed at the estimate after the command line has attached its
    session (model, declared effects, airframe): the airframe's name is not the scene's handle."""
    from groundstation.estimation.loop import Snapshot
    from web.dashboard import Dashboard

    dash = Dashboard(port=0)
    try:
        dash.attach_session(model="altitude", declared=[], vehicle="sim_quad")
        dash.feed_snapshot(
            Snapshot(1.0, "altitude", ("z", "vz", "b_acc"), np.array([2.5, 0, 0]), np.eye(3) * 1e-4, None, 0)
        )
        dash.update_scene()
        assert tuple(dash.vehicle_frame.position) == pytest.approx((0.0, 0.0, 2.5))  # NED z = -2.5: 2.5 m up
    finally:
        dash.stop()


@async_test(timeout=20)
async def test_a_failing_scene_update_is_reported_and_the_updates_go_on(capsys):
    """A frame that raises (a fault no input here causes; injected) is said on stderr once and
    counted, and the panels and the scene keep updating."""
    from web.dashboard import Dashboard

    dash = Dashboard(port=0, scene_hz=50.0, plot_hz=50.0)
    calls = 0

    def flaky():
        nonlocal calls
        calls += 1
        if calls == 2:
            raise RuntimeError("a bad frame")

    dash.update_panels = flaky
    task = asyncio.create_task(dash.run())
    try:
        while calls < 6:
            await asyncio.sleep(0.02)
        assert dash.update_errors == {"flaky: RuntimeError: a bad frame": 1}
        assert "dashboard: flaky: RuntimeError: a bad frame (the updates go on)" in capsys.readouterr().err
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        dash.stop()


def test_the_diagnosis_panel_follows_the_session():
    """The panel offers the session's own model: a 3-DOF rig's session its own diagnosis."""
    from web.dashboard import Dashboard

    dash = Dashboard(port=0)
    try:
        dash.attach_session(model="quad_thrust", declared=[], vehicle="apm2_sonar")
        assert (dash.diagnosis_model.value, dash.airframe) == ("quad_thrust", "apm2_sonar")
        dash.attach_session(model="heli3dof", declared=[])
        assert (dash.diagnosis_model.value, dash.airframe) == ("heli3dof", None)
    finally:
        dash.stop()
