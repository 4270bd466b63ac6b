"""Environment models: geomagnetic field, Sun, Moon, shadow.

Geomagnetic field: :func:`magnetic_field_itrs` is IGRF-14 (:mod:`sim.igrf`, degrees 1..13 at the
epoch) unless a caller asks for ``model="dipole"`` by name: the centred (tilted) dipole of
:func:`dipole_field_itrs`, given by three degree-1 Gauss coefficients and independent of time. The
dipole is exact for what it is and serves comparison cases and the scenarios that ask for it
(``magnetic_field = "dipole"``, which ``stand.compose`` passes on by name).

Sun and Moon positions are re-exported from :mod:`sim.ephemeris`, where they live with their
interpolated track.
"""

from __future__ import annotations

import numpy as np

from .constants import R_EARTH, R_IGRF

# Re-exported: they live in sim.ephemeris with their track.
from .ephemeris import moon_position_gcrs, sun_position_gcrs

__all__ = ["dipole_field_itrs", "magnetic_field_itrs", "moon_position_gcrs", "shadow_fraction", "sun_position_gcrs"]

#: Degree-1 Gauss coefficients (nT) of the dipole: IGRF's 1925.0 values (g10, g11, h11), those of
#: the B-dot detumble comparison with Basilisk (the ``detumble`` scenario).
DIPOLE_G10_NT = -30926.0
DIPOLE_G11_NT = -2318.0
DIPOLE_H11_NT = 5817.0


def dipole_field_itrs(r_itrs, g10_nT: float = DIPOLE_G10_NT, g11_nT: float = DIPOLE_G11_NT,
                      h11_nT: float = DIPOLE_H11_NT, r_ref_m: float = R_IGRF) -> np.ndarray:
    """Field (T) of the degree-1 geomagnetic potential at Earth-fixed positions ``r_itrs`` (m).

    With ``g = (g11, h11, g10)`` the potential is ``V = a^3 (g . r) / r^3``, so
    ``B = -grad V = a^3 (3 (g . r_hat) r_hat - g) / r^3``. At the north pole this is
    ``2 g10`` along +z, i.e. pointing down into the Earth for the present-day negative g10.
    """
    r = np.asarray(r_itrs, dtype=float)
    g = np.array([g11_nT, h11_nT, g10_nT]) * 1e-9
    rn = np.linalg.norm(r, axis=-1, keepdims=True)
    if np.any(rn < 0.5 * r_ref_m) or not np.all(np.isfinite(r)):
        raise ValueError(
            "magnetic field requested at a position inside the Earth or non-finite "
            f"(|r| = {float(np.min(rn)):.6g} m; at least {0.5 * r_ref_m:.6g} m is allowed)."
        )
    rhat = r / rn
    return (r_ref_m / rn) ** 3 * (3.0 * np.sum(g * rhat, axis=-1, keepdims=True) * rhat - g)


def magnetic_field_itrs(epoch, r_itrs, model: str = "igrf", degree: int | None = None) -> np.ndarray:
    """Geomagnetic field (T, ITRS components) at ``r_itrs`` (m) and ``epoch``.

    ``model="igrf"`` (the default) is IGRF-14 (:mod:`sim.igrf`) to ``degree`` (1..13, default 13)
    at ``epoch`` (Epoch or decimal year, 1900.0-2030.0; refused outside). ``model="dipole"`` is the
    centred dipole of :func:`dipole_field_itrs` (time-independent; ``epoch`` and ``degree`` unused)
    and is evaluated only when asked for by name.
    """
    if model == "igrf":
        from .igrf import MAX_DEGREE, field_itrs

        return field_itrs(epoch, r_itrs, MAX_DEGREE if degree is None else degree)
    if model == "dipole":
        return dipole_field_itrs(r_itrs)
    raise ValueError(f"magnetic field model {model!r} is not available; allowed: 'dipole', 'igrf'.")


#: Solar radius, m (IAU 2015 Resolution B3 nominal value).
R_SUN = 6.957e8


def shadow_fraction(r_sat, r_sun, model: str = "conical", r_body_m: float = R_EARTH) -> np.ndarray:
    """Fraction of the Sun's disk visible from ``r_sat`` (1 = full sun, 0 = umbra), shape ``(...)``.

    ``r_sat``, ``r_sun``: geocentric positions (m) in one frame (e.g. GCRS), ``(..., 3)``, broadcast.
    ``model="conical"`` (Montenbruck & Gill, *Satellite Orbits*, sec. 3.4.2): apparent radii of the
    Sun ``a = asin(R_sun / |r_sun - r_sat|)`` and of the Earth ``b = asin(R / |r_sat|)``, separation
    ``c`` of their centres; the visible fraction is ``1 - overlap / (pi a^2)`` with the overlap of
    the two disks (treated as flat circles: exact to ~1e-5 of the fraction at these angles);
    penumbra included, annular case ``1 - b^2 / a^2`` far from the Earth.
    ``model="cylindrical"``: 0 inside the infinite cylinder of radius R behind the Earth, else 1.
    The Earth is a sphere of radius ``r_body_m`` (default equatorial WGS 84; no atmosphere).
    """
    rs = np.asarray(r_sat, dtype=float)
    rS = np.asarray(r_sun, dtype=float)
    if not (np.all(np.isfinite(rs)) and np.all(np.isfinite(rS))):
        raise ValueError("shadow_fraction needs finite r_sat and r_sun (m).")
    if model == "cylindrical":
        sh = rS / np.linalg.norm(rS, axis=-1, keepdims=True)
        along = np.sum(rs * sh, axis=-1)
        perp = np.linalg.norm(rs - along[..., None] * sh, axis=-1)
        return np.where((along < 0.0) & (perp < r_body_m), 0.0, 1.0)
    if model != "conical":
        raise ValueError(f"shadow model {model!r} is not available; allowed: 'conical', 'cylindrical'.")
    d_sun = rS - rs
    n_sat = np.linalg.norm(rs, axis=-1)
    n_sun = np.linalg.norm(d_sun, axis=-1)
    if np.any(n_sat <= r_body_m):
        raise ValueError(f"shadow_fraction: |r_sat| = {float(np.min(n_sat)):.6g} m is inside the Earth; "
                         f"more than {r_body_m:.6g} m is allowed.")
    a = np.arcsin(np.minimum(R_SUN / n_sun, 1.0))
    b = np.arcsin(r_body_m / n_sat)
    c = np.arctan2(np.linalg.norm(np.cross(-rs, d_sun), axis=-1), np.sum(-rs * d_sun, axis=-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        x = (c * c + a * a - b * b) / (2.0 * c)
        y = np.sqrt(np.maximum(a * a - x * x, 0.0))
        area = (a * a * np.arccos(np.clip(x / a, -1.0, 1.0)) + b * b * np.arccos(np.clip((c - x) / b, -1.0, 1.0))
                - c * y)
    frac = 1.0 - area / (np.pi * a * a)
    frac = np.where(c >= a + b, 1.0, frac)
    frac = np.where(c <= a - b, 1.0 - (b * b) / (a * a), frac)
    frac = np.where(c <= b - a, 0.0, frac)
    return np.clip(frac, 0.0, 1.0)
