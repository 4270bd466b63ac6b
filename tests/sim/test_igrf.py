"""IGRF-14 against ppigrf's reference values, closed forms and its own invariants."""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim import environment as env
from sim import harmonics, igrf
from sim.constants import R_IGRF
from sim.time import Epoch

NT = 1e-9
REF = Path(__file__).resolve().parents[2] / "fixtures" / "reference" / "igrf" / "igrf_ppigrf.csv"


def test_within_1_nT_of_ppigrf_at_1000_points():
    d = np.loadtxt(REF, delimiter=",")
    assert d.shape[0] >= 1000
    err = np.array([np.linalg.norm(igrf.field_itrs(row[0], row[1:4]) / NT - row[4:7]) for row in d])
    assert err.max() < 1.0, f"worst {err.max():.3f} nT at row {err.argmax()}"


def test_vectorised_equals_pointwise():
    d = np.loadtxt(REF, delimiter=",")[:50]
    B = igrf.field_itrs(2020.5, d[:, 1:4])
    for k in range(0, 50, 7):
        np.testing.assert_allclose(B[k], igrf.field_itrs(2020.5, d[k, 1:4]), rtol=1e-13, atol=1e-18)
    assert igrf.field_itrs(2020.5, d[:6, 1:4].reshape(2, 3, 3)).shape == (2, 3, 3)


def test_degree_1_is_the_centred_dipole_of_the_same_coefficients():
    g, h = igrf.coefficients(1925.0)
    nn, mm = harmonics.index_nm(igrf.MAX_DEGREE)
    k10, k11 = np.flatnonzero((nn == 1) & (mm == 0))[0], np.flatnonzero((nn == 1) & (mm == 1))[0]
    # The dipole (the Basilisk detumble comparison's field) is exactly the 1925 degree-1 terms.
    assert (g[k10], g[k11], h[k11]) == (env.DIPOLE_G10_NT, env.DIPOLE_G11_NT, env.DIPOLE_H11_NT)
    r = np.random.default_rng(3).normal(size=(30, 3)) * 7e6
    np.testing.assert_allclose(igrf.field_itrs(1925.0, r, degree=1), env.dipole_field_itrs(r), rtol=1e-12)


def test_pole_is_continuous_with_its_neighbourhood():
    r = R_IGRF + 500e3
    pole = igrf.field_itrs(2026.0, [0.0, 0.0, r])
    near = igrf.field_itrs(2026.0, [r * 1e-9, 0.0, r])
    assert np.all(np.isfinite(pole))
    np.testing.assert_allclose(pole, near, atol=1e-3 * NT)


def test_secular_variation_2025_to_2030_is_linear():
    r = np.array([3e6, -4e6, 4.5e6])
    b0, b1, bh = (igrf.field_itrs(y, r) for y in (2025.0, 2030.0, 2027.5))
    np.testing.assert_allclose(bh, 0.5 * (b0 + b1), atol=1e-6 * NT)


def test_epoch_path_uses_the_calendar_decimal_year():
    e = Epoch.from_iso("2026-07-02T12:00:00Z")  # 182.5 days into a 365-day year
    assert igrf.decimal_year(e) == pytest.approx(2026.5, abs=1e-9)
    r = [4e6, 1e6, 5.5e6]
    np.testing.assert_array_equal(env.magnetic_field_itrs(e, r, model="igrf"), igrf.field_itrs(igrf.decimal_year(e), r))


def test_default_field_model_is_igrf_and_the_dipole_only_by_name():
    e = Epoch.from_iso("2026-03-20T12:00:00Z")
    r = np.array([[7e6, 0.0, 0.0], [0.0, 0.0, 6.9e6], [-3e6, 4e6, 4.5e6]])
    default = env.magnetic_field_itrs(e, r)
    np.testing.assert_array_equal(default, igrf.field_itrs(e, r, degree=igrf.MAX_DEGREE))
    np.testing.assert_array_equal(env.magnetic_field_itrs(e, r, degree=3), igrf.field_itrs(e, r, degree=3))
    dipole = env.magnetic_field_itrs(e, r, model="dipole")
    np.testing.assert_array_equal(dipole, env.dipole_field_itrs(r))
    # The 1925 dipole against the 2026 field to degree 13: microtesla apart in LEO (6-14 uT here).
    assert np.all(np.linalg.norm(default - dipole, axis=-1) > 1000 * NT)


@pytest.mark.parametrize("year", [1899.99, 2030.01, 2100.0])
def test_epochs_outside_1900_2030_are_refused(year):
    with pytest.raises(ValueError, match=r"outside its validity 1900.0 to 2030.0"):
        igrf.field_itrs(year, [7e6, 0, 0])


def test_bad_degree_and_position_are_refused():
    with pytest.raises(ValueError, match="igrf degree 14"):
        igrf.field_itrs(2020.0, [7e6, 0, 0], degree=14)
    with pytest.raises(ValueError, match="inside the Earth"):
        igrf.field_itrs(2020.0, [1e6, 0, 0])
    with pytest.raises(ValueError, match="allowed: 'dipole', 'igrf'"):
        env.magnetic_field_itrs(2020.0, [7e6, 0, 0], model="wmm")


@settings(max_examples=25, deadline=None)
@given(st.floats(0.0, 2 * np.pi), st.floats(-1.0, 1.0), st.floats(0.0, 2e6), st.floats(1900.0, 2030.0))
def test_field_is_curl_free_and_matches_the_potential_gradient(lon, sinlat, alt, year):
    """B = -grad V: central differences of the potential summed independently in spherical form."""
    from scipy.special import lpmv

    g, h = igrf.coefficients(year)
    nn, mm = harmonics.index_nm(igrf.MAX_DEGREE)

    def V(p):
        rr = np.linalg.norm(p)
        s = p[2] / rr
        lam = np.arctan2(p[1], p[0])
        schmidt = np.array([(-1.0) ** m * lpmv(m, n, s) * harmonics.norm_factor(n, m) / np.sqrt(2 * n + 1)
                            for n, m in zip(nn, mm, strict=True)])
        return R_IGRF * np.sum((R_IGRF / rr) ** (nn + 1) * schmidt * (g * np.cos(mm * lam) + h * np.sin(mm * lam)))

    cl = np.sqrt(1 - sinlat**2)
    p = (R_IGRF + alt) * np.array([cl * np.cos(lon), cl * np.sin(lon), sinlat])
    e = 10.0
    grad = np.array([(V(p + e * d) - V(p - e * d)) / (2 * e) for d in np.eye(3)])
    np.testing.assert_allclose(igrf.field_itrs(year, p) / NT, -grad, atol=1e-4 * np.linalg.norm(grad))


def test_dipole_scene_never_evaluates_igrf(monkeypatch):
    """A scenario asking for the dipole must not read or evaluate the IGRF model."""

    def boom(*_a, **_k):
        raise AssertionError("IGRF was evaluated for a dipole scene")

    monkeypatch.setattr(igrf, "field_itrs", boom)
    monkeypatch.setattr(igrf, "_load", boom)
    env.magnetic_field_itrs(2026.0, [7e6, 0.0, 0.0], model="dipole")
