"""The orbit force model a scenario asks for, as one callable ``accel(t_s, r_N, v_N) -> a_N``.

Each term exists only when asked for: the spherical-harmonic field needs the Earth rotation, the
third bodies and radiation pressure need the Sun or Moon track, drag needs the Earth-fixed
velocity. Everything is in GCRS (m, m/s, m/s^2); ``t_s`` is seconds since the scenario epoch.
"""

from __future__ import annotations

import numpy as np

from .constants import J2_EARTH, MU_EARTH, OMEGA_EARTH, R_EARTH
from .gravity import GM_MOON, GM_SUN, accel_drag_exponential, accel_srp_cannonball, accel_third_body, load_field
from .orbit import accel_j2

GM = {"sun": GM_SUN, "moon": GM_MOON}


class OrbitForces:
    def __init__(self, *, gravity: str = "j2", degree: int = 20, rotation=None, tracks: dict | None = None,
                 third_bodies=(), drag: dict | None = None, srp: dict | None = None, mass_kg: float = 1.0):
        if gravity not in ("point", "j2", "jgm3"):
            raise ValueError(f"orbit.gravity = {gravity!r}; allowed: 'point', 'j2', 'jgm3'.")
        if (gravity == "jgm3" or drag) and rotation is None:
            raise ValueError("an Earth-fixed force term (harmonic gravity or drag) needs an Earth rotation model.")
        tracks = tracks or {}
        for body in list(third_bodies) + (["sun"] if srp else []):
            if body not in tracks:
                raise ValueError(f"the {body} track is needed by the force model but was not given.")
        self.gravity = gravity
        self.field = load_field("jgm3", degree) if gravity == "jgm3" else None
        self.rotation = rotation
        self.tracks = tracks
        self.third_bodies = tuple(third_bodies)
        self.drag = drag
        self.srp = srp
        self.mass_kg = float(mass_kg)

    def __call__(self, t_s: float, r_N, v_N) -> np.ndarray:
        C = self.rotation.dcm_itrs_gcrs(t_s) if self.rotation is not None else None
        if self.gravity == "jgm3":
            a = C.T @ self.field.accel_itrs(C @ r_N)
        else:
            a = accel_j2(r_N, MU_EARTH, J2_EARTH if self.gravity == "j2" else 0.0, R_EARTH)
        for body in self.third_bodies:
            a = a + accel_third_body(r_N, self.tracks[body].position_gcrs(t_s), GM[body])
        if self.drag:
            # The atmosphere turns with the Earth: drag acts on the velocity relative to the air.
            v_air = v_N - np.cross([0.0, 0.0, OMEGA_EARTH], r_N)
            a = a + C.T @ accel_drag_exponential(C @ r_N, C @ v_air, self.drag["cd"], self.drag["area_m2"],
                                                 self.mass_kg)
        if self.srp:
            a = a + accel_srp_cannonball(r_N, self.tracks["sun"].position_gcrs(t_s), self.srp["cr"],
                                         self.srp["area_m2"], self.mass_kg, self.srp.get("shadow", "conical"))
        return a
