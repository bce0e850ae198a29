"""Measurements derived from others, for logs that lack them.

:func:`with_attitude` inserts ATTITUDE (roll, pitch) from the IMU through the
complementary filter of the coaxial document's chapter 8, for logs with an IMU
but no attitude (Crazyflie uSD logs): the altitude filter needs the tilt to
turn specific force into vertical acceleration. The derived measurements are
marked by their source (``derived/cf``); truth is never used.
"""
from __future__ import annotations

from typing import Iterable, Iterator

import numpy as np

from .attitude import ComplementaryFilter
from .measurement import Kind, Measurement


def with_attitude(ms: Iterable[Measurement], *, rate: float = 100.0, w_c: float = 1.0) -> Iterator[Measurement]:
    cf = ComplementaryFilter(w_c)
    next_t = -np.inf
    for m in ms:
        if m.kind in (Kind.ACCEL, Kind.GYRO):
            cf.handle(m)
            if m.kind is Kind.GYRO and cf.x is not None and m.t >= next_t:
                next_t = m.t + 1.0 / rate
                yield Measurement(m.t, Kind.ATTITUDE, np.array([cf.x[0], cf.x[1], 0.0]), "derived/cf.1", m.t_rx)
        yield m
