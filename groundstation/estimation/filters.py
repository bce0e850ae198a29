"""A thin layer over filterpy: a declared model in, predict/update, an innovation log out.

:class:`ModelFilter` drives ``filterpy.kalman.KalmanFilter`` with the exact
discretisation of a :class:`~groundstation.estimation.models.base.LinearModel` for each
step, and records for every measurement update the innovation nu, its
covariance S, NIS = nu^T S^-1 nu, the gain K and the inputs used
(:class:`InnovationLog`): the closed-loop diagnosis reads this log.
Attributes keep filterpy's (and the textbook's) symbols: ``x, P, F, Q, H, R``.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Hashable, Iterator
from dataclasses import dataclass

import numpy as np
from filterpy.kalman import KalmanFilter

from . import kernels
from .context import Context
from .models.base import LinearModel, MeasurementModel, discretize, discretize_series

#: |A| dt below which the discretisation's integrals are summed as a series (models.base.discretize_series)
SERIES_LIMIT = 0.2
#: the most halvings of a step the series is summed over (|A| dt up to 0.2 * 2^6 = 12.8); a longer
#: step, or a stiffer A, takes the exponentials
MAX_HALVINGS = 6


def discretized(A: np.ndarray, B: np.ndarray, Qc: np.ndarray, dt: float, *, with_q: bool = True):
    """(Phi, G, Q_k) of a step not seen before: by the series (:func:`discretize_series`), halved until
    |A| dt / 2^s < :data:`SERIES_LIMIT`, or by Van Loan's exponentials past :data:`MAX_HALVINGS`.
    ``with_q=False``: Q_k is None (a step of the state alone)."""
    k = kernels.compiled()
    if k is not None:  # the same, compiled (kernels.py)
        Phi, G, Qk, halvings = k[0](_c(A), _c(B), _c(Qc), float(dt), with_q, SERIES_LIMIT, MAX_HALVINGS)
        if halvings >= 0:
            return Phi, G, Qk if with_q else None
        return discretize(A, B, Qc, dt, with_q=with_q)
    size = float(np.abs(A).sum(axis=1).max()) * dt
    if not math.isfinite(size):  # a NaN in A: the exponentials, which the divergence check then reads
        return discretize(A, B, Qc, dt, with_q=with_q)
    halvings = 0 if size < SERIES_LIMIT else math.ceil(math.log2(size / SERIES_LIMIT) + 1e-12)
    if halvings > MAX_HALVINGS:
        return discretize(A, B, Qc, dt, with_q=with_q)
    return discretize_series(A, B, Qc, dt, halvings, with_q=with_q)


def _c(a: np.ndarray) -> np.ndarray:
    """``a`` as contiguous doubles (itself where it is: the kernels compile once per layout)."""
    if type(a) is np.ndarray and a.dtype is _F64 and a.flags.c_contiguous:
        return a
    return np.ascontiguousarray(a, dtype=float)


_F64 = np.dtype(float)


def _matrix(a) -> np.ndarray:
    """``a`` as a 2-D array of doubles: itself where it is one already (an H, an R, an S: read at
    every update, where ``np.atleast_2d(a).astype(float)`` costs more than the arithmetic)."""
    if type(a) is np.ndarray and a.ndim == 2 and a.dtype is _F64:
        return a
    return np.atleast_2d(a).astype(float, copy=False)


@dataclass(slots=True)  # no __dict__: a long log's run holds one per update
class InnovationRecord:
    t: float
    sensor: str
    nu: np.ndarray
    S: np.ndarray
    nis: float
    K: np.ndarray
    u: np.ndarray
    z: np.ndarray


#: a gain tape's steps (:class:`GainTape`)
_PREDICT, _UPDATE, _RESTART = 0, 1, 2


class GainTape:
    """Every step of a run as the filter took it, in order (:meth:`steps`): a prediction as
    ``(Phi, G, u)`` (x <- Phi x + G u), a measurement update as ``(sensor, H, K, reset, record)``
    (``reset``: the states a reset update set, else None; ``record``: its index in the innovation
    log), and a restart of the filter (a clock jump, a divergence) as None. The diagnosis runs
    every candidate effect through these gains at once (:mod:`groundstation.diagnosis.runs.signature`).

    Kept compact, as a long log's run takes a million steps: a prediction as the index of its
    (Phi, G), which the filter's discretisation cache shares among steps, and u as doubles; an
    update as its sensor's index and H and K as doubles (a tuple of arrays a step was some 300
    bytes, and crossed between processes as a million objects)."""

    def __init__(self) -> None:
        self.starts: list[float] = []  #: when the filter started, and started over [s]
        self._step = array("b")  # each step's kind
        self._pairs: list[tuple[np.ndarray, np.ndarray]] = []  # the distinct (Phi, G), held
        self._pair_of: dict[tuple[int, int], int] = {}  # (id(Phi), id(G)) -> index (held: ids stay unique)
        self._pred = array("i")  # each prediction's (Phi, G)
        self._u = array("d")  # each prediction's u, flattened
        self._m = 0  # u's length
        self._sensors: list[tuple[str, tuple[int, int], tuple[int, ...] | None]] = []  # (name, H's shape, reset)
        self._sensor_of: dict[tuple, int] = {}
        self._upd = array("i")  # each update's entry in _sensors
        self._record = array("q")  # each update's innovation record
        self._hk = array("d")  # each update's H then K, flattened

    def restart(self, t0: float) -> None:
        if self.starts:
            self._step.append(_RESTART)
        self.starts.append(t0)

    def predict(self, Phi: np.ndarray, G: np.ndarray, u: np.ndarray) -> None:
        key = (id(Phi), id(G))
        k = self._pair_of.get(key)
        if k is None:
            k = self._pair_of[key] = len(self._pairs)
            self._pairs.append((Phi, G))
            self._m = len(u)
        self._step.append(_PREDICT)
        self._pred.append(k)
        self._u.extend(u.tolist())

    def update(self, sensor: str, H: np.ndarray, K: np.ndarray, reset: tuple[int, ...] | None, record: int) -> None:
        key = (sensor, H.shape, reset)
        k = self._sensor_of.get(key)
        if k is None:
            k = self._sensor_of[key] = len(self._sensors)
            self._sensors.append((sensor, H.shape, reset))
        self._step.append(_UPDATE)
        self._upd.append(k)
        self._record.append(record)
        self._hk.extend(H.ravel().tolist())
        self._hk.extend(K.ravel().tolist())

    def __len__(self) -> int:
        return len(self._step)

    def records(self) -> tuple[np.ndarray, np.ndarray]:
        """Each update's innovation record, and the filter start it belongs to (0 the first)."""
        step = np.frombuffer(self._step, dtype=np.int8)
        segment = np.cumsum(step == _RESTART)[step == _UPDATE]
        return np.array(self._record, dtype=np.int64), segment

    def steps(self) -> Iterator[tuple | None]:
        """The steps as the class docstring gives them (arrays read off the tape, not to be written)."""
        u = np.frombuffer(self._u, dtype=float).reshape(-1, self._m) if self._m else np.zeros((len(self._pred), 0))
        hk = np.frombuffer(self._hk, dtype=float)
        pairs, sensors = self._pairs, self._sensors
        pred, upd, record = self._pred, self._upd, self._record
        i = j = o = 0
        for kind in self._step:
            if kind == _PREDICT:
                Phi, G = pairs[pred[i]]
                yield Phi, G, u[i]
                i += 1
            elif kind == _UPDATE:
                name, (k, n), reset = sensors[upd[j]]
                H = hk[o : o + k * n].reshape(k, n)
                o += k * n
                K = hk[o : o + n * k].reshape(n, k)
                o += n * k
                yield name, H, K, reset, record[j]
                j += 1
            else:
                yield None

    def __getstate__(self) -> dict:
        """Pickled without the index of pairs by their ids (which another process's are not)."""
        state = dict(self.__dict__)
        state["_pair_of"] = {}
        return state


