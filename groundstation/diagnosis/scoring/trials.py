"""A candidate's filter runs ("trials"), and the cores they run on.

Scoring a candidate of the catalogue costs full filter runs over the log: one per shape the
likelihood chooses among (a ground effect's fall-off height), one per delay of its grid and of
the grid's refinement, and for an effect on the input one more with the effect acting at a small
size (its signature). Trials of one ranking do not depend on one another (a profile's refinement
only on its own grid's), so :class:`Trials` runs them on every core it is given: a pool of
forked processes that inherit the log, the model and the candidates (closures, which no pickle
carries), each sending back its :class:`.Run` without the model (rebuilt here, it is cheap) and
with the estimator's final context only. With one worker everything runs here, in order. Either
way each trial's run is the same, number for number: the ranking does not depend on the cores.

Forking is safe where nothing else runs threads of its own (the command line): the library's
default is one worker, and the command line asks for more.
"""

from __future__ import annotations

import math
import multiprocessing
import os
from collections.abc import Callable, Hashable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from typing import TypeVar

import numpy as np
from threadpoolctl import threadpool_limits

from groundstation.core.measurement import Measurement
from groundstation.diagnosis.catalogue.altitude import delayed_kinds, shift
from groundstation.diagnosis.catalogue.candidate import Candidate
from groundstation.diagnosis.runs.run import Prepared, Run, ending, run_model
from groundstation.estimation.models.base import LinearModel

T = TypeVar("T")
R = TypeVar("R")

#: every candidate scored by filter runs of its own, every grid value and every refinement run (no
#: two-stage filter through the base run's gains, no :func:`scan_grid` stop, no :func:`refine`
#: gate): the path ``bench/diagnosis_speed.py`` measures the diagnosis against, and the tests
#: compare its findings with. GROUNDSTATION_TRACE=runs in the environment
BY_RUNS = os.environ.get("GROUNDSTATION_TRACE") == "runs"

#: the key of an input effect's signature trial (the effect acting at :data:`SIGNATURE_SIZE`)
SIGNATURE = "signature"
#: the size an input effect is made to act at for its signature (the filter is linear in it: any small one)
SIGNATURE_SIZE = 0.01


def first_keys(cand: Candidate) -> list[Hashable]:
    """The trials a candidate needs whatever its runs show: its grid or its shapes (``None``: its
    one augmented model), and its signature."""
    keys: list[Hashable] = []
    if cand.delays:
        keys += [round(float(d), 4) for d in cand.delays]
    elif cand.augment is not None:
        keys += list(cand.shapes or (None,))
    if cand.perturb is not None:
        keys.append(SIGNATURE)
    return keys


def delayed(cand: Candidate, ms: Sequence[Measurement], d: float) -> Sequence[Measurement]:
    """The stream a grid candidate is run on at grid value ``d``: its sensor's readings taken as of
    ``t - d``, or the candidate's own reshaping (an actuator lag)."""
    if cand.reshape:
        return cand.reshape(ms, d)
    return shift(ms, delayed_kinds(cand), d)


def trial_model(cand: Candidate, key: Hashable, model: LinearModel) -> LinearModel:
    """The model a trial runs: the base model for a delay and the signature, else the augmented one."""
    if key == SIGNATURE or cand.delays or cand.augment is None:
        return model
    return cand.augment(model) if key is None else cand.augment(model, key)


def trial(
    cand: Candidate, key: Hashable, model: LinearModel, prep: Prepared, make, ms, scores_only: bool = False
) -> Run | None:
    """One trial's run; None when the augmented filter ran away (its innovation covariance went
    singular): not a finding, and not the end of the diagnosis. Not taped: of a ranking's dozen
    trials only an added effect's run starts the next ranking, and it is taped then (the same run,
    number for number: the tape only records); a trial's gains and probes are some 40 MB on a 1-hour log.
    ``scores_only``: without its covariances and signals as well (``run_model``'s), where the added
    effect's run is made again with the probes (a linear model's: ``search.Search._take``)."""
    if key == SIGNATURE:
        assert cand.perturb is not None
        return run_model(model, prep, make, measurements=cand.perturb(ms, SIGNATURE_SIZE), scores_only=scores_only)
    if cand.delays:
        d = float(key)  # type: ignore[arg-type]
        return run_model(model, prep, make, measurements=delayed(cand, ms, d), scores_only=scores_only)
    try:
        return run_model(trial_model(cand, key, model), prep, make, measurements=ms, scores_only=scores_only)
    except np.linalg.LinAlgError:
        return None


