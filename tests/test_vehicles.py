"""Several vehicles on one link: one estimator, status line, export file and dashboard entry per
MAVLink system id. Two simulated vehicles (their own processes and sockets) hover at different
heights and write to one ``udpin`` port; merged, one filter fused both range sensors and the
status line flipped between 1.0 and 1.6 m."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from groundstation.app.outputs import VehicleOutputs, beside
from groundstation.core.measurement import Kind, Measurement, source_system
from web.dashboard import Dashboard

from .conftest import free_udp_port
from .helpers import running, simulated_vehicle

GS = [sys.executable, "-m", "groundstation"]
#: quad seeds whose hovers are 0.6 m apart (1.61 m and 1.00 m: sim_bridge/profile.py)
SEEDS = {1: 1, 2: 4}


def _column(path: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    rows = list(csv.DictReader(open(path)))
    return np.array([float(r["t"]) for r in rows]), np.array([float(r[name]) for r in rows])


def _rmse(est: Path, truth: Path) -> float:
    """Height estimate against a vehicle's truth, in its hover (8-14 s of its clock)."""
    t, z = _column(est, "z")
    tt, h = _column(truth, "h")
    keep = (t > 8.0) & (t < 14.0)
    assert keep.sum() > 100, f"{est} has {keep.sum()} estimates in the hover"
    return float(np.sqrt(np.mean((z[keep] - np.interp(t[keep], tt, h)) ** 2)))


@pytest.mark.slow
def test_two_vehicles_on_one_port_are_estimated_each_on_its_own(tmp_path):
    port = free_udp_port()
    est = tmp_path / "est.csv"
    connect = [*GS, "connect", f"udpin:127.0.0.1:{port}", "--no-web", "--no-record", "--export", est]
    truths = {k: tmp_path / f"truth{k}.csv" for k in SEEDS}
    with running([*connect, "--duration", "16"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as gs:
        sims = [
            simulated_vehicle(port, "--sysid", str(k), "--seed", str(s), "--duration", "20", "--truth", str(truths[k]))
            for k, s in SEEDS.items()
        ]
        with sims[0], sims[1]:
            out, err = gs.communicate(timeout=60)
    assert gs.returncode == 0, err
    assert "Traceback" not in err
    assert "vehicle 1:" in out and "vehicle 2:" in out  # a status line each
    files = [est, beside(est, 1), beside(est, 2)]
    written = [f for f in files if f.exists()]
    assert len(written) == 2, written  # the first vehicle heard: est.csv; the other beside it
    # each file follows one vehicle: matched to its own truth within centimetres, to the other's not
    err_ = {(f.name, k): _rmse(f, truths[k]) for f in written for k in SEEDS}
    own = min(
        err_[(written[0].name, 1)] + err_[(written[1].name, 2)], err_[(written[0].name, 2)] + err_[(written[1].name, 1)]
    )
    assert own / 2 < 0.1, err_
    assert max(err_.values()) > 0.4, err_  # the other vehicle's height is 0.6 m away


def _m(t: float, kind: Kind, value: float, source: str) -> Measurement:
    return Measurement(t, kind, np.array([value]), source, t)


def test_the_dashboard_offers_each_vehicle_and_shows_the_one_picked():
    """Two vehicles' range readings through the per-vehicle outputs into a real dashboard (its
    viser server): the picker appears with the second vehicle, and picking it shows its data only."""
    import argparse

    args = argparse.Namespace(model="altitude", noise=None, export=None, export_measurements=None)
    dash = Dashboard(port=0)
    try:
        outs = VehicleOutputs(args, None, dash, is_vehicle=lambda k: k != 255, on_new=dash.set_vehicles)
        dash.on_vehicle = outs.show
        outs.see(_m(1.0, Kind.RANGE, 1.0, "mav/1.1"))
        assert not dash.vehicle_choice.visible
        outs.see(_m(1.0, Kind.RANGE, 1.6, "mav/2.1"))
        outs.see(_m(1.1, Kind.RANGE, 1.1, "mav/255.190"))  # a ground station's: the first vehicle's
        assert dash.vehicle_choice.visible and dash.vehicle_choice.options == ("1", "2")
        assert dash._range == 1.1  # the first vehicle shown, and only its readings
        outs.see(_m(1.2, Kind.RANGE, 1.7, "mav/2.1"))
        assert dash._range == 1.1
        outs.show(2)
        assert dash._range != dash._range  # the view starts over for vehicle 2 ...
        outs.see(_m(1.3, Kind.RANGE, 1.8, "mav/2.1"))
        outs.see(_m(1.3, Kind.RANGE, 1.2, "mav/1.1"))
        assert dash._range == 1.8  # ... and shows its readings only
        assert dash.estimator_counters is outs.by_id[2].estimator.counters
    finally:
        dash.stop()


def test_system_ids_and_the_files_beside():
    assert source_system("mav/2.1") == 2 and source_system("replay/17.1") == 17 and source_system("board") is None
    assert beside(Path("out/est.csv"), 3) == Path("out/est.sys3.csv") and beside(None, 3) is None