class _SensorUpdates:
    """One sensor's updates as doubles: time, NIS, and the innovation, its covariance and the
    reading flattened (each of the one shape every update of a sensor has)."""

    def __init__(self, r: InnovationRecord, k: int) -> None:
        self.k = k  # its place among the log's sensors
        self.shapes = (r.nu.shape, r.S.shape, r.z.shape)
        self.t, self.nis, self.nu, self.S, self.z = array("d"), array("d"), array("d"), array("d"), array("d")

    def add(self, r: InnovationRecord) -> None:
        if (r.nu.shape, r.S.shape, r.z.shape) != self.shapes:
            raise ValueError(f"sensor {r.sensor}: an update of another size than its first")
        self.t.append(r.t)
        self.nis.append(r.nis)
        self.nu.extend(r.nu.ravel().tolist())
        self.S.extend(r.S.ravel().tolist())
        self.z.extend(r.z.ravel().tolist())

    def __len__(self) -> int:
        return len(self.t)

    def truncate(self, n: int) -> None:
        """Keep the first ``n`` updates."""
        for col, shape in ((self.nu, self.shapes[0]), (self.S, self.shapes[1]), (self.z, self.shapes[2])):
            del col[n * math.prod(shape) :]
        del self.t[n:], self.nis[n:]

    def arrays(self) -> dict[str, np.ndarray]:
        (nu, S, z), n = self.shapes, len(self.t)
        return {
            "t": np.array(self.t),
            "nu": np.array(self.nu).reshape(n, *nu),
            "S": np.array(self.S).reshape(n, *S),
            "nis": np.array(self.nis),
            "z": np.array(self.z).reshape(n, *z),
        }


