"""Gravity: JGM-3 20x20 against satkit, J2 in RSW against accel_j2, third body, drag and SRP."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim import gravity, harmonics
from sim.constants import AU, J2_EARTH, MU_EARTH, R_EARTH
from sim.frames import dcm_rsw_gcrs
from sim.orbit import accel_j2
from tests.oracles import require


def _points(n, seed):
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    u[:2] = [[0, 0, 1], [0, 0, -1]]  # the poles exactly
    return u * rng.uniform(R_EARTH + 200e3, R_EARTH + 2000e3, (n, 1))


def test_jgm3_degree_20_matches_satkit_to_1e_12():
    satkit = require("satkit")
    field = gravity.load_field("jgm3", 20)
    r = _points(60, 1)
    a = field.accel_itrs(r)
    for k in range(len(r)):
        b = satkit.gravity(r[k], model=satkit.gravmodel.jgm3, degree=20)
        assert np.linalg.norm(a[k] - b) < 1e-12 * np.linalg.norm(b)
    for deg in (2, 7):
        b = satkit.gravity(r[5], model=satkit.gravmodel.jgm3, degree=deg)
        assert np.linalg.norm(gravity.load_field("jgm3", deg).accel_itrs(r[5]) - b) < 1e-12 * np.linalg.norm(b)


def test_zonal_j2_series_equals_the_closed_form():
    nn, mm = harmonics.index_nm(2)
    C = np.where((nn == 0), 1.0, 0.0) + np.where((nn == 2) & (mm == 0), -J2_EARTH / np.sqrt(5.0), 0.0)
    field = gravity.GravityField("j2", MU_EARTH, R_EARTH, 2, C, np.zeros_like(C))
    r = _points(40, 2)
    np.testing.assert_allclose(field.accel_itrs(r), accel_j2(r), rtol=1e-13, atol=0)


@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, np.pi), st.floats(0.0, 2 * np.pi), st.floats(0.0, 2 * np.pi), st.floats(6.6e6, 4.2e7),
       st.floats(0.0, 0.3))
def test_rsw_j2_equals_accel_j2_rotated_into_rsw(i, raan, u, r_m, vr):
    r = r_m * np.array([np.cos(raan) * np.cos(u) - np.sin(raan) * np.sin(u) * np.cos(i),
                        np.sin(raan) * np.cos(u) + np.cos(raan) * np.sin(u) * np.cos(i),
                        np.sin(u) * np.sin(i)])
    w = np.array([np.sin(raan) * np.sin(i), -np.cos(raan) * np.sin(i), np.cos(i)])
    vc = np.sqrt(MU_EARTH / r_m)
    v = vc * np.cross(w, r / r_m) + vr * vc * r / r_m  # any velocity in the plane
    pert = accel_j2(r) + MU_EARTH * r / r_m**3
    expected = dcm_rsw_gcrs(r, v) @ pert
    got = gravity.accel_j2_rsw(r, v)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9 * np.linalg.norm(pert))


def test_third_body_on_the_line_matches_the_closed_form():
    D = 384_400e3
    r_body = np.array([D, 0.0, 0.0])
    for x in (7e6, -7e6, 4.2e7):
        a = gravity.accel_third_body(np.array([x, 0.0, 0.0]), r_body, gravity.GM_MOON)
        exact = gravity.GM_MOON * (np.sign(D - x) / (D - x) ** 2 - 1 / D**2)
        assert a[0] == pytest.approx(exact, rel=1e-12)
        assert a[1] == a[2] == 0.0
    # Off the line: equal to the direct difference in extended precision.
    rs = np.array([3e6, -5e6, 4e6])
    rb = np.array([-1.2e11, 8.4e10, 3.6e10])
    d = rb.astype(np.longdouble) - rs.astype(np.longdouble)
    ref = gravity.GM_SUN * (d / np.linalg.norm(d) ** 3 - rb / np.linalg.norm(rb.astype(np.longdouble)) ** 3)
    np.testing.assert_allclose(gravity.accel_third_body(rs, rb, gravity.GM_SUN), ref.astype(float), rtol=1e-9)


def test_drag_opposes_the_air_relative_velocity_and_follows_the_density():
    r = np.array([R_EARTH + 500e3, 0.0, 0.0])
    v = np.array([0.0, 7600.0, 10.0])
    a = gravity.accel_drag_exponential(r, v, cd=2.2, area_m2=0.05, mass_kg=4.0)
    expected = -0.5 * 6.967e-13 * 2.2 * 0.05 / 4.0 * np.linalg.norm(v) * v
    np.testing.assert_allclose(a, expected, rtol=1e-14)
    higher = gravity.accel_drag_exponential(r + [63.822e3, 0, 0], v, cd=2.2, area_m2=0.05, mass_kg=4.0)
    np.testing.assert_allclose(higher, a / np.e, rtol=1e-12)
    with pytest.raises(ValueError, match="drag mass_kg = 0"):
        gravity.accel_drag_exponential(r, v, cd=2.2, area_m2=0.05, mass_kg=0)


def test_srp_is_zero_in_umbra_and_the_inverse_square_value_in_sun():
    r_sun = np.array([AU, 0.0, 0.0])
    lit = gravity.accel_srp_cannonball([0.0, 7e6, 0.0], r_sun, cr=1.5, area_m2=0.1, mass_kg=10.0)
    d = r_sun - [0.0, 7e6, 0.0]
    np.testing.assert_allclose(lit, -gravity.P_SUN_1AU * (AU / np.linalg.norm(d)) ** 2 * 1.5 * 0.1 / 10.0
                               * d / np.linalg.norm(d), rtol=1e-14)
    dark = gravity.accel_srp_cannonball([-7e6, 0.0, 0.0], r_sun, cr=1.5, area_m2=0.1, mass_kg=10.0)
    np.testing.assert_array_equal(dark, 0.0)


def test_bad_model_degree_and_position_are_refused():
    with pytest.raises(ValueError, match="gravity model 'egm2008' is not available"):
        gravity.load_field("egm2008", 20)
    with pytest.raises(ValueError, match="gravity degree 21 is not allowed for jgm3; use an integer from 2 to 20"):
        gravity.load_field("jgm3", 21)
    with pytest.raises(ValueError, match="valid outside the Earth"):
        gravity.load_field("jgm3", 4).accel_itrs([1e6, 0, 0])
