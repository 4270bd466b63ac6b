"""Guidance: the reference attitude ``q_RN`` and its rate ``omega_RN_R`` (rad/s, reference axes).

Each function returns ``(q_RN, omega_RN_R)``; a controller tracks R with the body (B = R at zero error).

* :func:`inertial`: a fixed attitude in GCRS, zero rate.
* :func:`nadir`: the LVLH frame (z to nadir, y along the negative orbit normal) from
  :func:`sim.frames.dcm_lvlh_gcrs`; its rate is the orbit's angular rate ``h / r^2`` about -y
  (exact for a Keplerian orbit; perturbations turn the orbit plane far more slowly).
* :func:`sun_pointing`: a body axis at the Sun, a second axis as near a secondary direction as the Sun
  allows; the Sun's apparent motion (~2e-7 rad/s) is neglected.
* :func:`target_pointing`: a body axis at a point on the Earth (inertial position and velocity of
  target and spacecraft), the second axis towards a secondary direction (default the orbit normal, fixed
  for a Keplerian orbit; a given secondary is held fixed in GCRS); the rate by a central
  difference over ``dt_s`` of the two-vector frame with both positions moved along their velocities
  (the accelerations cancel in the central difference, so the rate is second-order exact).

Pointing frames are built by the two-vector (TRIAD-like) rule: the primary axis exactly, the second
axis in the plane of the secondary direction; refused when the two are within 1 deg of parallel.
"""

from __future__ import annotations

import math

import numpy as np

from sim.frames import dcm_lvlh_gcrs
from sim.rotations import canonical, quat_from_dcm

from .quat import cross as cross_floats
from .quat import finite3

__all__ = ["inertial", "nadir", "pointing_frame", "sun_pointing", "target_pointing"]

#: Smallest sine between a primary and a secondary direction (1 deg) before the frame is refused.
MIN_SINE = math.sin(math.radians(1.0))


class GuidanceError(ValueError):
    """Guidance input that cannot define a frame (NaN, zero, parallel directions)."""


def _vec(v, name: str) -> np.ndarray:
    return np.array(finite3(v, name, GuidanceError))


def cross(a, b) -> np.ndarray:
    """``a x b`` of two 3-vectors as an array (the guidance does its frame algebra in numpy: it runs once a period)."""
    return np.array(cross_floats(a, b))


def _unit(v, name: str) -> np.ndarray:
    a = _vec(v, name)
    n = float(np.linalg.norm(a))
    if n == 0.0:
        raise GuidanceError(f"{name} is the zero vector; a direction is needed.")
    return a / n


def inertial(q_RN) -> tuple[np.ndarray, np.ndarray]:
    q = np.asarray(q_RN, dtype=float)
    if q.shape != (4,) or not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1.0) > 1e-6:
        raise GuidanceError(f"q_RN = {np.asarray(q_RN).tolist()} must be a finite unit quaternion [w, x, y, z].")
    return canonical(q), np.zeros(3)


def nadir(r_N, v_N) -> tuple[np.ndarray, np.ndarray]:
    """LVLH reference from the spacecraft's inertial position (m) and velocity (m/s)."""
    r, v = _vec(r_N, "r_N"), _vec(v_N, "v_N")
    h = cross(r, v)
    if np.linalg.norm(h) <= MIN_SINE * np.linalg.norm(r) * np.linalg.norm(v):
        raise GuidanceError("r_N and v_N are (nearly) parallel; the orbit normal, and so LVLH, is undefined.")
    C_RN = dcm_lvlh_gcrs(r, v)
    omega_RN_R = C_RN @ (h / float(r @ r))
    return quat_from_dcm(C_RN), omega_RN_R


def pointing_frame(primary_N, secondary_N, primary_axis_B=(0.0, 0.0, 1.0),
                   secondary_axis_B=(1.0, 0.0, 0.0)) -> np.ndarray:
    """``dcm_RN`` that puts body ``primary_axis_B`` on ``primary_N`` and ``secondary_axis_B`` towards ``secondary_N``.
    """
    p, s = _unit(primary_N, "primary_N"), _unit(secondary_N, "secondary_N")
    a, b = _unit(primary_axis_B, "primary_axis_B"), _unit(secondary_axis_B, "secondary_axis_B")
    for name, u, w in (("primary_N, secondary_N", p, s), ("primary_axis_B, secondary_axis_B", a, b)):
        if np.linalg.norm(cross(u, w)) < MIN_SINE:
            raise GuidanceError(f"{name} are within 1 deg of parallel; they cannot fix a frame.")

    def triad(u, w):
        t2 = cross(u, w)
        t2 /= np.linalg.norm(t2)
        return np.column_stack((u, t2, cross(u, t2)))

    return triad(a, b) @ triad(p, s).T


def sun_pointing(sun_N, secondary_N, sun_axis_B=(0.0, 0.0, 1.0),
                 secondary_axis_B=(1.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Body ``sun_axis_B`` at the Sun (``sun_N``: direction or position relative to the spacecraft, GCRS)."""
    return quat_from_dcm(pointing_frame(sun_N, secondary_N, sun_axis_B, secondary_axis_B)), np.zeros(3)


def target_pointing(r_N, v_N, target_r_N, target_v_N, secondary_N=None, boresight_B=(0.0, 0.0, 1.0),
                    secondary_axis_B=(1.0, 0.0, 0.0), dt_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Body ``boresight_B`` at a target on the Earth. Positions in m and velocities in m/s, GCRS (the target's
    inertial velocity is ``omega_earth x r``). ``secondary_N`` (held fixed over the difference) defaults to the
    orbit normal ``r x v``."""
    r, v, rt, vt = _vec(r_N, "r_N"), _vec(v_N, "v_N"), _vec(target_r_N, "target_r_N"), _vec(target_v_N, "target_v_N")
    if not (math.isfinite(dt_s) and dt_s > 0.0):
        raise GuidanceError(f"dt_s = {dt_s!r}; the differencing interval must be a positive number of seconds.")

    sec = cross(r, v) if secondary_N is None else _vec(secondary_N, "secondary_N")

    def frame(tau):
        return pointing_frame((rt + vt * tau) - (r + v * tau), sec, boresight_B, secondary_axis_B)

    C = frame(0.0)
    Cp, Cm = frame(dt_s), frame(-dt_s)
    # dC/dt = -[omega x] C  =>  [omega x] = -dC/dt C^T
    W = -(Cp - Cm) / (2.0 * dt_s) @ C.T
    omega_RN_R = 0.5 * np.array([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]])
    return quat_from_dcm(C), omega_RN_R
