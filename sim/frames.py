"""Reference frames and the matrices between them.

Every function returns a direction cosine matrix ``dcm_XY`` that maps Y components to X components
(``v_X = dcm_XY @ v_Y``), broadcast over leading axes.

* ``gcrs``: inertial, the star catalog's frame (J2000 to within the 23 mas frame bias).
* ``itrs``: Earth-fixed. GCRS -> ITRS uses the full IAU 2006/2000A precession-nutation (CIO based,
  ERFA ``c2t06a``), not sidereal time alone: that shortcut is 0.37 deg off in 2026.
* ``lvlh``: z to nadir, y along the negative orbit normal, x completes (x is along-track for a
  circular orbit).
* ``rsw``: radial, along-track (in-plane, perpendicular to r), orbit normal.
* ``esd``: local east, south, down at a position (geocentric, spherical Earth).
"""

from __future__ import annotations

import erfa
import numpy as np

from .constants import OMEGA_EARTH
from .time import Epoch, ignore_dubious_year


def _unit(v, name: str) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(n == 0.0) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be a finite non-zero vector to define a frame.")
    return v / n


def dcm_itrs_gcrs(epoch: Epoch, xp_rad: float = 0.0, yp_rad: float = 0.0, eop=None) -> np.ndarray:
    """GCRS -> ITRS at ``epoch`` by IAU 2006/2000A (ERFA ``c2t06a``), with polar motion if given.

    UT1 comes from ``epoch.dut1_s``; without IERS data both UT1 - UTC and polar motion are 0,
    which costs at most 13.5 arcsec of Earth rotation and 0.5 arcsec of pole position.
    ``eop``: a :class:`sim.eop.EOP` (values at this epoch), a :class:`sim.eop.EOPTable` or
    ``"default"`` (astropy-iers-data's table if installed, else the zero fallback); it then
    supplies UT1 - UTC and polar motion, replacing ``epoch.dut1_s``, ``xp_rad`` and ``yp_rad``.
    """
    tt1, tt2 = epoch.jd_tt
    if eop is not None:
        from .eop import EOP, eop_at

        e = eop if isinstance(eop, EOP) else eop_at(epoch, eop)
        xp_rad, yp_rad = e.xp_rad, e.yp_rad
        # erfa.utcut1 handles the stretched quasi-JD of a leap-second day (Epoch.jd_ut1 adds
        # dut1 / 86400 to it, which is up to 1 s off in UT1 on such a day).
        with ignore_dubious_year():
            u1, u2 = erfa.utcut1(*epoch.jd_utc, e.dut1_s)
    else:
        u1, u2 = epoch.jd_ut1
    return np.asarray(erfa.c2t06a(tt1, tt2, u1, u2, xp_rad, yp_rad))


