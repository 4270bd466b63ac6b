"""Gravity and other orbital forces, each a separate function (SI units, vectorised over ``(..., 3)``).

* :class:`GravityField`: Earth's field as a spherical-harmonic series from fully normalised
  coefficients (JGM-3 to degree and order 20, ``fixtures/gravity/``), acceleration in ITRS by the
  normalised Cunningham recursion of :mod:`sim.harmonics` (stable, exact at the poles).
* :func:`accel_j2_rsw`: the seed paper's J2 perturbation in radial, transverse and normal
  components (Vallado, *Fundamentals of Astrodynamics*, eq. 8-29), a cross-check of
  :func:`sim.orbit.accel_j2`.
* :func:`accel_third_body`: Sun or Moon tidal acceleration on a geocentric satellite.
* :func:`accel_drag_exponential`: cannonball drag in a single-exponential atmosphere.
* :func:`accel_srp_cannonball`: cannonball solar radiation pressure, scaled by the visible fraction
  of the Sun (:func:`sim.environment.shadow_fraction`).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

import fixtures

from . import harmonics
from .constants import AU, J2_EARTH, MU_EARTH, OMEGA_EARTH, R_EARTH

__all__ = ["GravityField", "load_field", "accel_j2_rsw", "accel_third_body", "accel_drag_exponential",
           "accel_srp_cannonball", "GM_SUN", "GM_MOON", "P_SUN_1AU"]

GRAVITY_DIR = fixtures.ROOT / "gravity"
#: Models available offline: name -> coefficient file in ``fixtures/gravity/`` (checksum beside it).
MODELS = {"jgm3": "JGM3_deg20.gfc"}
#: Sun and Moon gravitational parameters, m^3/s^2 (DE421 / IERS Conventions 2010 values).
GM_SUN = 1.32712440041e20
GM_MOON = 4.902800076e12
#: Solar radiation pressure at 1 AU on a perfect absorber, N/m^2 (1361 W/m^2 / c).
P_SUN_1AU = 4.56e-6


@dataclass(frozen=True)
class GravityField:
    """Spherical-harmonic gravity field. ``C``, ``S``: fully normalised, flat in
    :func:`sim.harmonics.index_nm` order to ``degree``; ``gm`` (m^3/s^2), ``r_ref`` (m)."""

    name: str
    gm: float
    r_ref: float
    degree: int
    C: np.ndarray
    S: np.ndarray

    def accel_itrs(self, r_itrs) -> np.ndarray:
        """Acceleration (m/s^2, ITRS) at Earth-fixed positions ``r_itrs`` (m, ``(..., 3)``), point mass included."""
        r = np.asarray(r_itrs, dtype=float)
        if r.shape[-1:] != (3,) or not np.all(np.isfinite(r)):
            raise ValueError(f"r_itrs must be finite with shape (..., 3); got shape {r.shape}.")
        rn = np.linalg.norm(r, axis=-1)
        if np.any(rn < 0.9 * self.r_ref):
            raise ValueError(f"gravity field requested at |r| = {float(rn.min()):.6g} m; the series is valid "
                             f"outside the Earth (|r| >= {0.9 * self.r_ref:.6g} m is allowed).")
        return self.gm / self.r_ref**2 * harmonics.gradient(r, self.C, self.S, self.r_ref, self.degree)


def _read_gfc(path: Path, degree: int) -> tuple[float, float, int, np.ndarray, np.ndarray]:
    gm = r_ref = None
    max_deg = None
    nn, mm = harmonics.index_nm(degree)
    col = {(int(n), int(m)): k for k, (n, m) in enumerate(zip(nn, mm, strict=True))}
    C = np.zeros(nn.size)
    S = np.zeros(nn.size)
    in_data = False
    for line in path.read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if not in_data:
            key = parts[0].lower()
            if key == "earth_gravity_constant":
                gm = float(parts[1].replace("D", "E").replace("d", "e"))
            elif key == "radius":
                r_ref = float(parts[1].replace("D", "E").replace("d", "e"))
            elif key == "max_degree":
                max_deg = int(parts[1])
            elif key == "end_of_head":
                in_data = True
            continue
        if parts[0] != "gfc":
            continue
        n, m = int(parts[1]), int(parts[2])
        if n <= degree:
            C[col[(n, m)]] = float(parts[3].replace("D", "E").replace("d", "e"))
            S[col[(n, m)]] = float(parts[4].replace("D", "E").replace("d", "e"))
    if gm is None or r_ref is None or max_deg is None:
        raise ValueError(f"{path} lacks earth_gravity_constant, radius or max_degree in its header.")
    return gm, r_ref, max_deg, C, S


@lru_cache(maxsize=8)
def load_field(model: str = "jgm3", degree: int = 20) -> GravityField:
    """Gravity field ``model`` (``"jgm3"``) truncated at ``degree`` (2..20: the stored file's limit)."""
    if model not in MODELS:
        raise ValueError(f"gravity model {model!r} is not available; allowed: {sorted(MODELS)}.")
    if not isinstance(degree, int | np.integer) or isinstance(degree, bool):
        raise ValueError(f"gravity degree {degree!r} is not allowed for {model}; use an integer from 2 to 20.")
    fname = MODELS[model]
    path = GRAVITY_DIR / fname
    expected = (GRAVITY_DIR / (fname + ".sha256")).read_text().split()[0]
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    if digest != expected:
        raise ValueError(f"{path} has SHA-256 {digest}; expected {expected}. Rebuild it with "
                         "fixtures/gravity/make_gravity_fixture.py.")
    gm, r_ref, max_deg, C, S = _read_gfc(path, max(int(degree), 0))
    if not 2 <= degree <= max_deg:
        raise ValueError(f"gravity degree {degree!r} is not allowed for {model}; use an integer from 2 to {max_deg}.")
    return GravityField(model, gm, r_ref, int(degree), C, S)


def accel_j2_rsw(r, v, mu: float = MU_EARTH, j2: float = J2_EARTH, r_eq: float = R_EARTH) -> np.ndarray:
    """J2 perturbing acceleration (m/s^2) in RSW components (radial, transverse, normal).

    With argument of latitude ``u`` and inclination ``i`` of the osculating plane of ``(r, v)`` (m,
    m/s, a frame whose z is the pole):
    ``a_R = -k (1 - 3 sin^2 i sin^2 u)``, ``a_S = -k sin^2 i sin 2u``, ``a_W = -k sin 2i sin u``,
    ``k = 3/2 J2 mu R^2 / r^4``. Equals :func:`sim.orbit.accel_j2` minus the point mass, rotated
    by :func:`sim.frames.dcm_rsw_gcrs` (tested).
    """
    r = np.asarray(r, dtype=float)
    v = np.asarray(v, dtype=float)
    h = np.cross(r, v)
    hn = np.linalg.norm(h, axis=-1)
    rn = np.linalg.norm(r, axis=-1)
    if np.any(hn == 0.0) or np.any(rn == 0.0):
        raise ValueError("accel_j2_rsw needs r and v that span an orbit plane (r x v != 0).")
    cos_i = h[..., 2] / hn
    sin_i = np.hypot(h[..., 0], h[..., 1]) / hn
    raan = np.arctan2(h[..., 0], -h[..., 1])
    # u from the ascending node; for an equatorial orbit sin i = 0 and u drops out of the result.
    sin_u_sin_i = r[..., 2] / rn
    cos_u = (r[..., 0] * np.cos(raan) + r[..., 1] * np.sin(raan)) / rn
    sin_u = np.where(sin_i > 0, sin_u_sin_i / np.where(sin_i > 0, sin_i, 1.0), 0.0)
    k = 1.5 * j2 * mu * r_eq**2 / rn**4
    aR = -k * (1.0 - 3.0 * sin_i**2 * sin_u**2)
    aS = -k * sin_i**2 * 2.0 * sin_u * cos_u
    aW = -k * 2.0 * sin_i * cos_i * sin_u
    return np.stack((aR, aS, aW), axis=-1)


def accel_third_body(r_sat, r_body, gm_body: float) -> np.ndarray:
    """Tidal acceleration (m/s^2) of a body at geocentric ``r_body`` (m) on a satellite at ``r_sat``.

    ``a = GM (d / |d|^3 - r_body / |r_body|^3)``, ``d = r_body - r_sat``, written with Battin's
    ``f(q)`` so the difference of two nearly equal terms is not formed (the Moon's term is 2 % of
    its parts at LEO; the Sun's 0.005 %).
    """
    rs = np.asarray(r_sat, dtype=float)
    rb = np.asarray(r_body, dtype=float)
    d = rb - rs
    dn3 = np.linalg.norm(d, axis=-1) ** 3
    rb2 = np.sum(rb * rb, axis=-1)
    # Battin (Astrodynamics, 8.60): 1/|d|^3 - 1/|rb|^3 = f(q) / |rb|^3 with d^2 = rb^2 (1 + q).
    q = np.sum(rs * (rs - 2.0 * rb), axis=-1) / rb2
    fq = q * (3.0 + 3.0 * q + q * q) / (1.0 + (1.0 + q) ** 1.5)
    # a = GM (d/|d|^3 - rb/|rb|^3) = -GM (rs + f(q) rb) / |d|^3
    return -gm_body * (rs + fq[..., None] * rb) / dn3[..., None]


def accel_drag_exponential(r_itrs, v_itrs, cd: float, area_m2: float, mass_kg: float,
                           rho0_kg_m3: float = 6.967e-13, h0_m: float = 500e3,
                           scale_height_m: float = 63.822e3) -> np.ndarray:
    """Cannonball drag (m/s^2, ITRS) with ``rho = rho0 exp(-(h - h0) / H)`` over a spherical Earth.

    ``r_itrs``, ``v_itrs``: Earth-fixed position (m) and velocity (m/s): the atmosphere co-rotates,
    so the Earth-fixed velocity is the velocity relative to the air. Defaults: Vallado's
    exponential-model row at 500 km (rho0 = 6.967e-13 kg/m^3, H = 63.822 km); use the row of your
    altitude band (the model is coarse: real density varies by 10x with solar activity).
    """
    for name, val in (("cd", cd), ("area_m2", area_m2), ("mass_kg", mass_kg), ("scale_height_m", scale_height_m)):
        if not (np.isfinite(val) and val > 0):
            raise ValueError(f"drag {name} = {val!r} must be a finite positive number.")
    r = np.asarray(r_itrs, dtype=float)
    v = np.asarray(v_itrs, dtype=float)
    h = np.linalg.norm(r, axis=-1) - R_EARTH
    rho = rho0_kg_m3 * np.exp(-(h - h0_m) / scale_height_m)
    vn = np.linalg.norm(v, axis=-1, keepdims=True)
    return -0.5 * (rho * cd * area_m2 / mass_kg)[..., None] * vn * v


def accel_srp_cannonball(r_sat, r_sun, cr: float, area_m2: float, mass_kg: float,
                         shadow: str | None = "conical") -> np.ndarray:
    """Cannonball solar radiation pressure (m/s^2) in the frame of ``r_sat``, ``r_sun`` (m, geocentric).

    ``a = -nu P (AU / |d|)^2 Cr A / m  d_hat`` with ``d = r_sun - r_sat`` and ``nu`` the visible
    fraction of the Sun (``shadow``: ``"conical"``, ``"cylindrical"`` or None for always lit).
    """
    from .environment import shadow_fraction

    for name, val in (("cr", cr), ("area_m2", area_m2), ("mass_kg", mass_kg)):
        if not (np.isfinite(val) and val > 0):
            raise ValueError(f"SRP {name} = {val!r} must be a finite positive number.")
    rs = np.asarray(r_sat, dtype=float)
    d = np.asarray(r_sun, dtype=float) - rs
    dn = np.linalg.norm(d, axis=-1, keepdims=True)
    nu = 1.0 if shadow is None else shadow_fraction(rs, r_sun, model=shadow)[..., None]
    return -nu * P_SUN_1AU * (AU / dn) ** 2 * cr * area_m2 / mass_kg * d / dn


def omega_cross(r_itrs) -> np.ndarray:
    """Velocity of the co-rotating atmosphere (m/s) at ``r_itrs`` seen from an inertial frame."""
    return np.cross([0.0, 0.0, OMEGA_EARTH], np.asarray(r_itrs, dtype=float))
