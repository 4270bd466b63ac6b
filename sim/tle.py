"""Two-line elements: parse, propagate with SGP4 (the ``sgp4`` package), rotate TEME to GCRS.

SGP4 works in TEME (true equator, mean equinox of date). TEME -> GCRS follows the standard route
(Vallado et al. 2006, "Revisiting Spacetrack Report #3", AIAA 2006-6753, sec. on TEME):
``r_PEF = R3(GMST82(UT1)) r_TEME``, ``r_ITRS = W(xp, yp) r_PEF`` (ERFA ``pom00``), and
``r_GCRS = dcm_itrs_gcrs^T r_ITRS`` by the IAU 2006/2000A chain of :mod:`sim.frames`. Velocities add
the Earth-rotation term ``omega x r`` on the way through the rotating frames (the small rate of
polar motion and precession-nutation is neglected: below 1e-9 relative).

``sgp4`` is an optional dependency (extra ``env``); it is imported when a TLE is parsed.
"""

from __future__ import annotations

from dataclasses import dataclass

import erfa
import numpy as np

from .constants import OMEGA_EARTH
from .frames import dcm_itrs_gcrs, rotation_z
from .time import Epoch, ignore_dubious_year

__all__ = ["TLE", "parse_tle", "teme_to_gcrs"]

_TEMPLATE = (
    "1 NNNNNC NNNNNAAA NNNNN.NNNNNNNN +.NNNNNNNN +NNNNN-N +NNNNN-N N NNNNN\n"
    "2 NNNNN NNN.NNNN NNN.NNNN NNNNNNN NNN.NNNN NNN.NNNN NN.NNNNNNNNNNNNNN"
)


def _checksum(line: str) -> int:
    return sum(int(c) if c.isdigit() else (1 if c == "-" else 0) for c in line[:68]) % 10


def _check_line(k: int, line: str) -> None:
    line = line.rstrip()
    where = f"line {k} of the two-line elements"
    if len(line) != 69:
        raise ValueError(f"{where} has {len(line)} characters; exactly 69 are allowed, laid out as\n"
                         f"{_TEMPLATE}\ngot:\n{line}")
    if line[0] != str(k) or line[1] != " ":
        raise ValueError(f"{where} must start with '{k} '; got {line[:2]!r} in\n{line}")
    if not line[68].isdigit() or int(line[68]) != _checksum(line):
        raise ValueError(f"{where} has checksum digit {line[68]!r}; the digits of columns 1-68 give "
                         f"{_checksum(line)} (sum of digits, '-' counts 1, modulo 10):\n{line}")


@dataclass(frozen=True)
class TLE:
    """A parsed element set; ``satrec`` is the ``sgp4.api.Satrec``."""

    line1: str
    line2: str
    satrec: object

    @property
    def epoch_jd_utc(self) -> tuple[float, float]:
        """Element epoch as a split UTC Julian date."""
        return float(self.satrec.jdsatepoch), float(self.satrec.jdsatepochF)

    def propagate_teme(self, jd_utc1, jd_utc2) -> tuple[np.ndarray, np.ndarray]:
        """SGP4 position (m) and velocity (m/s) in TEME at split UTC Julian dates (arrays broadcast).

        Raises ValueError naming SGP4's error code (e.g. decayed orbit) at the first bad time.
        """
        j1, j2 = np.broadcast_arrays(np.asarray(jd_utc1, dtype=float), np.asarray(jd_utc2, dtype=float))
        e, r, v = self.satrec.sgp4_array(np.ravel(j1).copy(), np.ravel(j2).copy())
        if np.any(e != 0):
            from sgp4.api import SGP4_ERRORS

            k = int(np.flatnonzero(e)[0])
            raise ValueError(f"SGP4 error code {int(e[k])} at jd {j1.flat[k] + j2.flat[k]:.6f}: "
                             f"{SGP4_ERRORS.get(int(e[k]), 'unknown')}.")
        shape = j1.shape + (3,)
        return r.reshape(shape) * 1e3, v.reshape(shape) * 1e3

    def state_gcrs(self, epoch: Epoch, eop=None) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and velocity (m/s) in GCRS at ``epoch`` (EOP as in :func:`teme_to_gcrs`)."""
        r, v = self.propagate_teme(*epoch.jd_utc)
        return teme_to_gcrs(r, v, epoch, eop=eop)


def parse_tle(line1: str, line2: str) -> TLE:
    """Parse two-line elements; a malformed line raises ValueError showing the column template."""
    for k, ln in ((1, line1), (2, line2)):
        if not isinstance(ln, str):
            raise ValueError(f"line {k} of the two-line elements must be text; got {type(ln).__name__}.")
        _check_line(k, ln)
    if line1[2:7] != line2[2:7]:
        raise ValueError(f"the catalogue numbers of the two lines differ: {line1[2:7]!r} and {line2[2:7]!r}.")
    from sgp4.api import WGS72, Satrec

    try:
        sat = Satrec.twoline2rv(line1.rstrip(), line2.rstrip(), WGS72)
    except ValueError as exc:
        raise ValueError(f"two-line elements could not be parsed: {exc}\nexpected layout:\n{_TEMPLATE}") from None
    return TLE(line1.rstrip(), line2.rstrip(), sat)


def teme_to_gcrs(r_teme, v_teme, epoch: Epoch, eop=None) -> tuple[np.ndarray, np.ndarray]:
    """TEME position (m) / velocity (m/s) at ``epoch`` -> GCRS.

    ``eop``: as :func:`sim.frames.dcm_itrs_gcrs` (None: ``epoch.dut1_s`` and zero polar motion).
    """
    from .eop import EOP, eop_at

    e = EOP(epoch.dut1_s, 0.0, 0.0, False, False, "epoch") if eop is None else (
        eop if isinstance(eop, EOP) else eop_at(epoch, eop))
    with ignore_dubious_year():
        ut1 = erfa.utcut1(*epoch.jd_utc, e.dut1_s)  # exact on leap-second days too
    W = np.asarray(erfa.pom00(e.xp_rad, e.yp_rad, erfa.sp00(*epoch.jd_tt)))  # PEF (TIRS) -> ITRS
    C = dcm_itrs_gcrs(epoch, eop=e)  # GCRS -> ITRS
    M = rotation_z(erfa.gmst82(*ut1))  # TEME -> PEF
    w = np.array([0.0, 0.0, OMEGA_EARTH])
    r_pef = np.einsum("ij,...j->...i", M, np.asarray(r_teme, dtype=float))
    v_pef = np.einsum("ij,...j->...i", M, np.asarray(v_teme, dtype=float)) - np.cross(w, r_pef)
    r_itrs = np.einsum("ij,...j->...i", W, r_pef)
    v_itrs = np.einsum("ij,...j->...i", W, v_pef)
    r_g = np.einsum("ji,...j->...i", C, r_itrs)
    v_g = np.einsum("ji,...j->...i", C, v_itrs + np.cross(w, r_itrs))
    return r_g, v_g
