"""The filter's inner steps compiled: the discretisation's series, a scalar and a vector reading's
update, and the state's step.

A diagnosis runs its model over a log a hundred times and more, and in each run nearly half the time
went to two small steps: the fourth-order series of a step's (Phi, G, Q_k) where A moves with the
input (a thrust model's A with every throttle record), and the Joseph-form update of a scalar
reading (a baro, a range). Each is a few dozen 6x6 products, where numpy's cost is its call, not
its arithmetic. So is the state's step x <- Phi x + G u at every IMU sample: two products and a
sum, 3.4 us in numpy and 1.6 us compiled, most of either the call; and so is a vector reading's
update (the 3-DOF rig's gyro and accelerometer) with its S^-1: 31 us an update through numpy's
inverse, 6 us as loops with a Gauss-Jordan inverse. numba compiles the four to
loops (:mod:`.kernels_numba`; ``cache=True``: once a machine, in ``__pycache__``): a diagnosis of
the thrust model on a 7-minute DataFlash log takes 131 s where the numpy forms take 181 s, with
the same findings.

The numpy forms stay the reference: :func:`groundstation.estimation.models.base.discretize_series`,
``ModelFilter._update_written_out``'s (scalar and vector) and ``ModelFilter.predict_to``'s.
``GROUNDSTATION_KERNELS=python``, or numba missing, runs them alone, and ``tests/test_kernels.py``
holds the compiled ones to them. numba is imported, and the kernels loaded from its cache, when
the first filter is made (:func:`ready`), never by a command that makes none (``groundstation
--help`` stays quick).
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable

import numpy as np

#: the kernels, compiled at first use; None: the numpy reference (numba missing or not wanted)
_compiled: tuple[Callable, Callable, Callable, Callable] | None | bool = False


def compiled() -> tuple[Callable, Callable, Callable, Callable] | None:
    """(discretized_step, scalar_update, state_step, vector_update) compiled (:mod:`.kernels_numba`),
    or None where the numpy reference runs."""
    global _compiled
    if _compiled is False:
        _compiled = None if os.environ.get("GROUNDSTATION_KERNELS") == "python" else _compile()
    return _compiled  # type: ignore[return-value]


def ready() -> None:
    """The kernels loaded now, once a process (a filter being made calls it). numba loads a kernel's
    machine code from its cache at the kernel's first call, about a tenth of a second each: taken at
    a live filter's first reading, the 3-DOF rig's estimate stalled the event loop for 0.34 s right
    after arming, longer than the 0.3 s after which a silent board link is lost, and the commander
    disarmed."""
    global _ready
    if not _ready:
        _ready = True
        warm()


_ready = False


def warm() -> None:
    """Compile the kernels now, into numba's cache (``make setup``: not at a diagnosis' first step),
    or load them from it."""
    k = compiled()
    if k is not None:
        for n in (3, 6):
            k[0](np.eye(n), np.ones((n, 1)), np.eye(n), 0.01, True, 0.2, 6)
            k[1](np.zeros(n), np.eye(n), np.ones((1, n)), 1.0, 0.0)
            k[2](np.eye(n), np.ones((n, 1)), np.zeros(n), np.zeros(1))
            k[3](np.zeros(n), np.eye(n), np.ones((2, n)), np.eye(2), np.zeros(2))


def _compile() -> tuple[Callable, Callable, Callable, Callable] | None:
    try:  # imported here, not above: numba takes half a second to import
        k = importlib.import_module(f"{__package__}.kernels_numba")
    except ImportError:
        return None
    return k.discretized_step, k.scalar_update, k.state_step, k.vector_update
