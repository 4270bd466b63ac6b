"""Relative motion of an approaching ship (the chaser) in the target's LVLH frame.

LVLH (as in :func:`sim.frames.dcm_lvlh_gcrs`): origin at the target, z to nadir, y along the
negative orbit normal, x completes (along-track, the direction of flight on a circular orbit).
``r_L`` is the chaser's position relative to the target and ``v_L`` its velocity *as seen in the
rotating frame* (the time derivative of ``r_L``), both in LVLH components.

Three trajectories:

* :func:`cw_state`: Clohessy-Wiltshire (Hill) equations, closed form, for a circular target orbit
  of mean motion ``n``: ``x'' = 2 n z'``, ``y'' = -n^2 y``, ``z'' = 3 n^2 z - 2 n x'`` (Fehse,
  *Automated Rendezvous and Docking of Spacecraft*, sec. 3.3). Linearised: the error grows with
  the square of the separation over the orbit radius (about 2 m after one orbit at 1 km from a
  420 km orbit; ``fixtures/reference/relative_motion`` holds the nonlinear reference).
* :func:`line_state`: a straight line at constant velocity in LVLH (a forced final approach
  along the docking axis; the thrust that holds it is not modelled).
* :func:`kepler_relative_state`: both ships on exact two-body orbits (universal variables,
  :func:`sim.orbit.propagate_kepler`), seen from the target's LVLH: the nonlinear motion CW
  approximates, for any target eccentricity.

All functions are vectorised over the times ``t_s`` (shape ``(T,)`` in, ``(T, 3)`` out).
"""

from __future__ import annotations

import numpy as np

from .constants import MU_EARTH
from .frames import dcm_lvlh_gcrs
from .orbit import propagate_kepler

__all__ = ["cw_state", "line_state", "kepler_relative_state", "lvlh_from_inertial", "inertial_from_lvlh",
           "mean_motion", "pointing_dcm", "lvlh_rate"]


def mean_motion(a_m: float, mu: float = MU_EARTH) -> float:
    """Mean motion ``sqrt(mu / a^3)`` (rad/s) of an orbit with semi-major axis ``a_m`` (m, > 0)."""
    if not np.isfinite(a_m) or a_m <= 0:
        raise ValueError(f"a_m = {a_m!r} must be a finite semi-major axis > 0 m for a mean motion.")
    return float(np.sqrt(mu / a_m ** 3))


def _vec3(v, name: str) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} = {np.asarray(v).tolist()} must be a list of 3 finite numbers.")
    return v


