"""Two-line elements: sgp4's published verification vectors, parse errors, TEME -> GCRS."""

import os

import numpy as np
import pytest

from sim import tle
from sim.time import Epoch
from tests.oracles import require

sgp4 = require("sgp4", "the env extra (in the test extra)")

HERE = os.path.dirname(sgp4.__file__)
ISS = ("1 25544U 98067A   08264.51782528 -.00002182  00000-0 -11606-4 0  2927",
       "2 25544  51.6416 247.4627 0006703 130.5360 325.0288 15.72125391563537")


def _vectors():
    with open(os.path.join(HERE, "SGP4-VER.TLE")) as f:
        lines = [ln.rstrip("\n") for ln in f if not ln.startswith("#")]
    pairs = {int(a[2:7]): (a, b[:69]) for a, b in zip(lines[::2], lines[1::2], strict=True)}
    rows, cur = {}, None
    with open(os.path.join(HERE, "tcppver.out")) as f:
        text = f.read().splitlines()
    for ln in text:
        p = ln.split()
        if len(p) == 2 and p[1] == "xx":
            cur = int(p[0])
            rows[cur] = []
        elif p:
            rows[cur].append([float(x) for x in p[:7]])
    return pairs, rows


def _restamp(line):
    return line[:68] + str(tle._checksum(line))


def test_sgp4_matches_vallado_verification_vectors():
    pairs, rows = _vectors()
    assert len(pairs) >= 30
    for sat, (a, b) in pairs.items():
        if sat in (33333, 33334, 33335):
            with pytest.raises(ValueError, match="checksum"):
                tle.parse_tle(a, b)
            # Vallado's error cases (decay, eccentricity out of range): only the refusal is checked.
            assert tle.parse_tle(_restamp(a), _restamp(b)).satrec.satnum == sat
            continue
        t = tle.parse_tle(a, b)
        ref = np.array(rows[sat])
        j1, j2 = t.epoch_jd_utc
        r, v = t.propagate_teme(np.full(len(ref), j1), j2 + ref[:, 0] / 1440.0)
        np.testing.assert_allclose(r, ref[:, 1:4] * 1e3, rtol=0, atol=1e-3, err_msg=f"satellite {sat}")
        np.testing.assert_allclose(v, ref[:, 4:7] * 1e3, rtol=0, atol=1e-6, err_msg=f"satellite {sat}")


@pytest.mark.parametrize(("l1", "l2", "message"), [
    (ISS[0][:60], ISS[1], "line 1 of the two-line elements has 60 characters; exactly 69"),
    (ISS[0], "3" + ISS[1][1:], "must start with '2 '"),
    (ISS[0][:68] + "0", ISS[1], "checksum digit '0'"),
    (ISS[0], ISS[1][:2] + "25545" + ISS[1][7:68] + "8", "catalogue numbers of the two lines differ"),
])
def test_malformed_lines_are_refused_with_the_template(l1, l2, message):
    with pytest.raises(ValueError, match=message):
        tle.parse_tle(l1, l2)


def test_teme_to_gcrs_matches_astropy():
    """astropy's TEME -> GCRS (independent code path: its own frame graph, same ERFA core)."""
    require("astropy")
    from astropy import units as u
    from astropy.coordinates import GCRS, TEME, CartesianDifferential, CartesianRepresentation
    from astropy.time import Time
    from astropy.utils import iers

    from sim import eop

    r_teme = np.array([-6102.44328, -986.33249, -2820.31316]) * 1e3
    v_teme = np.array([-1.455, -5.525, 5.101]) * 1e3
    epoch = Epoch.from_iso("2024-04-06T07:22:24Z")
    with iers.conf.set_temp("auto_download", False), iers.conf.set_temp("iers_degraded_accuracy", "ignore"):
        t = Time("2024-04-06T07:22:24", scale="utc")
        rep = CartesianRepresentation(r_teme * u.m, differentials=CartesianDifferential(v_teme * u.m / u.s))
        g = TEME(rep, obstime=t).transform_to(GCRS(obstime=t))
        r_ref = g.cartesian.xyz.to_value(u.m)
        v_ref = g.velocity.d_xyz.to_value(u.m / u.s)
    r, v = tle.teme_to_gcrs(r_teme, v_teme, epoch, eop="default" if eop.default_table() else None)
    # 2 cm at 7000 km is 0.6 mas: room for astropy's own EOP interpolation, nothing more.
    np.testing.assert_allclose(r, r_ref, atol=2e-2)
    np.testing.assert_allclose(v, v_ref, atol=1e-4)
