"""Readings held as columns (groundstation.core.readings): the records they give back are those put
in, field by field, and the whole-log operations equal the same done record by record."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from groundstation.core.measurement import Kind, Measurement
from groundstation.core.readings import Readings, ReadingsBuilder

CONTEXT = {Kind.ATTITUDE, Kind.THROTTLE}


def _log(n: int = 3000, seed: int = 1) -> list[Measurement]:
    """Readings of several kinds, widths and sources, some with a variance, NaN values or no time,
    out of time order (as a log's file order can be), several at equal times."""
    rng = random.Random(seed)
    out = []
    for i in range(n):
        t = round(rng.uniform(0.0, 30.0), 2)  # (rounded: equal times happen)
        pick = rng.randrange(7)
        if pick == 0:
            out.append(Measurement(t, Kind.BARO_PRESSURE, np.array([101325.0 + rng.gauss(0, 5)]), "mav/1.1", t + 0.5))
        elif pick == 1:
            v = np.array([rng.gauss(0, 1) for _ in range(3)])
            out.append(Measurement(t, Kind.ATTITUDE, v, "mav/1.1", t + 0.5, instance=0))
        elif pick == 2:
            f = np.array([0.1, -0.2, -9.8 + rng.gauss(0, 1)])
            out.append(Measurement(t, Kind.ACCEL, f, "blocks", t, samples=10))
        elif pick == 3:
            width = rng.choice((8, 16))  # one kind in two widths (SERVO_OUTPUT_RAW's 8 or 16 outputs)
            v = np.full(width, math.nan)
            v[:4] = rng.random()
            out.append(Measurement(t, Kind.ACTUATOR, v, "mav/1.1", t + 0.5))
        elif pick == 4:
            var = np.array([0.01])
            out.append(Measurement(t, Kind.RANGE, np.array([rng.uniform(0.1, 3)]), "board", t, var, instance=2))
        elif pick == 5:
            out.append(Measurement(t, Kind.THROTTLE, np.array([rng.random()]), "mav/2.1", t + 0.5))
        else:
            out.append(Measurement(math.nan, Kind.GPS, np.array([47.0, 8.0, 400.0]), "mav/1.1", float(i)))
    return out


def _same(a: Measurement, b: Measurement) -> bool:
    def eq(x, y):
        return (x == y) or (x != x and y != y)

    return (
        eq(a.t, b.t)
        and a.kind is b.kind
        and a.source == b.source
        and eq(a.t_rx, b.t_rx)
        and a.instance == b.instance
        and a.samples == b.samples
        and a.value.dtype == b.value.dtype
        and np.array_equal(a.value, b.value, equal_nan=True)
        and ((a.variance is None) == (b.variance is None))
        and (a.variance is None or np.array_equal(a.variance, b.variance))
    )


def _all_same(xs, ys) -> bool:
    xs, ys = list(xs), list(ys)
    return len(xs) == len(ys) and all(_same(a, b) for a, b in zip(xs, ys))


def test_records_come_back_as_they_went_in():
    ms = _log()
    r = Readings.of(ms)
    assert len(r) == len(ms)
    assert _all_same(r, ms)
    assert _same(r[0], ms[0]) and _same(r[-1], ms[-1]) and _same(r[1234], ms[1234])
    assert _all_same(r[100:200], ms[100:200])
    with pytest.raises(IndexError):
        r[len(ms)]
    assert Readings.of(r) is r
    assert r.kinds() == {m.kind for m in ms}


def test_built_a_chunk_at_a_time_the_same():
    ms = _log(500)
    b = ReadingsBuilder(chunk=7)
    b.extend(ms)
    assert len(b) == 500
    assert _all_same(b.build(), ms)
    assert len(ReadingsBuilder().build()) == 0


def test_values_are_read_only():
    """A record's value is a view of its stream's values: changing it in place would change every
    later read, so it cannot be."""
    r = Readings.of(_log(50))
    with pytest.raises(ValueError):
        r[0].value[0] = 1.0


def test_whole_log_operations_equal_the_record_by_record_ones():
    ms = _log()
    r = Readings.of(ms)
    kinds = {Kind.RANGE, Kind.ACCEL}
    assert _all_same(r.only(kinds), [m for m in ms if m.kind in kinds])
    assert _all_same(r.without(kinds), [m for m in ms if m.kind not in kinds])
    assert _all_same(r.before(12.0), [m for m in ms if m.t < 12.0])
    assert _all_same(r + ms[:10], ms + ms[:10])
    shifted = [m._replace(t=m.t - 0.013) if m.kind is Kind.RANGE else m for m in ms]
    assert _all_same(r.shifted({Kind.RANGE}, 0.013), shifted)
    scaled = [m._replace(value=m.value * 1.02) if m.kind is Kind.ACCEL else m for m in ms]
    assert _all_same(r.with_values(Kind.ACCEL, lambda v: v * 1.02), scaled)


def test_columns_are_what_a_loop_over_the_records_reads():
    """One kind's (or several kinds') times, times of receipt and values as columns, in the readings'
    order; a kind read in two widths padded with NaN to the wider."""
    ms = _log()
    r = Readings.of(ms)
    for kinds in ((Kind.ACTUATOR,), (Kind.ACCEL,), (Kind.THROTTLE, Kind.ACTUATOR), (Kind.GPS,)):
        recs = [m for m in ms if m.kind in kinds]
        t, t_rx, v = r.columns(kinds if len(kinds) > 1 else kinds[0])
        assert np.array_equal(t, [m.t for m in recs], equal_nan=True)
        assert np.array_equal(t_rx, [m.t_rx for m in recs], equal_nan=True)
        assert v.shape == (len(recs), max((len(m.value) for m in recs), default=0))
        for m, row in zip(recs, v, strict=True):
            assert np.array_equal(row[: len(m.value)], m.value, equal_nan=True)
            assert np.isnan(row[len(m.value) :]).all()


def test_time_order_is_a_stable_sort_with_context_first():
    """By time, at equal times the context kinds first, else in their order; those without a time last."""
    ms = _log()
    timed = [m for m in ms if m.t == m.t]
    expected = sorted(timed, key=lambda m: (m.t, m.kind not in CONTEXT))
    got = Readings.of(ms).in_time_order(CONTEXT)
    assert _all_same(got[: len(timed)], expected)
    assert all(m.t != m.t for m in got[len(timed) :])


def test_a_tenth_of_the_memory_of_records():
    """What the columns hold per reading (a record is some 400 bytes: a tuple, two floats, an array)."""
    ms = [Measurement(i * 0.01, Kind.BARO_PRESSURE, np.array([1e5 + i]), "mav/1.1", i * 0.01) for i in range(10000)]
    r = Readings.of(ms)
    held = sum(a.nbytes for a in (r.t, r.t_rx, r.samples, r.stream, r.row)) + sum(s.values.nbytes for s in r.streams)
    assert held / len(ms) <= 28 + 8
