"""Two-body and J2 orbit mechanics: Kepler's equation, classical elements <-> state, universal-variable
propagation, and a J2 Cowell propagator.

Frames and units
----------------
Positions and velocities are in an inertial, central-body-centred frame (``gcrs`` for the Earth), in
m and m/s, as ``(..., 3)`` arrays. Angles are in radians. The classical elements are

=========  ===============================================================================
``p``      semi-latus rectum, m (finite for every conic, so it is the stored size element)
``a``      semi-major axis, m: > 0 elliptic, < 0 hyperbolic, ``inf`` parabolic
``e``      eccentricity: 0 circular, < 1 elliptic, 1 parabolic, > 1 hyperbolic
``i``      inclination in [0, pi] between the frame's z axis and the angular momentum
``raan``   right ascension of the ascending node, from the frame's x axis
``argp``   argument of perigee, from the ascending node in the direction of motion
``nu``     true anomaly, from perigee in the direction of motion
=========  ===============================================================================

Mean anomaly ``M`` is the conic-appropriate one: ``E - e sin E`` (elliptic),
``e sinh H - H`` (hyperbolic) and Barker's ``D + D**3/3`` with ``D = tan(nu/2)`` (parabolic). The
matching mean motions are ``sqrt(mu/a**3)``, ``sqrt(mu/(-a)**3)`` and ``2 sqrt(mu/p**3)``, so
``M = n (t - tp)`` for every conic.

Numerics (docs/numerical_methods.md, "Orbits and Kepler's equation")
--------------------------------------------------------------------
* Kepler's equation: Markley (1995) starter with its fifth-order correction, then Newton steps on the
  cancellation-free residual ``(E - sin E) + (1 - e) sin E - M`` (series for ``E - sin E`` at small
  ``E``). Hyperbolic: a starter that is a proven upper bound (cubic or logarithmic), then Halley on
  ``(sinh H - H) + (e - 1) sinh H - M``. Parabolic: Barker's closed form. Every loop has a fixed
  iteration bound; NaN in gives NaN out.
* ``propagate_kepler`` uses universal variables (Stumpff functions with series near zero) and a
  Laguerre-Conway iteration safeguarded by a bracket, so it cannot diverge; it is continuous across
  ``e = 1``.
* ``propagate_j2`` is a fixed-step Cowell RK4 that re-evaluates the force at every stage, or scipy's
  DOP853 as an offline reference.

Degenerate element sets (documented conventions of ``state_to_elements``)
--------------------------------------------------------------------------
* circular (``e < ECC_CIRCULAR``): ``argp = 0`` and ``nu`` is the argument of latitude;
* equatorial (``i < INC_EQUATORIAL`` or ``pi - i < INC_EQUATORIAL``): ``raan = 0`` and ``argp`` is
  measured from the x axis (longitude of perigee), in the direction of motion;
* circular and equatorial: ``raan = argp = 0`` and ``nu`` is the true longitude.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.constants import J2_EARTH, MU_EARTH, R_EARTH

__all__ = [
    "ECC_CIRCULAR",
    "INC_EQUATORIAL",
    "Elements",
    "accel_j2",
    "elements_to_state",
    "j2_energy",
    "mean_from_true_anomaly",
    "propagate_j2",
    "propagate_kepler",
    "solve_kepler",
    "state_to_elements",
    "true_anomaly_from_mean",
]

#: Below this eccentricity ``state_to_elements`` treats the orbit as circular (``argp = 0``).
ECC_CIRCULAR = 1e-11
#: Below this inclination (or within it of pi) ``state_to_elements`` treats the orbit as equatorial.
INC_EQUATORIAL = 1e-11

_TWO_PI = 2.0 * math.pi
_EPS = np.finfo(float).eps
# 2 pi split in four parts (Cody-Waite): the first three carry 26 significant bits each, so k * part
# is exact for |k| < 2**27 (|M| up to 8.4e8 rad) and M - k * 2 pi keeps full relative accuracy even
# when M is close to a multiple of 2 pi (which matters near perigee as e -> 1, where dE/dM ~ 1/(1-e)).
_TWO_PI_1 = 6.283185243606567
_TWO_PI_2 = 6.357301884918343e-08
_TWO_PI_3 = 2.4492935728214377e-16
_TWO_PI_4 = 2.54732686540438e-24
_EXACT_K_MAX = 2.0 ** 27

# Taylor coefficients of the Stumpff functions: S(z) = sum (-z)**k / (2k+3)!, C(z) = sum (-z)**k / (2k+2)!.
# With |z| < 2.25 the first omitted term is below 1e-18 relative.
_SERIES_Z_MAX = 2.25
_S_COEF = np.array([(-1.0) ** k / math.factorial(2 * k + 3) for k in range(11)])
_C_COEF = np.array([(-1.0) ** k / math.factorial(2 * k + 2) for k in range(11)])

_KEPLER_ELLIPTIC_ITER = 6
_KEPLER_HYPERBOLIC_ITER = 12
_UNIVERSAL_ITER = 100


# --------------------------------------------------------------------------------------------------
# Validation helpers: messages are one sentence naming the field, the value given and what is allowed.


def _shown(value) -> str:
    """One offending value as text (the first one when an array is given)."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        return repr(float(arr))
    return repr(float(arr.ravel()[0])) + f" (the first of {arr.size} offending values)"


def _fail(field: str, bad, value, allowed: str) -> None:
    """Raise ValueError naming ``field`` and its first offending value if any of ``bad`` is set."""
    bad = np.asarray(bad)
    if np.any(bad):
        value = np.asarray(value, dtype=float)
        shape = np.broadcast_shapes(bad.shape, value.shape)
        offending = np.broadcast_to(value, shape)[np.broadcast_to(bad, shape)]
        raise ValueError(f"{field} = {_shown(offending if offending.size > 1 else offending[0])} is not "
                         f"allowed: {allowed}.")


def _finite(field: str, value, unit: str = "") -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    _fail(field, ~np.isfinite(arr), arr, f"{field} must be a finite number{unit}")
    return arr


