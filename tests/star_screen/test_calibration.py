"""Calibration recovers a known synthetic screen-plus-collimator distortion from a ChArUco image."""

import dataclasses

import numpy as np
import pytest

from star_screen.geometry import BrownConrady, Collimator, default_bench
from tests.oracles import require

require("cv2", "the base install (opencv-contrib-python-headless)")


def test_charuco_calibration_recovers_known_distortion():
    from star_screen.calibration import calibrate_screen, charuco_screen_image, simulate_camera_view

    nominal = default_bench()
    truth = dataclasses.replace(
        nominal,
        collimator=Collimator(1.1 * 1.01, BrownConrady(k1=-0.3, k2=1.0, p1=5e-4, p2=-3e-4)),
        sx0=963.2,
        sy0=537.9,
    )
    screen_img, pattern = charuco_screen_image(nominal, 30, 22, 40)
    camera_img = simulate_camera_view(screen_img, truth)
    cal = calibrate_screen([camera_img], pattern, nominal)
    assert cal.n_points > 300 and cal.rms_px < 0.5
    t = nominal.tracker
    px = np.random.default_rng(0).uniform([0, 0], [t.width, t.height], (2000, 2))
    d = t.unproject(px)
    want = truth.direction_to_screen(d)[0]
    before = np.abs(nominal.direction_to_screen(d)[0] - want).max()
    after = np.abs(cal.bench.direction_to_screen(d)[0] - want).max()
    assert before > 5.0  # the distortion is real: several screen pixels at the field edge
    assert after < 0.5  # recovered to a fraction of a screen pixel over the whole tracker field
    assert abs(cal.bench.collimator.distortion.k1 / -0.3 - 1) < 0.05
    assert abs(cal.bench.collimator.focal_length_m / 1.111 - 1) < 2e-3


def test_board_that_does_not_fit_is_refused():
    from star_screen.calibration import charuco_screen_image

    with pytest.raises(ValueError, match="does not fit"):
        charuco_screen_image(default_bench(), 40, 30, 64)
