"""IGRF-14 geomagnetic main field, Earth-fixed Cartesian in and out.

Coefficients: ``fixtures/igrf/IGRF14.shc`` (IAGA, IGRF 14th generation, doi 10.5281/zenodo.14012302),
copied byte for byte from the ppigrf 2.1.0 wheel by ``fixtures/igrf/copy_igrf14.py``; its SHA-256
is checked on load. Schmidt semi-normalised Gauss coefficients in nT at 5-year epochs 1900-2025,
plus the 2030 column (= 2025 main field + 5 years of secular variation).

Time: as IGRF defines it, coefficients vary linearly in decimal year between the 5-year epochs,
and 2025.0-2030.0 uses the secular variation. The decimal year is the UTC calendar fraction
(``year + (day of year - 1 + fraction of day) / days in that year``). Epochs outside 1900.0-2030.0
are refused (IGRF is not defined there; other implementations extrapolate silently).

Space: the potential ``V = a sum (a/r)^(n+1) P_n^m(cos theta) (g cos m phi + h sin m phi)`` with
``a = 6371.2 km`` is in the geocentric Earth-fixed frame (ITRS); ``B = -grad V``. The gradient is
taken in Cartesian coordinates by :mod:`sim.harmonics` (no division by sin(colatitude): exact at the
poles), vectorised over positions. Degrees 1..``degree`` are summed (``degree`` 1..13; the
1900-1995 models stop at degree 10 and carry zeros above).

One position per call (``r_itrs`` of shape ``(3,)``) takes a separate path built for it, about
ten times faster and equal to the vectorised one to 1e-12 relative (2e-15 measured on the
ppigrf reference points):

* the field is linear in the coefficients and the coefficients are linear in the decimal year
  inside each 5-year interval, so ``B = B_k(r) + f B'_k(r)`` with ``f`` the fraction of the
  interval. Both series are folded once per interval and degree into polynomial form
  (:class:`sim.harmonics.PointSeries`) and a call is two small matrix products; no coefficient
  is interpolated per call;
* the decimal year of an :class:`~sim.time.Epoch` is taken from ERFA once per UTC day and then
  by arithmetic on the TAI date while the epoch stays in that day (see :func:`decimal_year`).
"""

from __future__ import annotations

import hashlib
import math
from bisect import bisect_right
from functools import lru_cache

import erfa
import numpy as np

import fixtures

from . import harmonics
from .constants import R_IGRF
from .time import Epoch, ignore_dubious_year

__all__ = ["IGRF_FILE", "YEAR_MIN", "YEAR_MAX", "MAX_DEGREE", "decimal_year", "coefficients", "field_itrs"]

IGRF_FILE = fixtures.ROOT / "igrf" / "IGRF14.shc"
_SHA256 = "717f6dce821a8f2bfcc6a77f79cc227ba91f61aeb458d5433e8c72450d48f8e0"
YEAR_MIN = 1900.0
YEAR_MAX = 2030.0
MAX_DEGREE = 13


