"""Bright bodies (Sun, Moon, Earth) near a tracker's field: flags for the frame's truth.

A :class:`BrightBodies` is built for the bodies a scene's devices care about; bodies not listed are
never computed (no ephemeris call at all). For each listed body and frame it reports the apparent
centre direction, angular radius, angle from the boresight, the detector pixel of the centre, the
illuminated fraction (Moon, Earth) and ``in_field``: the disk grown by the body's exclusion margin
intersects the detector rectangle. Bodies are flagged, not drawn (a screen cannot show the Sun).

The Earth follows the transform chain of the seed paper on planet-satellite arrangement:
planet-fixed (ITRS) -> inertial (GCRS) -> orbital (LVLH: z to nadir, y along the negative orbit
normal) -> body -> camera (:func:`earth_point_in_camera_chain`); a test proves it equals the direct
``dcm(q_SN) @ (r - r_sc)``. Planet-fixed -> inertial uses ERFA's IAU 2006/2000A ``c2t06a`` with
polar motion set to zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sim import ephemeris
from sim.constants import R_EARTH
from sim.frames import dcm_itrs_gcrs, dcm_lvlh_gcrs
from sim.rotations import dcm
from sim.time import Epoch
from star_screen.geometry import TrackerOptics

__all__ = [
    "BrightBodies",
    "R_SUN",
    "R_MOON",
    "dcm_itrs_gcrs",
    "dcm_lvlh_gcrs",
    "earth_point_in_camera_chain",
    "DEFAULT_MARGINS_DEG",
]

R_SUN = 6.957e8  # m, IAU 2015 nominal
R_MOON = 1.7374e6  # m
DEFAULT_MARGINS_DEG = {"sun": 30.0, "moon": 10.0, "earth": 15.0}
_KNOWN = ("sun", "moon", "earth")


def earth_point_in_camera_chain(r_point_itrs, epoch: Epoch, r_sc_N, v_sc_N, q_BO, q_SB) -> np.ndarray:
    """Position of an Earth-fixed point relative to the spacecraft in camera axes, step by step:
    planet-fixed -> inertial -> (relative to the spacecraft) orbital -> body -> camera."""
    r_inertial = dcm_itrs_gcrs(epoch).T @ np.asarray(r_point_itrs, float)  # planet-fixed -> inertial
    rel_N = r_inertial - np.asarray(r_sc_N, float)
    rel_O = dcm_lvlh_gcrs(r_sc_N, v_sc_N) @ rel_N  # inertial -> orbital
    rel_B = dcm(q_BO) @ rel_O  # orbital -> body
    return dcm(q_SB) @ rel_B  # body -> camera


@dataclass
class BrightBodies:
    """Flags for the listed bodies in one tracker's field."""

    tracker: TrackerOptics
    bodies: tuple = ("sun", "moon")
    margins_deg: dict = field(default_factory=lambda: dict(DEFAULT_MARGINS_DEG))

    def __post_init__(self):
        self.bodies = tuple(self.bodies)
        for b in self.bodies:
            if b not in _KNOWN:
                raise ValueError(f"bright body {b!r} is not known; choose from {', '.join(_KNOWN)}.")
        t = self.tracker
        self._corners = np.array([[0, 0], [t.width, 0], [0, t.height], [t.width, t.height]], float)
        self._half_diag = t.half_diagonal_rad()

    def _flag(self, name, r_rel_N, radius_m, C_SN, illum=None) -> dict:
        dist = float(np.linalg.norm(r_rel_N))
        u_N = r_rel_N / dist
        ang_r = math.asin(min(1.0, radius_m / dist))
        margin = math.radians(self.margins_deg.get(name, 0.0))
        d_S = C_SN @ u_N
        off = math.acos(max(-1.0, min(1.0, d_S[2])))
        reach = ang_r + margin
        rec = {
            "angular_radius_deg": math.degrees(ang_r),
            "off_boresight_deg": math.degrees(off),
            "margin_deg": math.degrees(margin),
            "distance_m": dist,
            "u_N": u_N.tolist(),
            "detector_xy": None,
        }
        if illum is not None:
            rec["illuminated_fraction"] = illum
        in_field = False
        if off <= self._half_diag + reach:
            if d_S[2] > 1e-6:
                px, _ = self.tracker.project(d_S)
                rec["detector_xy"] = px.tolist()
                t = self.tracker
                nearest = np.clip(px, [0.0, 0.0], [t.width, t.height])
                d_near = t.unproject(nearest)
                in_field = bool(math.acos(max(-1.0, min(1.0, float(d_near @ d_S)))) <= reach)
            else:
                in_field = off - reach <= self._half_diag
        rec["in_field"] = in_field
        return rec

    def evaluate(self, q_SN, epoch: Epoch, r_sc_gcrs_m=None) -> dict:
        """Flags of every listed body (and nothing for the others); ``any_in_field`` summarises."""
        C = dcm(q_SN)
        r_sc = np.zeros(3) if r_sc_gcrs_m is None else np.asarray(r_sc_gcrs_m, float)
        out: dict = {}
        r_sun = None
        if "sun" in self.bodies or "moon" in self.bodies or "earth" in self.bodies:
            r_sun = ephemeris.sun_position_gcrs(epoch)
        if "sun" in self.bodies:
            out["sun"] = self._flag("sun", r_sun - r_sc, R_SUN, C)
        if "moon" in self.bodies:
            r_moon = ephemeris.moon_position_gcrs(epoch)
            rel = r_moon - r_sc
            s = r_sun - r_moon
            phase = math.acos(
                float(np.clip(np.dot(-rel, s) / (np.linalg.norm(rel) * np.linalg.norm(s)), -1, 1))
            )
            out["moon"] = self._flag("moon", rel, R_MOON, C, illum=0.5 * (1 + math.cos(phase)))
        if "earth" in self.bodies:
            if r_sc_gcrs_m is None:
                raise ValueError(
                    "the Earth is listed among bright bodies, so r_sc_gcrs_m (spacecraft position, m) "
                    "is required."
                )
            rel = -r_sc
            s = r_sun
            phase = math.acos(
                float(np.clip(np.dot(-rel, s) / (np.linalg.norm(rel) * np.linalg.norm(s)), -1, 1))
            )
            out["earth"] = self._flag("earth", rel, R_EARTH, C, illum=0.5 * (1 + math.cos(phase)))
        out["any_in_field"] = any(v["in_field"] for v in out.values() if isinstance(v, dict))
        return out
