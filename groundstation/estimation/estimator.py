"""An estimator: a :class:`~groundstation.estimation.filters.ModelFilter` plus the rules that
route measurements to it (which kinds are inputs, which feed the context,
which are measurement updates), and the handling of time: prediction through
dropouts, re-initialisation on clock jumps. The rules of each model are in
:mod:`groundstation.estimation.routing`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from groundstation.core.measurement import Kind, Measurement
from groundstation.core.validity import reading_problem

from . import still_noise as still
from .context import Context
from .filters import InnovationRecord, ModelFilter
from .models.base import LinearModel

#: The coarsest timestamp of a vehicle's clock (MAVLink's ``time_boot_ms``): a reading stamped up
#: to this much before the filter's time is on time, taken as current (one stamped in milliseconds
#: trails the microsecond-stamped IMU reading of the same instant by up to that much)
TIME_RESOLUTION_S = 1e-3

InputRule = Callable[[Measurement, Context], "np.ndarray | None"]
ContextRule = Callable[[Measurement, Context], None]


@dataclass
class EstimatorCounters:
    updates: int = 0
    predictions: int = 0
    reinitialisations: int = 0
    #: times the filter's state or covariance went non-finite and it started over
    diverged: int = 0
    skipped: dict = field(default_factory=dict)

    def skip(self, why: str) -> None:
        self.skipped[why] = self.skipped.get(why, 0) + 1

    @property
    def rejected(self) -> dict[str, int]:
        """The skips of data: readings not finite or implausible (``accel_not_finite``,
        ``baro_pressure_implausible``), out of order, invalid, or refused by a model with its reason
        (``range_on_ground``, ``range_out_of_bounds``). Not ``*_not_used``: a barometer's calibration
        readings, a pseudo-sensor's constraint that did not apply (``landed`` in flight)."""
        return {k: n for k, n in self.skipped.items() if not k.endswith("_not_used")}


