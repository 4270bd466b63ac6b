"""Gradient of an exterior spherical-harmonic series in Cartesian coordinates, fully normalised.

One kernel serves the geomagnetic field (IGRF) and the gravity field. For a reference radius ``R``
and fully normalised (4 pi) coefficients ``C_nm, S_nm`` the series is

    F(r) = sum_{n, m} (C_nm Vb_nm + S_nm Wb_nm),
    Vb_nm + i Wb_nm = Ub_nm = (R / r)^(n+1) Pb_nm(sin lat) exp(i m lon),

and :func:`gradient` returns ``R * grad F`` (dimensionless per unit coefficient) at Cartesian
positions in the body-fixed frame. Gravity is ``a = GM / R^2 * gradient(...)``; a magnetic
potential ``V = a_ref * sum (g V + h W)`` gives ``B = -gradient(...)`` in the coefficients' unit.

Method: Cunningham's recursion of the solid harmonics in x, y, z (Montenbruck & Gill, *Satellite
Orbits*, 2000, sec. 3.2.4, eqs. 3.30-3.33), carried in fully normalised form (Holmes &
Featherstone 2002 style coefficients, all quantities O(1), so it neither overflows nor loses digits
at high degree) and in complex arithmetic ``U = V + i W`` so one pass gives both. It never divides
by cos(latitude): it is exact at the poles, where spherical-coordinate formulas need a limit.
The recursion runs over the degree with all orders at once, so a call is a few dozen numpy
operations whatever the number of positions.

One position at a time, those few dozen operations cost far more than the arithmetic. For that
case :func:`point_tensor` folds a coefficient set, once, into polynomial form: every solid harmonic
``Ub_nm`` is ``(R / r) h_nm(x', y', z')`` with ``h_nm`` a homogeneous polynomial of degree n in
``x' = R x / r^2`` (same for y, z), built by the same recursion on polynomial coefficients
(``rho`` becomes ``x^2 + y^2 + z^2``, which is what it is before the scaling). The gradient is
then one fixed tensor ``T[c, i, j, k]`` contracted with the powers ``x'^i y'^j z'^k``
(:class:`PointSeries`: two small matrix products, whatever the degree up to the cap). The
monomial coefficients grow with the degree (1e5 at degree 14), so cancellation costs digits:
measured against :func:`gradient`, 3e-14 relative at degree 13 with a flat spectrum and 3e-13 at
degree 20; degrees above :data:`POINT_MAX_DEGREE` are refused.
"""

from __future__ import annotations

from functools import lru_cache
from math import lgamma, log, sqrt

import numpy as np

__all__ = ["POINT_MAX_DEGREE", "PointSeries", "gradient", "norm_factor", "point_tensor"]

#: Highest degree :func:`point_tensor` accepts (its cancellation is measured to 20, see above).
POINT_MAX_DEGREE = 20


def norm_factor(n: int, m: int) -> float:
    """Full (4 pi) normalisation ``N_nm`` with ``Pb_nm = N_nm P_nm`` (P without Condon-Shortley phase)."""
    return float(np.exp(0.5 * (log(2.0 - (m == 0)) + log(2 * n + 1) + lgamma(n - m + 1) - lgamma(n + m + 1))))


@lru_cache(maxsize=16)
def _tables(nmax: int):
    """Recursion and gradient weights for series of degree ``nmax`` (solid harmonics to nmax + 1)."""
    top = nmax + 1
    a = np.zeros((top + 1, top + 1))
    b = np.zeros((top + 1, top + 1))
    for n in range(2, top + 1):
        for m in range(0, n - 1):
            a[n, m] = sqrt((2 * n - 1) * (2 * n + 1) / ((n - m) * (n + m)))
            b[n, m] = sqrt((2 * n + 1) * (n + m - 1) * (n - m - 1) / ((2 * n - 3) * (n + m) * (n - m)))
    for n in range(1, top + 1):
        # Ub_{n,n-1} = sqrt(2n+1) z' Ub_{n-1,n-1}: the general formula with b = 0.
        a[n, n - 1] = sqrt(2 * n + 1)
    # Sectoral terms Ub_mm = c_m (x' + i y') Ub_{m-1,m-1}, c_1 = sqrt(3), c_m = sqrt((2m+1)/(2m)).
    c = np.array([1.0] + [sqrt((2.0 if m == 1 else 1.0) * (2 * m + 1) / (2 * m)) for m in range(1, top + 1)])
    cum = np.cumprod(c)
    # Gradient weights (M&G 3.33 rewritten for normalised quantities): for each (n, m) of the series
    # the terms in Ub_{n+1,m+1}, Ub_{n+1,m-1} and Ub_{n+1,m}, scaled by N_nm / N_{n+1,k}.
    nn, mm = [], []
    w1, wm, w0 = [], [], []
    for n in range(0, nmax + 1):
        for m in range(0, n + 1):
            nn.append(n)
            mm.append(m)
            f = norm_factor(n, m)
            half = 1.0 if m == 0 else 0.5
            w1.append(half * f / norm_factor(n + 1, m + 1))
            wm.append(0.0 if m == 0 else 0.5 * (n - m + 2) * (n - m + 1) * f / norm_factor(n + 1, m - 1))
            w0.append((n - m + 1) * f / norm_factor(n + 1, m))
    nn, mm = np.array(nn), np.array(mm)
    return (a, b, cum, nn, mm, np.array(w1), np.array(wm), np.array(w0))


