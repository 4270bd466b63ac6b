"""Catalog fixture, proper motion and apparent places against astropy references."""

import json
import pathlib

import erfa
import numpy as np
import pytest

from sim.ephemeris import aberrate, earth_pv_bcrs
from sim.time import Epoch
from star_screen.catalog import DEFAULT_CATALOG_PATH, radec_to_unit, unit_to_radec

from .star_screen_helpers import MAS, separation

REF = pathlib.Path(__file__).parents[2] / "fixtures" / "reference" / "star_screen" / "apparent_places.json"


def test_fixture_is_compact_and_complete_to_hp_8_5(catalog):
    assert DEFAULT_CATALOG_PATH.stat().st_size < 4_000_000
    assert catalog.hp_limit >= 8.5
    # hip2 holds 56,863 stars with Hp <= 8.5 (counted from hip2.dat by build_hip2.py's source).
    assert np.count_nonzero(catalog.mag <= 8.5) == 56863
    assert np.all(np.diff(catalog.mag) >= 0)
    assert catalog.hip.dtype == np.int32 and catalog.mag.dtype == np.float32
    assert len(np.unique(catalog.hip)) == len(catalog)


def test_magnitude_cut_is_a_prefix(catalog):
    c7 = catalog.brighter_than(7.0)
    assert c7.mag.max() <= 7.0 and len(c7) == np.count_nonzero(catalog.mag <= 7.0)


def test_mag_limit_beyond_fixture_is_refused():
    from star_screen.catalog import Catalog

    with pytest.raises(ValueError, match="mag_limit"):
        Catalog.load(mag_limit=10.5)


def _ref():
    return json.loads(REF.read_text())


@pytest.mark.parametrize("case", _ref()["cases"], ids=lambda c: f"{c['name']}-{c['epoch_utc'][:4]}")
def test_places_match_astropy(catalog, case):
    ep = Epoch.from_iso(case["epoch_utc"])
    row = int(np.flatnonzero(catalog.hip == case["hip"])[0])
    # proper motion only (catalog places at the epoch)
    u_pm = catalog.places(ep, parallax=False).u_N[row]
    ref_pm = radec_to_unit(np.radians(case["pm_ra_deg"]), np.radians(case["pm_dec_deg"]))
    assert separation(u_pm, ref_pm) < 1.0 * MAS
    # apparent place from the moving spacecraft: parallax + annual + orbital aberration
    u = catalog.places(ep, parallax=True).u_N[row]
    v = earth_pv_bcrs(ep)[1] + np.array(_ref()["v_sc_gcrs_m_s"])
    app = aberrate(u, v)
    ref = radec_to_unit(np.radians(case["apparent_ra_deg"]), np.radians(case["apparent_dec_deg"]))
    assert separation(app, ref) < 20.0 * MAS
    # and the shift really is there (aberration is tens of arcsec, not zero)
    assert separation(app, u_pm) > 5.0 * 1000 * MAS


def test_aberrate_matches_erfa_ab(epoch):
    rng = np.random.default_rng(3)
    u = rng.normal(size=(50, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = earth_pv_bcrs(epoch)[1] + [7000.0, 2000.0, -1000.0]
    V = v / 299792458.0
    ref = erfa.ab(u, V, 1e9, np.sqrt(1 - V @ V))  # far from the Sun: no gravitational term
    assert np.max(np.linalg.norm(aberrate(u, v) - ref, axis=1)) < 1e-12


def test_radec_round_trip_at_wrap_and_poles():
    ra = np.radians([0.0, 359.9999, 180.0, 10.0])
    dec = np.radians([0.0, 10.0, 89.9999, -89.9999])
    r2, d2 = unit_to_radec(radec_to_unit(ra, dec))
    assert np.allclose(r2, ra, atol=1e-12) and np.allclose(d2, dec, atol=1e-12)
