"""Running a model over a log, fast enough to run it dozens of times.

The diagnosis runs the model once per candidate effect (and per delay on a
grid), so the log is prepared once: sorted, truth set aside, and the IMU
(accelerometer and gyro, at 500-1000 Hz: the altitude and attitude filters'
*inputs*) averaged over ``input_dt`` blocks. With a zero-order-hold input the filter integrates the
held value over each step anyway; the block mean is that integral's best
value, so the estimate barely changes while the run is 5-10 times cheaper.

A :class:`Run` keeps what every later step needs: per sensor the innovations
(nu, S, NIS) and the regression signals at those instants, the state
trajectory with its covariance, and the innovation log-likelihood
``l = -1/2 sum(nu' S^-1 nu + log det(2 pi S))`` over the scored window.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from operator import attrgetter

import numpy as np

from groundstation.core.imu import IMU_KINDS, ImuColumns, block_means
from groundstation.core.measurement import Kind, Measurement
from groundstation.core.readings import Readings
from groundstation.core.validity import reading_problem
from groundstation.diagnosis.runs.signals import add_signal_rules
from groundstation.diagnosis.runs.signature import Probes
from groundstation.estimation.context import Context, Zero
from groundstation.estimation.estimator import KalmanEstimator
from groundstation.estimation.filters import GainTape, InnovationLog
from groundstation.estimation.models.base import LinearModel

# the on-ground constraints' pseudo-sensor (models.ground): not a sensor to diagnose, and not
# scored. Its innovations are smooth (n / n_eff = 199 on a simulated flight): a clean quad's
# diagnosis credited thrust_ground_effect (R = 0.28 m, Delta BIC -240) for what the constraint
# alone "gained", and made the height error worse (1.03 -> 1.35 cm)
from groundstation.estimation.models.ground import LANDED
from groundstation.estimation.whiteness import effective_size


@dataclass
class Prepared:
    """A log made ready for repeated runs."""

    measurements: Readings  # sorted, truth removed, IMU input decimated
    truth: list[Measurement]
    kinds: set[Kind]
    t0: float
    t1: float
    #: the log has a throttle of its own (else THROTTLE is a stand-in derived from vibration or range)
    logged_throttle: bool = False
    #: readings left out as no estimator takes them (``core.validity``), by ``<kind>_<problem>``
    unusable: dict[str, int] = field(default_factory=dict)
    #: the absolute sensors' zeros against the estimate (a baro's, a GPS's: models.base.
    #: relative_to_estimate), taken once by :func:`hold_zeros` and then the same for every model run
    #: over the log: a zero taken against each model's own estimate made the candidates' filters
    #: differ by more than their effects (the two-stage filter, signature.py, holds them fixed too)
    zeros: dict[str, Zero] = field(default_factory=dict)

    @property
    def duration(self) -> float:
        return self.t1 - self.t0


#: what sets the context measurements are read in (the tilt, the throttle): at one instant these
#: come first, so a range reading stamped with an attitude sample is read with that attitude
CONTEXT_KINDS = frozenset(
    {
        Kind.ATTITUDE,
        Kind.ATTITUDE_QUATERNION,
        Kind.ANGULAR_RATE,
        Kind.THROTTLE,
        Kind.ACTUATOR,
        Kind.VEHICLE_STATUS,
        Kind.TEMPERATURE,
        Kind.BATTERY_VOLTAGE,
        Kind.BATTERY_CURRENT,
    }
)


def in_time_order(m: Measurement) -> tuple[float, int]:
    return m.t, m.kind not in CONTEXT_KINDS


def prepare(
    ms: Iterable[Measurement],
    input_dt: float = 0.01,
    imu: ImuColumns | None = None,
    imu_kinds: tuple[Kind, ...] = IMU_KINDS,
) -> Prepared:
    """``ms`` made ready for repeated runs: sorted, truth set aside, the IMU's readings (in ``ms``, or
    given as columns in ``imu``) averaged over ``input_dt`` blocks (:func:`.core.imu.block_means`),
    the ones no estimator takes counted and left out, all held as columns
    (:class:`~groundstation.core.readings.Readings`). Only the first IMU's blocks are kept: every
    model reads instance 0; and only of ``imu_kinds``, the ones the models read (the altitude's
    read no gyro: a 1-hour log's gyro blocks are 0.1 GB)."""
    every = Readings.of(ms)
    truth = list(every.only({Kind.TRUTH_POSE}))
    rest = every.without({Kind.TRUTH_POSE})
    del every
    if rest.is_kind(IMU_KINDS).any():
        imu_rest, more = ImuColumns.split(rest.only(IMU_KINDS))  # (one of fewer than three axes stays)
        rest = rest.without(IMU_KINDS) + imu_rest
        imu = more if imu is None else ImuColumns({**imu.series, **more.series})
    vib: list[tuple[float, float]] = []  # (t, spread of |f| within the block)
    blocks: list[Readings] = []
    for kind in imu_kinds:
        s = imu.get(kind, 0) if imu is not None else None
        if s is None:
            continue
        means = block_means(s, kind, 0, input_dt)
        blocks.append(means.readings)
        if kind is Kind.ACCEL:
            vib = list(zip(means.spread_t.tolist(), means.spread.tolist()))
    logged_throttle = bool(rest.is_kind({Kind.THROTTLE, Kind.ACTUATOR}).any())
    out = rest = rest.in_time_order(CONTEXT_KINDS)
    for b in blocks:
        out = out + b
    if not logged_throttle:
        out = out + (motors_from_vibration(vib) or airborne_from_range(rest))
    out = out.in_time_order(CONTEXT_KINDS)
    status = next(iter(out.only({Kind.VEHICLE_STATUS})), None)
    if status is not None and out:
        # the vehicle's type (which outputs are motors) holds for the whole log: known from the
        # first sample on, not from the first 1 Hz HEARTBEAT (before it a coax's four outputs,
        # two of them swash-plate servos at mid-range, averaged to a 0.25 throttle on the ground)
        out = Readings.of([status._replace(t=out[0].t)]) + out
    # checked once here, not on each of the dozens of runs (what the estimator would skip, it never sees)
    unusable: dict[str, int] = {}
    ok = np.ones(len(out), dtype=bool)
    for i, m in enumerate(out):
        bad = reading_problem(m)
        if bad is not None:
            ok[i] = False
            key = f"{m.kind.value}_{bad}"
            unusable[key] = unusable.get(key, 0) + 1
    usable = out.where(ok) if not ok.all() else out
    kinds = usable.kinds()
    t0, t1 = (float(usable.t[0]), float(usable.t[-1])) if len(usable) else (0.0, 0.0)
    return Prepared(usable, truth, kinds, t0, t1, logged_throttle, unusable)


def motors_from_vibration(vib: list[tuple[float, float]]) -> list[Measurement]:
    """A throttle stand-in for logs without one (the Crazyflie's): rotors running or not.

    Within each input block the specific force's spread is the rotors' vibration
    (a 1 kHz IMU sees it; a block mean hides it). It is bimodal, motors off and on,
    so the threshold is the geometric mean of its 5th and 95th percentiles, on a
    0.2 s median; with no clear gap (p95/p5 < 4) there is no stand-in. Emitted as
    THROTTLE 0/1 from ``derived/vibration``, so the catalogue's throttle regressors
    (baro_thrust, ground effect) read "motors running" where no throttle exists.
    """
    if len(vib) < 200:
        return []
    t = np.array([v[0] for v in vib])
    x = np.array([v[1] for v in vib])
    k = 20
    med = np.array([np.median(x[max(0, i - k // 2) : i + k // 2 + 1]) for i in range(len(x))])
    lo, hi = np.percentile(med, [5, 95])
    if lo <= 0 or hi / lo < 4.0:
        return []
    on = med > math.sqrt(lo * hi)
    return [
        Measurement(float(ti), Kind.THROTTLE, np.array([1.0 if o else 0.0]), "derived/vibration", float(ti))
        for ti, o in zip(t[::5], on[::5])
    ]


def airborne_from_range(ms: Iterable[Measurement], clearance: float = 0.05) -> list[Measurement]:
    """The second stand-in: the rotors carry the vehicle while the range sensor reads more
    than its resting value plus ``clearance`` (a vehicle standing on the ground with its
    motors idling gives no vibration gap, the Crazyflie's logs among them)."""
    rng = [(m.t, float(m.value[0])) for m in Readings.of(ms).only({Kind.RANGE})]
    if len(rng) < 50:
        return []
    rest = float(np.median([r for _, r in rng[:10]]))
    return [
        Measurement(t, Kind.THROTTLE, np.array([1.0 if r > rest + clearance else 0.0]), "derived/range", t)
        for t, r in rng
    ]


@dataclass
class SensorTrace:
    t: np.ndarray
    nu: np.ndarray  # (n, dim)
    S: np.ndarray  # (n, dim, dim)
    nis: np.ndarray
    z: np.ndarray  # what was measured (after extraction)
    signals: dict[str, np.ndarray] = field(default_factory=dict)  # context at each update

    @property
    def nu_normalised(self) -> np.ndarray:
        return self.nu[:, 0] / np.sqrt(self.S[:, 0, 0])

    @property
    def loglik(self) -> np.ndarray:
        """Each update's innovation log-likelihood, -1/2 (nu' S^-1 nu + log det(2 pi S))."""
        dim = self.S.shape[1]
        logdet = np.log(np.linalg.det(self.S)) if dim > 1 else np.log(self.S[:, 0, 0])
        return -0.5 * (self.nis + logdet + dim * math.log(2 * math.pi))


@dataclass
class Taped:
    """What the two-stage filter (:mod:`.signature`) reads of a run: every step's gains, and per
    innovation record (every update, in order) its time, sensor, innovation and variance (scalar
    readings; NaN for a vector one), the probed regressors' values, and which record each row of
    the run's ``x`` follows (``x_record``)."""

    tape: GainTape
    t: np.ndarray
    sensor: np.ndarray
    nu: np.ndarray
    S: np.ndarray
    probes: Probes | None
    x_record: np.ndarray

    @property
    def scalar(self) -> bool:
        """Every reading is a scalar (the two-stage filter is written for those)."""
        return bool(np.all(np.isfinite(self.S)))


@dataclass
class Run:
    model: LinearModel
    sensors: dict[str, SensorTrace]
    t: np.ndarray  # after each update
    x: np.ndarray
    #: the covariance after each update, or a function of a slice of its rows that computes them (a
    #: run through the base filter's gains, ``gains.virtual_run``: most candidates' runs are scored
    #: by their innovations alone, and theirs would be the largest arrays of a diagnosis); :attr:`P`
    #: reads it either way
    covariance: np.ndarray | Callable[[slice], np.ndarray]
    loglik: float  # over the scored window, all sensors but LANDED
    n_scored: int  # innovations in it
    ctx: Context  # the filter's context at the end of the log
    loglik_by: dict[str, float] = field(default_factory=dict)  # the same, per sensor
    inflation: dict[str, float] = field(default_factory=dict)  # n / n_eff of each sensor's innovations
    #: with ``taped``: the run's gains and innovations record by record (signature.py)
    taped: Taped | None = None
    #: the two-stage filter's account of an augmented model's run (gains.virtual_run), not a run of it
    through_gains: bool = False
    #: read for its scores alone (``run_model(scores_only=True)``): its covariance the last alone, no signals
    scores_only: bool = False

    @property
    def P(self) -> np.ndarray:
        """The covariance after each update (computed now if it was left for later, and kept)."""
        if self.scores_only:
            raise ValueError("a run read for its scores holds its last covariance alone (Run.final)")
        if callable(self.covariance):
            self.covariance = self.covariance(slice(None))
        return self.covariance

    def P_rows(self, k: slice) -> np.ndarray:
        """Rows ``k`` of :attr:`P`, without computing the others."""
        if self.scores_only:
            if k != slice(-1, None):
                raise ValueError("a run read for its scores holds its last covariance alone (Run.final)")
            return np.asarray(self.covariance)
        return self.covariance(k) if callable(self.covariance) else self.covariance[k]

    def final(self, state: str) -> tuple[float, float]:
        i = self.model.index(state)
        return float(self.x[-1, i]), float(math.sqrt(max(self.P_rows(slice(-1, None))[0, i, i], 0.0)))

    def __getstate__(self) -> dict:
        """Pickled with :attr:`P` computed (a function of arrays held elsewhere does not cross processes)."""
        if callable(self.covariance):
            _ = self.P
        return self.__dict__


def ending(run: Run) -> Run:
    """``run`` without its trajectory: its scores (each sensor's innovations, the likelihoods) and
    where it ended (the last state and covariance, :meth:`Run.final`), no tape. What a candidate
    that is not added is read for once its ranking is decided (``scored.smallest_claimed``); its
    whole run, through the gains or its own, is 10-30 MB on a 1-hour log."""
    last = slice(-1, None)
    return replace(run, t=run.t[last].copy(), x=run.x[last].copy(), covariance=run.P_rows(last).copy(), taped=None)


def hold_zeros(prep: Prepared, run: Run) -> None:
    """The zeros ``run`` took (its context's) held for every later run over ``prep``: each still
    calibrates on the same first readings, and ends on the zero ``run`` took."""
    prep.zeros = {k: Zero(held=z.ref) for k, z in run.ctx.zeros.items() if z.ref is not None}


#: s: the filter settles this long before the likelihood is scored (run_model's score_from)
SETTLE_S = 5.0

#: context values recorded beside every innovation (for cross-correlation and regression)
SIGNALS = (
    "throttle",
    "throttle_lp",
    "roll",
    "pitch",
    "temperature",
    "voltage",
    "current",
    "vibration",
    "ground_speed",
)


def run_model(
    model: LinearModel,
    prep: Prepared,
    make_estimator: Callable[[LinearModel], KalmanEstimator],
    *,
    measurements: Iterable[Measurement] | None = None,
    score_from: float = SETTLE_S,
    taped: bool = False,
    probes: Probes | None = None,
    scores_only: bool = False,
) -> Run:
    """The model over the prepared log; the likelihood scored from ``score_from`` s in. ``taped``:
    with its gains recorded (:class:`.Run`'s ``tape``); ``probes``: regressors evaluated at each
    update of their sensor (:mod:`.signature`). ``scores_only``: the innovations and the state after
    each update, without the covariances (the run's :attr:`.Run.P` holds the last one alone) or the
    signals beside the innovations: a run read for its scores, at a fraction of the memory (a 1-hour
    log's covariances are 0.1 GB a run)."""
    est = make_estimator(model)
    if prep.zeros:
        est.filter.ctx.zeros = dict(prep.zeros)
    add_signal_rules(est, probes.throttle_tcs if probes is not None else ())
    taped = taped or probes is not None
    if taped:
        est.filter.tape = GainTape()
    kinds = est.kinds
    ms = Readings.of(prep.measurements if measurements is None else measurements).only(kinds)
    # the estimate and covariance after each update as doubles as they come, not an array object each
    ts, xs, Ps, x_record = array("d"), array("d"), array("d"), array("q")
    # each signal as doubles as it comes (not a float object a value: a long log's run holds millions)
    sig: dict[str, dict[str, array[float]]] = {}
    sig_cols: dict[str, list[array[float]]] = {}  # the same columns, in SIGNALS' order
    signals_of = attrgetter(*SIGNALS)
    f = est.filter
    for m in ms:
        rec = est.handle(m, checked=True, singular_raises=True)  # prepare() checked every reading
        if rec is None:
            continue
        ts.append(rec.t)
        xs.extend(f.kf.x.tolist())
        if scores_only:
            continue
        Ps.extend(f.kf.P.ravel().tolist())
        if taped:
            x_record.append(len(f.log) - 1)
        d = sig_cols.get(rec.sensor)
        if d is None:
            sig[rec.sensor] = {k: array("d") for k in SIGNALS}
            d = sig_cols[rec.sensor] = list(sig[rec.sensor].values())
        ctx = f.ctx
        if probes is not None:
            probes.record(rec.sensor, ctx, f.kf.x - rec.K @ rec.nu)
        for col, value in zip(d, signals_of(ctx)):
            col.append(math.nan if value is None else value)
    if scores_only and len(ts):
        Ps.extend(f.kf.P.ravel().tolist())  # the last one alone: where the run ended
    log = est.filter.log
    sensors, ll_by, inflation, n_sc = _traces(log, sig, prep.t0 + score_from)
    n = model.n
    # the doubles themselves, not a copy (a long log's covariances are 0.1 GB a run, twice over while copied)
    x, P = np.frombuffer(xs, dtype=float).reshape(-1, n), np.frombuffer(Ps, dtype=float).reshape(-1, n, n)
    del xs, Ps
    tape = est.filter.tape
    recorded = None
    if tape is not None:
        recorded = Taped(
            tape,
            *log.in_order(),
            probes,
            np.array(x_record, dtype=int).reshape(-1),
        )
    return Run(
        model,
        sensors,
        np.array(ts).reshape(-1),
        x,
        P,
        sum(ll_by.values()),
        n_sc,
        est.filter.ctx,
        ll_by,
        inflation,
        recorded,
        scores_only=scores_only,
    )


def _traces(
    log: InnovationLog, sig: dict[str, dict[str, array[float]]], t_score: float
) -> tuple[dict[str, SensorTrace], dict[str, float], dict[str, float], int]:
    """Each sensor's trace (its innovations and the signals beside them), and from ``t_score`` on each
    one's log-likelihood, its innovations' colour (updates per effective sample) and the updates
    scored."""
    sensors: dict[str, SensorTrace] = {}
    ll_by: dict[str, float] = {}
    inflation: dict[str, float] = {}
    n_sc = 0
    for s in log.sensors():
        a = log.arrays(s)
        tr = SensorTrace(
            a["t"], a["nu"], a["S"], a["nis"], a["z"], {k: np.array(v, dtype=float) for k, v in sig.get(s, {}).items()}
        )
        sensors[s] = tr
        scored = tr.t >= t_score
        if scored.any() and s != LANDED:
            ll_by[s] = float(np.sum(tr.loglik[scored]))
            inflation[s] = int(scored.sum()) / max(effective_size(tr.nu_normalised[scored]), 1.0)
            n_sc += int(scored.sum())
    return sensors, ll_by, inflation, n_sc
