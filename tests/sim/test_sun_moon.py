"""Sun and Moon against JPL DE421 (geometric, geocentric), the interpolated track, the cheap Sun."""

import os

import numpy as np
import pytest

from sim import ephemeris as eph
from sim.time import Epoch
from tests.oracles import require, unavailable

ARCSEC = 1.0 / 3600.0


def _angle_arcsec(a, b):
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))) * 3600


@pytest.fixture(scope="module")
def de421():
    require("jplephem")
    skyfield_data = require("skyfield_data", "skyfield-data in the test extra")
    from jplephem.spk import SPK

    path = os.path.join(os.path.dirname(skyfield_data.__file__), "data", "de421.bsp")
    if not os.path.exists(path):
        unavailable(f"de421.bsp is not in skyfield-data ({path})")
    kernel = SPK.open(path)
    yield kernel
    kernel.close()


def _de421(kernel, jd):
    sun = kernel[0, 10].compute(jd) - kernel[0, 3].compute(jd) - kernel[3, 399].compute(jd)
    moon = kernel[3, 301].compute(jd) - kernel[3, 399].compute(jd)
    return sun.T * 1e3, moon.T * 1e3


def test_sun_and_moon_within_1_and_15_arcsec_of_de421_2000_2050(de421):
    jd2 = np.random.default_rng(5).uniform(0.0, 50 * 365.25, 400)
    jd1 = np.full_like(jd2, 2451545.0)
    sun, moon = _de421(de421, jd1 + jd2)
    assert _angle_arcsec(eph.sun_position_gcrs((jd1, jd2)), sun).max() < 1.0
    assert _angle_arcsec(eph.moon_position_gcrs((jd1, jd2)), moon).max() < 15.0
    np.testing.assert_allclose(np.linalg.norm(eph.sun_position_gcrs((jd1, jd2)), axis=-1),
                               np.linalg.norm(sun, axis=-1), rtol=1e-6)
    analytic = _angle_arcsec(eph.sun_position_gcrs_analytic((jd1, jd2)), sun)
    assert analytic.max() < eph.SUN_ANALYTIC_ERROR_ARCSEC


@pytest.mark.parametrize("body", ["sun", "moon"])
def test_track_interpolates_erfa_to_0_01_arcsec_and_stays_within_de421_bounds(de421, body):
    epoch = Epoch.from_iso("2031-03-05T00:00:00Z")
    track = eph.EphemerisTrack(epoch, body)
    t = np.linspace(0.0, 2 * 86400.0, 301)
    direct = (eph.sun_position_gcrs if body == "sun" else eph.moon_position_gcrs)([epoch + x for x in t])
    got = track.position_gcrs(t)
    assert _angle_arcsec(got, direct).max() < 0.01
    tt1, tt2 = epoch.jd_tt
    sun, moon = _de421(de421, tt1 + tt2 + t / 86400.0)
    assert _angle_arcsec(got, sun if body == "sun" else moon).max() < (1.0 if body == "sun" else 15.0)
    # Only the nodes of the two days were computed (lazily), once.
    assert track.evaluations == int(2 * 86400 / track.step_s) + 2  # the end time opens one more interval
    track.position_gcrs(t[::3])
    assert track.evaluations == int(2 * 86400 / track.step_s) + 2  # the end time opens one more interval


@pytest.mark.parametrize("body", ["sun", "moon"])
def test_one_point_as_floats_is_the_array_result_to_the_bit(body):
    track = eph.EphemerisTrack(Epoch.from_iso("2031-03-05T00:00:00Z"), body)
    times = np.concatenate([np.arange(0.0, 3 * 86400.0, 97.0), np.random.default_rng(5).uniform(-3600.0, 4e5, 3000),
                            [0.0, track.step_s, 2 * track.step_s - 1e-9]])  # on a node, and just below one
    for t in times:
        assert track.position_gcrs_floats(float(t)) == tuple(track.position_gcrs(float(t)).tolist()), t
    with pytest.raises(ValueError, match="must be finite"):
        track.position_gcrs_floats(float("nan"))


def test_track_that_is_never_asked_never_evaluates():
    track = eph.EphemerisTrack(Epoch.from_iso("2026-01-01T00:00:00Z"), "moon")
    assert track.evaluations == 0


def test_bad_track_arguments_are_refused():
    e = Epoch.from_iso("2026-01-01T00:00:00Z")
    with pytest.raises(ValueError, match="ephemeris body 'mars'"):
        eph.EphemerisTrack(e, "mars")
    with pytest.raises(ValueError, match=r"step_s = 0.0 s is outside \(0, 86400\]"):
        eph.EphemerisTrack(e, "sun", step_s=0.0)
