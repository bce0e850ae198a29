"""Every candidate effect through the base filter's own gains, in one pass: the two-stage bias filter.

A candidate that adds unknown constants theta to the model, each acting linearly (a regressor on a
sensor's reading, ``y = H x + D theta``, or a term on the dynamics' input, ``x_dot = A x + B u + C theta``),
needs no filter run of its own. Run with theta known, the base filter's estimate moves by
``Delta theta`` and its innovations by ``-G theta``, where the *signature* follows the base filter's
gains (Willsky and Jones 1976, the generalised likelihood ratio's "fault signature")::

    predict:  Delta <- Phi Delta + Gamma          (Gamma: the input term over the step, G_u[:, i] c(u))
    update:   G_k    = H Delta + D_k              (the innovation's sensitivity to theta)
              Delta <- Delta - K G_k              (a reset update: the reset states' rows set to 0)

With theta a random constant of prior ``P_theta`` (the augmented model's state), the augmented
filter is exactly the base filter plus a recursive least-squares estimate of theta on the base
innovations (Friedland 1969, the separate-bias estimator; Ignagni 1981). With the sums over the
updates before k::

    A_k = sum G_j' S_j^-1 G_j,   b_k = sum G_j' S_j^-1 nu_j,   Sigma_k = (P_theta^-1 + A_k)^-1,
    theta_k = Sigma_k b_k,

the augmented filter's innovation at update k is ``nu_k - G_k theta_k`` with covariance
``S_k + G_k Sigma_k G_k'``, and its estimate ``x_k + Delta_k theta``. One pass over the base run's
:class:`~groundstation.estimation.filters.GainTape` thus gives every such candidate's whole run (its
innovations, likelihood per sensor, parameters with their sigma, estimate), all candidates and
every shape of theirs (a time constant's grid) together, as cumulative sums over time; and the
held-out blocks of :mod:`~groundstation.diagnosis.scoring.holdout` become sums over the other blocks.

It is exact where the base filter's gains do not depend on the data (the ground's constraints are
resets for this reason: :func:`groundstation.estimation.models.ground.on_ground`). Where a rule reads
the estimate (a regressor of the height, as the baro's ground effect; the ground below 0.5 m; a
barometer's zero taken against the first readings' estimate) the augmented filter would have
read its own estimate, centimetres apart; such a column says so (``exact=False``). The effect that
is added is then run as a filter of its own, and that run is what the next step starts from.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from groundstation.estimation.context import Context
from groundstation.estimation.filters import GainTape

#: a measurement column's regressor: (the context at the update, the state before it) -> D_k
Regressor = Callable[[Context, np.ndarray], float]


@dataclass(frozen=True, eq=False)
class Column:
    """One unknown constant of a candidate effect (the augmented state ``state``) at unit size, acting
    on ``sensor``'s reading through ``regressor`` (evaluated in the run at each of that sensor's
    updates) or ``of_time`` (of the updates' times and of when the filter started, read after the
    run), or on the
    model's input ``input`` as ``theta factor(u)`` (added to that input over each step)."""

    state: str
    prior: float  #: the augmented state's prior variance
    sensor: str | None = None
    regressor: Regressor | None = None
    of_time: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    input: int | None = None
    factor: Callable[[np.ndarray], float] | None = None
    #: the rotor wash's low-pass time constant the regressor reads (``ctx.throttle_lps``), kept by the run
    throttle_tc: float | None = None
    #: False where the regressor reads the estimate (the augmented filter reads its own)
    exact: bool = True
    #: the least the constant can physically be (a delay's 0), or None: a stand-in's gain bounds the
    #: effect only at the values it can take
    at_least: float | None = None


