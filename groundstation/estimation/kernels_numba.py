"""The compiled forms of :mod:`.kernels` (imported only when a filter takes its first step: numba is
heavy to import). Each is a loop over a few small matrices; their numpy references and the contract
are in :mod:`.kernels`."""

from __future__ import annotations

import math

import numba
import numpy as np

# cache: compiled once a machine, into __pycache__ beside this file; error_model "numpy": a zero
# innovation variance gives an infinite gain, which the caller refuses as the reference does,
# rather than an exception raised from inside the loop
_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def discretized_step(A, B, Qc, dt, with_q, limit, max_halvings):
    """``filters.discretized``'s series branch: the step's size |A|_inf dt, the halvings that bring it
    under ``limit``, and (Phi, G, Q_k) by :func:`series`; halvings -1 (and zeros) where the
    exponentials are due (a NaN in A, or more than ``max_halvings``)."""
    n = A.shape[0]
    size = 0.0
    finite = True
    for i in range(n):
        r = 0.0
        for j in range(n):
            r += abs(A[i, j])
        if not math.isfinite(r):
            finite = False
        elif r > size:
            size = r
    size *= dt
    if not finite or not math.isfinite(size):
        return np.zeros((n, n)), np.zeros((n, B.shape[1])), np.zeros((n, n)), -1
    halvings = 0 if size < limit else int(math.ceil(math.log2(size / limit) + 1e-12))
    if halvings > max_halvings:
        return np.zeros((n, n)), np.zeros((n, B.shape[1])), np.zeros((n, n)), -1
    Phi, G, Qk = series(A, B, Qc, dt, halvings, with_q)
    return Phi, G, Qk, halvings


@_jit
def _mm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a b, summed in k's order (a b^T as ``_mm(a, b.T)``: the same sums, b read across)."""
    out = np.zeros((a.shape[0], b.shape[1]))
    for i in range(a.shape[0]):
        for j in range(b.shape[1]):
            s = 0.0
            for k in range(a.shape[1]):
                s += a[i, k] * b[k, j]
            out[i, j] = s
    return out


@_jit
def _symmetrised(Q: np.ndarray) -> np.ndarray:
    """(Q + Q^T) / 2, in place."""
    n = Q.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            q = 0.5 * (Q[i, j] + Q[j, i])
            Q[i, j] = q
            Q[j, i] = q
    return Q


@_jit
def series(A: np.ndarray, B: np.ndarray, Qc: np.ndarray, dt: float, halvings: int, with_q: bool):
    """``discretize_series(A, B, Qc, dt, halvings, with_q=with_q)`` as loops (models/base.py gives the
    series and the doublings): (Phi, G, Q_k), Q_k zeros when not ``with_q``."""
    n = A.shape[0]
    T = dt / 2.0**halvings
    AT = A * T
    # Gamma = I + AT/2 + (AT)^2/6 + (AT)^3/24 in Horner's form; Phi = I + AT Gamma; G = Gamma B T
    Gam = np.eye(n) + AT / 4.0
    for c in (3.0, 2.0):
        Gam = np.eye(n) + _mm(AT, Gam) / c
    Phi = np.eye(n) + _mm(AT, Gam)
    G = _mm(Gam, B) * T
    Qk = np.zeros((n, n))
    if with_q:
        # M_k = A M_{k-1} + M_{k-1} A^T, M_0 = Qc; Q_k = sum T^{k+1}/(k+1)! M_k
        M = Qc.copy()
        f = T
        Qk = Qc * T
        for order in range(1, 4):
            AM = _mm(A, M)
            f = f * T / (order + 1)
            M = AM + AM.T
            Qk += M * f
        _symmetrised(Qk)
    for _ in range(halvings):
        # Phi(2T) = Phi^2, G(2T) = G + Phi G, Q_k(2T) = Q_k + Phi Q_k Phi^T
        G = G + _mm(Phi, G)
        if with_q:
            Qk = Qk + _mm(_mm(Phi, Qk), Phi.T)
        Phi = _mm(Phi, Phi)
    if with_q and halvings:
        _symmetrised(Qk)
    return Phi, G, Qk


