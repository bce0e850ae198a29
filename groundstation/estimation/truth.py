"""Truth for scoring an estimate: motion capture in the log, or a truth CSV beside it.

Metrics only: no estimator ever reads it. ``evaluate`` and ``diagnose`` score against it.
"""

from __future__ import annotations

import csv
import math
from array import array
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from groundstation.core.measurement import Kind, Measurement

from .models.base import LinearModel


def sigma_honesty(error: np.ndarray, sigma: np.ndarray) -> tuple[float, float]:
    """The share of errors within 2 sigma (95 % for an honest Gaussian sigma) and their mean square
    in sigmas (the NEES of one state, 1 for an honest sigma; Bar-Shalom, Li and Kirubarajan 2001,
    5.4). A sigma of zero (an estimate held exactly, as on the ground) counts as a micrometre."""
    e = error / np.maximum(sigma, 1e-6)
    return float(np.mean(np.abs(e) <= 2.0)), float(np.mean(e * e))


class Estimated(Protocol):
    """A run of a model over a log: its estimates ``x`` at times ``t``."""

    model: LinearModel
    t: np.ndarray
    x: np.ndarray


@dataclass
class Truth:
    """Height truth [m, up] and, when the source has it, roll and pitch [rad] (motion capture or
    the simulator's sidecar): metrics only."""

    t: np.ndarray
    h: np.ndarray
    source: str
    cos_tilt: np.ndarray | None = None  # cos(roll) cos(pitch) of the truth's attitude, when it has one
    roll: np.ndarray | None = None
    pitch: np.ndarray | None = None

    def rmse(self, t: np.ndarray, z: np.ndarray, t0: float, t1: float) -> float:
        k = (t >= max(t0, self.t[0])) & (t <= min(t1, self.t[-1]))
        return float(np.sqrt(np.mean((z[k] - np.interp(t[k], self.t, self.h)) ** 2))) if k.any() else math.nan

    def consistency(self, t: np.ndarray, z: np.ndarray, sigma: np.ndarray, t0: float, t1: float) -> tuple[float, float]:
        """Whether a height estimate's sigma is honest against truth (:func:`sigma_honesty`) over
        [t0, t1]."""
        k = (t >= max(t0, self.t[0])) & (t <= min(t1, self.t[-1]))
        if not k.any():
            return math.nan, math.nan
        return sigma_honesty(z[k] - np.interp(t[k], self.t, self.h), sigma[k])

    def error(self, run: Estimated, t0: float, t1: float) -> float:
        """RMSE against truth of what the run estimates: the height [m], or roll and pitch
        together [rad] (the attitude model)."""
        states = run.model.states
        if "z" in states:
            return self.rmse(run.t, run.x[:, states.index("z")], t0, t1)
        if "roll" in states and self.roll is not None and self.pitch is not None:
            k = (run.t >= max(t0, self.t[0])) & (run.t <= min(t1, self.t[-1]))
            if not k.any():
                return math.nan
            e = np.concatenate(
                [
                    run.x[k, 0] - np.interp(run.t[k], self.t, self.roll),
                    run.x[k, 1] - np.interp(run.t[k], self.t, self.pitch),
                ]
            )
            e = (e + math.pi) % (2 * math.pi) - math.pi
            return float(np.sqrt(np.mean(e**2)))
        return math.nan

    @staticmethod
    def quantity(run: Estimated) -> str:
        return "height [m]" if "z" in run.model.states else "roll and pitch [rad]"


