"""Pointing of a tracker given as right ascension, declination and roll.

Convention (used by ``stand screen --ra --dec --roll``; tested in tests/star_screen/test_attitude.py):

* The boresight +z_S points to (ra, dec).
* roll = 0: image *up* (-y_S) points toward the north celestial pole and east is to the *left*
  (+x_S points west), the usual sky-chart orientation (tetra3/cedar use the same).
  With the local unit vectors at the boresight ``east = (-sin ra, cos ra, 0)`` and
  ``north = (-sin dec cos ra, -sin dec sin ra, cos dec)`` the rows of ``dcm(q_SN)`` are
  ``x_S = -east``, ``y_S = -north``, ``z_S = boresight``.
* roll > 0 is a right-handed frame rotation of the tracker about +z_S by ``roll``:
  ``dcm(q_SN) = M3(roll) @ dcm0``. Seen on the image (x right, y down) the sky turns
  *counter-clockwise* by ``roll``: north moves from up toward the left.

At the poles the formulas stay well defined: (ra, dec = +90) points at the pole and ``ra`` only
sets which meridian is "up" (north is then the direction of decreasing ``dec`` along that
meridian, continuous with nearby declinations).
"""

from __future__ import annotations

import numpy as np

from sim.rotations import dcm, quat_from_dcm

__all__ = ["q_SN_from_radec_roll", "radec_roll_from_q_SN"]


def _dcm_from_radec_roll(ra, dec, roll) -> np.ndarray:
    ra, dec, roll = (np.asarray(a, dtype=float) for a in (ra, dec, roll))
    ca, sa, cd, sd = np.cos(ra), np.sin(ra), np.cos(dec), np.sin(dec)
    zero = np.zeros_like(ca * cd * roll)
    east = np.stack((-sa + zero, ca + zero, zero), axis=-1)
    north = np.stack((-sd * ca + zero, -sd * sa + zero, cd + zero), axis=-1)
    bore = np.stack((cd * ca + zero, cd * sa + zero, sd + zero), axis=-1)
    c0 = np.stack((-east, -north, bore), axis=-2)
    cr, sr = np.cos(roll) + zero, np.sin(roll) + zero
    one, nul = np.ones_like(zero), zero
    m3 = np.stack(
        (np.stack((cr, sr, nul), -1), np.stack((-sr, cr, nul), -1), np.stack((nul, nul, one), -1)), axis=-2
    )
    return m3 @ c0


def q_SN_from_radec_roll(ra_deg, dec_deg, roll_deg) -> np.ndarray:
    """Quaternion ``q_SN`` (scalar first, w >= 0) of a tracker pointed at (ra, dec) with roll, in degrees."""
    dec = np.asarray(dec_deg, dtype=float)
    if np.any(~np.isfinite(dec)) or np.any(np.abs(dec) > 90.0):
        raise ValueError(f"dec = {dec_deg!r} deg; declination must lie in [-90, 90] deg.")
    for name, v in (("ra", ra_deg), ("roll", roll_deg)):
        if np.any(~np.isfinite(np.asarray(v, dtype=float))):
            raise ValueError(f"{name} = {v!r} deg; it must be a finite angle in degrees.")
    C = _dcm_from_radec_roll(np.radians(ra_deg), np.radians(dec_deg), np.radians(roll_deg))
    return quat_from_dcm(C)


def radec_roll_from_q_SN(q_SN) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of :func:`q_SN_from_radec_roll` (degrees; ra in [0, 360), roll in (-180, 180]).

    At the celestial poles ra and roll are not separable; ra is then returned as 0.
    """
    C = dcm(q_SN)
    z = C[..., 2, :]
    ra = np.mod(np.degrees(np.arctan2(z[..., 1], z[..., 0])), 360.0)
    dec = np.degrees(np.arctan2(z[..., 2], np.hypot(z[..., 0], z[..., 1])))
    ra = np.where(np.hypot(z[..., 0], z[..., 1]) < 1e-12, 0.0, ra)
    C0 = _dcm_from_radec_roll(np.radians(ra), np.radians(dec), 0.0)
    M = C @ np.swapaxes(C0, -1, -2)
    roll = np.degrees(np.arctan2(M[..., 0, 1], M[..., 0, 0]))
    return ra, dec, roll