@dataclass
class Probes:
    """The regressors of measurement columns, evaluated at every update of their sensor during a run
    (:func:`.run.run_model`'s ``probes``)."""

    columns: Sequence[Column]
    #: sensor -> per update, per column (as doubles: a long log's run probes millions of values)
    values: dict[str, array[float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.by_sensor: dict[str, list[Column]] = {}
        for c in self.columns:
            if c.sensor is not None and c.regressor is not None:
                self.by_sensor.setdefault(c.sensor, []).append(c)

    @property
    def throttle_tcs(self) -> tuple[float, ...]:
        return tuple(dict.fromkeys(c.throttle_tc for c in self.columns if c.throttle_tc is not None))

    def fresh(self) -> Probes:
        """The same columns, no values: for another run."""
        return Probes(self.columns)

    def detached(self) -> Probes:
        """The values without the columns (whose regressors are closures no pickle carries), to
        cross between processes; :meth:`attached` gives the columns back."""
        return Probes((), self.values)

    def attached(self, columns: Sequence[Column]) -> Probes:
        return Probes(columns, self.values)

    def record(self, sensor: str, ctx: Context, x_prior: np.ndarray) -> None:
        cols = self.by_sensor.get(sensor)
        if cols:
            got = self.values.get(sensor)
            if got is None:
                got = self.values[sensor] = array("d")
            got.extend([c.regressor(ctx, x_prior) for c in cols])  # type: ignore[misc]

    def at(self, sensor: str, width: int) -> np.ndarray:
        """``sensor``'s values, (updates, width)."""
        if not width:
            return np.zeros((0, 0))
        return np.array(self.values.get(sensor, array("d"))).reshape(-1, width)


@dataclass
class Signatures:
    """The columns' signatures through one base run, per innovation record of it (in time order):
    G the innovation's sensitivity (records, P; :meth:`G_of`) and Delta the estimate's after the
    update (records, n, P; :meth:`columns_at`); with the records' own base innovations ``nu`` and
    ``S`` (scalar sensors), times, sensors, and which records tell theta anything (``informs``: a
    sensor's, not a constraint's). ``segment``: the filter's start each record belongs to (a
    restart forgets theta), and ``t_start`` its time. theta is each column's value at that start.

    Delta is kept for the columns asked for (:meth:`keep`), not for all: at a ranking's 71 columns
    it is 0.3 GB on a 1-hour log, and a ranking reads it for each candidate's best shape alone.
    Once a ranking is made, G and Delta of the columns no claim reads are let go of
    (:meth:`forget`). A column asked for afterwards is computed then, by another pass over the tape."""

    columns: list[Column]
    G: np.ndarray  #: the columns' G that are kept, (records, kept), in the order of ``g_index``
    t: np.ndarray
    sensor: np.ndarray
    nu: np.ndarray
    S: np.ndarray
    informs: np.ndarray
    segment: np.ndarray
    t_start: np.ndarray  #: the time its filter started (its segment's)
    #: the pass over the base run's tape: (the columns whose Delta it keeps, with G or not) -> (G, Delta)
    walk: Callable[..., tuple[np.ndarray | None, np.ndarray]]
    #: column -> its Delta, (records, n) float32
    delta: dict[int, np.ndarray] = field(default_factory=dict)
    #: column -> its place in ``G`` (None: every column, in order)
    g_index: dict[int, int] | None = None

    def G_of(self, J: Sequence[int]) -> np.ndarray:
        """G of the columns ``J``, (records, len(J)) (a copy)."""
        if self.g_index is not None and any(int(j) not in self.g_index for j in J):
            G, _ = self.walk([], with_G=True)  # a column let go of: G of every column again
            assert G is not None
            self.G, self.g_index = G, None
        if self.g_index is None:
            return self.G[:, list(J)]
        return self.G[:, [self.g_index[int(j)] for j in J]]

    def keep(self, J: Sequence[int]) -> None:
        """Delta of the columns ``J`` computed (in one pass for all of them) and kept."""
        missing = sorted({int(j) for j in J} - set(self.delta))
        if missing:
            _, D = self.walk(missing, with_G=False)
            for q, j in enumerate(missing):
                self.delta[j] = D[:, :, q]  # (views: the pass's array is held by its columns alone)

    def forget(self, J: Sequence[int]) -> None:
        """G and Delta of every column but ``J`` let go of (a column read after all is computed again)."""
        J = sorted({int(j) for j in J})
        self.G = self.G_of(J)
        self.g_index = {j: q for q, j in enumerate(J)}
        self.delta = {j: d for j, d in self.delta.items() if j in self.g_index}

    def columns_at(self, records: np.ndarray, J: Sequence[int]) -> np.ndarray:
        """Delta of the columns ``J`` at ``records``, (len(records), n, len(J))."""
        self.keep(J)
        return np.stack([self.delta[int(j)][records] for j in J], axis=2)

    def where(self, columns: Sequence[Column]) -> list[int]:
        """The indices of ``columns`` (by identity)."""
        ids = [id(c) for c in self.columns]
        return [ids.index(id(c)) for c in columns]


def signatures(
    tape: GainTape,
    n: int,
    t: np.ndarray,
    sensor: np.ndarray,
    nu: np.ndarray,
    S: np.ndarray,
    informs: np.ndarray,
    probes: Probes | None,
    extra: Sequence[Column] = (),
    delta: Sequence[int] | None = None,
) -> Signatures:
    """Every column's signature along a base run's gains (module docstring). ``t``, ``sensor``,
    ``nu``, ``S``, ``informs``: per innovation record of the run; ``probes``: its measurement columns
    with their values from it; ``extra``: columns read off the run afterwards (``of_time``,
    ``input``); ``delta``: the columns whose Delta is kept from this pass (None: every one)."""
    probed = list(probes.columns) if probes is not None else []
    columns = probed + [c for c in extra if all(c is not p for p in probed)]
    records = len(t)
    # each record's filter start (a restart is a None among the steps)
    segment = np.zeros(records, dtype=int)
    rec_of, seg_of = tape.records()
    segment[rec_of] = seg_of
    t_start = np.asarray(tape.starts or [0.0])[np.minimum(segment, max(len(tape.starts) - 1, 0))]
    walk = _Walk(tape, n, columns, probes, t, sensor, t_start)
    keep = list(range(len(columns))) if delta is None else sorted({int(j) for j in delta})
    G, D = walk(keep, with_G=True)
    assert G is not None
    sig = Signatures(columns, G, t, sensor, nu, S, informs, segment, t_start, walk)
    for q, j in enumerate(keep):
        sig.delta[j] = D[:, :, q]
    return sig


def _measured(
    columns: list[Column], probes: Probes | None, t: np.ndarray, sensor: np.ndarray, t_start: np.ndarray
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The measurement columns by sensor: their indices, and per update of that sensor their values
    (the probed regressors', or of the updates' times)."""
    meas: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    by_sensor: dict[str, list[int]] = {}
    for j, c in enumerate(columns):
        if c.sensor is not None:
            by_sensor.setdefault(c.sensor, []).append(j)
    for s, js in by_sensor.items():
        rows = np.flatnonzero(sensor == s)
        vals = np.zeros((len(rows), len(js)))
        probed_s = [columns.index(c) for c in (probes.by_sensor.get(s, []) if probes is not None else [])]
        got = probes.at(s, len(probed_s)) if probes is not None else np.zeros((0, 0))
        for q, j in enumerate(js):
            c = columns[j]
            if c.of_time is not None:
                vals[:, q] = c.of_time(t[rows], t_start[rows])
            elif j in probed_s and len(got) == len(rows):
                vals[:, q] = got[:, probed_s.index(j)]
            elif j in probed_s:
                raise ValueError(f"column {c.state}: {len(got)} probed values for {len(rows)} updates of {s}")
        meas[s] = (np.array(js), vals)
    return meas


@dataclass
class _Walk:
    """One pass over a base run's tape with every column's Delta (the module docstring's recursion),
    giving G of all columns and Delta of those asked for. Every column is carried along even when
    only some are kept, so a column's numbers are the same whichever pass gives them. The measured
    columns' values are gathered for each pass, not held between them (the probes are the run's)."""

    tape: GainTape
    n: int
    columns: list[Column]
    probes: Probes | None
    t: np.ndarray
    sensor: np.ndarray
    t_start: np.ndarray

    def __call__(self, keep: list[int], *, with_G: bool) -> tuple[np.ndarray | None, np.ndarray]:
        n, P, records = self.n, len(self.columns), len(self.t)
        G_out = np.zeros((records, P)) if with_G else None
        # float32: Delta moves an estimate by Delta theta; its 7 digits put that within 1e-7 of itself,
        # far below any sensor's noise. G, which the likelihoods are summed from, stays float64.
        D_out = np.zeros((records, n, len(keep)), dtype=np.float32)
        every = keep == list(range(P))  # (then stored as it is, not gathered)
        kept = np.asarray(keep, dtype=int)
        inputs = [(j, c.input, c.factor) for j, c in enumerate(self.columns) if c.input is not None]
        meas = _measured(self.columns, self.probes, self.t, self.sensor, self.t_start)
        counts: dict[str, int] = {}
        D = np.zeros((n, P))
        for op in self.tape.steps():
            if op is None:  # the filter started over: nothing of before carries on
                D = np.zeros((n, P))
                continue
            if len(op) == 3:
                Phi, Gu, u = op
                D = Phi @ D
                for j, i, factor in inputs:
                    D[:, j] += Gu[:, i] * factor(u)  # type: ignore[misc]
                continue
            name, H, K, reset, rec = op
            g = H @ D
            cols = meas.get(name)
            if cols is not None:
                k = counts.get(name, 0)
                counts[name] = k + 1
                g[0, cols[0]] += cols[1][k]
            if G_out is not None:
                G_out[rec] = g[0]
            if reset is not None:
                D = D.copy()
                D[list(reset), :] = 0.0
            else:
                D = D - K @ g
            if every:
                D_out[rec] = D
            elif len(kept):
                D_out[rec] = D[:, kept]
        return G_out, D_out


@dataclass
class TwoStage:
    """A candidate's run as the two-stage filter gives it, per innovation record of the base run:
    the augmented filter's innovation ``nu`` and its covariance ``S``; theta's estimate and
    covariance after each record (``theta``, ``Sigma``)."""

    nu: np.ndarray  # (records,)
    S: np.ndarray  # (records,)
    theta: np.ndarray  # (records, p)
    Sigma: np.ndarray  # (records, p, p)


def _cumulative(x: np.ndarray, segment: np.ndarray) -> np.ndarray:
    """Cumulative sums along axis 0 that start over at each new segment."""
    c = np.cumsum(x, axis=0)
    starts = np.flatnonzero(np.diff(segment)) + 1
    if len(starts):
        before = np.zeros_like(c)
        for s in starts:
            before[s:] = c[s - 1]
        c = c - before
    return c


def two_stage(sig: Signatures, J: Sequence[int], prior: np.ndarray, informs: np.ndarray | None = None) -> TwoStage:
    """The augmented filter of the columns ``J`` (priors ``prior``), from the base run's innovations
    (module docstring). ``informs``: the records whose update tells theta something (default: the
    signatures'; a held-out block leaves its own out)."""
    G = sig.G_of(J)
    p = G.shape[1]
    w = np.where(sig.informs if informs is None else informs, 1.0 / sig.S, 0.0)
    Gw = G * w[:, None]
    b_incl = _cumulative(Gw * sig.nu[:, None], sig.segment)
    A_incl = _cumulative(Gw[:, :, None] * G[:, None, :], sig.segment)
    # before each record: the sums of its segment up to the one before it
    first = np.r_[True, np.diff(sig.segment) != 0]
    b_excl = np.where(first[:, None], 0.0, np.vstack([np.zeros((1, p)), b_incl[:-1]]))
    A_excl = np.where(first[:, None, None], 0.0, np.concatenate([np.zeros((1, p, p)), A_incl[:-1]]))
    Pinv = np.diag(1.0 / np.asarray(prior, dtype=float))
    Sig_excl = np.linalg.inv(Pinv[None] + A_excl)
    th_excl = np.einsum("kij,kj->ki", Sig_excl, b_excl)
    nu_a = sig.nu - np.einsum("ki,ki->k", G, th_excl)
    S_a = sig.S + np.einsum("ki,kij,kj->k", G, Sig_excl, G)
    Sig_incl = np.linalg.inv(Pinv[None] + A_incl)
    th_incl = np.einsum("kij,kj->ki", Sig_incl, b_incl)
    return TwoStage(nu_a, S_a, th_incl, Sig_incl)


def fitted_without(sig: Signatures, J: Sequence[int], prior: np.ndarray, informs: np.ndarray) -> np.ndarray:
    """theta fitted on the ``informs`` records of the whole log (its last segment's estimate)."""
    return two_stage(sig, J, prior, informs).theta[-1]


def loglik(nu: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Each scalar update's innovation log-likelihood, -1/2 (nu^2 / S + log(2 pi S))."""
    return -0.5 * (nu * nu / S + np.log(S) + math.log(2 * math.pi))