def rotation_z(angle) -> np.ndarray:
    """Frame rotation matrix about z by ``angle`` (rad), broadcast: ``M3(angle)``."""
    angle = np.asarray(angle, dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack(
        (np.stack((c, s, z), -1), np.stack((-s, c, z), -1), np.stack((z, z, o), -1)), axis=-2
    )


class EarthRotation:
    """GCRS -> ITRS over a run, cheap at every step.

    ``model="iau2006"``: ERFA's celestial-to-intermediate matrix (precession-nutation, moves by
    milliarcseconds per minute) is evaluated on a coarse grid and interpolated linearly, and the
    Earth rotation angle is exact (linear in UT1). Polar motion is held constant over the run.
    ``model="uniform"``: rotation about the GCRS z axis at the nominal rate from ``era0_rad`` at
    the epoch, the idealised Earth of comparison cases (the B-dot detumble comparison with Basilisk
    starts with the Earth-fixed axes equal to the inertial axes).
    """

    def __init__(self, epoch: Epoch, model: str = "iau2006", era0_rad: float = 0.0,
                 xp_rad: float = 0.0, yp_rad: float = 0.0, grid_s: float = 600.0):
        if model not in ("iau2006", "uniform"):
            raise ValueError(f"earth rotation model {model!r} is not one of 'iau2006', 'uniform'.")
        self.epoch = epoch
        self.model = model
        self.era0_rad = float(era0_rad)
        self.grid_s = float(grid_s)
        self._w = np.asarray(erfa.pom00(xp_rad, yp_rad, erfa.sp00(*epoch.jd_tt)))
        self._cache: dict[int, np.ndarray] = {}

    def _c2i(self, k: int) -> np.ndarray:
        m = self._cache.get(k)
        if m is None:
            tt1, tt2 = (self.epoch + k * self.grid_s).jd_tt
            m = self._cache[k] = np.asarray(erfa.c2i06a(tt1, tt2))
        return m

    def dcm_itrs_gcrs(self, t_s) -> np.ndarray:
        """``(..., 3, 3)`` GCRS -> ITRS at sim times ``t_s`` (seconds since the epoch)."""
        t = np.asarray(t_s, dtype=float)
        if self.model == "uniform":
            return rotation_z(self.era0_rad + OMEGA_EARTH * t)
        u1, u2 = self.epoch.jd_ut1
        era = erfa.era00(u1, u2 + t / 86400.0)
        k = np.floor(t / self.grid_s).astype(int)
        frac = (t / self.grid_s - k)[..., None, None]
        ks = np.unique(np.concatenate((np.ravel(k), np.ravel(k) + 1)))
        table = {int(kk): self._c2i(int(kk)) for kk in ks}
        c0 = np.stack([table[int(kk)] for kk in np.ravel(k)]).reshape(k.shape + (3, 3))
        c1 = np.stack([table[int(kk) + 1] for kk in np.ravel(k)]).reshape(k.shape + (3, 3))
        c2i = c0 + (c1 - c0) * frac
        return self._w @ rotation_z(era) @ c2i


def dcm_rsw_gcrs(r_N, v_N) -> np.ndarray:
    """GCRS -> RSW (radial, along-track, orbit normal) for position ``r_N`` and velocity ``v_N``."""
    r_N = np.asarray(r_N, dtype=float)
    v_N = np.asarray(v_N, dtype=float)
    R = _unit(r_N, "r_N")
    W = _unit(np.cross(r_N, v_N), "r_N x v_N (the orbit normal)")
    S = np.cross(W, R)
    return np.stack((R, S, W), axis=-2)


def dcm_lvlh_gcrs(r_N, v_N) -> np.ndarray:
    """GCRS -> LVLH (z nadir, y negative orbit normal, x = y cross z)."""
    r_N = np.asarray(r_N, dtype=float)
    z = -_unit(r_N, "r_N")
    y = -_unit(np.cross(r_N, np.asarray(v_N, dtype=float)), "r_N x v_N (the orbit normal)")
    x = np.cross(y, z)
    return np.stack((x, y, z), axis=-2)


def dcm_esd_itrs(r_itrs) -> np.ndarray:
    """ITRS -> local east, south, down at Earth-fixed position ``r_itrs`` (geocentric)."""
    r = np.asarray(r_itrs, dtype=float)
    down = -_unit(r, "r_itrs")
    pole = np.broadcast_to([0.0, 0.0, 1.0], r.shape)
    east = np.cross(pole, -down)
    ne = np.linalg.norm(east, axis=-1, keepdims=True)
    if np.any(ne < 1e-12 * np.linalg.norm(r, axis=-1, keepdims=True)):
        raise ValueError("east is undefined exactly above a pole; nudge the position off the axis.")
    east = east / ne
    south = np.cross(down, east)
    return np.stack((east, south, down), axis=-2)


def dcm_esd_gcrs(r_N, epoch: Epoch) -> np.ndarray:
    """GCRS -> local east, south, down at inertial position ``r_N`` and time ``epoch``."""
    C = dcm_itrs_gcrs(epoch)
    r_itrs = np.einsum("ij,...j->...i", C, np.asarray(r_N, dtype=float))
    return dcm_esd_itrs(r_itrs) @ C