class KalmanEstimator:
    """``handle(m)`` -> the innovation record when ``m`` was a measurement update.

    Clock jumps: a measurement more than ``jump_back`` seconds before the
    filter's time (a reboot, a replay seek) or more than ``max_gap`` after it
    re-initialises the filter at the new time, cleanly and counted. Shorter
    gaps are predicted through (the covariance grows, as it should).
    """

    def __init__(
        self,
        model: LinearModel,
        *,
        inputs: dict[Kind, InputRule],
        context: dict[Kind, ContextRule],
        name: str | None = None,
        jump_back: float = 0.5,
        max_gap: float = 5.0,
        still_noise: bool = False,
    ) -> None:
        self.name = name or model.name
        self.model = model
        self.filter = ModelFilter(model)
        self.inputs = inputs
        self.context = context
        self.jump_back = jump_back
        self.max_gap = max_gap
        self.counters = EstimatorCounters()
        self.started = False
        self._by_kind: dict[Kind, list] = {}
        for mm in model.measurements.values():
            self._by_kind.setdefault(mm.kind, []).append(mm)
        # kinds that only carry constraints on the state as it is (MeasurementModel.untimed): they
        # leave the filter's clock alone, unless the kind is an input as well
        self._untimed = {k for k, mms in self._by_kind.items() if k not in inputs and all(mm.untimed for mm in mms)}
        #: the kinds whose noise is read from the still stretch before the first take-off (:mod:`.still_noise`)
        self.still_kinds = frozenset(still.HEIGHT_OF) & set(self._by_kind) if still_noise else frozenset()

    @property
    def kinds(self) -> set[Kind]:
        return set(self.inputs) | set(self.context) | set(self._by_kind) | set(self.model.impulses)

    def checkpoint(self) -> tuple:
        """Everything a rollback needs, before the first measurement too (a late one there was
        dropped: the outputs stamped just before the attitude that started the filter)."""
        return self.started, self.filter.checkpoint()

    def restore(self, cp: tuple) -> None:
        self.started, f = cp
        self.filter.restore(f)

    @property
    def t(self) -> float:
        return self.filter.t

    @property
    def still_noise_note(self) -> str:
        """What the still stretch before take-off said of the sensors' noise (:func:`.still_noise.note`)."""
        R_of = {k: self._by_kind[k][0].R for k in self.still_kinds}
        return still.note(self.still_kinds, R_of, self.filter.ctx)

    def _time(self, t: float) -> bool:
        f = self.filter
        if not self.started:
            f.reset(t)
            self.started = True
            return True
        if t < f.t - self.jump_back or t > f.t + self.max_gap:
            self.counters.reinitialisations += 1
            f.reset(t)  # the context (calibrations, tilt, throttle) carries over: same vehicle, same sensors
            return True
        return t >= f.t

    def handle(
        self, m: Measurement, *, checked: bool = False, singular_raises: bool = False
    ) -> InnovationRecord | None:
        """The reading through its context rule, input or measurement update; its innovation when
        it updated the filter. ``checked``: it passed ``core.validity`` already (a prepared log run
        many times over); else it is checked here, and a bad one counted and skipped.

        A filter run away (a non-finite estimate, or an update whose innovation covariance is
        singular: garbage that passed its CRC grows P past what a double holds) starts over, counted
        as a divergence; ``singular_raises``: the singular update raises ``LinAlgError`` instead (a
        diagnosis' trial, whose run then ends as a model that cannot describe the log)."""
        k = m.kind
        if k not in self.context and k not in self.inputs and k not in self._by_kind:
            return None
        if not checked:
            bad = reading_problem(m)
            if bad is not None:
                # every component checked: one NaN in a vector reading poisoned the filter for good
                self.counters.skip(f"{m.kind.value}_{bad}")
                return None
        f = self.filter
        if self.started and f.t - TIME_RESOLUTION_S <= m.t < f.t:
            # on time: taken as current, for every rule too (a hysteresis timed on it must not
            # see time run back: the ground contact, entered at an ATTITUDE, left at the outputs
            # stamped a fraction of a microsecond before it)
            m = m._replace(t=f.t)
        try:
            rec = self._handle(m)
        except np.linalg.LinAlgError:
            if singular_raises:
                raise
            self._start_over(m.t)
            return None
        if k not in self.inputs and k not in self._by_kind:
            return None  # a context rule (and an impulse on P): the state was not touched
        # the sums propagate any NaN or infinity; P only where an update touched it (summed as floats:
        # numpy's sum of a few elements costs ten times the addition, at every reading of a run)
        kf = f.kf
        if not math.isfinite(sum(kf.x.tolist())) or (rec is not None and not math.isfinite(sum(kf.P.ravel().tolist()))):
            # whatever got it there (a model's own arithmetic), the estimate is no estimate
            self._start_over(m.t)
            return None
        return rec

    def _start_over(self, t: float) -> None:
        """A diverged filter started over at ``t`` (counted)."""
        self.counters.diverged += 1
        self.started = False
        self.filter.reset(t)

    def _handle(self, m: Measurement) -> InnovationRecord | None:
        f = self.filter
        ctx = f.ctx
        kind = m.kind
        ctx.t = m.t
        rule = self.context.get(kind)
        if rule is not None:
            ctx.x = f.kf.x
            ctx.u = f.u
            rule(m, ctx)
        impulses = self.model.impulses
        if impulses:
            for impulse in impulses.get(kind, ()):
                added = impulse(m, ctx)
                if added and self.started:
                    f.add_variance({self.model.index(s): q for s, q in added.items()})
        inp = self.inputs.get(kind)
        mms = self._by_kind.get(kind)
        if inp is None and not mms:
            return None
        if kind in self._untimed:
            return self._update(m, mms or ()) if self.started else None
        if not self._time(m.t):
            self.counters.skip("out_of_order")
            return None
        f.predict_to(m.t)
        self.counters.predictions += 1
        if inp is not None:
            u = inp(m, ctx)
            if u is not None:
                f.u = u
        return self._update(m, mms) if mms else None

    def _update(self, m: Measurement, mms: Sequence) -> InnovationRecord | None:
        f = self.filter
        ctx = f.ctx
        rec = None
        if m.kind in self.still_kinds:
            still.see(m, ctx)
        for mm in mms:
            if mm.instance is not None and m.instance != mm.instance:
                continue
            ctx.z = float(f.kf.x[0])
            z = mm.extract(m, ctx)
            why, ctx.skip_why = ctx.skip_why, None  # an extract's own reason (models.range_gate)
            if z is None:
                self.counters.skip(f"{mm.name}_{why or 'not_used'}")  # calibrating, out of range
                continue
            if not all(map(math.isfinite, (z if isinstance(z, np.ndarray) else np.asarray(z)).ravel().tolist())):
                self.counters.skip(f"{mm.name}_invalid")
                continue
            R = still.still_R(m.kind, mm.R, ctx) if m.kind in self.still_kinds else None
            if mm.per_sample and m.samples > 1:
                R = (mm.R if R is None else R) / m.samples
            rec = f.update(mm, z, R=R)
            self.counters.updates += 1
        return rec
