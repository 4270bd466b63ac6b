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
        s = np.clip(p[2] / rr, -1.0, 1.0)  # rounding may put it a hair beyond the pole, outside lpmv's domain
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


def _unit(rng, n):
    u = rng.normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1)[:, None]


def test_single_point_path_equals_the_vectorised_path():
    """One position per call takes the folded polynomial path; many positions the recursion. They
    agree to 1e-12 of |B| over all intervals (nodes and the 2025-2030 secular variation included),
    degrees, radii from half the reference radius out, and directions at and near the poles."""
    rng = np.random.default_rng(14)
    n = 400
    u = _unit(rng, n)
    u[:12] = [0.0, 0.0, 1.0]
    u[12:24, :2] = rng.normal(size=(12, 2)) * 1e-9  # within 1e-9 rad of a pole
    u[12:24, 2] = np.where(np.arange(12) % 2, 1.0, -1.0)
    u[24:30] = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1, 1, 0]]
    u /= np.linalg.norm(u, axis=1)[:, None]
    r = u * R_IGRF * rng.uniform(0.5, 4.0, size=(n, 1))
    years = np.concatenate([[1900.0, 1995.0, 2000.0, 2025.0, 2029.999, 2030.0, 1962.5], rng.uniform(1900, 2030, n)])
    worst = 0.0
    for k in range(n):
        year = float(years[k])
        degree = (13, 10, 1, 7)[k % 4]
        one = igrf.field_itrs(year, r[k], degree=degree)
        many = igrf.field_itrs(year, r[k][None, :], degree=degree)[0]
        worst = max(worst, np.linalg.norm(one - many) / np.linalg.norm(many))
    assert worst < 1e-12, worst


def test_single_point_path_on_the_ppigrf_reference_points():
    d = np.loadtxt(REF, delimiter=",")
    one = np.array([igrf.field_itrs(row[0], row[1:4]) for row in d])
    many = np.array([igrf.field_itrs(row[0], row[None, 1:4])[0] for row in d])
    rel = np.linalg.norm(one - many, axis=1) / np.linalg.norm(many, axis=1)
    assert rel.max() < 1e-12, rel.max()
    assert np.linalg.norm(one / NT - d[:, 4:7], axis=1).max() < 1.0  # issue 5's tolerance


def test_single_point_refusals_match_the_vectorised_ones():
    for bad in ([1e6, 0.0, 0.0], [np.nan, 7e6, 0.0], [np.inf, 0.0, 0.0]):
        with pytest.raises(ValueError, match="inside the Earth or non-finite"):
            igrf.field_itrs(2020.0, np.array(bad))
        with pytest.raises(ValueError, match="inside the Earth or non-finite"):
            igrf.field_itrs(2020.0, np.array([bad]))
    with pytest.raises(ValueError, match="igrf degree 0"):
        igrf.field_itrs(2020.0, [7e6, 0, 0], degree=0)


def test_decimal_year_by_arithmetic_within_a_day_equals_erfa():
    """Within a UTC day the decimal year is arithmetic on the TAI date; it must equal ERFA's
    to the last bit or two of the result (one unit in the last place of 2026 is 7 us), including the
    first and last instants of a year."""
    rng = np.random.default_rng(5)
    # Whole-year spans (2026, 2024, 1999) and day spans in a year with a leap second (2016).
    starts = ["2026-06-01T00:00:00Z", "2025-12-31T00:00:00Z", "2024-02-29T00:00:00Z", "1999-12-31T12:00:00Z",
              "2016-03-01T00:00:00Z", "2016-12-30T00:00:00Z"]
    for iso in starts:
        e0 = Epoch.from_iso(iso)
        for dt in np.concatenate([[0.0, 1e-6, 43200.0, 86399.999999], rng.uniform(0.0, 86400.0, 20)]):
            e = e0 + float(dt)
            fast = igrf.decimal_year(e)
            assert igrf._span is not None  # the arithmetic path served this epoch
            slow = igrf._decimal_year_erfa(e)
            assert abs(fast - slow) <= 2 * np.spacing(slow), (iso, dt)


def test_decimal_year_does_not_depend_on_what_was_asked_before():
    """Runs must repeat bit for bit in one process: the same epoch gives the same bits whichever
    day the arithmetic path last served, midnight included."""
    probes = [Epoch.from_iso(t) for t in ("2026-06-01T00:00:00Z", "2026-06-01T00:00:00.000001Z",
                                          "2026-05-31T23:59:59.9999Z", "2026-06-01T12:00:00Z", "2026-12-31T23:59:59Z",
                                          "2027-01-01T00:00:00Z")]
    fresh = []
    for e in probes:
        igrf._span = None
        fresh.append(igrf.decimal_year(e))
    for before in probes + [Epoch.from_iso("2026-05-31T06:00:00Z"), Epoch.from_iso("2026-06-02T06:00:00Z")]:
        for e, want in zip(probes, fresh, strict=True):
            igrf.decimal_year(before)
            assert igrf.decimal_year(e) == want


def test_decimal_year_on_a_day_ending_in_a_leap_second_follows_erfa():
    """2016-12-31 lasted 86401 s; its instants, the leap second among them, go through ERFA; so do
    instants before 1972, when UTC ran at a rate offset from TAI."""
    e0 = Epoch.from_iso("2016-12-31T23:59:58Z")
    prev = -np.inf
    for dt in np.arange(0.0, 4.0, 0.25):
        e = e0 + float(dt)
        y = igrf.decimal_year(e)
        assert abs(y - igrf._decimal_year_erfa(e)) <= 2 * np.spacing(y)
        assert y >= prev  # never runs backwards across the leap second and the new year
        prev = y
    assert igrf.decimal_year(Epoch.from_iso("2017-01-01T00:00:00Z")) == 2017.0
    for iso in ("1965-04-01T06:00:00Z", "1910-04-01T06:00:00Z"):
        e = Epoch.from_iso(iso)
        for dt in (0.0, 3600.0, 7200.0):
            assert abs(igrf.decimal_year(e + dt) - igrf._decimal_year_erfa(e + dt)) <= 2 * np.spacing(1965.0)


def test_point_series_follows_the_recursion_to_degree_20_and_refuses_beyond():
    rng = np.random.default_rng(20)
    nn, mm = harmonics.index_nm(20)
    C = rng.normal(size=nn.size)
    S = rng.normal(size=nn.size) * (mm > 0)
    series = harmonics.PointSeries(C, S, 20)
    for p in _unit(rng, 50) * rng.uniform(1.0, 3.0, size=(50, 1)):
        ref = harmonics.gradient(p, C, S, 1.0, 20)
        got = np.array(series.gradient(*p, 1.0))
        assert np.linalg.norm(got - ref) <= 1e-12 * np.linalg.norm(ref)
    with pytest.raises(ValueError, match="degree 21 is not allowed"):
        harmonics.point_tensor(np.zeros(253), np.zeros(253), 21)
