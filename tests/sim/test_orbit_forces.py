"""The general Cowell propagator and force model against the dedicated J2 path and each other."""

import numpy as np
import pytest

from sim.forces import OrbitForces
from sim.frames import EarthRotation
from sim.orbit import accel_j2, elements_to_state, propagate_cowell, propagate_j2
from sim.time import Epoch

R0, V0 = elements_to_state(a=6878137.0, e=0.001, i=np.radians(97.4), raan=0.3, argp=0.2, nu=0.1)


def test_cowell_rk4_equals_the_dedicated_j2_rk4():
    t1, r1, v1 = propagate_j2(R0, V0, 6000.0, 10.0)
    t2, r2, v2 = propagate_cowell(R0, V0, 6000.0, 10.0, lambda t, r, v: accel_j2(r))
    np.testing.assert_allclose(t2, t1)
    np.testing.assert_allclose(r2, r1, rtol=0, atol=1e-6)
    np.testing.assert_allclose(v2, v1, rtol=0, atol=1e-9)


def test_force_terms_are_small_perturbations_of_the_right_size():
    epoch = Epoch.from_iso("2026-03-20T12:00:00Z")
    rot = EarthRotation(epoch, "iau2006")
    from sim.ephemeris import EphemerisTrack

    tracks = {"sun": EphemerisTrack(epoch, "sun"), "moon": EphemerisTrack(epoch, "moon")}
    base = OrbitForces(gravity="j2")(0.0, R0, V0)
    full = OrbitForces(gravity="jgm3", degree=20, rotation=rot, tracks=tracks, third_bodies=("sun", "moon"),
                       drag={"cd": 2.2, "area_m2": 0.03}, srp={"cr": 1.5, "area_m2": 0.03}, mass_kg=4.0)(0.0, R0, V0)
    d = np.linalg.norm(full - base)
    # Higher harmonics at 500 km are ~1e-5 m/s^2 (J3.. and tesserals); third bodies ~1e-6; drag ~1e-7.
    assert 1e-6 < d < 1e-4
    assert tracks["moon"].evaluations > 0


def test_earth_fixed_terms_need_an_earth_rotation():
    with pytest.raises(ValueError, match="Earth rotation"):
        OrbitForces(gravity="jgm3")
    with pytest.raises(ValueError, match="sun track"):
        OrbitForces(gravity="j2", srp={"cr": 1.5, "area_m2": 0.1})
