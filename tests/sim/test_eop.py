"""Earth orientation from IERS finals2000A.all against astropy's own reader, and GCRS -> ITRS."""

import functools

import erfa
import numpy as np
import pytest

from sim import eop, frames
from sim.time import Epoch
from tests.oracles import require, unavailable

MAS = np.pi / (180 * 3600e3)
TABLE = eop.default_table()


@pytest.fixture
def needs_table():
    if TABLE is None:
        unavailable("astropy-iers-data is not installed (the env extra, in the test extra)")
EPOCHS = ["1980-03-01T00:00:00Z", "1999-12-31T18:00:00Z", "2016-12-31T12:00:00Z", "2017-01-01T00:00:30Z",
          "2024-04-06T07:22:24Z", "2026-06-01T00:00:00Z"]


@functools.lru_cache(maxsize=1)
def _astropy_table():
    from astropy.utils import iers

    return iers.IERS_A.open(str(TABLE.path))


@functools.cache
def _astropy_eop(iso):
    from astropy.time import Time
    from astropy.utils import iers

    with iers.conf.set_temp("auto_download", False):
        table = _astropy_table()
        t = Time(iso.rstrip("Z"), scale="utc")
        dut1 = float(table.ut1_utc(t).to_value("s"))
        xp, yp = (float(q.to_value("rad")) for q in table.pm_xy(t))
    return dut1, xp, yp


def _angle(a, b):
    """Rotation angle between two DCMs from the skew part (arccos of the trace has 2e-8 rad noise)."""
    d = a.T @ b
    return np.arcsin(0.5 * np.linalg.norm([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]]))


@pytest.mark.usefixtures("needs_table")
@pytest.mark.parametrize("iso", EPOCHS)
def test_eop_values_match_astropys_reader(iso):
    require("astropy")
    dut1, xp, yp = _astropy_eop(iso)
    e = eop.eop_at(Epoch.from_iso(iso))
    assert e.available
    assert e.dut1_s == pytest.approx(dut1, abs=1e-6)  # 1 us of UT1 = 0.015 mas
    assert e.xp_rad == pytest.approx(xp, abs=0.01 * MAS)
    assert e.yp_rad == pytest.approx(yp, abs=0.01 * MAS)


@pytest.mark.usefixtures("needs_table")
@pytest.mark.parametrize("iso", EPOCHS)
def test_gcrs_to_itrs_within_1_mas_of_pyerfa_with_the_same_eop(iso):
    require("astropy")
    dut1, xp, yp = _astropy_eop(iso)
    ep = Epoch.from_iso(iso, dut1_s=dut1)
    ut1 = erfa.utcut1(*ep.jd_utc, dut1)
    ref = erfa.c2t06a(*ep.jd_tt, *ut1, xp, yp)
    assert _angle(frames.dcm_itrs_gcrs(Epoch.from_iso(iso), eop=TABLE), ref) < 1 * MAS
    assert _angle(frames.dcm_itrs_gcrs(Epoch.from_iso(iso), eop="default"), ref) < 1 * MAS


def test_fallback_is_zero_and_flagged_without_warning():
    e = eop.eop_at(Epoch.from_iso("2026-06-01T00:00:00Z"), table=None)
    assert (e.dut1_s, e.xp_rad, e.yp_rad, e.available, e.source) == (0.0, 0.0, 0.0, False, eop.FALLBACK_SOURCE)
    if TABLE is not None:
        late = eop.eop_at(Epoch.from_iso("2090-01-01T00:00:00Z"))
        assert not late.available and late.dut1_s == 0.0
    ep = Epoch.from_iso("2026-06-01T00:00:00Z")
    np.testing.assert_array_equal(frames.dcm_itrs_gcrs(ep, eop=e), frames.dcm_itrs_gcrs(ep))


def test_unknown_table_name_is_refused():
    with pytest.raises(ValueError, match="EOP table 'bulletin-z' is not known"):
        eop.eop_at(Epoch.from_iso("2026-06-01T00:00:00Z"), "bulletin-z")