def cw_state(r0_L, v0_L, t_s, n_rad_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Clohessy-Wiltshire position (m) and velocity (m/s) at ``t_s`` from ``r0_L``, ``v0_L`` at 0."""
    x0, y0, z0 = _vec3(r0_L, "r0_L")
    u0, v0, w0 = _vec3(v0_L, "v0_L")
    n = float(n_rad_s)
    if not np.isfinite(n) or n <= 0:
        raise ValueError(f"n_rad_s = {n_rad_s!r} must be a finite mean motion > 0 rad/s.")
    t = np.asarray(t_s, dtype=float)
    c, s = np.cos(n * t), np.sin(n * t)
    x = x0 + 6.0 * (n * t - s) * z0 + (4.0 * s / n - 3.0 * t) * u0 + 2.0 * (1.0 - c) / n * w0
    y = c * y0 + s / n * v0
    z = (4.0 - 3.0 * c) * z0 + 2.0 * (c - 1.0) / n * u0 + s / n * w0
    vx = 6.0 * n * (1.0 - c) * z0 + (4.0 * c - 3.0) * u0 + 2.0 * s * w0
    vy = -n * s * y0 + c * v0
    vz = 3.0 * n * s * z0 - 2.0 * s * u0 + c * w0
    return np.stack((x, y, z), axis=-1), np.stack((vx, vy, vz), axis=-1)


def line_state(r0_L, v_L, t_s) -> tuple[np.ndarray, np.ndarray]:
    """Straight line at constant LVLH velocity: ``r0 + v t``."""
    r0 = _vec3(r0_L, "r0_L")
    v = _vec3(v_L, "v_L")
    t = np.asarray(t_s, dtype=float)[..., None]
    return r0 + v * t, np.broadcast_to(v, t.shape[:-1] + (3,)).copy()


def lvlh_rate(r_T_N, v_T_N) -> np.ndarray:
    """Angular velocity of LVLH relative to inertial, LVLH components (two-body: ``|h| / r^2``
    about the orbit normal, which is ``-y``)."""
    r = np.asarray(r_T_N, dtype=float)
    h = np.linalg.norm(np.cross(r, np.asarray(v_T_N, dtype=float)), axis=-1)
    w = h / np.sum(r * r, axis=-1)
    z = np.zeros_like(w)
    return np.stack((z, -w, z), axis=-1)


def lvlh_from_inertial(r_T_N, v_T_N, r_C_N, v_C_N) -> tuple[np.ndarray, np.ndarray]:
    """Chaser relative position and rotating-frame velocity in the target's LVLH."""
    C = dcm_lvlh_gcrs(r_T_N, v_T_N)
    rho = np.einsum("...ij,...j->...i", C, np.asarray(r_C_N) - np.asarray(r_T_N))
    drho = np.einsum("...ij,...j->...i", C, np.asarray(v_C_N) - np.asarray(v_T_N))
    return rho, drho - np.cross(lvlh_rate(r_T_N, v_T_N), rho)


def inertial_from_lvlh(r_T_N, v_T_N, r_L, v_L) -> tuple[np.ndarray, np.ndarray]:
    """Chaser inertial position and velocity from its LVLH relative state (inverse of the above)."""
    C = dcm_lvlh_gcrs(r_T_N, v_T_N)
    r_L = np.asarray(r_L, dtype=float)
    v_in = np.asarray(v_L, dtype=float) + np.cross(lvlh_rate(r_T_N, v_T_N), r_L)
    return (np.asarray(r_T_N) + np.einsum("...ji,...j->...i", C, r_L),
            np.asarray(v_T_N) + np.einsum("...ji,...j->...i", C, v_in))


def kepler_relative_state(r_T0_N, v_T0_N, r0_L, v0_L, t_s, mu: float = MU_EARTH):
    """Exact two-body relative motion: both ships propagated by universal variables from the
    target's inertial state and the chaser's LVLH state at 0, returned in the target's LVLH."""
    r_T0 = _vec3(r_T0_N, "r_T0_N")
    v_T0 = _vec3(v_T0_N, "v_T0_N")
    r_C0, v_C0 = inertial_from_lvlh(r_T0, v_T0, _vec3(r0_L, "r0_L"), _vec3(v0_L, "v0_L"))
    t = np.asarray(t_s, dtype=float)
    r_T, v_T = propagate_kepler(r_T0, v_T0, t, mu)
    r_C, v_C = propagate_kepler(r_C0, v_C0, t, mu)
    return lvlh_from_inertial(r_T, v_T, r_C, v_C)


def pointing_dcm(axis_L, hint_L=(0.0, 0.0, 1.0), roll_rad: float = 0.0) -> np.ndarray:
    """``dcm_CL`` of a frame C whose +x is ``axis_L`` and whose +z is as close to ``hint_L`` as
    it can be (then turned by ``roll_rad`` about +x), broadcast over ``(..., 3)`` axes.

    Used for the chaser pointing its docking axis (+x) at the target with +z toward nadir.
    Refuses an axis parallel to the hint, where the roll is undefined.
    """
    x = np.asarray(axis_L, dtype=float)
    nx = np.linalg.norm(x, axis=-1, keepdims=True)
    if np.any(nx == 0) or not np.all(np.isfinite(x)):
        raise ValueError("pointing axis must be finite and non-zero.")
    x = x / nx
    h = np.broadcast_to(np.asarray(hint_L, dtype=float), x.shape)
    z = h - np.sum(h * x, axis=-1, keepdims=True) * x
    nz = np.linalg.norm(z, axis=-1, keepdims=True)
    if np.any(nz < 1e-9 * np.linalg.norm(h, axis=-1, keepdims=True)):
        raise ValueError("pointing axis is parallel to the roll hint (nadir): the roll about it is undefined; "
                         "approach off that line or give another hint.")
    z = z / nz
    y = np.cross(z, x)
    if roll_rad:
        c, s = np.cos(roll_rad), np.sin(roll_rad)
        y, z = c * y + s * z, -s * y + c * z
    return np.stack((x, y, z), axis=-2)
