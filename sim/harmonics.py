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
"""

from __future__ import annotations

from functools import lru_cache
from math import lgamma, log, sqrt

import numpy as np

__all__ = ["gradient", "norm_factor"]


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