@lru_cache(maxsize=1)
def _load() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(years (T,), g (T, K), h (T, K)) in nT, K over (n, m) in :func:`sim.harmonics.index_nm` order."""
    raw = IGRF_FILE.read_bytes()
    digest = hashlib.sha256(raw).hexdigest()
    if digest != _SHA256:
        raise ValueError(
            f"{IGRF_FILE} has SHA-256 {digest}; expected {_SHA256} (the IGRF-14 file of ppigrf 2.1.0). "
            "Restore it with fixtures/igrf/copy_igrf14.py."
        )
    lines = [ln for ln in raw.decode().splitlines() if ln.strip() and not ln.startswith("#")]
    years = np.array(lines[1].split(), dtype=float)
    nn, mm = harmonics.index_nm(MAX_DEGREE)
    col = {(int(n), int(m)): k for k, (n, m) in enumerate(zip(nn, mm, strict=True))}
    g = np.zeros((years.size, nn.size))
    h = np.zeros((years.size, nn.size))
    for ln in lines[2:]:
        parts = ln.split()
        n, m = int(parts[0]), int(parts[1])
        vals = np.array(parts[2:], dtype=float)
        if m >= 0:
            g[:, col[(n, m)]] = vals
        else:
            h[:, col[(n, -m)]] = vals
    return years, g, h


# The span of UTC time of the last epoch whose decimal year was asked for, over which UTC advances
# with TAI (no leap second, no pre-1972 rate offset): 1 January as a split UTC Julian date, TAI - UTC
# (days), the year, days in the year, and the span as days since 1 January (the whole year, or one
# day of a year with a leap second). Instants of the span are then arithmetic on the TAI date.
_span: tuple[float, float, float, float, float, float, float] | None = None
# Instants this close to a span's ends (days; 86 us) always go through ERFA: which span claims them
# would otherwise hang on rounding and on which span is cached, and the result must not depend on
# history. Inside a span, midnights are nothing special.
_EDGE = 1e-9


def decimal_year(epoch: Epoch) -> float:
    """IGRF's time argument: UTC calendar year plus the elapsed fraction of that year.

    A pure function of the epoch: arithmetic on the TAI date inside a span where UTC advances with
    TAI (a year without a leap second, else a day without one), ERFA's UTC calendar elsewhere and
    within 86 us of a span's ends; the two agree to the last bit or two.
    """
    global _span
    a, b = epoch.jd_tai
    span = _span
    if span is None or not span[5] + _EDGE <= ((a - span[0]) - span[1]) + (b - span[2]) < span[6] - _EDGE:
        span = _span_of(epoch)
        if span is None or not span[5] + _EDGE <= ((a - span[0]) - span[1]) + (b - span[2]) < span[6] - _EDGE:
            return _decimal_year_erfa(epoch)
        _span = span
    j1, j2, dat, year, length = span[:5]
    return year + (((a - j1) - j2) + (b - dat)) / length


def _span_of(epoch: Epoch) -> tuple[float, float, float, float, float, float, float] | None:
    """The arithmetic-path parameters around the epoch (see ``_span``), or None on a day that does
    not last 86400 s of TAI (a leap second, or UTC before 1972 with its rate offset)."""
    u1, u2 = epoch.jd_utc
    with ignore_dubious_year():
        y, mo, d, _ = erfa.jd2cal(u1, u2)
        y, mo, d = int(y), int(mo), int(d)
        j0, j1 = erfa.cal2jd(y, 1, 1)
        k0, k1 = erfa.cal2jd(y + 1, 1, 1)
        length = float((k0 - j0) + (k1 - j1))
        dat = erfa.dat(y, 1, 1, 0.0)
        if dat == erfa.dat(y + 1, 1, 1, 0.0):
            lo, hi = 0.0, length
        else:
            s0, s1 = erfa.cal2jd(y, mo, d)
            yn, mn, dn, _ = erfa.jd2cal(s0, s1 + 1.0)
            dat = erfa.dat(y, mo, d, 0.0)
            if dat != erfa.dat(int(yn), int(mn), int(dn), 0.0):
                return None
            lo = float((s0 - j0) + (s1 - j1))
            hi = lo + 1.0
    return float(j0), float(j1), float(dat) / 86400.0, float(y), length, lo, hi


def _decimal_year_erfa(epoch: Epoch) -> float:
    u1, u2 = epoch.jd_utc
    with ignore_dubious_year():
        y, _, _, _ = erfa.jd2cal(u1, u2)
        j0, j1 = erfa.cal2jd(int(y), 1, 1)
        k0, k1 = erfa.cal2jd(int(y) + 1, 1, 1)
    days = (u1 - j0) + (u2 - j1)
    return float(y) + days / ((k0 - j0) + (k1 - j1))


def _year_of(epoch) -> float:
    if isinstance(epoch, Epoch):
        return decimal_year(epoch)
    try:
        return float(epoch)
    except (TypeError, ValueError):
        raise TypeError(
            f"epoch must be a sim.time.Epoch or a decimal year; got {type(epoch).__name__}."
        ) from None


def coefficients(epoch, degree: int = MAX_DEGREE) -> tuple[np.ndarray, np.ndarray]:
    """Schmidt semi-normalised (g, h) in nT at ``epoch`` (Epoch or decimal year), flat in
    :func:`sim.harmonics.index_nm` order, degrees above ``degree`` set to 0."""
    year = _year_of(epoch)
    if not YEAR_MIN <= year <= YEAR_MAX:
        raise ValueError(
            f"IGRF-14 epoch {year:.6f} (decimal year) is outside its validity 1900.0 to 2030.0; "
            "IGRF is not extrapolated."
        )
    if not (isinstance(degree, int | np.integer) and 1 <= degree <= MAX_DEGREE):
        raise ValueError(f"igrf degree {degree!r} is not allowed; use an integer from 1 to {MAX_DEGREE}.")
    years, g, h = _load()
    k = int(min(np.searchsorted(years, year, side="right") - 1, years.size - 2))
    f = (year - years[k]) / (years[k + 1] - years[k])
    gi = g[k] + f * (g[k + 1] - g[k])
    hi = h[k] + f * (h[k + 1] - h[k])
    nn, _ = harmonics.index_nm(MAX_DEGREE)
    keep = (nn >= 1) & (nn <= degree)
    return np.where(keep, gi, 0.0), np.where(keep, hi, 0.0)


@lru_cache(maxsize=64)
def _normalised(year: float, degree: int) -> tuple[np.ndarray, np.ndarray]:
    g, h = coefficients(year, degree)
    nn, _ = harmonics.index_nm(degree)
    scale = 1e-9 / np.sqrt(2.0 * nn + 1.0)  # nT -> T, Schmidt -> full (4 pi) normalisation
    k = nn.size
    return g[:k] * scale, h[:k] * scale


def field_itrs(epoch, r_itrs, degree: int = MAX_DEGREE) -> np.ndarray:
    """IGRF-14 main field ``B`` (T, ITRS components) at Earth-fixed positions ``r_itrs`` (m, ``(..., 3)``).

    ``epoch``: :class:`sim.time.Epoch` or decimal year (UTC calendar), 1900.0 to 2030.0.
    ``degree``: highest degree summed, 1..13. Positions must be finite and outside half the
    reference radius (the series diverges towards the core; the model is meant for r >= a).
    """
    year = _year_of(epoch)
    if not (YEAR_MIN <= year <= YEAR_MAX and isinstance(degree, int | np.integer) and 1 <= degree <= MAX_DEGREE):
        coefficients(year, degree)  # raises the documented message for the bad year or degree
    r = np.asarray(r_itrs, dtype=float)
    if r.shape == (3,):
        return _field_point(year, r, int(degree))
    if r.shape[-1:] != (3,):
        raise ValueError(f"r_itrs must have shape (..., 3); got {r.shape}.")
    rn = np.linalg.norm(r, axis=-1)
    if not np.all(np.isfinite(r)) or np.any(rn < 0.5 * R_IGRF):
        raise ValueError(
            "magnetic field requested at a position inside the Earth or non-finite "
            f"(|r| = {float(np.min(rn)):.6g} m; at least {0.5 * R_IGRF:.6g} m is allowed)."
        )
    C, S = _normalised(year, int(degree))
    return -harmonics.gradient(r, C, S, R_IGRF, int(degree))


@lru_cache(maxsize=1)
def _node_years() -> tuple[float, ...]:
    return tuple(float(y) for y in _load()[0])


@lru_cache(maxsize=MAX_DEGREE)
def _interval_series(degree: int) -> list[harmonics.PointSeries]:
    """Per 5-year interval k: the potential at node k and its change to node k + 1, folded for
    single positions (all intervals of a degree in one pass, about 10 ms; 2 MB per degree)."""
    years = _node_years()
    C, S = zip(*(_normalised(y, degree) for y in years), strict=True)
    return harmonics.PointSeries.split(_base_slope(np.array(C)), _base_slope(np.array(S)), degree, per=2)


def _base_slope(A: np.ndarray) -> np.ndarray:
    """Rows node k, node k + 1 - node k, for every interval k, interleaved."""
    return np.stack((A[:-1], A[1:] - A[:-1]), axis=1).reshape(-1, A.shape[1])


def _field_point(year: float, r: np.ndarray, degree: int) -> np.ndarray:
    x, y, z = r.tolist()
    rn = math.hypot(x, y, z)
    if not (math.isfinite(rn) and rn >= 0.5 * R_IGRF):
        raise ValueError(
            "magnetic field requested at a position inside the Earth or non-finite "
            f"(|r| = {rn:.6g} m; at least {0.5 * R_IGRF:.6g} m is allowed)."
        )
    nodes = _node_years()
    k = min(bisect_right(nodes, year) - 1, len(nodes) - 2)  # as coefficients() picks the interval
    f = (year - nodes[k]) / (nodes[k + 1] - nodes[k])
    g0, g1, g2, d0, d1, d2 = _interval_series(degree)[k].gradient(x, y, z, R_IGRF)
    return np.array((-(g0 + f * d0), -(g1 + f * d1), -(g2 + f * d2)))  # B = -grad V