@_jit
def scalar_update(x: np.ndarray, P: np.ndarray, H: np.ndarray, r: float, z: float):
    """One scalar reading's update as ``ModelFilter._update_written_out`` makes it (y = z - H x,
    s = H P H^T + r, K = P H^T / s, x + K y, Joseph's P = (I - K H) P (I - K H)^T + K r K^T), as loops:
    (x, P, K as a column, s, y). s == 0 is the caller's to refuse (before the division: here K is
    then not finite)."""
    n = x.shape[0]
    PHt = np.zeros(n)
    for i in range(n):
        s = 0.0
        for k in range(n):
            s += P[i, k] * H[0, k]
        PHt[i] = s
    S = 0.0
    hx = 0.0
    for k in range(n):
        S += H[0, k] * PHt[k]
        hx += H[0, k] * x[k]
    S += r
    y = z - hx
    si = 1.0 / S
    K = np.zeros((n, 1))
    xn = x.copy()
    for i in range(n):
        K[i, 0] = PHt[i] * si
        xn[i] += K[i, 0] * y
    I_KH = np.eye(n)
    for i in range(n):
        for j in range(n):
            I_KH[i, j] -= K[i, 0] * H[0, j]
    Pn = _mm(_mm(I_KH, P), I_KH.T)
    for i in range(n):
        for j in range(n):
            Pn[i, j] += K[i, 0] * r * K[j, 0]
    return xn, Pn, K, S, y


@_jit
def state_step(Phi: np.ndarray, G: np.ndarray, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``ModelFilter.predict_to``'s x <- Phi x + G u, each row summed over x, then over u."""
    n = x.shape[0]
    out = np.empty(n)
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += Phi[i, j] * x[j]
        g = 0.0
        for j in range(u.shape[0]):
            g += G[i, j] * u[j]
        out[i] = s + g
    return out


@_jit
def _inverse(S: np.ndarray):
    """S^-1 by Gauss-Jordan elimination with partial pivoting, and False where a pivot is 0 or not
    finite (S singular: numpy's inverse raises there)."""
    k = S.shape[0]
    a = S.copy()
    inv = np.eye(k)
    for c in range(k):
        p = c
        best = abs(a[c, c])
        for r in range(c + 1, k):
            if abs(a[r, c]) > best:
                best = abs(a[r, c])
                p = r
        if best == 0.0 or not math.isfinite(best):
            return inv, False
        if p != c:
            for j in range(k):
                a[c, j], a[p, j] = a[p, j], a[c, j]
                inv[c, j], inv[p, j] = inv[p, j], inv[c, j]
        d = 1.0 / a[c, c]
        for j in range(k):
            a[c, j] *= d
            inv[c, j] *= d
        for r in range(k):
            if r != c:
                f = a[r, c]
                if f != 0.0:
                    for j in range(k):
                        a[r, j] -= f * a[c, j]
                        inv[r, j] -= f * inv[c, j]
    return inv, True


@_jit
def vector_update(x: np.ndarray, P: np.ndarray, H: np.ndarray, R: np.ndarray, z: np.ndarray):
    """A vector reading's update as ``ModelFilter._update_written_out`` makes it (y = z - H x,
    S = H P H^T + R, K = P H^T S^-1, x + K y, Joseph's P = (I - K H) P (I - K H)^T + K R K^T), as
    loops: (x, P, K, S, y, NIS y^T S^-1 y, ok). ok False: S is singular, the caller's to refuse
    (x and P are then returned as they came)."""
    n = x.shape[0]
    k = H.shape[0]
    PHt = _mm(P, H.T)
    S = _mm(H, PHt)
    for i in range(k):
        for j in range(k):
            S[i, j] += R[i, j]
    y = np.empty(k)
    for i in range(k):
        hx = 0.0
        for j in range(n):
            hx += H[i, j] * x[j]
        y[i] = z[i] - hx
    SI, ok = _inverse(S)
    if not ok:
        return x.copy(), P.copy(), np.zeros((n, k)), S, y, 0.0, False
    K = _mm(PHt, SI)
    xn = x.copy()
    for i in range(n):
        s = 0.0
        for j in range(k):
            s += K[i, j] * y[j]
        xn[i] += s
    I_KH = np.eye(n) - _mm(K, H)
    Pn = _mm(_mm(I_KH, P), I_KH.T) + _mm(_mm(K, R), K.T)
    nis = 0.0
    for i in range(k):
        s = 0.0
        for j in range(k):
            s += SI[i, j] * y[j]
        nis += y[i] * s
    return xn, Pn, K, S, y, nis, True