#: the function the pool being forked maps (its workers inherit it: closures travel no other way)
_WORK: Callable | None = None


def _call(item):
    assert _WORK is not None, "a pool's worker runs only what it was forked with"
    return _WORK(item)


def fork_map(fn: Callable[[T], R], items: Iterable[T], workers: int) -> list[R]:
    """``[fn(x) for x in items]`` on up to ``workers`` forked processes (here, with one); ``fn``
    may be a closure over anything, its results must pickle (a :class:`.Run` through
    :func:`portable`)."""
    items = list(items)
    n = min(workers, len(items))
    if n <= 1:
        return [fn(x) for x in items]
    global _WORK
    _WORK = fn
    try:
        # a fork pool starts all its workers at the first task, within this block: all inherit fn,
        # and one BLAS thread. OpenBLAS's pool does not survive a fork: in the children every call
        # on the filters' 5x5 matrices paid for it, and a run took 4-18 s instead of 1.2 s (the
        # 23-minute dronekit tlog)
        with (
            threadpool_limits(limits=1, user_api="blas"),
            ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("fork")) as pool,
        ):
            return list(pool.map(_call, items))
    finally:
        _WORK = None


def portable(r: Run | None) -> Run | None:
    """An untaped run as it can travel between processes: without its model (closures; the receiver
    gives it back, :meth:`Trials.attach`)."""
    if r is None:
        return None
    assert r.taped is None, "a taped run's probes hold closures: trials run untaped"
    return replace(r, model=None)  # type: ignore[arg-type]


def refine(
    cand: Candidate, lik: dict[float, float], run: Callable[[float], Run | None], runs: dict, floor: float = -math.inf
) -> None:
    """A grid candidate's profile refined (:func:`profile_steps`) from its grid's
    log-likelihoods ``lik``; the new runs go to ``runs`` and their likelihoods to ``lik``. Not
    refined where even the parabola through its best grid value and their neighbours peaks below
    ``floor`` (:func:`parabola_peak`): a profile that no refinement brings near a claim."""
    if not BY_RUNS and parabola_peak(lik) < floor:
        return

    def at(d: float) -> float:
        d = round(float(d), 4)
        if d not in lik:
            r = run(d)
            assert r is not None  # a delayed stream does not change the model
            runs[d], lik[d] = r, r.loglik
        return lik[d]

    profile_steps(at, lik)


def scan_grid(grid: Iterable[float], at: Callable[[float], float], drop: float) -> dict[float, float]:
    """A grid's profile likelihood (value -> log-likelihood, ``at(v)`` one run), scanned upwards and
    stopped where it has fallen at :data:`SCAN_DECLINES` grid values in a row and lies ``drop`` (the
    candidate's BIC penalty) below its best: past a clear decline a profile does not come back, and
    the values beyond it are neither its best nor the best's neighbours, which are all that its
    refinement, its standard error and its held-out check read. On a flight without a delay
    the range's profile scores 0, -405 and -1606 at 0, 0.04 and 0.08 s, and the three runs beyond
    them are not made."""
    lik: dict[float, float] = {}
    falls = 0
    for v in grid:
        v = round(float(v), 4)
        prev = lik[max(lik)] if lik else -math.inf
        lik[v] = at(v)
        falls = falls + 1 if lik[v] < prev else 0
        if not BY_RUNS and falls >= SCAN_DECLINES and lik[v] < max(lik.values()) - drop:
            break
    return lik


#: grid values in a row at which a profile falls before its scan stops (:func:`scan_grid`)
SCAN_DECLINES = 2


