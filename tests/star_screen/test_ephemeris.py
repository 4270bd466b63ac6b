"""Sun and Moon geometric positions against a hand-computable almanac formula."""

import math

import numpy as np

from sim.constants import AU
from sim.ephemeris import moon_position_gcrs, sun_position_gcrs
from sim.time import Epoch


def _almanac_sun(ep):
    """Astronomical Almanac low-precision Sun (0.01 deg 1950-2050), unit vector and distance (AU)."""
    a, b = ep.jd_tt
    n = (a - 2451545.0) + b
    L = math.radians((280.460 + 0.9856474 * n) % 360)
    g = math.radians((357.528 + 0.9856003 * n) % 360)
    lam = L + math.radians(1.915) * math.sin(g) + math.radians(0.020) * math.sin(2 * g)
    eps = math.radians(23.439 - 4.0e-7 * n)
    R = 1.00014 - 0.01671 * math.cos(g) - 0.00014 * math.cos(2 * g)
    u = np.array([math.cos(lam), math.cos(eps) * math.sin(lam), math.sin(eps) * math.sin(lam)])
    return u, R


def test_sun_against_almanac():
    for iso in ("2000-01-01T12:00:00Z", "2026-03-20T12:00:00Z", "2031-07-15T06:00:00Z"):
        ep = Epoch.from_iso(iso)
        r = sun_position_gcrs(ep)
        u, R = _almanac_sun(ep)
        # the almanac formula is of date (precession ~0.36 deg in 26 yr) and 0.01 deg accurate
        assert math.degrees(math.acos(r @ u / np.linalg.norm(r))) < 0.02 + 0.0142 * abs(
            ep.decimal_year - 2000
        )
        assert abs(np.linalg.norm(r) / AU - R) < 2e-4


def test_vectorised_and_moon_distance():
    eps = [Epoch.from_iso("2026-01-01T00:00:00Z") + 86400.0 * k for k in range(30)]
    r = moon_position_gcrs(eps)
    assert r.shape == (30, 3)
    d = np.linalg.norm(r, axis=1)
    assert 356e6 < d.min() and d.max() < 407e6
    assert sun_position_gcrs(eps).shape == (30, 3)
    one = moon_position_gcrs(eps[3])
    assert np.allclose(one, r[3])