def _polyval_z(coef: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Horner evaluation of sum coef[k] * z**k."""
    out = np.full_like(z, coef[-1])
    for c in coef[-2::-1]:
        out = out * z + c
    return out


# --------------------------------------------------------------------------------------------------
# Cancellation-free pieces shared by Kepler's equation and the Stumpff functions.


def _x_minus_sin(x: np.ndarray) -> np.ndarray:
    """x - sin(x) without cancellation: a series for |x| < 1.5, the direct difference beyond."""
    x2 = x * x
    small = x2 < _SERIES_Z_MAX
    out = np.empty_like(x)
    out[small] = x[small] * x2[small] * _polyval_z(_S_COEF, x2[small])
    out[~small] = x[~small] - np.sin(x[~small])
    return out


def _sinh_minus_x(x: np.ndarray) -> np.ndarray:
    """sinh(x) - x without cancellation: a series for |x| < 1.5, the direct difference beyond."""
    x2 = x * x
    small = x2 < _SERIES_Z_MAX
    out = np.empty_like(x)
    out[small] = x[small] * x2[small] * _polyval_z(_S_COEF, -x2[small])
    out[~small] = np.sinh(x[~small]) - x[~small]
    return out


def _stumpff(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stumpff functions C(z) = c2 and S(z) = c3 for any real z (series near zero).

    For z > 0 C = 2 sin(sqrt(z)/2)**2 / z (no cancellation) and S = (x - sin x) / x**3 with x = sqrt(z);
    for z < 0 the hyperbolic analogues. Large negative z overflows to inf, which the caller's bracket
    handles.
    """
    c = np.empty_like(z)
    s = np.empty_like(z)
    small = np.abs(z) < _SERIES_Z_MAX
    pos = (z > 0) & ~small
    neg = (z < 0) & ~small
    c[small] = _polyval_z(_C_COEF, z[small])
    s[small] = _polyval_z(_S_COEF, z[small])
    x = np.sqrt(z[pos])
    c[pos] = 2.0 * np.sin(0.5 * x) ** 2 / z[pos]
    s[pos] = (x - np.sin(x)) / (x * x * x)
    x = np.sqrt(-z[neg])
    with np.errstate(over="ignore", invalid="ignore"):
        c[neg] = 2.0 * np.sinh(0.5 * x) ** 2 / -z[neg]
        s[neg] = (np.sinh(x) - x) / (x * x * x)
    return c, s


# --------------------------------------------------------------------------------------------------
# Kepler's equation.


def _wrap_2pi(x: np.ndarray) -> np.ndarray:
    """x modulo 2 pi in [0, 2 pi): np.mod rounds tiny negative angles up to exactly 2 pi."""
    y = np.mod(x, _TWO_PI)
    return np.where(y >= _TWO_PI, 0.0, y)


def _reduce_angle(M: np.ndarray) -> np.ndarray:
    """M - 2 pi k in [-pi, pi] with k = round(M / 2 pi), accurate near multiples of 2 pi.

    Exact-product Cody-Waite reduction for |M| < 8.4e8 rad. Beyond, the binary64 M itself is coarse
    (ulp >= 1.2e-7) and the reduction is done against the binary64 2 pi with fmod (exact), which
    costs an absolute phase error of about 4e-17 |M|: still round-off relative to |M|.
    """
    k = np.round(M / _TWO_PI)
    exact = np.abs(k) < _EXACT_K_MAX
    k = np.where(exact, k, 0.0)
    r = (((M - k * _TWO_PI_1) - k * _TWO_PI_2) - k * _TWO_PI_3) - k * _TWO_PI_4
    if not np.all(exact):
        far = np.fmod(M[~exact], _TWO_PI)
        r[~exact] = far - _TWO_PI * np.round(far / _TWO_PI)
    return r


def _kepler_elliptic(M: np.ndarray, e: np.ndarray) -> np.ndarray:
    """E solving E - e sin E = M for 0 <= e < 1 and finite M (1-d arrays)."""
    Mr = _reduce_angle(M)
    sign = np.where(Mr < 0.0, -1.0, 1.0)
    m = np.abs(Mr)  # in [0, pi]; the solution is odd in M
    one_minus_e = 1.0 - e  # exact for e >= 0.5 (Sterbenz), which is where it matters

    # Markley (1995), Celest. Mech. Dyn. Astr. 63, 101: Pade-cubic starter.
    pi2 = math.pi * math.pi
    alpha = (3.0 * pi2 + 1.6 * math.pi * (math.pi - m) / (1.0 + e)) / (pi2 - 6.0)
    d = 3.0 * one_minus_e + alpha * e
    q = 2.0 * alpha * d * one_minus_e - m * m
    r = 3.0 * alpha * d * (d - one_minus_e) * m + m * m * m
    w = np.cbrt(np.abs(r) + np.sqrt(np.maximum(q * q * q + r * r, 0.0))) ** 2
    E = (2.0 * r * w / (w * w + w * q + q * q) + m) / d

    def residual(E, m, e, one_minus_e):
        # E - e sin E - m = (E - sin E) + (1 - e) sin E - m: no cancellation as e -> 1, E -> 0.
        sE = np.sin(E)
        f0 = _x_minus_sin(E) + one_minus_e * sE - m
        # 1 - e cos E = (1 - e) + 2 e sin^2(E/2), again without cancellation.
        f1 = one_minus_e + 2.0 * e * np.sin(0.5 * E) ** 2
        return f0, f1, e * sE, e * np.cos(E)

    # Markley's fifth-order correction (one step of a Householder-type iteration).
    f0, f1, f2, f3 = residual(E, m, e, one_minus_e)
    d3 = -f0 / (f1 - 0.5 * f0 * f2 / f1)
    d4 = -f0 / (f1 + 0.5 * d3 * f2 + d3 * d3 * f3 / 6.0)
    d5 = -f0 / (f1 + 0.5 * d4 * f2 + d4 * d4 * f3 / 6.0 - d4 * d4 * d4 * f2 / 24.0)
    E = E + d5

    # Newton polish on the accurate residual, usually one step that changes nothing. Converged
    # entries are frozen, so a result does not depend on what else is in the batch.
    step = np.zeros_like(E)
    active = np.ones(E.shape, dtype=bool)
    for _ in range(_KEPLER_ELLIPTIC_ITER):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        f0, f1, _, _ = residual(E[idx], m[idx], e[idx], one_minus_e[idx])
        step_a = -f0 / f1
        E[idx] += step_a
        step[idx] = step_a
        active[idx] = np.abs(step_a) > 2.0 * _EPS * E[idx]
    _check_converged("solve_kepler (elliptic)", step, E)
    E = sign * E
    # Return M + (E - M) computed in the reduced range, so the revolution count of M is kept exactly
    # and e = 0 gives E = M bit for bit.
    return np.where(e == 0.0, M, M + (E - Mr))


def _kepler_hyperbolic(M: np.ndarray, e: np.ndarray) -> np.ndarray:
    """H solving e sinh H - H = M for e > 1 and finite M (1-d arrays)."""
    sign = np.where(M < 0.0, -1.0, 1.0)
    m = np.abs(M)
    em1 = e - 1.0  # exact for e <= 2 (Sterbenz), which is where it matters

    # Two upper bounds on the root, both safe from overflow:
    # 1. cubic: e sinh H - H >= (e - 1) H + e H^3 / 6, so the root of the cubic is >= H
    #    (stable Cardano form t = Q / (A^2 + P/3 + (P/(3A))^2), no cancellation);
    # 2. logarithmic: (e - 1) sinh H <= M gives H <= asinh(M/(e-1)) <= ln(2M + (e-1)) - ln(e-1).
    # Then one fixed-point step H <- asinh((M + H)/e) keeps the bound and tightens it a lot for
    # large M (Gooding & Odell 1988 use ln(2M/e) there).
    big = m > 1e100
    mc = np.where(big, 1.0, m)
    P = 6.0 * em1 / e
    Q = 6.0 * mc / e
    A = np.cbrt(0.5 * Q + np.sqrt(0.25 * Q * Q + P ** 3 / 27.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        B = np.where(A > 0.0, P / (3.0 * A), 0.0)
        h_cubic = np.where(A > 0.0, Q / (A * A + P / 3.0 + B * B), 0.0)
    h_cubic = np.where(big, np.inf, h_cubic)
    h_log = np.log(2.0 * mc + em1) - np.log(em1)
    h_log = np.where(big, np.log(np.where(big, m, 1.0)) - np.log(em1) + math.log(2.0), h_log)
    H = np.arcsinh((m + np.minimum(h_cubic, h_log)) / e)
    # For M > 1e280 sinh would overflow in the iteration; there e sinh H = e e^H / 2 to double
    # precision (e^-2H < 1e-17), and H << ulp(M), so the root is ln(2M/e) in closed form.
    huge = m > 1e280
    H[huge] = np.log(m[huge]) + math.log(2.0) - np.log(e[huge])

    step = np.zeros_like(H)
    active = ~huge
    for _ in range(_KEPLER_HYPERBOLIC_ITER):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        Ha, ea, em1a = H[idx], e[idx], em1[idx]
        sh = np.sinh(Ha)
        f0 = _sinh_minus_x(Ha) + em1a * sh - m[idx]
        f1 = em1a * np.cosh(Ha) + 2.0 * np.sinh(0.5 * Ha) ** 2  # e cosh H - 1 without cancellation
        newton = -f0 / f1
        # Halley written as a Newton step divided by a correction, so f0 * f1 never underflows.
        step_a = newton / (1.0 + 0.5 * newton * ea * sh / f1)
        H[idx] = Ha + step_a
        step[idx] = step_a
        active[idx] = np.abs(step_a) > 2.0 * _EPS * H[idx]
    _check_converged("solve_kepler (hyperbolic)", step, H)
    return sign * H


def _barker(M: np.ndarray) -> np.ndarray:
    """D = tan(nu/2) solving D + D^3/3 = M (Barker), closed form plus one Newton polish."""
    m = np.abs(M)
    # Beyond 1e100, D = cbrt(3M) to double precision (the next term is relatively 1e-67), and the
    # closed form below would overflow.
    big = m > 1e100
    mc = np.where(big, 1.0, m)
    w = 1.5 * mc + np.hypot(1.0, 1.5 * mc)
    z = np.cbrt(w)
    # D = z - 1/z, rewritten as 3M / (z^2 + 1 + z^-2) because z^3 - z^-3 = 3M: no cancellation.
    D = 3.0 * mc / (z * z + 1.0 + 1.0 / (z * z))
    D = D - (D + D ** 3 / 3.0 - mc) / (1.0 + D * D)
    D = np.where(big, np.cbrt(3.0) * np.cbrt(m), D)
    return np.where(M < 0.0, -D, D)


def _check_converged(what: str, step: np.ndarray, x: np.ndarray) -> None:
    # Should never fire: the starters and iteration bounds were checked against 50-digit references.
    if np.any(np.abs(step) > 1e-12 * np.maximum(1.0, np.abs(x))):
        raise ArithmeticError(f"{what} did not converge within its iteration bound; please report this "
                              "input.")


def _check_e(e: np.ndarray) -> None:
    _fail("e", e < 0.0, e, "the eccentricity e must be >= 0 (0 circular, < 1 elliptic, 1 parabolic, "
          "> 1 hyperbolic)")


def solve_kepler(M, e):
    """Solve Kepler's equation for any conic, vectorised over numpy broadcasting of ``M`` and ``e``.

    Parameters
    ----------
    M : array_like
        Mean anomaly (rad for e != 1; dimensionless Barker value for e == 1), any real value.
    e : array_like
        Eccentricity, >= 0.

    Returns
    -------
    numpy.ndarray or numpy.float64
        * ``0 <= e < 1``: eccentric anomaly ``E`` (rad) with ``E - e sin E = M``. ``M`` is reduced
          modulo 2 pi internally but the revolution count is kept, so ``E`` is continuous in ``M`` and
          ``E = M`` exactly at ``e = 0``.
        * ``e > 1``: hyperbolic anomaly ``H`` with ``e sinh H - H = M``.
        * ``e == 1``: ``D = tan(nu/2)`` with ``D + D**3/3 = M`` (Barker, closed form).

        Accuracy: within about 5e-16 * max(1, |E|) of a 50-digit reference
        (``fixtures/reference/kepler``). NaN or infinite input gives NaN (no endless loop).

    Raises
    ------
    ValueError
        If any ``e`` is negative.
    """
    M_arr = np.asarray(M, dtype=float)
    e_arr = np.asarray(e, dtype=float)
    _check_e(e_arr)
    M_b, e_b = np.broadcast_arrays(M_arr, e_arr)
    shape = M_b.shape
    M1 = M_b.ravel()
    e1 = e_b.ravel()
    out = np.full(M1.shape, np.nan)
    ok = np.isfinite(M1) & np.isfinite(e1)
    ell = ok & (e1 < 1.0)
    hyp = ok & (e1 > 1.0)
    par = ok & (e1 == 1.0)
    if np.any(ell):
        out[ell] = _kepler_elliptic(M1[ell], e1[ell])
    if np.any(hyp):
        out[hyp] = _kepler_hyperbolic(M1[hyp], e1[hyp])
    if np.any(par):
        out[par] = _barker(M1[par])
    return out.reshape(shape)[()]


def true_anomaly_from_mean(M, e):
    """True anomaly ``nu`` (rad) from the conic-appropriate mean anomaly ``M``, vectorised.

    Elliptic: ``nu = E + 2 atan(beta sin E / (1 - beta cos E))`` with ``beta = e / (1 + sqrt(1 - e^2))``,
    so ``nu`` keeps the revolution count of ``M``. Hyperbolic: ``nu`` in (-nu_inf, nu_inf) with
    ``nu_inf = acos(-1/e)``. Parabolic: ``nu = 2 atan(D)`` in (-pi, pi).
    """
    e_arr = np.asarray(e, dtype=float)
    _check_e(e_arr)
    X = solve_kepler(M, e_arr)
    X, e_b = np.broadcast_arrays(np.asarray(X, dtype=float), e_arr)
    nu = np.full(X.shape, np.nan)
    ell = e_b < 1.0
    hyp = e_b > 1.0
    par = e_b == 1.0
    if np.any(ell):
        E, ee = X[ell], e_b[ell]
        s = np.sqrt((1.0 - ee) * (1.0 + ee))
        beta = ee / (1.0 + s)
        # 1 - beta cos E = (1 - beta) + 2 beta sin^2(E/2), and 1 - beta = ((1 - e) + s) / (1 + s).
        den = ((1.0 - ee) + s) / (1.0 + s) + 2.0 * beta * np.sin(0.5 * E) ** 2
        nu[ell] = E + 2.0 * np.arctan2(beta * np.sin(E), den)
    if np.any(hyp):
        H, ee = X[hyp], e_b[hyp]
        nu[hyp] = 2.0 * np.arctan(np.sqrt((ee + 1.0) / (ee - 1.0)) * np.tanh(0.5 * H))
    if np.any(par):
        nu[par] = 2.0 * np.arctan(X[par])
    return nu[()]


def _check_hyperbolic_nu(nu: np.ndarray, e: np.ndarray, field: str = "nu") -> None:
    """Refuse a true anomaly on or beyond the asymptote of an open orbit."""
    with np.errstate(invalid="ignore"):
        nu_inf = np.where(e >= 1.0, np.arccos(-1.0 / np.maximum(e, 1.0)), np.inf)
    _fail(field, np.abs(nu) >= nu_inf, nu,
          f"for an open orbit (e >= 1) the true anomaly {field} must lie strictly between the "
          "asymptotes, |nu| < acos(-1/e) (|nu| < pi for e = 1)")


def mean_from_true_anomaly(nu, e):
    """Conic-appropriate mean anomaly ``M`` from the true anomaly ``nu`` (rad), vectorised.

    Elliptic: ``M = E - e sin E`` with the revolution count of ``nu`` kept. Hyperbolic:
    ``M = e sinh H - H``. Parabolic: ``M = D + D**3/3`` with ``D = tan(nu/2)``.

    Raises ValueError for e < 0 or for an open orbit's ``nu`` on or beyond the asymptote.
    """
    nu_arr = _finite("nu", nu, " in rad")
    e_arr = np.asarray(e, dtype=float)
    _check_e(e_arr)
    nu_b, e_b = np.broadcast_arrays(nu_arr, e_arr)
    _check_hyperbolic_nu(nu_b, e_b)
    return _mean_from_true(nu_b, e_b)[()]


def _mean_from_true(nu: np.ndarray, e: np.ndarray) -> np.ndarray:
    """mean_from_true_anomaly without validation; an open orbit's nu is clamped inside the asymptote."""
    M = np.full(nu.shape, np.nan)
    ell = e < 1.0
    hyp = e > 1.0
    par = e == 1.0
    if np.any(ell):
        v, ee = nu[ell], e[ell]
        # Reduce nu to (-pi, pi] keeping k revolutions, then tan(E/2) = sqrt((1-e)/(1+e)) tan(nu/2) in
        # atan2 form: no cancellation for small E as e -> 1 (nu - 2 atan(...) would lose digits).
        k = np.round(v / _TWO_PI)
        v0 = _reduce_angle(v)
        E0 = 2.0 * np.arctan2(np.sqrt(1.0 - ee) * np.sin(0.5 * v0), np.sqrt(1.0 + ee) * np.cos(0.5 * v0))
        # E - e sin E; the cancellation-free form for small |E|.
        small = np.abs(E0) < 1.0
        M0 = E0 - ee * np.sin(E0)
        M0[small] = _x_minus_sin(E0[small]) + (1.0 - ee[small]) * np.sin(E0[small])
        M[ell] = np.where(k == 0.0, M0, M0 + k * _TWO_PI)
    if np.any(hyp):
        v, ee = nu[hyp], e[hyp]
        # tanh(H/2) = sqrt((e-1)/(e+1)) tan(nu/2); clamp below 1 so rounding at the asymptote gives a
        # large finite H rather than inf.
        th = np.clip(np.sqrt((ee - 1.0) / (ee + 1.0)) * np.tan(0.5 * v), -1.0 + _EPS, 1.0 - _EPS)
        H = 2.0 * np.arctanh(th)
        M[hyp] = _sinh_minus_x(H) + (ee - 1.0) * np.sinh(H)
    if np.any(par):
        D = np.tan(0.5 * nu[par])
        M[par] = D + D ** 3 / 3.0
    return M


# --------------------------------------------------------------------------------------------------
# Elements <-> state.


@dataclass(frozen=True, eq=False)
class Elements:
    """Classical orbital elements (arrays broadcast over the leading axes of the state).

    Attributes
    ----------
    p : semi-latus rectum, m.
    a : semi-major axis, m (> 0 elliptic, < 0 hyperbolic, ``inf`` only when ``e == 1`` exactly).
    e : eccentricity.
    i : inclination, rad, in [0, pi].
    raan : right ascension of the ascending node, rad, in [0, 2 pi); 0 for equatorial orbits.
    argp : argument of perigee, rad, in [0, 2 pi); 0 for circular orbits, measured from the x axis
        (longitude of perigee) for equatorial orbits.
    nu : true anomaly, rad: in [0, 2 pi) for e < 1, in (-nu_inf, nu_inf) for e >= 1; the argument of
        latitude for circular orbits, the true longitude for circular equatorial ones.
    M : conic-appropriate mean anomaly (see module docstring): in [0, 2 pi] for e < 1.
    arglat : argument of latitude ``argp + nu``, rad, in [0, 2 pi).
    truelon : true longitude ``raan + argp + nu``, rad, in [0, 2 pi) (angles summed as in the element
        set: for retrograde orbits this runs in the direction of motion, not eastward).
    """

    p: np.ndarray
    a: np.ndarray
    e: np.ndarray
    i: np.ndarray
    raan: np.ndarray
    argp: np.ndarray
    nu: np.ndarray
    M: np.ndarray
    arglat: np.ndarray
    truelon: np.ndarray


def _check_mu(mu) -> float:
    mu_arr = _finite("mu", mu, " in m^3/s^2")
    _fail("mu", mu_arr <= 0.0, mu_arr, "the gravitational parameter mu must be > 0 m^3/s^2")
    return mu_arr


def elements_to_state(*, e, i, raan, argp, a=None, p=None, nu=None, M=None, tp=None, t=0.0, mu=MU_EARTH,
                      min_radius=None):
    """Position and velocity (inertial frame, m and m/s) from classical elements, vectorised.

    Give the size as exactly one of ``a`` (semi-major axis, m; not allowed for e == 1) or ``p``
    (semi-latus rectum, m), and the position on the orbit as exactly one of ``nu`` (true anomaly,
    rad), ``M`` (conic-appropriate mean anomaly, see the module docstring) or ``tp`` (time of perigee
    passage, s, with ``t`` the time at which the state is wanted, so ``M = n (t - tp)``; ``t`` is used
    only with ``tp``). ``e``, ``i``, ``raan``, ``argp`` are the eccentricity and angles in rad.
    Arguments broadcast against each other.

    ``min_radius`` (m), when given, refuses orbits whose perigee radius ``p / (1 + e)`` is below it
    (e.g. ``R_EARTH``: a trajectory through the Earth).

    Returns
    -------
    r, v : numpy.ndarray, shape (..., 3)
        Position (m) and velocity (m/s) in the frame the angles are measured in.

    Raises
    ------
    ValueError
        One sentence naming the field, the value and what is allowed, for: a missing or doubled
        size or anomaly argument; non-finite values; e < 0; p <= 0; a <= 0 with e < 1, a >= 0 with
        e > 1, or a given with e == 1; i outside [0, pi]; an open orbit's nu on or beyond the
        asymptote; a perigee below ``min_radius``; mu <= 0.
    """
    if (a is None) == (p is None):
        raise ValueError("Give exactly one of a (semi-major axis, m) or p (semi-latus rectum, m); "
                         f"got {'both' if a is not None else 'neither'}.")
    given = [name for name, val in (("nu", nu), ("M", M), ("tp", tp)) if val is not None]
    if len(given) != 1:
        raise ValueError("Give exactly one of nu (true anomaly, rad), M (mean anomaly) or tp (time of "
                         f"perigee passage, s); got {', '.join(given) if given else 'none'}.")
    mu = _check_mu(mu)
    e = _finite("e", e)
    _check_e(e)
    i = _finite("i", i, " in rad")
    _fail("i", (i < 0.0) | (i > math.pi), i, "the inclination i must lie in [0, pi] rad")
    raan = _finite("raan", raan, " in rad")
    argp = _finite("argp", argp, " in rad")

    if p is not None:
        p = _finite("p", p, " in m")
        _fail("p", p <= 0.0, p, "the semi-latus rectum p must be > 0 m")
        p, e_s = np.broadcast_arrays(p, e)
    else:
        a = _finite("a", a, " in m")
        a, e_s = np.broadcast_arrays(a, e)
        _fail("a", e_s == 1.0, a, "inconsistent a and e: a parabolic orbit (e = 1) has no finite "
              "semi-major axis, give p instead")
        _fail("a", (e_s < 1.0) & (a <= 0.0), a, "inconsistent a and e: an elliptic orbit (e < 1) needs "
              "a > 0 m")
        _fail("a", (e_s > 1.0) & (a >= 0.0), a, "inconsistent a and e: a hyperbolic orbit (e > 1) needs "
              "a < 0 m")
        p = a * ((1.0 - e_s) * (1.0 + e_s))

    if min_radius is not None:
        min_radius = _finite("min_radius", min_radius, " in m")
        rp = p / (1.0 + e_s)
        if np.any(rp < min_radius):
            bad = rp < min_radius
            raise ValueError(
                f"The perigee radius p/(1+e) = {_shown(np.broadcast_to(rp, bad.shape)[bad])} m is below "
                f"min_radius = {_shown(np.broadcast_to(min_radius, bad.shape)[bad])} m: the trajectory "
                "would pass through the central body; raise p or a, or lower e.")

    if nu is not None:
        nu = _finite("nu", nu, " in rad")
        _check_hyperbolic_nu(*np.broadcast_arrays(nu, e_s))
    else:
        if M is None:
            tp = _finite("tp", tp, " in s")
            t = _finite("t", t, " in s")
            # Mean motion of the conic: sqrt(mu/|a|^3) with |a| = p/|1 - e^2|, Barker's 2 sqrt(mu/p^3).
            one_m_e2 = np.abs((1.0 - e_s) * (1.0 + e_s))
            n = np.where(e_s == 1.0, 2.0, one_m_e2 ** 1.5) * np.sqrt(mu / p ** 3)
            M = n * (t - tp)
        else:
            M = _finite("M", M)
        nu = true_anomaly_from_mean(M, e_s)

    shape = np.broadcast_shapes(np.shape(nu), p.shape, e_s.shape, i.shape, raan.shape, argp.shape,
                                np.shape(mu))
    nu, p, e_s, i, raan, argp = (np.broadcast_to(x, shape) for x in (nu, p, e_s, i, raan, argp))
    cnu, snu = np.cos(nu), np.sin(nu)
    r_mag = p / (1.0 + e_s * cnu)
    vs = np.sqrt(mu / p)
    # Perifocal position and velocity, then the rotation R3(-raan) R1(-i) R3(-argp) through its first
    # two columns P (towards perigee) and Q (90 deg ahead in the plane).
    r_pf_x, r_pf_y = r_mag * cnu, r_mag * snu
    v_pf_x, v_pf_y = -vs * snu, vs * (e_s + cnu)
    cO, sO = np.cos(raan), np.sin(raan)
    cw, sw = np.cos(argp), np.sin(argp)
    ci, si = np.cos(i), np.sin(i)
    P = np.stack([cO * cw - sO * sw * ci, sO * cw + cO * sw * ci, sw * si], axis=-1)
    Q = np.stack([-cO * sw - sO * cw * ci, -sO * sw + cO * cw * ci, cw * si], axis=-1)
    r = r_pf_x[..., None] * P + r_pf_y[..., None] * Q
    v = v_pf_x[..., None] * P + v_pf_y[..., None] * Q
    return r, v


def _check_state(r, v) -> tuple[np.ndarray, np.ndarray]:
    r = _finite("r", r, " in m")
    v = _finite("v", v, " in m/s")
    if r.shape[-1:] != (3,) or v.shape[-1:] != (3,):
        raise ValueError(f"r and v must be (..., 3) arrays of position (m) and velocity (m/s); got shapes "
                         f"{r.shape} and {v.shape}.")
    return r, v


def _check_orbit_plane(r: np.ndarray, v: np.ndarray, rn: np.ndarray, hn: np.ndarray) -> None:
    """Refuse r = 0 and r x v = 0 (rectilinear motion has no orbit plane), showing the vectors."""

    def first(x, bad):
        return [float(c) for c in np.broadcast_to(x, bad.shape + (3,))[bad][0]]

    if np.any(rn == 0.0):
        raise ValueError(f"r = {first(r, rn == 0.0)} is not allowed: the position must not be the centre of "
                         "attraction (|r| > 0 m).")
    if np.any(hn == 0.0):
        bad = hn == 0.0
        raise ValueError(f"v = {first(v, bad)} m/s is not allowed with r = {first(r, bad)} m: the angular "
                         "momentum r x v must not be zero (rectilinear motion has no orbit plane and is "
                         "not supported).")


def state_to_elements(r, v, mu=MU_EARTH) -> Elements:
    """Classical elements from inertial position ``r`` (m) and velocity ``v`` (m/s), vectorised.

    ``r`` and ``v`` are ``(..., 3)``; every field of the result has shape ``(...)``. Singular cases
    follow the conventions in the module docstring (circular: ``argp = 0``; equatorial: ``raan = 0``;
    both: ``nu`` is the true longitude). ``a`` is ``inf`` only when the computed ``e`` is exactly 1.

    Raises ValueError for non-finite input, ``r = 0``, or zero angular momentum (a rectilinear
    trajectory has no orbit plane).
    """
    r, v = _check_state(r, v)
    mu = _check_mu(mu)
    r, v = np.broadcast_arrays(r, v)
    rn = np.linalg.norm(r, axis=-1)
    h = np.cross(r, v)
    hn = np.linalg.norm(h, axis=-1)
    _check_orbit_plane(r, v, rn, hn)
    hx, hy, hz = h[..., 0], h[..., 1], h[..., 2]
    hxy = np.hypot(hx, hy)
    p = hn * hn / mu

    # Eccentricity vector e = (v x h)/mu - r/|r|.
    e_vec = np.cross(v, h) / np.asarray(mu)[..., None] - r / rn[..., None]
    e = np.linalg.norm(e_vec, axis=-1)
    inc = np.arctan2(hxy, hz)  # accurate near 0 and pi, unlike acos(hz/|h|)

    equatorial = (inc < INC_EQUATORIAL) | (math.pi - inc < INC_EQUATORIAL)
    circular = e < ECC_CIRCULAR
    safe_hxy = np.where(equatorial, 1.0, hxy)
    sO = np.where(equatorial, 0.0, hx / safe_hxy)
    cO = np.where(equatorial, 1.0, -hy / safe_hxy)
    raan = np.where(equatorial, 0.0, _wrap_2pi(np.arctan2(sO, cO)))

    # Components along the line of nodes N = (cos raan, sin raan, 0) and along h_hat x N (which
    # reduces to cos i (-sin raan, cos raan, 0) + sin i (0, 0, 1)); with raan := 0 for equatorial
    # orbits the angles are measured from x.
    ci, si = hz / hn, hxy / hn

    def in_plane_angle(x):
        along_n = x[..., 0] * cO + x[..., 1] * sO
        along_m = ci * (x[..., 1] * cO - x[..., 0] * sO) + si * x[..., 2]
        return np.arctan2(along_m, along_n)

    arglat = _wrap_2pi(in_plane_angle(r))
    # True anomaly straight from the state: e cos nu = p/r - 1, e sin nu = (r . v) |h| / (mu |r|).
    ecosnu = p / rn - 1.0
    esinnu = np.sum(r * v, axis=-1) * hn / (mu * rn)
    nu = np.arctan2(esinnu, ecosnu)
    nu = np.where(circular, arglat, nu)
    closed = e < 1.0
    nu = np.where(closed, _wrap_2pi(nu), nu)
    argp = np.where(circular, 0.0, _wrap_2pi(arglat - nu))
    truelon = _wrap_2pi(raan + arglat)

    one_m_e2 = (1.0 - e) * (1.0 + e)
    with np.errstate(divide="ignore"):
        a = np.where(e == 1.0, np.inf, p / np.where(e == 1.0, 1.0, one_m_e2))
    M = _mean_from_true(nu, e)
    M = np.where(closed, _wrap_2pi(M), M)
    return Elements(p=p[()], a=a[()], e=e[()], i=inc[()], raan=raan[()], argp=argp[()], nu=nu[()],
                    M=np.asarray(M)[()], arglat=arglat[()], truelon=truelon[()])


# --------------------------------------------------------------------------------------------------
# Universal-variable two-body propagation.


def propagate_kepler(r, v, dt, mu=MU_EARTH):
    """Two-body state after ``dt`` seconds, for every conic, by universal variables.

    Parameters
    ----------
    r, v : array_like, shape (..., 3)
        Initial inertial position (m) and velocity (m/s).
    dt : array_like
        Time offsets (s), positive or negative; broadcasts against the leading axes of ``r`` and ``v``
        (e.g. one state and an array of times gives ``(len(dt), 3)`` outputs).
    mu : float
        Gravitational parameter, m^3/s^2.

    Returns
    -------
    r, v : numpy.ndarray, shape (..., 3)

    Method: Goodyear/Shepperd/Vallado universal variable chi with Stumpff functions (series near zero,
    so it is continuous across e = 1), started from Kepler's equation of the osculating conic and
    solved by Laguerre-Conway steps inside a bracket that is known to hold the root (F(chi) is
    increasing with F' = r, and |chi| <= sqrt(mu)|dt|/r_p), with bisection whenever a step leaves the
    bracket or stalls; at most 100 iterations. Elliptic ``dt`` is first reduced modulo the period.
    Zero angular momentum (rectilinear motion) is refused.

    Accuracy is limited by the state itself: alpha = 2/r - v^2/mu loses log10(1/|1 - e|) digits to
    cancellation, so the timing of a long near-parabolic arc carries a relative error of about
    1e-16/|1 - e| (e.g. one period of an e = 0.999999 orbit is uncertain by parts in 1e10).
    """
    r, v = _check_state(r, v)
    mu = float(_check_mu(mu))
    dt = _finite("dt", dt, " in s")
    shape = np.broadcast_shapes(r.shape[:-1], v.shape[:-1], dt.shape)
    r0 = np.broadcast_to(r, shape + (3,)).reshape(-1, 3)
    v0 = np.broadcast_to(v, shape + (3,)).reshape(-1, 3)
    dt = np.broadcast_to(dt, shape).ravel().astype(float)

    r0n = np.linalg.norm(r0, axis=-1)
    hvec = np.cross(r0, v0)
    hn = np.linalg.norm(hvec, axis=-1)
    _check_orbit_plane(r0, v0, r0n, hn)
    sqmu = math.sqrt(mu)
    rv = np.sum(r0 * v0, axis=-1)
    sigma0 = rv / sqmu
    alpha = 2.0 / r0n - np.sum(v0 * v0, axis=-1) / mu  # 1/a
    ecc = np.linalg.norm(np.cross(v0, hvec) / mu - r0 / r0n[:, None], axis=-1)
    rp = hn * hn / mu / (1.0 + ecc)

    # Elliptic: reduce dt modulo the period so chi stays within about one revolution.
    ell = alpha > 0.0
    period = np.full_like(alpha, np.inf)
    period[ell] = _TWO_PI / math.sqrt(mu) / alpha[ell] ** 1.5
    k = np.where(ell, np.round(dt / period), 0.0)
    k = np.where(np.isfinite(k), k, 0.0)
    dt_r = dt - k * np.where(ell, period, 0.0)

    # Bracket: |chi| <= sqrt(mu) |dt| / r_p; for elliptic orbits also |Delta E| <= |Delta M| + 2e.
    chi_max = sqmu * np.abs(dt_r) / rp
    chi_max[ell] = np.minimum(chi_max[ell], (math.pi + 2.0 * ecc[ell]) / np.sqrt(alpha[ell]))
    lo = np.where(dt_r >= 0.0, 0.0, -chi_max)
    hi = np.where(dt_r >= 0.0, chi_max, 0.0)
    chi = np.clip(_universal_starter(r0n, sigma0, alpha, hn * hn / mu, dt_r, mu), lo, hi)
    one_m_ar = 1.0 - alpha * r0n
    sdt = sqmu * dt_r

    done = dt_r == 0.0
    chi[done] = 0.0
    last_step = np.full_like(chi, np.inf)  # |step| one and two iterations ago, for the safeguard
    prev_step = np.full_like(chi, np.inf)
    n_lag = 5.0
    for _ in range(_UNIVERSAL_ITER):
        idx = np.flatnonzero(~done)
        if idx.size == 0:
            break
        x = chi[idx]
        z = alpha[idx] * x * x
        with np.errstate(over="ignore", invalid="ignore"):
            c, s = _stumpff(z)
            x2 = x * x
            F = sigma0[idx] * x2 * c + one_m_ar[idx] * x2 * x * s + r0n[idx] * x - sdt[idx]
            dF = sigma0[idx] * x * (1.0 - z * s) + one_m_ar[idx] * x2 * c + r0n[idx]
            d2F = sigma0[idx] * (1.0 - z * c) + one_m_ar[idx] * x * (1.0 - z * s)
            # F is increasing: its sign tells which side of the root x is on. An overflowed F (far out
            # on a hyperbola) is beyond the root on the side of x.
            bad_F = ~np.isfinite(F)
            lo_a = np.where((F < 0.0) | (bad_F & (x < 0.0)), x, lo[idx])
            hi_a = np.where((F > 0.0) | (bad_F & (x > 0.0)), x, hi[idx])
            # Laguerre-Conway step (n = 5).
            disc = np.sqrt(np.abs((n_lag - 1.0) ** 2 * dF * dF - n_lag * (n_lag - 1.0) * F * d2F))
            x_new = x - n_lag * F / (dF + disc)
        # Safeguard (as in rtsafe): bisect when the step leaves the bracket or is not at least half the
        # step before last, e.g. while creeping down the exponential wall of a hyperbola.
        slow = np.abs(x_new - x) > 0.5 * prev_step[idx]
        bisect = ~np.isfinite(x_new) | (x_new <= lo_a) | (x_new >= hi_a) | slow
        x_new = np.where(F == 0.0, x, np.where(bisect, 0.5 * (lo_a + hi_a), x_new))
        step = np.abs(x_new - x)
        tol = 4.0 * _EPS * np.maximum(np.abs(x_new), 1e-300)
        conv = (step <= tol) | (hi_a - lo_a <= tol) | (F == 0.0)
        lo[idx], hi[idx], chi[idx] = lo_a, hi_a, x_new
        prev_step[idx] = last_step[idx]
        last_step[idx] = step
        done[idx] = conv
    if not np.all(done):
        raise ArithmeticError("propagate_kepler did not converge within its iteration bound; please report "
                              "this input.")

    z = alpha * chi * chi
    c, s = _stumpff(z)
    chi2 = chi * chi
    rn = sigma0 * chi * (1.0 - z * s) + one_m_ar * chi2 * c + r0n  # = dF/dchi = |r(t)|
    f = 1.0 - chi2 * c / r0n
    g = dt_r - chi2 * chi * s / sqmu
    fdot = sqmu / (rn * r0n) * chi * (z * s - 1.0)
    gdot = 1.0 - chi2 * c / rn
    r_out = f[:, None] * r0 + g[:, None] * v0
    v_out = fdot[:, None] * r0 + gdot[:, None] * v0
    return r_out.reshape(shape + (3,)), v_out.reshape(shape + (3,))


def _universal_starter(r0n, sigma0, alpha, p, dt, mu):
    """Starting chi from Kepler's equation for the conic that alpha = 1/a says it is.

    chi = Delta E / sqrt(alpha) (ellipse), Delta H / sqrt(-alpha) (hyperbola), sqrt(p) Delta D
    (parabola). The eccentricity is taken as sqrt(1 - p alpha) so it always agrees with the sign of
    alpha. Only a starter: the universal iteration polishes it (the state -> anomaly map is
    ill-conditioned near e = 1, the universal equation is not).
    """
    chi = np.zeros_like(r0n)
    e = np.sqrt(np.maximum(1.0 - p * alpha, 0.0))
    ell = alpha > 0.0
    hyp = alpha < 0.0
    par = alpha == 0.0
    if np.any(ell):
        sa = np.sqrt(alpha[ell])
        ee = e[ell]
        E0 = np.arctan2(sigma0[ell] * sa, 1.0 - r0n[ell] * alpha[ell])
        M1 = E0 - ee * np.sin(E0) + math.sqrt(mu) * sa ** 3 * dt[ell]
        chi[ell] = (solve_kepler(M1, ee) - E0) / sa
    if np.any(hyp):
        sa = np.sqrt(-alpha[hyp])
        ee = e[hyp]
        H0 = np.arcsinh(sigma0[hyp] * sa / ee)
        M1 = ee * np.sinh(H0) - H0 + math.sqrt(mu) * sa ** 3 * dt[hyp]
        chi[hyp] = (solve_kepler(M1, ee) - H0) / sa
    if np.any(par):
        sp = np.sqrt(p[par])
        D0 = sigma0[par] / sp
        D1 = solve_kepler(D0 + D0 ** 3 / 3.0 + 2.0 * math.sqrt(mu) / sp ** 3 * dt[par], 1.0)
        chi[par] = sp * (D1 - D0)
    return chi


# --------------------------------------------------------------------------------------------------
# J2 gravity and its propagator.


def accel_j2(r, mu=MU_EARTH, j2=J2_EARTH, r_eq=R_EARTH):
    """Point-mass plus J2 gravitational acceleration (m/s^2), vectorised over ``(..., 3)`` positions.

    ``r`` (m) is in a body-centred frame whose z axis is the body's pole (rotation axis). The stand
    treats the inertial frame's z as the Earth's pole (the pole's precession is far below what J2
    accuracy needs over a scenario), so ``r`` may be given in ``gcrs``. ``j2`` is the unnormalised
    zonal coefficient, ``r_eq`` its reference radius (m).
    """
    r = _finite("r", r, " in m")
    rn2 = np.sum(r * r, axis=-1)
    rn = np.sqrt(rn2)
    z2_r2 = r[..., 2] ** 2 / rn2
    k = 1.5 * j2 * r_eq * r_eq / rn2
    base = -mu / (rn2 * rn)
    fxy = base * (1.0 + k * (1.0 - 5.0 * z2_r2))
    fz = base * (1.0 + k * (3.0 - 5.0 * z2_r2))
    return np.stack([fxy * r[..., 0], fxy * r[..., 1], fz * r[..., 2]], axis=-1)


def j2_energy(r, v, mu=MU_EARTH, j2=J2_EARTH, r_eq=R_EARTH):
    """Specific energy (J/kg) in the point-mass plus J2 field.

    ``v^2/2 - mu/r + mu j2 r_eq^2 (3 z^2/r^2 - 1) / (2 r^3)``, the last term being the J2 potential.
    Conserved by motion under ``accel_j2`` in a frame whose z axis is the (fixed) pole. Vectorised over
    ``(..., 3)`` inputs (m, m/s).
    """
    r = np.asarray(r, dtype=float)
    v = np.asarray(v, dtype=float)
    rn2 = np.sum(r * r, axis=-1)
    rn = np.sqrt(rn2)
    p2 = 0.5 * (3.0 * r[..., 2] ** 2 / rn2 - 1.0)
    return 0.5 * np.sum(v * v, axis=-1) - mu / rn + mu * j2 * r_eq * r_eq * p2 / (rn2 * rn)


def _output_grid(duration_s: float, step_s: float) -> np.ndarray:
    """0, h, 2h, ... and a last partial step that ends exactly at duration_s."""
    n_full = math.floor(duration_s / step_s)
    # A remainder below 1e-9 of a step is round-off in duration/step, not a real partial step.
    if duration_s - n_full * step_s <= 1e-9 * step_s:
        t = np.arange(n_full + 1) * step_s
        t[-1] = duration_s
        return t
    t = np.arange(n_full + 2) * step_s
    t[-1] = duration_s
    return t


def propagate_j2(r0, v0, duration_s, step_s, mu=MU_EARTH, j2=J2_EARTH, r_eq=R_EARTH, method="rk4", *,
                 rtol=1e-12, atol=1e-6):
    """Cowell propagation under point-mass + J2 gravity (``accel_j2``), output at every step.

    Parameters
    ----------
    r0, v0 : array_like, shape (3,)
        Initial inertial position (m) and velocity (m/s); z is the pole (see ``accel_j2``).
    duration_s : float
        Span to propagate, s (>= 0).
    step_s : float
        Output spacing and, for ``"rk4"``, the integration step, s. The last step is shortened so the
        output ends exactly at ``duration_s``.
    method : {"rk4", "dop853"}
        ``"rk4"``: fixed-step classical Runge-Kutta, the force re-evaluated at each of the four stages
        (never held across the step). ``"dop853"``: scipy ``solve_ivp`` DOP853 with ``rtol`` and
        ``atol`` (atol in m and m/s alike), its dense output sampled on the same grid; an offline
        reference, not for the real-time loop.

    Returns
    -------
    t : (N,) s from 0; r : (N, 3) m; v : (N, 3) m/s.

    Raises
    ------
    ValueError
        For a non-positive or non-finite ``step_s``; for RK4, a step longer than one twentieth of the
        orbital period (of the circular orbit at perigee for open orbits), which is where RK4 stops
        being accurate; a negative ``duration_s``; an unknown ``method``. Note the period/20 limit is a
        necessary guard, not a sufficient one for eccentric orbits, where the error concentrates at
        perigee (numerics note, section 3.5).
    """
    r0 = _finite("r0", r0, " in m").reshape(-1)
    v0 = _finite("v0", v0, " in m/s").reshape(-1)
    if r0.shape != (3,) or v0.shape != (3,):
        raise ValueError(f"r0 and v0 must each be 3-vectors (m, m/s); got shapes {r0.shape} and {v0.shape}.")
    duration_s = float(_finite("duration_s", duration_s, " in s"))
    step_s = float(_finite("step_s", step_s, " in s"))
    if step_s <= 0.0:
        raise ValueError(f"step_s = {step_s!r} is not allowed: the step must be > 0 s.")
    if duration_s < 0.0:
        raise ValueError(f"duration_s = {duration_s!r} is not allowed: the duration must be >= 0 s.")
    if method not in ("rk4", "dop853"):
        raise ValueError(f"method = {method!r} is not allowed: use 'rk4' or 'dop853'.")
    mu = float(_check_mu(mu))
    j2 = float(_finite("j2", j2))
    r_eq = float(_finite("r_eq", r_eq, " in m"))
    rn = float(np.linalg.norm(r0))
    if rn == 0.0:
        raise ValueError("r0 = [0, 0, 0] is not allowed: the position must not be the centre of attraction.")
    t = _output_grid(duration_s, step_s)

    if method == "dop853":
        return _propagate_j2_dop853(r0, v0, t, mu, j2, r_eq, rtol, atol)

    # RK4 accuracy guard: a twentieth of the period (the circular period at perigee for open orbits).
    alpha = 2.0 / rn - float(v0 @ v0) / mu
    h = np.cross(r0, v0)
    ecc = float(np.linalg.norm(np.cross(v0, h) / mu - r0 / rn))
    if alpha > 0.0 and ecc < 1.0:
        period = _TWO_PI / math.sqrt(mu * alpha ** 3)
        what = "orbital period"
    else:
        rp = float(h @ h) / mu / (1.0 + ecc)
        period = _TWO_PI * math.sqrt(rp ** 3 / mu)
        what = "period of a circular orbit at the perigee radius of this open orbit"
    limit = period / 20.0
    if step_s > limit:
        raise ValueError(f"step_s = {step_s!r} s is not allowed: RK4 needs a step of at most {limit:.6g} s, "
                         f"one twentieth of the {what} ({period:.6g} s).")
    return t, *_rk4_j2(r0, v0, t, mu, j2, r_eq)


def _rk4_j2(r0, v0, t, mu, j2, r_eq):
    """Classical RK4 over the grid t in plain float arithmetic (numpy per step would cost more)."""
    k_j2 = 1.5 * j2 * r_eq * r_eq
    sqrt = math.sqrt

    def acc(x, y, z):
        r2 = x * x + y * y + z * z
        inv_r2 = 1.0 / r2
        base = -mu * inv_r2 / sqrt(r2)
        kk = k_j2 * inv_r2
        q = 5.0 * z * z * inv_r2
        fxy = base * (1.0 + kk * (1.0 - q))
        return fxy * x, fxy * y, base * (1.0 + kk * (3.0 - q)) * z

    n = t.size
    out = [None] * n
    x, y, z = (float(c) for c in r0)
    vx, vy, vz = (float(c) for c in v0)
    out[0] = (x, y, z, vx, vy, vz)
    steps = np.diff(t).tolist()
    for j, h in enumerate(steps, start=1):
        hh = 0.5 * h
        a1x, a1y, a1z = acc(x, y, z)
        v2x, v2y, v2z = vx + hh * a1x, vy + hh * a1y, vz + hh * a1z
        a2x, a2y, a2z = acc(x + hh * vx, y + hh * vy, z + hh * vz)
        v3x, v3y, v3z = vx + hh * a2x, vy + hh * a2y, vz + hh * a2z
        a3x, a3y, a3z = acc(x + hh * v2x, y + hh * v2y, z + hh * v2z)
        v4x, v4y, v4z = vx + h * a3x, vy + h * a3y, vz + h * a3z
        a4x, a4y, a4z = acc(x + h * v3x, y + h * v3y, z + h * v3z)
        h6 = h / 6.0
        x += h6 * (vx + 2.0 * (v2x + v3x) + v4x)
        y += h6 * (vy + 2.0 * (v2y + v3y) + v4y)
        z += h6 * (vz + 2.0 * (v2z + v3z) + v4z)
        vx += h6 * (a1x + 2.0 * (a2x + a3x) + a4x)
        vy += h6 * (a1y + 2.0 * (a2y + a3y) + a4y)
        vz += h6 * (a1z + 2.0 * (a2z + a3z) + a4z)
        out[j] = (x, y, z, vx, vy, vz)
    arr = np.array(out)
    return arr[:, :3], arr[:, 3:]


def _propagate_j2_dop853(r0, v0, t, mu, j2, r_eq, rtol, atol):
    from scipy.integrate import solve_ivp  # imported here: only the offline reference needs scipy

    k_j2 = 1.5 * j2 * r_eq * r_eq

    def rhs(_t, y):
        x, yy, z, vx, vy, vz = y.tolist()
        r2 = x * x + yy * yy + z * z
        inv_r2 = 1.0 / r2
        base = -mu * inv_r2 / math.sqrt(r2)
        kk = k_j2 * inv_r2
        q = 5.0 * z * z * inv_r2
        fxy = base * (1.0 + kk * (1.0 - q))
        return [vx, vy, vz, fxy * x, fxy * yy, base * (1.0 + kk * (3.0 - q)) * z]

    y0 = np.concatenate([r0, v0])
    if t[-1] == 0.0:
        return t, r0[None, :].copy(), v0[None, :].copy()
    sol = solve_ivp(rhs, (0.0, t[-1]), y0, method="DOP853", t_eval=t, rtol=rtol, atol=atol)
    if not sol.success:
        raise ArithmeticError(f"DOP853 failed: {sol.message}")
    return t, sol.y[:3].T.copy(), sol.y[3:].T.copy()


def propagate_cowell(r0, v0, duration_s, step_s, accel, t0_s: float = 0.0):
    """Fixed-step RK4 of ``r'' = accel(t, r, v)`` (Cowell), the force re-evaluated at every stage.

    ``accel(t_s, r (3,), v (3,)) -> a (3,)`` in m/s^2, any force model (``sim.forces.OrbitForces``);
    ``t_s`` is absolute sim time, starting at ``t0_s``. Output grid as :func:`propagate_j2`.
    """
    t = _output_grid(float(duration_s), float(step_s)) if duration_s > 0 else np.zeros(1)
    r = np.asarray(r0, dtype=float).copy()
    v = np.asarray(v0, dtype=float).copy()
    rs, vs = [r.copy()], [v.copy()]
    for k in range(1, t.size):
        h = t[k] - t[k - 1]
        ts = t0_s + t[k - 1]
        a1 = accel(ts, r, v)
        a2 = accel(ts + 0.5 * h, r + 0.5 * h * v, v + 0.5 * h * a1)
        a3 = accel(ts + 0.5 * h, r + 0.5 * h * (v + 0.5 * h * a1), v + 0.5 * h * a2)
        a4 = accel(ts + h, r + h * (v + 0.5 * h * a2), v + h * a3)
        r = r + h * v + h * h / 6.0 * (a1 + a2 + a3)
        v = v + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        if not (np.all(np.isfinite(r)) and np.all(np.isfinite(v))):
            raise FloatingPointError(f"orbit propagation produced a non-finite state at t = {ts + h:.6g} s.")
        rs.append(r)
        vs.append(v)
    return t + t0_s, np.array(rs), np.array(vs)