def parabola_peak(lik: dict[float, float]) -> float:
    """The highest log-likelihood a profile sampled at ``lik`` (value -> log-likelihood) promises:
    the vertex of the parabola through its best value and their neighbours where that lies
    between them, else the best value itself. On the standard flight a range delay of 0.015 s
    scores 0, -108 and -988 at the grid's 0, 0.04 and 0.08 s; the parabola's vertex, at 0.0144 s,
    promises +50 (the likelihood has +47 at 0.01 s)."""
    xs = sorted(lik)
    best = max(lik.values())
    if len(xs) < 3:
        return best
    i = max(range(len(xs)), key=lambda j: lik[xs[j]])
    x = np.array(xs[min(max(i - 1, 0), len(xs) - 3) :][:3])
    a, b, c = np.polyfit(x - x[1], [lik[v] for v in x], 2)
    if a >= 0 or not x[0] < x[1] - b / (2 * a) < x[2]:
        return best
    return max(best, float(c - b * b / (4 * a)))


#: parabolic steps the profile over a delay takes after its grid
PROFILE_STEPS = 3


def profile_steps(at: Callable[[float], float], lik: dict[float, float]) -> None:
    """Refine a profile likelihood sampled on a grid (``lik``: value -> log-likelihood, ``at(v)``
    adds one): up to PROFILE_STEPS times, the vertex of the parabola through the best point and its
    neighbours. At the grid's first point (no delay) the parabola through the first three points,
    or, when its vertex lies below the first, once a point a quarter of the way to the second: a range
    delay of 0.015 s was else never located, the grid's 0 being closer than its 0.04 (on the
    standard flight 0.02 s scores Delta BIC -205), and the curvature there, which
    :func:`profile_sigma` reads, was the grid's, not the likelihood's near zero."""
    closer = False
    for _ in range(PROFILE_STEPS):
        ds = sorted(lik)
        if len(ds) < 3:
            return
        i = max(range(len(ds)), key=lambda j: lik[ds[j]])
        if i == len(ds) - 1:
            return
        x0, x1, x2 = ds[max(i - 1, 0) : max(i - 1, 0) + 3]
        y0, y1, y2 = (lik[x] for x in (x0, x1, x2))
        den = (x1 - x0) * (y1 - y2) - (x1 - x2) * (y1 - y0)
        v = x1 - 0.5 * ((x1 - x0) ** 2 * (y1 - y2) - (x1 - x2) ** 2 * (y1 - y0)) / den if den != 0 else math.nan
        lo, hi = (x0, x2) if i > 0 else (x0, x1)
        if not lo < v < hi:
            if i > 0 or closer:
                return
            v, closer = x0 + 0.25 * (x1 - x0), True  # the edge: look closer to it, once
        if round(float(v), 4) in lik:
            return
        at(v)


#: the steps a log profile is carried beyond its shapes while the likelihood still rises there
LOG_PROFILE_EXTEND = 2


def log_profile(
    run_at: Callable[[float], Run | None],
    shapes: Iterable[float],
    known: dict[float, Run] | None = None,
    most: float = math.inf,
) -> tuple[float, Run | None]:
    """A continuous shape's best value (a time constant) and its run: the profile likelihood over the
    shape's logarithm, sampled at ``shapes``, carried outward while the best is at an end (up to
    :data:`LOG_PROFILE_EXTEND` steps of the end's spacing, and not past ``most``, the longest the
    effect's physics has: the two-stage filter's grid ends there too, gains.WASH_GRID), and refined by
    :func:`profile_steps`. ``run_at(shape)`` runs the model at a shape (None: its filter diverged, the
    worst there is); ``known``: runs already made, by shape."""
    known = known or {}
    shape_of: dict[float, float] = {}
    runs: dict[float, Run | None] = {}  # of the best likelihood so far only: that is the run returned
    lik: dict[float, float] = {}

    def at(v: float) -> float:
        v = round(float(v), 4)
        if v not in lik:
            shape = shape_of.setdefault(v, round(math.exp(v), 4))
            r = known[shape] if shape in known else run_at(shape)
            runs[v], lik[v] = r, (r.loglik if r is not None else -math.inf)
            top = max(lik.values())
            for u in [u for u in runs if lik[u] < top]:
                del runs[u]
        return lik[v]

    top = math.log(most)
    shapes = list(shapes)
    inside = [s for s in shapes if s <= most] or [min(shapes)]
    for s in inside:
        shape_of[round(math.log(s), 4)] = s
        at(math.log(s))
    for _ in range(LOG_PROFILE_EXTEND):
        vs = sorted(lik)
        best = max(vs, key=lambda x: lik[x])
        if len(vs) < 2 or vs[0] < best < vs[-1]:
            break
        step = vs[-1] - vs[-2] if best == vs[-1] else vs[0] - vs[1]
        v = min(best + step, top)
        if round(float(v), 4) in lik:
            break
        if v == top:
            shape_of.setdefault(round(top, 4), most)  # the bound itself, not its logarithm's rounding
        at(v)
    profile_steps(at, lik)
    v = max(lik, key=lambda x: lik[x])
    return shape_of[v], runs[v]


