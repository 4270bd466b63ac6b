"""Sun sensors: cosine law, eclipse awareness, fine-sensor geometry, seeded noise."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.sensors import CoarseSunSensors, FineSunSensor

SIX = np.vstack((np.eye(3), -np.eye(3)))


@settings(max_examples=50, deadline=None)
@given(st.floats(-1, 1), st.floats(0, 2 * np.pi), st.floats(0, 1))
def test_coarse_heads_follow_the_cosine_law_and_recover_the_sun(z, lon, nu):
    s = np.array([np.sqrt(1 - z * z) * np.cos(lon), np.sqrt(1 - z * z) * np.sin(lon), z])
    css = CoarseSunSensors(SIX, i_max_A=2e-3)
    i = css.measure(s, nu)
    np.testing.assert_allclose(i, 2e-3 * nu * np.maximum(SIX @ s, 0.0), atol=1e-18)
    if nu > 1e-6:
        # Opposite heads: I(+x) - I(-x) = I_max nu s_x, so the direction is recovered exactly.
        diff = i[:3] - i[3:]
        np.testing.assert_allclose(diff / np.linalg.norm(diff), s, atol=1e-9)


def test_eclipse_darkens_every_head_and_invalidates_the_fine_sensor():
    s = np.array([0.3, 0.4, np.sqrt(1 - 0.25)])
    assert np.all(CoarseSunSensors(SIX).measure(s, 0.0, rng=np.random.default_rng(1)) >= 0.0)
    np.testing.assert_array_equal(CoarseSunSensors(SIX).measure(s, 0.0), 0.0)
    fss = FineSunSensor(np.eye(3))
    ang, ok = fss.measure(np.stack([s, s, s]), np.array([1.0, 0.4, 0.0]))
    np.testing.assert_array_equal(ok, [True, False, False])
    assert np.all(np.isnan(ang[1:]))
    np.testing.assert_allclose(ang[0], [np.arctan2(0.3, s[2]), np.arctan2(0.4, s[2])])


def test_fine_sensor_mount_and_field_of_view():
    # Sensor boresight along body +x: dcm_SB maps body x to sensor z.
    dcm_SB = np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0]], dtype=float)
    fss = FineSunSensor(dcm_SB, fov_half_deg=30.0)
    s = np.array([np.cos(0.2), np.sin(0.2), 0.0])
    ang, ok = fss.measure(s, 1.0)
    assert ok
    np.testing.assert_allclose(ang, [0.2, 0.0], atol=1e-15)
    _, ok = fss.measure([np.cos(0.6), np.sin(0.6), 0.0], 1.0)  # 34 deg off boresight
    assert not ok


def test_noise_is_seeded_reproducible_and_has_the_stated_sigma():
    css = CoarseSunSensors(SIX, i_max_A=1e-3, noise_A=1e-5)
    s = np.tile([0.0, 0.0, 1.0], (4000, 1))
    a = css.measure(s, 1.0, rng=np.random.default_rng(7))
    b = css.measure(s, 1.0, rng=np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)
    assert np.std(a[:, 2]) == pytest.approx(1e-5, rel=0.05)
    fss = FineSunSensor(np.eye(3), noise_rad=1e-4)
    ang, _ = fss.measure(s, 1.0, rng=np.random.default_rng(8))
    assert np.std(ang[:, 0]) == pytest.approx(1e-4, rel=0.05)


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match="noise_A = -1"):
        CoarseSunSensors(SIX, noise_A=-1)
    with pytest.raises(ValueError, match="proper rotation"):
        FineSunSensor(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="fov_half_deg = 95"):
        FineSunSensor(np.eye(3), fov_half_deg=95)
