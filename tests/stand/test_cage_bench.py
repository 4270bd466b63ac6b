"""The pieces of ``stand bench cage`` that are not timing: the LEO profile, the lag estimator, and a
short 10 Hz following run through Modbus TCP in sim time."""

from __future__ import annotations

import numpy as np
import pytest

from stand.benches.cage import LeoProfile, _errors, _follow


def test_profile_is_a_leo_field_in_tumbling_body_axes():
    p = LeoProfile(5.0)
    t = np.arange(0.0, 5700.0, 10.0)
    b = p(t)
    norm = np.linalg.norm(b, axis=1)
    assert 17e-6 < norm.min() < norm.max() < 60e-6  # dipole field at 500 km: about 18 uT to 52 uT
    # a rotation does not change the magnitude: the same orbit without the tumble has the same |b|
    assert norm == pytest.approx(np.linalg.norm(LeoProfile(0.0)(t), axis=1), rel=1e-12)
    assert p(12.3) == pytest.approx(p(np.array([12.3]))[0])


def test_lag_estimator_finds_a_known_delay():
    p = LeoProfile(5.0)
    t = np.arange(0.0, 20.0, 0.01)
    rms, peak, lag, rms_lag = _errors(t, p(t - 0.042), p)
    assert lag == pytest.approx(0.042, abs=1e-9)
    assert rms_lag < 1e-3 * rms and peak >= rms > 0


def test_a_short_following_run_through_modbus_tracks_the_profile():
    t, cage, profile, _ = _follow(5.0, 4.0, lead_s=0.06)
    rms, peak, lag, _ = _errors(t, cage, profile)
    assert len(t) == 400
    assert rms < 60e-9 and lag < 0.03  # commanded ahead: the 10 Hz hold's error is left, not its delay
