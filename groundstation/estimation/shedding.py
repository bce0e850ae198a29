"""Load shedding for live estimation: decimate the high-rate sensors, never queue or drop.

A live link can deliver more readings than the estimators can process (a
1 kHz IMU on a slow machine, a burst after a stall). Queueing them puts the
estimate seconds behind the vehicle; dropping datagrams loses them for the
recording too. Instead each batch is decimated by a factor ``k``, sensor by
sensor (source, kind, instance):

* oversampled physical quantities (:data:`MEANS`: the IMU, the barometer) are
  block-averaged, as their drivers do when they oversample;
* state-like signals (:data:`THINNED`: an attitude, the outputs, a range) keep
  one reading in ``k`` (a block mean of a heading across +-pi, or of a range
  across an edge, is no reading);
* everything else (status, battery, GPS, truth) passes untouched.

:class:`LoadShedder` chooses ``k`` per batch.
"""

from __future__ import annotations

import math

import numpy as np

from groundstation.core.measurement import Kind, Measurement

#: Kinds whose readings are averaged in blocks under load.
MEANS = frozenset({Kind.ACCEL, Kind.GYRO, Kind.MAG, Kind.BARO_PRESSURE, Kind.DIFF_PRESSURE, Kind.TEMPERATURE})
#: Kinds of which one reading in k is kept under load (a later reading supersedes an earlier one).
THINNED = frozenset(
    {
        Kind.RANGE,
        Kind.ATTITUDE,
        Kind.ATTITUDE_QUATERNION,
        Kind.ANGULAR_RATE,
        Kind.ACTUATOR,
        Kind.THROTTLE,
        Kind.RC_INPUT,
        Kind.ALTITUDE,
        Kind.CLIMB_RATE,
        Kind.AIRSPEED,
        Kind.POSITION_NED,
        Kind.VELOCITY_NED,
        Kind.GPS_VD,
        Kind.BARO_ALTITUDE,
        Kind.ENCODERS,
        Kind.MOTOR_VOLTAGE,
    }
)


def decimate(ms: list[Measurement], k: int) -> tuple[list[Measurement], int]:
    """``ms`` with each sensor's readings decimated by ``k`` (see the module); returns the list, in
    the same order, and how many readings were merged or left out.

    A block of :data:`MEANS` readings becomes one at its *first* member's time and place, holding
    the mean of its values with ``samples`` summed: an input (the accelerometer) is then held,
    zero-order, at the block's mean over exactly the interval the block covered, and a measurement
    update weighs it as that many readings (``R / samples``). A block whose mean is not finite
    goes through reading by reading, for the estimator to reject and count the bad one.
    """
    out: list = []  # readings; None for a slot left empty, a list for a block passed through
    blocks: dict[tuple, tuple[int, list[Measurement]]] = {}  # open MEANS blocks: slot, members
    seen: dict[tuple, int] = {}  # THINNED: readings of each sensor so far
    removed = 0

    def close(at: int, members: list[Measurement]) -> None:
        nonlocal removed
        if len(members) > 1:
            try:
                value = np.mean([m.value for m in members], axis=0)
            except ValueError:  # shapes differ: no mean
                value = None
            if value is not None and np.isfinite(value).all():
                out[at] = members[0]._replace(value=value, samples=sum(m.samples for m in members))
                removed += len(members) - 1
                return
        out[at] = members if len(members) > 1 else members[0]

    for m in ms:
        kind = m.kind
        if kind in MEANS:
            key = (m.source, kind, m.instance)
            block = blocks.get(key)
            if block is None:
                out.append(None)
                block = blocks[key] = (len(out) - 1, [])
            block[1].append(m)
            if len(block[1]) == k:
                close(*blocks.pop(key))
        elif kind in THINNED:
            key = (m.source, kind, m.instance)
            n = seen.get(key, 0)
            seen[key] = n + 1
            if n % k == 0:
                out.append(m)
            else:
                removed += 1
        else:
            out.append(m)
    for at, members in blocks.values():
        close(at, members)
    flat: list[Measurement] = []
    for x in out:
        if type(x) is list:
            flat.extend(x)  # at its first reading's place: a rollback puts the readings between in order
        elif x is not None:
            flat.append(x)
    return flat, removed


class LoadShedder:
    """The decimation factor of each live batch.

    Two rules, the larger wins:

    * the batch must fit the latency budget at the measured cost per reading:
      ``k >= n cost / latency_s``; this caps a burst after a stall;
    * a standing factor follows the batches' *age* (how long the oldest reading
      waited since it was received): raised by half when a batch is older than
      ``latency_s``, lowered by a tenth when younger than half of it. The age
      counts all the work the event loop does (decoding, recording, the
      dashboard), which the cost per reading does not see.
    """

    def __init__(self, latency_s: float = 0.015, k_max: float = 1000.0) -> None:
        self.latency_s = latency_s
        self.k_max = k_max
        self.k = 1.0
        #: measured cost of one reading [s] (a moving mean; a first guess until measured)
        self.cost_s = 1e-4

    def factor(self, n: int, age_s: float) -> int:
        if age_s > self.latency_s:
            self.k = min(self.k * 1.5, self.k_max)
        elif age_s < self.latency_s / 2:
            self.k = max(self.k * 0.9, 1.0)
        fit = n * self.cost_s / self.latency_s
        return max(int(self.k), math.ceil(fit))

    def measured(self, n: int, seconds: float) -> None:
        """``n`` readings took ``seconds`` to process."""
        if n >= 8:  # one reading's time is too noisy to go by
            self.cost_s += 0.2 * (seconds / n - self.cost_s)
