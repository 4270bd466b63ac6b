"""Optics, screen and collimator maps: FOV, round trips, distortion, pixel conventions."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from star_screen.geometry import Bench, BrownConrady, Collimator, Screen, TrackerOptics, default_bench
from tests.oracles import require


def test_default_tracker_is_20_by_15_deg_on_1024_by_768():
    t = TrackerOptics()
    assert (t.width, t.height) == (1024, 768)
    assert np.allclose(t.fov_deg, (20.0, 15.0), atol=1e-12)
    assert (t.cx, t.cy) == (512.0, 384.0)


def test_pixel_convention_by_hand():
    t = TrackerOptics.from_fov(20.0, 15.0, 1024, 768)
    # boresight -> the array centre (512, 384): the corner shared by pixels 511 and 512
    px, front = t.project([0.0, 0.0, 1.0])
    assert front and np.allclose(px, [512.0, 384.0])
    # the half-field edge at +10 deg in x lands on the right border x = 1024
    px, _ = t.project([math.sin(math.radians(10)), 0.0, math.cos(math.radians(10))])
    assert np.allclose(px, [1024.0, 384.0])
    # (0.5, 0.5) is the centre of the top-left pixel, i.e. the direction of pixel (0, 0)
    d = t.unproject([0.5, 0.5])
    assert d[0] < 0 and d[1] < 0
    assert np.allclose(t.project(d)[0], [0.5, 0.5])


def test_screen_map_by_hand():
    b = default_bench(1920, 1080)
    k = 1.1 / 0.2768e-3
    s, _ = b.direction_to_screen([0.01, -0.02, 1.0])
    assert np.allclose(s, [960.0 + 0.01 * k, 540.0 - 0.02 * k])
    assert b.check_fits() == []
    small = Bench(screen=Screen(width=800, height=600, pitch_m=0.2768e-3))
    assert small.check_fits()


dist = BrownConrady(k1=-0.12, k2=0.05, p1=1e-3, p2=-5e-4, k3=-0.01)


@settings(max_examples=100, deadline=None)
@given(st.floats(-0.3, 0.3), st.floats(-0.25, 0.25))
def test_distortion_round_trip(x, y):
    xy = np.array([x, y])
    assert np.allclose(dist.undistort(dist.distort(xy)), xy, atol=1e-12)


def test_distortion_matches_opencv():
    cv2 = require("cv2", "the base install (opencv-contrib-python-headless)")
    pts = np.random.default_rng(1).uniform(-0.3, 0.3, (50, 2))
    obj = np.concatenate((pts, np.ones((50, 1))), axis=1)
    K = np.array([[1000.0, 0, 500], [0, 1000, 400], [0, 0, 1]])
    ref, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), K, dist.as_opencv())
    ours = dist.distort(pts) * 1000 + [500, 400]
    assert np.allclose(ref[:, 0], ours, atol=1e-9)


def test_bench_round_trip_with_distortion_and_flip():
    b = Bench(
        collimator=Collimator(1.1, dist), flip_x=True, tracker=TrackerOptics(distortion=BrownConrady(k1=0.02))
    )
    rng = np.random.default_rng(4)
    px = rng.uniform([0, 0], [1024, 768], (200, 2))
    d = b.tracker.unproject(px)
    assert np.allclose(b.tracker.project(d)[0], px, atol=1e-9)
    s, _ = b.direction_to_screen(d)
    assert np.allclose(b.screen_to_direction(s), d, atol=1e-13)


def test_gamma_inverse_table_picks_nearest_luminance():
    s = Screen()
    lum = s.response()
    L = np.random.default_rng(0).uniform(0, 1, 10000)
    codes = s.encode(L)
    err = np.abs(lum[codes] - L)
    alt = np.minimum(
        np.abs(lum[np.clip(codes.astype(int) + 1, 0, 255)] - L),
        np.abs(lum[np.clip(codes.astype(int) - 1, 0, 255)] - L),
    )
    assert np.all(err <= alt + 1e-15)
    assert s.encode([0.0])[0] == 0 and s.encode([1.0])[0] == 255


def test_bad_values_name_the_field():
    with pytest.raises(ValueError, match="fov_x_deg"):
        TrackerOptics.from_fov(0.0, 15.0, 1024, 768)
    with pytest.raises(ValueError, match="pitch_m"):
        Screen(pitch_m=-1.0)