class InnovationLog:
    """Every update's innovation, per sensor, as arrays on demand: ``t``, ``nu``, ``S``, ``nis``
    and ``z`` (the reading, less the model's offset).

    Kept as doubles per sensor, not as the update's record (some 600 bytes each with its arrays):
    a long log's run makes hundreds of thousands of updates, and a live session never stops."""

    def __init__(self) -> None:
        self._by_sensor: dict[str, _SensorUpdates] = {}
        self._names: list[str] = []  # the sensors in the order first seen
        self._order = array("H")  # each update's sensor, by its place in _names

    def __len__(self) -> int:
        return len(self._order)

    def append(self, r: InnovationRecord) -> None:
        u = self._by_sensor.get(r.sensor)
        if u is None:
            u = self._by_sensor[r.sensor] = _SensorUpdates(r, len(self._names))
            self._names.append(r.sensor)
        u.add(r)
        self._order.append(u.k)

    def sensors(self) -> list[str]:
        return sorted(s for s, u in self._by_sensor.items() if len(u))

    def arrays(self, sensor: str) -> dict[str, np.ndarray]:
        u = self._by_sensor.get(sensor)
        if u is None or not len(u):
            return {"t": np.empty(0), "nu": np.empty((0, 1)), "S": np.empty((0, 1, 1)), "nis": np.empty(0)}
        return u.arrays()

    def truncate(self, n: int) -> None:
        """Keep the first ``n`` updates (a rollback)."""
        later = np.bincount(np.array(self._order[n:], dtype=np.int64), minlength=len(self._names))
        for name, k in zip(self._names, later.tolist()):
            if k:
                u = self._by_sensor[name]
                u.truncate(len(u) - k)
        del self._order[n:]

    def in_order(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every update in the order it was made: its time, sensor, and for a scalar sensor its
        innovation and that's variance (NaN for a vector's)."""
        order = np.array(self._order, dtype=np.int64)
        t = np.empty(len(order))
        nu, S = np.full(len(order), np.nan), np.full(len(order), np.nan)
        for k, name in enumerate(self._names):
            at, u = np.flatnonzero(order == k), self._by_sensor[name]
            t[at] = np.array(u.t)
            if u.shapes[0] == (1,):
                nu[at], S[at] = np.array(u.nu), np.array(u.S)
        sensor = np.array(self._names + [""])[order]  # ("": a str array also when there is none)
        return t, sensor, nu, S


class ModelFilter:
    """Kalman filter for a declared linear model (filterpy underneath)."""

    def __init__(self, model: LinearModel, t0: float = 0.0) -> None:
        self.model = model
        self.ctx = Context()
        self.log = InnovationLog()
        self.updates = 0
        self._cache: dict = {}
        #: A by its key (``LinearModel.A_key``): a logged IMU's jittered steps each miss the
        #: discretisations' cache (their lengths differ), and building A through an augmented
        #: model's closures was a tenth of a run on a 400 Hz DataFlash log
        self._a_by_key: dict = {}
        self._eye = np.eye(model.n)
        # time-invariant models discretise once per step length; a nonlinear one at every step
        u0 = np.zeros(len(model.inputs))
        self._nonlinear = model.f is not None
        self._u_dependent = self._nonlinear or not np.array_equal(model.A(u0), model.A(u0 + 1.0))
        #: with a list here, every step's gains go to it (:class:`GainTape`)
        self.tape: GainTape | None = None
        kernels.ready()  # here, not at the first reading: a live loop must not stall on it
        self.reset(t0)

    def reset(self, t0: float) -> None:
        m = self.model
        kf = KalmanFilter(dim_x=m.n, dim_z=1, dim_u=len(m.inputs))
        kf.x = m.x0.astype(float).copy()
        kf.P = m.P0.astype(float).copy()
        self.kf = kf
        self.t = t0
        self.u = np.zeros(len(m.inputs))
        # the covariance's steps not yet applied: their total length (1e-7 s units), A's key (the
        # same for all), and how many
        self._pending_k = 0
        self._pending_akey: Hashable = None
        self._pending_A: np.ndarray | None = None
        self._pending_u: np.ndarray | None = None
        self._pending_n = 0
        if self.tape is not None:
            self.tape.restart(t0)

    # filterpy's symbols, as properties
    @property
    def x(self) -> np.ndarray:
        return self.kf.x

    @property
    def P(self) -> np.ndarray:
        self._apply_pending()
        return self.kf.P

    def add_variance(self, added: dict[int, float]) -> None:
        """P[i, i] += q for each state i: an impulse the dynamics lack, as discrete process noise at
        the filter's time (``LinearModel.impulses``)."""
        self._apply_pending()
        P = self.kf.P.copy()
        for i, q in added.items():
            P[i, i] += q
        self.kf.P = P

    def _apply_pending(self) -> None:
        """P = Phi P Phi^T + Q_k over the steps not yet applied.

        Steps of lengths a and b with the same A are one step of a + b exactly (Phi(b) Phi(a) =
        Phi(a + b), Phi(b) Q_k(a) Phi(b)^T + Q_k(b) = Q_k(a + b)), so the covariance is propagated
        only when someone reads it or A changes: a 1 kHz IMU's steps between two 50 Hz attitudes
        share their A, and a logged IMU's jittered steps (each its own length, each a new
        discretisation were the covariance stepped with them) are summed.
        """
        if self._pending_n:
            self._pending_n = 0
            dt = self._pending_k * 1e-7
            Phi, _, Qk, _ = self._discrete(dt, self._pending_akey, self._pending_A, self._pending_u)
            kf = self.kf
            kf.P = Phi @ kf.P @ Phi.T + Qk

    def _a_key(self) -> tuple[Hashable, np.ndarray | None]:
        """The held input's A's key (None for a time-invariant model), and A where computing the key
        took it (a model without ``A_key``: A's own bytes are the key)."""
        if not self._u_dependent:
            return None, None
        key_of = self.model.A_key
        if key_of is not None:
            return key_of(self.u), None
        A = self.model.A(self.u)
        return A.tobytes(), A

    def _discrete(
        self, dt: float, akey: Hashable, A: np.ndarray | None, u: np.ndarray | None = None, *, with_q: bool = True
    ):
        """(Phi, G, Q_k, the length they were made at) over ``dt`` with the A of key ``akey`` (``A``
        itself, or when None that of the input ``u``, by default the held one), cached on the step's
        length and that key: a model whose A takes one input of several (the altitude model's
        cos_tilt) reuses a discretisation while the others change. ``with_q=False``: Q_k may be None
        (a step of the state alone)."""
        k = int(dt * 1e7 + 0.5)
        key = (k, akey)
        d = self._cache.get(key)
        if d is None or (with_q and d[2] is None):
            if A is None:
                A = self._a_by_key.get(akey)  # (None: a time-invariant model's one A)
                if A is None:
                    A = self.model.A(self.u if u is None else u)
                    if len(self._a_by_key) > 4096:
                        self._a_by_key.clear()
                    self._a_by_key[akey] = A
            # a step not seen before (A changes with the input; a live clock jitters, so each step
            # has its own dt): a fourth-order series of the same integrals, 20x cheaper than two
            # matrix exponentials. An entry made without Q_k gains it at the length it was made for,
            # so that its Phi and G stay the ones its steps took
            at = dt if d is None else d[3]
            d = (*discretized(A, self.model.B, self.model.Qc, at, with_q=with_q), at)
            if len(self._cache) > 4096:
                self._cache.clear()
            self._cache[key] = d
        return d

    def _predict_nonlinear(self, dt: float) -> None:
        """The extended filter's step: linearised at the estimate, x_dot ~ f(x^, u) + F (x - x^)
        with F = df/dx, and that held over dt exactly as a linear model is:
        x <- x^ + Gamma f(x^, u),  Gamma = int_0^dt e^{F s} ds;  P <- Phi P Phi^T + Q_k."""
        if self.tape is not None:
            raise ValueError(f"{self.model.name}: a gain tape needs a linear model (its steps' Phi)")
        m, kf = self.model, self.kf
        f, jacobian = m.f, m.jacobian
        assert f is not None and jacobian is not None  # a nonlinear model has both (LinearModel)
        F = jacobian(kf.x, self.u)
        eye = np.eye(m.n)
        Phi, Gam, Qk = discretized(F, eye, m.Qc, dt)
        kf.x = kf.x + Gam @ f(kf.x, self.u)
        kf.P = Phi @ kf.P @ Phi.T + Qk

    def predict_to(self, t: float) -> None:
        """Propagate x and P to time t with the held input (zero-order hold)."""
        dt = t - self.t
        if dt <= 0.0:
            return
        if self._nonlinear:
            self._predict_nonlinear(dt)
            self.t = t
            return
        akey, A = self._a_key()
        # a step whose A is not the last step's: its covariance step is applied alone unless the next
        # steps hold this A (a thrust model's A moves with every throttle record and an update reads P
        # between them), so Q_k is made with Phi and G, not by a second series when P is read
        fresh = self._u_dependent and akey != self._pending_akey
        Phi, G, _, _ = self._discrete(dt, akey, A, with_q=fresh)
        # x = F x + B u every step; P = F P F^T + Q deferred (see _apply_pending).
        # (filterpy's predict, written out: its copies of the priors cost three
        # times the arithmetic at 1 kHz.)
        kf = self.kf
        kern = kernels.compiled()
        if kern is not None:  # the same, compiled (kernels.py)
            kf.x = kern[2](_c(Phi), _c(G), _c(kf.x), _c(self.u))
        else:
            kf.x = Phi @ kf.x + G @ self.u
        if self.tape is not None:
            self.tape.predict(Phi, G, self.u)
        k = int(dt * 1e7 + 0.5)
        if self._pending_n and akey == self._pending_akey:
            self._pending_k += k
            self._pending_n += 1
        else:
            self._apply_pending()
            # the run's A, or the input that makes it (computed only if its one step misses the cache)
            self._pending_k, self._pending_akey, self._pending_A, self._pending_n = k, akey, A, 1
            self._pending_u = self.u
        self.t = t

    def checkpoint(self) -> tuple:
        """Everything needed to come back to this instant (see :meth:`restore`)."""
        self._apply_pending()
        return (
            self.t,
            self.kf.x.copy(),
            self.kf.P.copy(),
            self.u.copy(),
            self.ctx.copy(),
            len(self.log),
            self.updates,
        )

    def restore(self, cp: tuple) -> None:
        """Back to a checkpoint: state, covariance, inputs, context; later log entries dropped."""
        t, x, P, u, ctx, n_log, updates = cp
        self.t, self.u, self.updates = t, u.copy(), updates
        self.kf.x, self.kf.P = x.copy(), P.copy()
        self._pending_n = 0
        self.ctx.set_to(ctx)
        self.log.truncate(n_log)

    def _update_only(self, mm: MeasurementModel, z: np.ndarray, H: np.ndarray, R: np.ndarray) -> None:
        """The Schmidt-Kalman ("consider") update: the gain's rows for the states not in
        ``mm.corrects`` set to zero, P by the Joseph form, which holds for any gain (Simon, Optimal
        State Estimation, 2006, sec. 7.3); or, with ``mm.reset``, those states set to the measured
        value. filterpy has neither."""
        kf = self.kf
        R = np.atleast_2d(R)
        y = np.atleast_1d(z).astype(float) - H @ kf.x
        PHt = kf.P @ H.T
        S = H @ PHt + R
        K = np.zeros_like(PHt)
        idx = list(mm.corrects or ())
        if mm.reset:
            # the states measured one to one (H picks them): set, with variance R, uncorrelated
            kf.x = kf.x.copy()
            kf.x[idx] = np.atleast_1d(z).astype(float)
            P = kf.P.copy()
            if len(idx) == 1:  # (the ground's one state: indexing by a number, not by lists)
                i = idx[0]
                P[i, :] = 0.0
                P[:, i] = 0.0
                P[i, i] = R[0, 0]
            else:
                P[idx, :] = 0.0
                P[:, idx] = 0.0
                P[np.ix_(idx, idx)] = R
            kf.P = P
            kf.y, kf.S, kf.K = y, S, K
            return
        if not idx:
            # a reading scored and not used (a sensor left out): K = 0 leaves x and P as they are, and
            # the Joseph form's products by I would give P back exactly
            kf.y, kf.S, kf.K = y, S, K
            return
        K[idx] = PHt[idx] @ np.linalg.inv(S)
        kf.x = kf.x + K @ y
        I_KH = self._eye - K @ H
        kf.P = I_KH @ kf.P @ I_KH.T + K @ R @ K.T
        kf.y, kf.S, kf.K = y, S, K

    def _update_written_out(self, z: np.ndarray, H: np.ndarray, R: np.ndarray) -> float:
        """filterpy's ``KalmanFilter.update``, written out: y = z - H x, S = H P H^T + R,
        K = P H^T S^-1, x = x + K y, and P by the same Joseph form,
        P = (I - K H) P (I - K H)^T + K R K^T. Without its copies of the priors and of z and its
        likelihood's reset, which cost twice the arithmetic at an IMU's rate; for one scalar
        reading (a range sensor, a baro) S is a number and needs no inverse. Returns the NIS,
        y^T S^-1 y."""
        kf = self.kf
        P = kf.P
        k = kernels.compiled()
        if k is not None and H.shape[0] > 1:
            x, P, K, S, y, nis, ok = k[3](_c(kf.x), _c(P), _c(H), _c(R), _c(z))
            if not ok:  # as numpy's inverse of S: a filter run away is the caller's to catch
                raise np.linalg.LinAlgError("singular innovation covariance")
            kf.x, kf.P, kf.y, kf.S, kf.K = x, P, y, S, K
            return float(nis)
        if k is not None:
            x, P, K, s, y0 = k[1](_c(kf.x), _c(P), _c(H), float(R[0, 0]), float(z[0]))
            if s == 0.0:  # as the reference: a filter run away is the caller's to catch
                raise np.linalg.LinAlgError("singular innovation covariance")
            kf.x, kf.P, kf.y, kf.S, kf.K = x, P, np.array([y0]), np.array([[s]]), K
            si = 1.0 / s
            return y0 * si * y0
        PHt = P @ H.T
        S = H @ PHt + R
        y = z - H @ kf.x
        if S.shape == (1, 1):
            s = float(S[0, 0])
            if s == 0.0:  # as filterpy's inverse of S would: a filter run away is the caller's to catch
                raise np.linalg.LinAlgError("singular innovation covariance")
            # the same products as the matrix forms, each a single one (an inner dimension of 1):
            # K = P H^T / S, x + K y, K H and K R K^T as outer products
            si = 1.0 / s
            K = PHt * si
            kf.x = kf.x + K[:, 0] * y[0]
            I_KH = self._eye - K * H
            kf.P = I_KH @ P @ I_KH.T + (K * float(R[0, 0])) * K.T
            kf.y, kf.S, kf.K = y, S, K
            y0 = float(y[0])
            return y0 * si * y0
        SI = np.linalg.inv(S)
        K = PHt @ SI
        kf.x = kf.x + K @ y
        I_KH = self._eye - K @ H
        kf.P = I_KH @ P @ I_KH.T + K @ R @ K.T
        kf.y, kf.S, kf.K = y, S, K
        return float(y @ SI @ y)

    def update(self, mm: MeasurementModel, z: np.ndarray, R: np.ndarray | None = None) -> InnovationRecord:
        """One measurement update with ``mm``'s H and offset, and its R unless ``R`` is given
        (a block mean's R / n, see ``MeasurementModel.per_sample``)."""
        self._apply_pending()
        kf = self.kf
        R = mm.R if R is None else R
        H = _matrix(mm.row(self.ctx))
        if mm.offset is not None:
            z = z - mm.offset(self.ctx)
        z = np.array(z, dtype=float, ndmin=1)  # a copy: the record keeps it
        if mm.corrects is None:
            nis = self._update_written_out(z, H, _matrix(R))
        else:
            self._update_only(mm, z, H, np.atleast_2d(R))
            nis = float(kf.y @ np.linalg.solve(kf.S, kf.y))
        # each update makes its own y, S and K (nothing writes into them after): kept as they are
        nu, S, K = kf.y, kf.S, kf.K
        if not (type(nu) is np.ndarray and nu.ndim == 1 and nu.dtype is _F64):
            nu = np.atleast_1d(nu).astype(float, copy=False)
        S = _matrix(S)
        if not (type(K) is np.ndarray and K.dtype is _F64):
            K = np.array(K, dtype=float)
        rec = InnovationRecord(self.t, mm.name, nu, S, nis, K, self.u.copy(), z)
        if self.tape is not None:
            self.tape.update(mm.name, H, rec.K, mm.corrects if mm.reset else None, len(self.log))
        self.log.append(rec)
        self.updates += 1
        return rec
