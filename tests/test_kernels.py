"""The compiled inner steps (estimation/kernels.py) against their numpy reference: the series'
(Phi, G, Q_k) at every halving and without Q_k, a scalar reading's update, and a whole run of the
model over a log, which scores as the reference's does."""

import os
import subprocess
import sys

import numpy as np
import pytest

from groundstation.estimation import kernels
from groundstation.estimation.models.base import discretize_series

from .conftest import REPO

compiled = kernels.compiled()
pytestmark = pytest.mark.skipif(compiled is None, reason="numba is not installed: the numpy reference runs alone")
if compiled is not None:
    from groundstation.estimation import kernels_numba


@pytest.mark.parametrize("halvings", [0, 1, 3])
@pytest.mark.parametrize("with_q", [True, False])
def test_the_series_is_the_references(halvings, with_q):
    rng = np.random.default_rng(halvings)
    for n, m in ((3, 1), (6, 3), (9, 3)):
        A, B = rng.normal(0.0, 1.0, (n, n)), rng.normal(0.0, 1.0, (n, m))
        L = rng.normal(0.0, 0.1, (n, n))
        Qc = L @ L.T
        dt = 0.02 * 2**halvings
        ref = discretize_series(A, B, Qc, dt, halvings, with_q=with_q)
        got = kernels_numba.series(A, B, Qc, dt, halvings, with_q)
        for r, g in zip(ref[:2], got[:2]):
            np.testing.assert_allclose(g, r, rtol=1e-12, atol=1e-15)
        if with_q:
            np.testing.assert_allclose(got[2], ref[2], rtol=1e-10, atol=1e-18)
            np.testing.assert_array_equal(got[2], got[2].T)


def test_a_step_takes_the_halvings_and_the_exponentials_the_reference_takes():
    """discretized: the series halved until |A| dt < 0.2, the exponentials past six halvings or with a
    NaN in A, compiled or not."""
    from groundstation.estimation import filters

    rng = np.random.default_rng(1)
    A, B, Qc = rng.normal(0.0, 1.0, (4, 4)), rng.normal(0.0, 1.0, (4, 2)), np.eye(4) * 0.01
    nan_A = A.copy()
    nan_A[1, 2] = np.nan
    for a, dt in ((A, 0.01), (A, 0.3), (A, 2.0), (A, 40.0), (nan_A, 0.01)):
        got = filters.discretized(a, B, Qc, dt)
        kernels._compiled = None
        try:
            ref = filters.discretized(a, B, Qc, dt)
        finally:
            kernels._compiled = compiled
        for g, r in zip(got, ref):
            np.testing.assert_allclose(g, r, rtol=1e-9, atol=1e-14)
    assert compiled[0](A, B, Qc, 40.0, True, 0.2, 6)[3] == -1  # past six halvings: the exponentials
    assert compiled[0](A, B, Qc, 0.3, True, 0.2, 6)[3] >= 1


def _six_state_filter(rng):
    """The thrust model's filter at a random state and covariance: (filter, x, P)."""
    from groundstation.estimation.filters import ModelFilter
    from groundstation.estimation.models.quad_thrust import quad_thrust_model

    f = ModelFilter(quad_thrust_model())
    L = rng.normal(0.0, 0.3, (6, 6))
    x, P = rng.normal(0.0, 1.0, 6), L @ L.T + 0.01 * np.eye(6)
    f.kf.x, f.kf.P = x.copy(), P.copy()
    return f, x, P


def _reference_update(f, z, H, R) -> float:
    """``f``'s update by the numpy reference, as GROUNDSTATION_KERNELS=python runs it: its NIS."""
    kernels._compiled = None
    try:
        return f._update_written_out(z, H, R)
    finally:
        kernels._compiled = compiled