class Trials:
    """One ranking's trials: ``runs[i][key]`` the run of candidate ``i`` at ``key``
    (:func:`first_keys`), computed on ``workers`` processes (one: here). ``base``: the model's own
    run on ``ms``, which is every grid candidate's trial at zero (no delay, no lag: the same stream
    and the same model), so that trial is not run again."""

    def __init__(
        self,
        cands: list[Candidate],
        model: LinearModel,
        prep: Prepared,
        make,
        ms: Sequence[Measurement],
        *,
        workers: int = 1,
        base: Run | None = None,
        scores_only: bool = False,
    ) -> None:
        self.cands, self.model, self.prep, self.make, self.ms = cands, model, prep, make, ms
        self.workers = max(1, workers)
        self.scores_only = scores_only  #: the trials run for their scores alone (:func:`trial`)
        self.base = base
        self.runs: list[dict[Hashable, Run | None]] = [
            {0.0: base} if base is not None and 0.0 in c.delays else {} for c in cands
        ]

    def floor(self, i: int) -> float:
        """The log-likelihood a refinement of candidate ``i``'s grid must promise to be run
        (:func:`refine`): a quarter of the way from the base run to a Delta BIC of 0, k ln(n) / 4
        above it. Every grid value worth its parameters promises more than that."""
        if self.base is None:
            return -math.inf
        return self.base.loglik + self.cands[i].k * math.log(max(self.base.n_scored, 1)) / 4.0

    def run(self, i: int, key: Hashable) -> Run | None:
        """Candidate ``i``'s run at ``key``: computed once, here when no pool computed it before."""
        runs = self.runs[i]
        if key not in runs:
            runs[key] = trial(self.cands[i], key, self.model, self.prep, self.make, self.ms, self.scores_only)
            self._ended_below_best(i)
        return runs[key]

    def _ended_below_best(self, i: int) -> None:
        """Candidate ``i``'s runs that score below its best so far, as their scores and where they ended
        (:func:`~groundstation.diagnosis.runs.run.ending`): its score is its best run's, and of the others only the
        likelihoods (a shape's profile) and the innovations (a delay's, held out block by block, holdout.py) are read. A
        run once below the best never becomes it; a tie stays whole. A shape refined in log steps takes some nine runs,
        15-20 MB each on a 1-hour log."""
        runs = self.runs[i]
        top = max((r.loglik for k, r in runs.items() if k != SIGNATURE and r is not None), default=None)
        if top is None:
            return
        for k, r in runs.items():
            if k != SIGNATURE and r is not None and r.loglik < top and len(r.x) > 1:
                runs[k] = ending(r)

    def pending(self) -> int:
        """The first trials not made yet (begun elsewhere, :class:`Started`, or the base run's zero)."""
        return sum(k not in self.runs[i] for i, c in enumerate(self.cands) for k in first_keys(c))

    def compute_all(self) -> None:
        """Every candidate's first trials and its grid's refinement, on the pool (nothing with one
        worker: :meth:`run` computes each when asked)."""
        if self.workers == 1:
            return
        tasks = [(i, k) for i, c in enumerate(self.cands) for k in first_keys(c) if k not in self.runs[i]]
        for (i, key), r in zip(tasks, fork_map(self._portable_trial, tasks, self.workers)):
            self.runs[i][key] = self.attach(i, key, r)
        grids = [
            (i, {d: r.loglik for d, r in self.runs[i].items() if isinstance(d, float) and r is not None})
            for i, c in enumerate(self.cands)
            if c.delays
        ]
        for (i, _), new in zip(grids, fork_map(self._portable_refinement, grids, self.workers)):
            for d, r in new.items():
                self.runs[i][d] = self.attach(i, d, r)
        for i in range(len(self.cands)):
            self._ended_below_best(i)

    def _portable_trial(self, task: tuple[int, Hashable]) -> Run | None:
        i, key = task
        return portable(trial(self.cands[i], key, self.model, self.prep, self.make, self.ms, self.scores_only))

    def _portable_refinement(self, grid: tuple[int, dict[float, float]]) -> dict[float, Run | None]:
        i, lik = grid
        runs: dict[float, Run | None] = {}
        refine(self.cands[i], dict(lik), lambda d: self.run(i, d), runs, self.floor(i))
        return {d: portable(r) for d, r in runs.items()}

    def attach(self, i: int, key: Hashable, r: Run | None) -> Run | None:
        """A run that travelled (:func:`portable`) as candidate ``i``'s at ``key``, whole again."""
        if r is None:
            return None
        return replace(r, model=trial_model(self.cands[i], key, self.model))

    def settle(self, i: int, keep: Iterable[Run]) -> None:
        """Candidate ``i`` scored (its support too, which its signature gives): its runs let go of,
        but ``keep`` (what its score holds)."""
        held = {id(r) for r in keep}
        self.runs[i] = {k: r for k, r in self.runs[i].items() if id(r) in held}


