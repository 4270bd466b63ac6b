"""sim.time: split Julian dates against published definitions (IERS, IAU)."""

import pytest

from sim.time import Epoch, seconds_to_ns

DAY = 86400.0


def jd(pair):
    return pair[0] + pair[1]


def days_between(a, b):
    """a - b for split dates, part by part so no digits are lost."""
    return (a[0] - b[0]) + (a[1] - b[1])


def test_j2000_is_jd_2451545_tt():
    # J2000.0 = 2000-01-01T12:00:00 TT = 11:58:55.816 UTC (TT - UTC = 32.184 s + 32 leap seconds).
    e = Epoch.from_iso("2000-01-01T11:58:55.816Z")
    assert abs(days_between(e.jd_tt, (2451545.0, 0.0)) * DAY) < 1e-6


def test_tt_minus_utc_in_2026_is_69_184_s():
    e = Epoch.from_iso("2026-03-20T12:00:00Z")
    assert abs(days_between(e.jd_tt, e.jd_utc) * DAY - 69.184) < 1e-6


def test_adding_seconds_crosses_a_leap_second_in_si_time():
    e = Epoch.from_iso("2016-12-31T23:59:59Z") + 2.0
    assert e.iso == "2017-01-01T00:00:00.000000Z"  # 23:59:60 was a real second


def test_nanosecond_resolution_and_difference():
    e = Epoch.from_iso("2026-01-01T00:00:00Z")
    f = e.add_ns(1)
    assert f.offset_ns - e.offset_ns == 1
    assert f - e == pytest.approx(1e-9, abs=1e-15)
    assert seconds_to_ns(0.1) * 56770 == seconds_to_ns(5677.0)  # exact rate ratios


def test_ut1_uses_dut1():
    e = Epoch.from_iso("2026-06-01T00:00:00Z", dut1_s=0.0178)
    assert abs(days_between(e.jd_ut1, e.jd_utc) * DAY - 0.0178) < 1e-6


@pytest.mark.parametrize("text", ["yesterday", "2026-13-01T00:00:00Z", "2026-01-01T00:00:00+02:00"])
def test_bad_epoch_is_named(text):
    with pytest.raises(ValueError, match="epoch"):
        Epoch.from_iso(text)


def test_ut1_on_a_leap_second_day_is_tai_minus_37_s_plus_dut1():
    # 2016-12-31 had 86401 s. Late that day UT1 = UTC + dut1 and TAI - UTC = 36 s, so
    # UT1 = TAI - 36 s + dut1 whatever ERFA's stretched quasi-JD of UTC looks like.
    e = Epoch.from_iso("2016-12-31T23:59:00Z", dut1_s=0.4)
    assert abs(days_between(e.jd_ut1, e.jd_tai) * DAY - (-36.0 + 0.4)) < 1e-6


def test_dubious_year_guard_silences_only_erfas_dubious_year_warning():
    import warnings

    import erfa

    from sim.time import ignore_dubious_year

    late = Epoch.from_iso("2090-06-01T00:00:00Z")  # far past ERFA's leap-second table
    assert late.iso == "2090-06-01T00:00:00.000000Z"  # guarded inside Epoch (warnings are errors here)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        erfa.taiutc(*late.jd_tai)  # unguarded: ERFA warns for this date
        with ignore_dubious_year():
            erfa.taiutc(*late.jd_tai)
            warnings.warn("another warning", UserWarning, stacklevel=1)
    assert [(w.category, "dubious year" in str(w.message)) for w in caught] == [
        (erfa.ErfaWarning, True), (UserWarning, False)]