def index_nm(nmax: int) -> tuple[np.ndarray, np.ndarray]:
    """Degree and order of each entry of the flat coefficient vectors :func:`gradient` takes."""
    t = _tables(nmax)
    return t[3], t[4]


def gradient(r, C, S, r_ref: float, nmax: int) -> np.ndarray:
    """``R * grad sum(C Vb + S Wb)`` at positions ``r`` (m, ``(..., 3)``, body-fixed Cartesian).

    ``C``, ``S``: flat fully normalised coefficients ordered as :func:`index_nm` (n = 0..nmax,
    m = 0..n), any unit; the result has that unit and shape ``(..., 3)``.
    """
    a, b, cum, nn, mm, w1, wm, w0 = _tables(nmax)
    r = np.asarray(r, dtype=float)
    shape = r.shape[:-1]
    p = r.reshape(-1, 3)
    r2 = np.einsum("ij,ij->i", p, p)
    s = r_ref / r2
    xp, yp, zp = p[:, 0] * s, p[:, 1] * s, p[:, 2] * s
    rho = r_ref * s  # (R / r)^2
    diag = np.arange(nmax + 2)
    top = nmax + 1
    # Degree-major layout (n, m, point): each recursion step works on contiguous rows.
    U = np.zeros((top + 1, top + 1, p.shape[0]), dtype=complex)
    # Sectoral diagonal in closed form: Ub_mm = cum_m (x' + i y')^m R / r.
    U[diag, diag] = cum[:, None] * (xp + 1j * yp)[None, :] ** diag[:, None] * np.sqrt(rho)[None, :]
    azs = a[:, :, None] * zp
    brs = b[:, :, None] * rho
    U[1, 0] = azs[1, 0] * U[0, 0]
    for n in range(2, top + 1):
        # All orders m < n at once; entries m >= n of rows n-1, n-2 are zero or the diagonal.
        U[n, :n] = azs[n, :n] * U[n - 1, :n] - brs[n, :n] * U[n - 2, :n]
    K = np.asarray(C, dtype=float) - 1j * np.asarray(S, dtype=float)
    X = (-w1 * K) @ U[nn + 1, mm + 1]
    Y = (wm * K) @ U[nn + 1, np.maximum(mm - 1, 0)]
    gz = ((-w0 * K) @ U[nn + 1, mm]).real
    out = np.stack((X.real + Y.real, X.imag - Y.imag, gz), axis=-1)
    return out.reshape(shape + (3,))


def _solid_rows(nmax: int):
    """Yield ``(n, h)`` for n = 0..nmax + 1, ``h[m]`` the complex coefficients of the homogeneous
    polynomial ``h_nm`` (m = 0..n) on the monomials ``x^i y^j z^k``, shape ``(n + 1, D, D, D)``."""
    a, b, cum = _tables(nmax)[:3]
    d = nmax + 2
    prev2 = None
    prev = np.zeros((1, d, d, d), dtype=complex)
    prev[0, 0, 0, 0] = 1.0  # h_00 = 1: Ub_00 = R / r
    yield 0, prev
    for n in range(1, d):
        row = np.zeros((n + 1, d, d, d), dtype=complex)
        # z h_{n-1,m} - r^2 h_{n-2,m}, all orders m < n at once (b is 0 where h_{n-2,m} is absent).
        row[:n, :, :, 1:] = a[n, :n, None, None, None] * prev[:n, :, :, :-1]
        if prev2 is not None:
            bb = b[n, : n - 1, None, None, None]
            row[: n - 1, 2:] -= bb * prev2[:, :-2]
            row[: n - 1, :, 2:] -= bb * prev2[:, :, :-2]
            row[: n - 1, :, :, 2:] -= bb * prev2[:, :, :, :-2]
        # Sectoral: h_nn = (c_n) (x + i y) h_{n-1,n-1}.
        c = cum[n] / cum[n - 1]
        row[n, 1:] += c * prev[n - 1, :-1]
        row[n, :, 1:] += 1j * c * prev[n - 1, :, :-1]
        prev2, prev = prev, row
        yield n, row


