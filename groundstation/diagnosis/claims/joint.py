"""After the search: the effects it added, estimated again together. Each was sized when it was
added, with the effects found before it; the final model holds them all, and the effects added
later can move an earlier one's parameters and its shape."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from groundstation.core.measurement import Measurement
from groundstation.diagnosis.catalogue.candidate import Candidate
from groundstation.diagnosis.effect import Effect
from groundstation.diagnosis.runs.run import Prepared, Run, run_model
from groundstation.diagnosis.scoring import trials
from groundstation.diagnosis.scoring.gains import WASH_GRID, profile_shape
from groundstation.diagnosis.scoring.trace import with_shape
from groundstation.diagnosis.scoring.trials import log_profile
from groundstation.estimation.models.base import LinearModel


def model_of(model0: LinearModel, added: Sequence[Candidate]) -> LinearModel:
    """``model0`` with the effects of ``added`` that are states added to it, in their order."""
    m = model0
    for c in added:
        if c.augment is not None:
            m = c.augment(m)
    return m


def joint_params(effects: list[Effect], added: list[Candidate], final: Run) -> None:
    """An effect estimated as states is reported as the final model estimates it, jointly with every
    effect added after it; its value when it was added goes to the evidence. Read when it was added,
    a thrust_voltage n = 1.5 found before a 0.1 s actuator lag read 1.36 (simulated thrust test flight,
    seed 1101); a profiled one (a delay, a lag: a grid of runs) keeps its profile's value."""
    for e, c in zip(effects, added):
        if c.augment is None or c.params is None or c.delays:
            continue
        joint = {**e.params, **c.params(final)}  # a chosen shape (a fall-off height) stays
        if joint != e.params:
            e.evidence.setdefault("params_when_added", e.params)
            e.params = joint


#: the factor either side of a shape chosen alone that :func:`joint_shapes` starts its profile at
JOINT_SHAPE_STEP = 1.5
#: a shape chosen again within this much of its log (2 %) is the same shape: the model is not run again
SAME_SHAPE = 0.02


def joint_shapes(
    model0: LinearModel,
    effects: list[Effect],
    added: list[Candidate],
    prep: Prepared,
    make,
    stream: Sequence[Measurement],
    model: LinearModel,
    base: Run,
) -> tuple[LinearModel, Run]:
    """A continuous shape (the rotor wash's time constant) chosen again with every effect found after it in the model,
    by its profile likelihood (:func:`~groundstation.diagnosis.scoring.trials.log_profile`, from the value chosen alone
    and a factor 1.5 either side). Chosen alone, the wash of a flight whose baro also read its temperature took 0.28 s
    for its true 0.39 s (the thermal error's share in what the wash explained), and the fix left 1.7 times the error of
    the true model; with the thermal term in the model the profile peaks at 0.36 s. ``model0``: the model the effects
    were added to, in the order of ``added``; returns the final model and its run, as they were when nothing moved."""
    for j, c in enumerate(added[:-1]):
        if c.unshaped is None:
            continue
        unshaped, e = c.unshaped, effects[j]

        def build(shape: float | None, j=j, c=c, unshaped=unshaped) -> LinearModel:
            """The final model with the shaped effect at ``shape`` (None: without it)."""
            at = replace(c, augment=None if shape is None else with_shape(unshaped, shape))
            return model_of(model0, [*added[:j], at, *added[j + 1 :]])

        s0 = float(e.params[c.shape_name])
        if c.columns is not None and not trials.BY_RUNS:
            # the others as they are, the shape profiled through their run's gains (gains.profile_shape)
            shape = profile_shape(c, build(None), prep, make, stream)
            if shape is None or abs(math.log(shape / s0)) < SAME_SHAPE:
                continue
            e.evidence["params_when_added"] = dict(e.params)
            e.params[c.shape_name] = shape
            added[j] = replace(c, augment=with_shape(unshaped, shape))
            model = build(shape)
            base = run_model(model, prep, make, measurements=stream, taped=True)
            continue

        def run_at(shape: float, build=build) -> Run | None:
            try:
                return run_model(build(shape), prep, make, measurements=stream)
            except np.linalg.LinAlgError:  # the filter ran away at that shape
                return None

        shapes = (s0 / JOINT_SHAPE_STEP, s0, s0 * JOINT_SHAPE_STEP)
        shape, r = log_profile(run_at, shapes, known={s0: base}, most=WASH_GRID[-1])
        if r is None or shape == s0:
            continue
        e.evidence["params_when_added"] = dict(e.params)
        e.params[c.shape_name] = shape
        added[j] = replace(c, augment=with_shape(unshaped, shape))
        model, base = build(shape), r
    return model, base
