"""The dashboard in a real browser (Debian's headless Chromium): screenshots kept in artifacts/."""
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario
from web.dashboard import frd_quat_to_view, ned_to_view

from .conftest import free_tcp_port

ARTIFACTS = Path(__file__).resolve().parents[1] / "artifacts"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def test_ned_maps_to_a_right_handed_z_up_view():
    np.testing.assert_allclose(ned_to_view([1.0, 2.0, -3.0]), [1.0, -2.0, 3.0])     # 3 m up is +z
    assert frd_quat_to_view((1.0, 0.0, 0.0, 0.0)) == (1.0, 0.0, 0.0, 0.0)
    # a yaw of +90 deg (nose east, NED) becomes a turn to -y (east is -y in the view)
    c = np.sqrt(0.5)
    assert frd_quat_to_view((c, 0.0, 0.0, c)) == pytest.approx((c, 0.0, 0.0, -c))


def screenshot(url: str, out: Path, budget_ms: int = 8000) -> np.ndarray:
    from PIL import Image
    profile = out.with_suffix(".profile")
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
           "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run",
           f"--user-data-dir={profile}", "--window-size=1200,900", f"--virtual-time-budget={budget_ms}",
           f"--screenshot={out}", url]
    subprocess.run(cmd, capture_output=True, timeout=120)
    shutil.rmtree(profile, ignore_errors=True)
    assert out.exists(), "chromium wrote no screenshot"
    return np.asarray(Image.open(out).convert("RGB"), dtype=float)


def non_white(img: np.ndarray) -> float:
    return float(np.mean(img.min(axis=2) < 235))


def blue_pixels(img: np.ndarray) -> int:
    """The vehicle's body is the scene's only strongly blue object (the grid is grey)."""
    return int(np.sum(img[..., 2] - img[..., 0] > 60))


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (make test installs it)")
def test_dashboard_draws_the_scene_and_the_plots_and_they_change(tmp_path):
    ARTIFACTS.mkdir(exist_ok=True)
    run_fast(Scenario.from_args("quad", 2, 40.0, ["range_tilt"], []), tmp_path / "q.tlog")
    port = free_tcp_port()
    proc = subprocess.Popen([sys.executable, "-m", "groundstation.cli", "replay", str(tmp_path / "q.tlog"),
                             "--speed", "2", "--port", str(port), "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = None
        while url is None:                          # wait for the server's own announcement
            line = proc.stdout.readline()
            assert line, proc.stderr.read()
            if line.startswith("dashboard: "):
                url = line.split()[1]
        a = screenshot(url, ARTIFACTS / "dashboard_1.png")
        b = screenshot(url, ARTIFACTS / "dashboard_2.png")          # the replay has moved on meanwhile
        scene_a, scene_b = a[:, :700], b[:, :700]                   # the 3D view (left of the panel)
        assert non_white(scene_a) > 0.01 and non_white(scene_b) > 0.01     # grid, trail, ray drawn
        assert blue_pixels(scene_a) > 100 and blue_pixels(scene_b) > 100   # the vehicle is there
        assert np.mean(np.abs(scene_a - scene_b).max(axis=2) > 30) > 2e-3  # and it moved
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (make test installs it)")
def test_dashboard_panels_and_plots_are_drawn(tmp_path):
    ARTIFACTS.mkdir(exist_ok=True)
    port = free_tcp_port()
    code = ("import sys, time; sys.path.insert(0, %r)\n"
            "from web.dashboard import Dashboard\n"
            "d = Dashboard(port=%d); d.update_panels(); print('ready', flush=True); time.sleep(60)\n"
            % (str(Path(__file__).resolve().parents[1]), port))
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        while (line := proc.stdout.readline()) and line.strip() != "ready":
            pass                                                    # viser's banner comes first
        assert line.strip() == "ready"
        img = screenshot(f"http://127.0.0.1:{port}", ARTIFACTS / "dashboard_panels.png")
        assert non_white(img[400:, 820:]) > 0.02                    # folders, tables and uPlot axes
    finally:
        proc.terminate()
        proc.wait(timeout=20)