class LiveTruthScore:
    """A height estimate against truth as the flight goes (motion capture in the stream): each
    estimate paired with the truth interpolated at its time between the two truth samples around it,
    over the last ``window_s``; what :meth:`Truth.consistency` says of a whole log. Truth and
    estimates reach the dashboard by different paths, either first: the truth of the last
    ``keep_s`` is kept, and an estimate newer than all of it waits for the next sample. Two truth
    samples more than ``gap_s`` apart bracket nothing (motion capture lost the vehicle)."""

    def __init__(self, window_s: float = 60.0, gap_s: float = 0.2, keep_s: float = 2.0) -> None:
        self.window_s, self.gap_s, self.keep_s = window_s, gap_s, keep_s
        self._truth: deque[tuple[float, float]] = deque()  # (t, h), the last keep_s
        self._waiting: deque[tuple[float, float, float]] = deque(maxlen=2000)  # (t, z, sigma) past the truth
        self.pairs: deque[tuple[float, float, float]] = deque()  # (t, estimate - truth, sigma)

    def clear(self) -> None:
        self._truth.clear()
        self._waiting.clear()
        self.pairs.clear()

    def truth(self, t: float, h: float) -> None:
        tr = self._truth
        if tr and t <= tr[-1][0]:
            if t < tr[-1][0] - 1.0:  # time went back (a seek, a loop)
                self.clear()
            else:
                return  # a repeat or out of order: the samples stay in time order
        tr.append((t, h))
        while tr[0][0] < t - self.keep_s:
            tr.popleft()
        while self._waiting and self._waiting[0][0] <= t:
            self._pair(*self._waiting.popleft())

    def estimate(self, t: float, z: float, sigma: float) -> None:
        if self.pairs and t < self.pairs[-1][0] - 1.0:
            self.clear()
        if self._truth and t <= self._truth[-1][0]:
            self._pair(t, z, sigma)
        else:
            self._waiting.append((t, z, sigma))

    def _pair(self, t: float, z: float, sigma: float) -> None:
        tr = self._truth
        i = len(tr) - 1  # the estimate is near the newest truth: search back from there
        while i > 0 and tr[i - 1][0] >= t:
            i -= 1
        if i == 0:
            return  # older than the truth kept
        (t0, h0), (t1, h1) = tr[i - 1], tr[i]
        if t1 - t0 > self.gap_s:
            return
        self.pairs.append((t, z - (h0 + (h1 - h0) * (t - t0) / (t1 - t0)), sigma))
        while self.pairs[0][0] < t - self.window_s:
            self.pairs.popleft()

    def summary(self) -> tuple[int, float, float, float] | None:
        """(pairs, RMS error [m], share within 2 sigma, NEES) over the window, or None without a pair."""
        if not self.pairs:
            return None
        a = np.array(self.pairs)
        return len(a), float(np.sqrt(np.mean(a[:, 1] ** 2))), *sigma_honesty(a[:, 1], a[:, 2])


def _truth_columns(p: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None] | None:
    """A truth CSV's t, height ("h", the simulator's sidecar, or "z"; up) and, where it has them,
    roll and pitch; None without those columns or rows. Read row by row into doubles, those columns
    alone (a 1-hour sidecar is 0.16 GB of text: as a dict a row it took a gigabyte)."""
    try:
        with open(p, newline="") as f:
            reader = csv.reader(f)
            header = next((row for row in reader if row), None)
            if header is None or "t" not in header:
                return None
            height = next((k for k in ("h", "z") if k in header), None)
            if height is None:
                return None
            names = ["t", height] + (["roll", "pitch"] if "roll" in header and "pitch" in header else [])
            at = [header.index(k) for k in names]
            cols = [array("d") for _ in names]
            for row in reader:
                if not row:  # a blank line, as csv.DictReader passes over it
                    continue
                for col, i in zip(cols, at):
                    col.append(float(row[i]))
    # a binary file, a broken quote, a short row, a cell not a number
    except (csv.Error, IndexError, ValueError) as e:  # (UnicodeDecodeError is a ValueError)
        raise ValueError(f"{p}: not a truth CSV: {e}") from None
    if not len(cols[0]):
        return None
    t, h = np.array(cols[0]), np.array(cols[1])
    if len(cols) == 2:
        return t, h, None, None
    return t, h, np.array(cols[2]), np.array(cols[3])


def truth_from(ms: Sequence[Measurement], log: Path | None, truth_csv: Path | None) -> Truth | None:
    pose = [m for m in ms if m.kind is Kind.TRUTH_POSE]
    if pose:
        q = np.array([m.value[3:7] for m in pose])
        w, x, y, z = q.T
        # the body z axis's vertical component, R_IB[2, 2] = cos(roll) cos(pitch)
        c = 1.0 - 2.0 * (x * x + y * y)
        roll = np.arctan2(2 * (w * x + y * z), c)
        pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
        return Truth(
            np.array([m.t for m in pose]), np.array([-m.value[2] for m in pose]), "motion capture", c, roll, pitch
        )
    p = truth_csv
    if p is None and log is not None:
        # the simulator's sidecar (NAME.csv) or a truth file beside the log (NAME_truth.csv)
        p = next((q for q in (log.with_suffix(".csv"), log.with_name(log.stem + "_truth.csv")) if q.exists()), None)
    if p is not None and p.exists():
        got = _truth_columns(p)
        if got is not None:
            t, h, roll, pitch = got
            c = None if roll is None or pitch is None else np.cos(roll) * np.cos(pitch)
            return Truth(
                t,
                h,
                f"{'simulator sidecar' if log is not None and p == log.with_suffix('.csv') else 'truth file'} {p.name}",
                c,
                roll,
                pitch,
            )
    return None