class Started:
    """First trials begun on forked processes, one each, before the ranking that may ask for them.
    A candidate without columns of its own (a changed measurement function: the range read along
    the tilt) is run whenever its screen through the base run's gains could be claimed, and its one
    trial needs only the model: begun beside the base run on a spare core, it is ready when the
    ranking asks (:meth:`take`) instead of starting then; one the ranking does not ask for is
    stopped. The runs are the ranking's own, number for number (:func:`portable`, attached by
    :class:`Trials`)."""

    def __init__(
        self,
        tasks: list[tuple[Candidate, Hashable]],
        model: LinearModel,
        prep: Prepared,
        make,
        ms: Sequence[Measurement],
    ) -> None:
        self._tasks = tasks
        # begun only beside a linear model's base run, whose added effect is run again with the probes
        self._trials = Trials([c for c, _ in tasks], model, prep, make, ms, scores_only=True)
        self._running: dict[int, tuple] = {}  # task -> (process, its pipe's reading end)
        ctx = multiprocessing.get_context("fork")
        with threadpool_limits(limits=1, user_api="blas"):  # as fork_map: one BLAS thread in the children
            for n, (_, key) in enumerate(tasks):
                recv, send = ctx.Pipe(duplex=False)
                proc = ctx.Process(target=self._work, args=(n, key, send), daemon=True)
                proc.start()
                send.close()
                self._running[n] = (proc, recv)

    def _work(self, n: int, key: Hashable, send) -> None:
        """In the child: the task's run, sent back (or the error that stopped it)."""
        try:
            out: object = self._trials._portable_trial((n, key))
        except BaseException as e:  # noqa: BLE001 -- carried to the parent, raised there
            out = e
        send.send(out)
        send.close()

    def take(self, cands: list[Candidate]) -> dict[int, dict[Hashable, Run | None]]:
        """The runs of those of ``cands`` begun here, by ``id(candidate)`` and key, travelled as
        they are (:func:`portable`); the trials no candidate of ``cands`` needs are stopped first."""
        wanted = {id(c) for c in cands}
        for n, (c, _) in enumerate(self._tasks):
            if id(c) not in wanted and n in self._running:
                self._stop(n)
        out: dict[int, dict[Hashable, Run | None]] = {}
        for n in list(self._running):
            c, key = self._tasks[n]
            proc, recv = self._running.pop(n)
            try:
                got = recv.recv()
            except EOFError:
                raise RuntimeError(f"the forked trial of {c.name} ended without its run") from None
            finally:
                recv.close()
                proc.join()
            if isinstance(got, BaseException):
                self.close()
                raise got
            out.setdefault(id(c), {})[key] = got
        return out

    def _stop(self, n: int) -> None:
        proc, recv = self._running.pop(n)
        if proc.is_alive():
            proc.terminate()
        proc.join()
        recv.close()

    def close(self) -> None:
        """Stop whatever still runs (the ranking did not ask, or an error came first)."""
        for n in list(self._running):
            self._stop(n)