def point_tensor(C, S, nmax: int) -> np.ndarray:
    """Fold coefficient sets into the tensor :class:`PointSeries` contracts.

    ``C``, ``S``: ``(B, K)`` (or ``(K,)``) fully normalised coefficients in :func:`index_nm` order.
    Returns ``(B, 3, D, D, D)`` (or ``(3, D, D, D)``) with ``D = nmax + 2``: component c of
    ``R grad F`` is ``(R / r) sum T[c, i, j, k] x'^i y'^j z'^k``. It costs a few milliseconds:
    build it once per coefficient set.
    """
    if not (isinstance(nmax, int | np.integer) and 0 <= nmax <= POINT_MAX_DEGREE):
        raise ValueError(
            f"point_tensor degree {nmax!r} is not allowed; use an integer from 0 to {POINT_MAX_DEGREE} "
            "(beyond it the polynomial form loses digits; use gradient())."
        )
    _, _, _, nn, mm, w1, wm, w0 = _tables(nmax)
    C = np.asarray(C, dtype=float)
    single = C.ndim == 1
    K = np.atleast_2d(C) - 1j * np.atleast_2d(np.asarray(S, dtype=float))
    if K.shape[-1] != nn.size:
        raise ValueError(f"coefficients must have {nn.size} entries (degree {nmax}); got {K.shape[-1]}.")
    d = nmax + 2
    # The gradient of series term (n, m) is a combination of Ub_{n+1, m+1}, Ub_{n+1, m-1}, Ub_{n+1, m}
    # (see gradient()); gather the weights per solid harmonic, then sum the polynomials once each.
    wx = np.zeros((K.shape[0], d, d), dtype=complex)
    wy = np.zeros_like(wx)
    wz = np.zeros_like(wx)
    for out, cols, w in ((wx, mm + 1, -w1), (wy, np.maximum(mm - 1, 0), wm), (wz, mm, -w0)):
        np.add.at(out, (slice(None), nn + 1, cols), w * K)
    X = np.zeros((K.shape[0], d, d, d), dtype=complex)
    Y = np.zeros_like(X)
    Z = np.zeros_like(X)
    for n, row in _solid_rows(nmax):
        if n == 0:
            continue
        X += np.tensordot(wx[:, n, : n + 1], row, 1)
        Y += np.tensordot(wy[:, n, : n + 1], row, 1)
        Z += np.tensordot(wz[:, n, : n + 1], row, 1)
    T = np.stack((X.real + Y.real, X.imag - Y.imag, Z.real), axis=1)
    return T[0] if single else T


class PointSeries:
    """Coefficient sets folded for evaluation at one position at a time (see the module notes).

    ``PointSeries(C, S, nmax)`` with ``C``, ``S`` of shape ``(B, K)`` or ``(K,)``; building costs
    milliseconds, :meth:`gradient` microseconds. :meth:`split` builds many series in one pass.
    """

    def __init__(self, C, S, nmax: int) -> None:
        self._set(point_tensor(C, S, nmax), nmax)

    @classmethod
    def split(cls, C, S, nmax: int, per: int) -> list[PointSeries]:
        """One series per ``per`` consecutive coefficient sets of ``C``, ``S`` (``(B, K)``, B a
        multiple of ``per``), folded together: the cost is mostly per degree, not per set."""
        T = point_tensor(np.atleast_2d(C), np.atleast_2d(S), nmax)
        out = []
        for start in range(0, T.shape[0], per):
            series = cls.__new__(cls)
            series._set(T[start:start + per], nmax)
            out.append(series)
        return out

    def _set(self, T: np.ndarray, nmax: int) -> None:
        d = nmax + 2
        self.nmax = nmax
        self.sets = 1 if T.ndim == 4 else T.shape[0]
        T = T.reshape(self.sets * 3, d, d, d)
        # Monomials x^i y^j z^k exist only for i + j + k <= d - 1: keep the (i, j) pairs that can
        # carry one, and lay z's axis first so the first product runs along contiguous rows.
        i, j = np.nonzero(np.add.outer(np.arange(d), np.arange(d)) <= d - 1)
        self._i, self._j = i, j
        self._T = np.ascontiguousarray(T[:, i, j, :].transpose(2, 0, 1).reshape(d, -1))
        self._rows = self.sets * 3
        self._exponents = np.arange(d, dtype=float)

    def gradient(self, x: float, y: float, z: float, r_ref: float) -> list[float]:
        """``R grad F`` at position ``(x, y, z)`` (m, r > 0, body-fixed): ``3 * B`` floats, set-major."""
        r2 = x * x + y * y + z * z
        s = r_ref / r2
        px, py, pz = np.power.outer((x * s, y * s, z * s), self._exponents)
        partial = (pz @ self._T).reshape(self._rows, -1)
        rho = sqrt(r_ref * s)
        return [rho * v for v in (partial @ (px[self._i] * py[self._j])).tolist()]
