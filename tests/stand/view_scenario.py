"""A short scenario for the operator-page tests: a slow turn that sweeps a star tracker's boresight into the Sun.

At the epoch (2026-03-20 12:00 UTC, the spacecraft at the vernal-equinox side of its orbit) the Sun is near the
zenith. The body's +x axis, the tracker's boresight, starts 55 deg from the Sun on the side away from the Moon and
turns toward the Sun at 0.5 deg/s (below the tracker's 1 deg/s rate limit) with no controller: the tracker
acquires and is valid, then the Sun enters its 40 deg exclusion cone after about 30 s and the solutions turn
invalid with the Sun flag.
"""

from __future__ import annotations

import math

import numpy as np

from sim.ephemeris import moon_position_gcrs, sun_position_gcrs
from sim.rotations import quat_from_dcm
from sim.time import Epoch
from stand.compose import initial_state
from stand.scenario import load

EPOCH = "2026-03-20T12:00:00Z"
START_DEG = 55.0
RATE_DEG_S = 0.5


def _unit(v):
    return v / np.linalg.norm(v)


def attitude() -> tuple[list[float], list[float]]:
    """(q_BN, omega_BN_B in deg/s) of the sweep."""
    sc = load("detumble_star_tracker")
    r, _ = initial_state(sc)
    epoch = Epoch.from_iso(EPOCH)
    s = _unit(sun_position_gcrs(epoch) - r)
    m = _unit(moon_position_gcrs(epoch) - r)
    e = _unit(m - (m @ s) * s)
    a = math.radians(START_DEG)
    b0 = math.cos(a) * s - math.sin(a) * e
    k = _unit(np.cross(b0, s))
    q = quat_from_dcm(np.stack((b0, k, np.cross(b0, k))))
    return [float(x) for x in q], [0.0, RATE_DEG_S, 0.0]


def write(path, duration_s: float = 60.0) -> str:
    q, w = attitude()
    text = f"""
[scenario]
name = "view_sun_sweep"
description = "a star tracker's boresight swept into the Sun"
epoch = "{EPOCH}"
duration_s = {duration_s}
seed = 3

[dynamics]
step_s = 0.1
integrator = "rk4"
torques = ["gravity_gradient"]

[orbit]
altitude_km = 500.0
i_deg = 97.4

[spacecraft]
mass_kg = 4.0
inertia_kg_m2 = [0.02, 0.02, 0.01]
q_BN = [{", ".join(repr(x) for x in q)}]
omega_BN_B_deg_s = [{", ".join(repr(x) for x in w)}]

[environment]
magnetic_field = "dipole"
earth_rotation = "iau2006"
eop = "none"

[[devices]]
name = "mtq"
kind = "magnetorquer"
interface = "virtual"
channel = "stand-view-test"

[[devices]]
name = "st1"
kind = "star_tracker"
q_SB = [0.70710678118654752, 0.0, 0.70710678118654752, 0.0]
output_interval_s = 0.2
rate_limit_deg_s = 1.0
sun_exclusion_deg = 40.0
moon_exclusion_deg = 20.0
earth_exclusion_deg = 20.0

[[devices]]
name = "fss"
kind = "sun_sensor"
type = "fine"
q_SB = [0.86602540378443865, 0.0, 0.5, 0.0]  # boresight 30 deg from the tracker's, toward body +z
rate_hz = 1.0
fov_half_deg = 60.0

[controller]
kind = "none"

[recording]
rate_hz = 10.0
"""
    path.write_text(text)
    return str(path)
