"""Eclipse: conical (penumbra) and cylindrical shadow against closed-form disk geometry."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.constants import AU, R_EARTH
from sim.environment import R_SUN, shadow_fraction


def geometry(a, b, c):
    """Satellite and Sun positions giving apparent radii a (Sun), b (Earth) and separation c (rad)."""
    d = R_EARTH / np.sin(b)
    r_sat = np.array([d, 0.0, 0.0])
    u = np.array([-np.cos(c), np.sin(c), 0.0])
    return r_sat, r_sat + (R_SUN / np.sin(a)) * u


def test_full_sun_and_umbra():
    r_sun = np.array([AU, 0.0, 0.0])
    sats = np.array([[7e6, 0, 0], [0, 7e6, 0], [-7e6, 0, 0], [-7e6, 0, 6.5e6]])
    np.testing.assert_array_equal(shadow_fraction(sats, r_sun), [1.0, 1.0, 0.0, 1.0])
    np.testing.assert_array_equal(shadow_fraction(sats, r_sun, model="cylindrical"), [1.0, 1.0, 0.0, 1.0])


@pytest.mark.parametrize("c_over_a", [0.2, 0.7, 1.0, 1.5, 1.9])
def test_equal_disks_overlap_matches_the_lens_formula(c_over_a):
    a = b = np.radians(0.26)
    c = c_over_a * a
    lens = 2 * a * a * np.arccos(c / (2 * a)) - 0.5 * c * np.sqrt(4 * a * a - c * c)
    r_sat, r_sun = geometry(a, b, c)
    assert shadow_fraction(r_sat, r_sun) == pytest.approx(1 - lens / (np.pi * a * a), abs=1e-9)


def test_limb_through_the_sun_centre_hides_half_the_sun():
    # Earth's disk much larger than the Sun's: its limb is almost straight across the Sun's centre.
    a, b = np.radians(0.267), np.radians(60.0)
    r_sat, r_sun = geometry(a, b, b)
    assert shadow_fraction(r_sat, r_sun) == pytest.approx(0.5, abs=2e-3)  # limb curvature a/b/(3 pi)


def test_annular_far_from_earth():
    a, b = np.radians(0.27), np.radians(0.1)
    r_sat, r_sun = geometry(a, b, 0.05 * a)
    assert shadow_fraction(r_sat, r_sun) == pytest.approx(1 - (b / a) ** 2, abs=1e-12)


@settings(max_examples=50, deadline=None)
@given(st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_fraction_is_monotonic_through_the_penumbra(s0, s1):
    a, b = np.radians(0.266), np.radians(65.0)
    lo, hi = sorted((s0, s1))
    cs = b - a + np.array([lo, hi]) * 2 * a
    f = [shadow_fraction(*geometry(a, b, c)) for c in cs]
    assert 0.0 <= f[0] <= f[1] + 1e-12 <= 1.0 + 1e-12


def test_vectorised_shape_and_errors():
    r_sat = np.random.default_rng(2).normal(size=(4, 5, 3)) * 8e6
    r_sat *= (7e6 / np.linalg.norm(r_sat, axis=-1))[..., None]
    assert shadow_fraction(r_sat, [AU, 0, 0]).shape == (4, 5)
    with pytest.raises(ValueError, match="allowed: 'conical', 'cylindrical'"):
        shadow_fraction([7e6, 0, 0], [AU, 0, 0], model="cone")
    with pytest.raises(ValueError, match="inside the Earth"):
        shadow_fraction([6e6, 0, 0], [AU, 0, 0])
