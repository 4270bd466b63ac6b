"""(ra, dec, roll) -> q_SN convention: hand-checked directions, round trip, poles."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.rotations import dcm
from star_screen.attitude import q_SN_from_radec_roll, radec_roll_from_q_SN
from star_screen.catalog import radec_to_unit


def _dir_S(q, ra, dec):
    return dcm(q) @ radec_to_unit(math.radians(ra), math.radians(dec))


def test_roll_zero_north_up_east_left():
    q = q_SN_from_radec_roll(40.0, 20.0, 0.0)
    assert np.allclose(_dir_S(q, 40.0, 20.0), [0, 0, 1], atol=1e-14)
    north = _dir_S(q, 40.0, 21.0)
    east = _dir_S(q, 41.0, 20.0)
    assert north[1] < -0.01 and abs(north[0]) < 1e-12  # image up (-y)
    assert east[0] < -0.01 and abs(east[1]) < 0.001  # image left (-x)
    assert q[0] >= 0


def test_positive_roll_turns_north_toward_left():
    q = q_SN_from_radec_roll(40.0, 20.0, 90.0)
    north = _dir_S(q, 40.0, 21.0)
    assert north[0] < -0.01 and abs(north[1]) < 1e-12
    q30 = q_SN_from_radec_roll(40.0, 20.0, 30.0)
    n30 = _dir_S(q30, 40.0, 21.0)
    assert math.isclose(math.degrees(math.atan2(-n30[0], -n30[1])), 30.0, abs_tol=1e-9)


@settings(max_examples=200, deadline=None)
@given(st.floats(0, 359.999), st.floats(-89.9, 89.9), st.floats(-179.9, 179.9))
def test_round_trip(ra, dec, roll):
    r2, d2, o2 = radec_roll_from_q_SN(q_SN_from_radec_roll(ra, dec, roll))
    assert abs((r2 - ra + 180) % 360 - 180) < 1e-7
    assert abs(d2 - dec) < 1e-9
    assert abs((o2 - roll + 180) % 360 - 180) < 1e-7


def test_pole_is_the_limit_from_below():
    q_pole = q_SN_from_radec_roll(30.0, 90.0, 10.0)
    q_near = q_SN_from_radec_roll(30.0, 90.0 - 1e-7, 10.0)
    assert np.allclose(dcm(q_pole), dcm(q_near), atol=1e-8)
    assert np.allclose(dcm(q_pole)[2], [0, 0, 1], atol=1e-15)


def test_bad_declination_names_the_field():
    with pytest.raises(ValueError, match="dec"):
        q_SN_from_radec_roll(0.0, 91.0, 0.0)