def test_a_scalar_update_is_the_references():
    rng = np.random.default_rng(3)
    f, x, P = _six_state_filter(rng)
    H, R, z = rng.normal(0.0, 1.0, (1, 6)), np.array([[0.04]]), np.array([0.7])
    got_x, got_P, got_K, s, y = compiled[1](x, P, H, 0.04, 0.7)
    nis = _reference_update(f, z, H, R)
    np.testing.assert_allclose(got_x, f.kf.x, rtol=1e-12)
    np.testing.assert_allclose(got_P, f.kf.P, rtol=1e-11, atol=1e-15)
    np.testing.assert_allclose(got_K, f.kf.K, rtol=1e-12)
    assert s == pytest.approx(float(f.kf.S[0, 0]), rel=1e-13) and y == pytest.approx(float(f.kf.y[0]), rel=1e-13)
    assert nis == pytest.approx(y * y / s, rel=1e-12)


@pytest.mark.parametrize("k", [2, 3])
def test_a_vector_update_is_the_references(k):
    """A 2- and a 3-axis reading (the 3-DOF rig's accelerometer and gyro) on a 6-state filter: the
    compiled Gauss-Jordan inverse and Joseph form against numpy's inverse and products."""
    rng = np.random.default_rng(5 + k)
    f, x, P = _six_state_filter(rng)
    B = rng.normal(0.0, 0.1, (k, k))
    H, R, z = rng.normal(0.0, 1.0, (k, 6)), B @ B.T + 0.01 * np.eye(k), rng.normal(0.0, 1.0, k)
    got_x, got_P, got_K, got_S, got_y, got_nis, ok = compiled[3](x, P, H, R, z)
    assert ok
    nis = _reference_update(f, z, H, R)
    np.testing.assert_allclose(got_x, f.kf.x, rtol=1e-11)
    np.testing.assert_allclose(got_P, f.kf.P, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(got_K, f.kf.K, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(got_S, f.kf.S, rtol=1e-13)
    np.testing.assert_allclose(got_y, f.kf.y, rtol=1e-13)
    assert got_nis == pytest.approx(nis, rel=1e-10)


def test_a_singular_vector_innovation_covariance_is_refused_as_the_reference_refuses_it():
    from groundstation.estimation.filters import ModelFilter
    from groundstation.estimation.models.quad_thrust import quad_thrust_model

    for kern in (compiled, None):
        kernels._compiled = kern
        try:
            f = ModelFilter(quad_thrust_model())
            f.kf.P = np.zeros((6, 6))
            with pytest.raises(np.linalg.LinAlgError, match="[Ss]ingular"):
                f._update_written_out(np.zeros(2), np.eye(2, 6), np.zeros((2, 2)))
        finally:
            kernels._compiled = compiled


def test_a_zero_innovation_variance_is_refused_as_the_reference_refuses_it():
    from groundstation.estimation.filters import ModelFilter
    from groundstation.estimation.models.quad_thrust import quad_thrust_model

    f = ModelFilter(quad_thrust_model())
    f.kf.P = np.zeros((6, 6))
    with pytest.raises(np.linalg.LinAlgError, match="singular"):
        f._update_written_out(np.array([1.0]), np.eye(1, 6), np.array([[0.0]]))


@pytest.mark.slow
def test_a_run_of_the_model_scores_as_the_reference_does(tmp_path):
    """The thrust model over a simulated flight (its A moves with every throttle record, so every
    step takes the series), run in a process with the kernels and in one without."""
    code = (
        "import sys\n"
        "from sim_bridge.fast import run_fast\n"
        "from sim_bridge.scenario import Scenario\n"
        "from groundstation.estimation.logs import load_log\n"
        "from groundstation.diagnosis.models import setup\n"
        "from groundstation.diagnosis.runs.run import run_model\n"
        f"log = {str(tmp_path / 'f.tlog')!r}\n"
        "run_fast(Scenario.from_args('quad', 4, 25.0, ['range_tilt'], ['baro_thrust:k=2']), log)\n"
        "su = setup(load_log(log).measurements, model_name='quad_thrust')\n"
        "r = run_model(su.model, su.prep, su.make)\n"
        "print(repr(r.loglik), repr(float(r.x[-1, 0])), repr(float(r.P[-1, 0, 0])))\n"
    )
    out = {}
    for mode in ("numba", "python"):
        env = dict(os.environ, GROUNDSTATION_KERNELS=mode)
        r = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr[-2000:]
        out[mode] = [float(v) for v in r.stdout.split()]
    (ll_c, h_c, p_c), (ll_r, h_r, p_r) = out["numba"], out["python"]
    assert ll_c == pytest.approx(ll_r, rel=1e-9)
    assert h_c == pytest.approx(h_r, rel=1e-8, abs=1e-9) and p_c == pytest.approx(p_r, rel=1e-8)


def test_the_state_step_is_the_references():
    """x <- Phi x + G u, compiled, against numpy's two products; a model without inputs included."""
    rng = np.random.default_rng(4)
    for n, m in ((3, 2), (6, 3), (5, 0)):
        Phi, G = rng.normal(0.0, 1.0, (n, n)), rng.normal(0.0, 1.0, (n, m))
        x, u = rng.normal(0.0, 1.0, n), rng.normal(0.0, 1.0, m)
        np.testing.assert_allclose(compiled[2](Phi, G, x, u), Phi @ x + G @ u, rtol=1e-13, atol=1e-15)


def test_the_drag_ekfs_compiled_update_is_filterpys(tmp_path):
    """The drag EKF's update with the compiled kernel and with filterpy's own call (the reference,
    as ``GROUNDSTATION_KERNELS=python`` runs it) over the same 10 s of simulated flight."""
    from drivers.replay import Replay
    from groundstation.estimation.attitude_filters import DragAttitudeEKF
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario

    run_fast(Scenario.from_args("quad", 4, 10.0, [], []), tmp_path / "q.tlog")
    ms = list(Replay(tmp_path / "q.tlog").iter_measurements())
    runs = []
    for k in (compiled, None):
        kernels._compiled = k
        try:
            drag = DragAttitudeEKF()
            for m in ms:
                drag.handle(m)
        finally:
            kernels._compiled = compiled
        runs.append(drag)
    fast, ref = runs
    assert len(fast.nis) == len(ref.nis) > 1000
    np.testing.assert_allclose(fast.nis, ref.nis, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(fast.ekf.x, ref.ekf.x, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(fast.P, ref.P, rtol=1e-7, atol=1e-15)


def test_a_filter_made_has_its_kernels_loaded_before_its_first_reading():
    """numba loads a kernel's machine code at its first call (a tenth of a second each): a live
    filter that took that at its first reading stalled the event loop past a board link's 0.3 s and
    the commander disarmed. Made in a fresh process, a filter has all four loaded before any step."""
    code = (
        "from groundstation.estimation import kernels_numba as k\n"
        "from groundstation.estimation.filters import ModelFilter\n"
        "from groundstation.estimation.models.heli3dof import heli3dof_model\n"
        "names = ('discretized_step', 'scalar_update', 'state_step', 'vector_update')\n"
        "assert not any(getattr(k, n).overloads for n in names)\n"
        "ModelFilter(heli3dof_model())\n"
        "print(' '.join(n for n in names if not getattr(k, n).overloads))\n"
    )
    _nothing_left_to_load(code)


def test_the_drag_ekf_made_has_its_update_loaded_before_its_first_reading():
    """The same for the multirotor attitude EKF, whose accelerometer update is the compiled one."""
    code = (
        "from groundstation.estimation import kernels_numba as k\n"
        "from groundstation.estimation.attitude_filters import DragAttitudeEKF\n"
        "assert not k.vector_update.overloads\n"
        "DragAttitudeEKF()\n"
        "print('' if k.vector_update.overloads else 'vector_update')\n"
    )
    _nothing_left_to_load(code)


def _nothing_left_to_load(code: str) -> None:
    """``code`` run in a fresh process prints the kernels a filter it made has not loaded: none."""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "", f"not loaded: {r.stdout}"
