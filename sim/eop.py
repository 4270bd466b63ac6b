"""Earth orientation parameters: UT1 - UTC and polar motion from IERS ``finals2000A.all``.

Source: the IERS Rapid Service/Prediction Centre file ``finals2000A.all`` (IAU 2000A, daily, from
1973 with about a year of predictions), read with numpy from a path, or from the copy shipped in the
``astropy-iers-data`` wheel when that package is installed (found through importlib; astropy itself
is never imported). As astropy does, Bulletin B values are used where present and Bulletin A
(including predictions) elsewhere, and values are interpolated linearly in UTC MJD with the 1 s
leap-second steps of UT1 - UTC removed before interpolating.

Fallback (documented, silent): when no file is available or the epoch is outside the table, the
result is UT1 - UTC = 0 and zero polar motion with ``available=False``; no warning is raised
(pytest runs warnings as errors, and a scenario decides whether that is acceptable). The cost of
the fallback: up to 0.9 s of UT1 (13.5 arcsec of Earth rotation) and about 0.5 arcsec of pole.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from importlib import util as _import_util
from pathlib import Path

import numpy as np

from .time import Epoch

__all__ = ["EOP", "EOPTable", "default_table", "eop_at"]

ARCSEC = np.pi / (180.0 * 3600.0)


@dataclass(frozen=True)
class EOP:
    """Earth orientation at one epoch: UT1 - UTC (s), pole x and y (rad).

    ``available`` is False for the zero fallback; ``predicted`` is True when a Bulletin A
    prediction (not a measurement) was used; ``source`` names the file or ``"fallback-zero"``.
    """

    dut1_s: float
    xp_rad: float
    yp_rad: float
    available: bool
    predicted: bool
    source: str


FALLBACK_SOURCE = "fallback-zero"


def _field(lines: list[str], a: int, b: int) -> np.ndarray:
    """Fixed-width float column (1-based inclusive columns a..b); NaN where blank."""
    out = np.full(len(lines), np.nan)
    for k, ln in enumerate(lines):
        s = ln[a - 1:b].strip()
        if s:
            out[k] = float(s)
    return out


class EOPTable:
    """Daily EOP table read from a ``finals2000A.all`` file (IERS fixed-width format)."""

    def __init__(self, path):
        self.path = Path(path)
        lines = self.path.read_text().splitlines()
        mjd = _field(lines, 8, 15)
        x_a, y_a, u_a = _field(lines, 19, 27), _field(lines, 38, 46), _field(lines, 59, 68)
        x_b, y_b, u_b = _field(lines, 135, 144), _field(lines, 145, 154), _field(lines, 155, 165)
        ok = np.isfinite(mjd) & np.isfinite(u_a) & np.isfinite(x_a) & np.isfinite(y_a)
        self.mjd = mjd[ok]
        self.x_arcsec = np.where(np.isfinite(x_b), x_b, x_a)[ok]
        self.y_arcsec = np.where(np.isfinite(y_b), y_b, y_a)[ok]
        self.dut1_s = np.where(np.isfinite(u_b), u_b, u_a)[ok]
        flags = np.array([ln[57:58] if len(ln) > 57 else " " for ln in lines])[ok]
        self.predicted = (flags == "P") & ~np.isfinite(u_b[ok])
        if self.mjd.size < 2:
            raise ValueError(f"EOP file {self.path} holds {self.mjd.size} usable rows; at least 2 are needed.")

    def at(self, epoch: Epoch) -> EOP:
        """EOP at ``epoch`` (linear in UTC MJD); the zero fallback outside the table."""
        u1, u2 = epoch.jd_utc
        mjd = (u1 - 2400000.5) + u2
        if not self.mjd[0] <= mjd <= self.mjd[-1]:
            return EOP(0.0, 0.0, 0.0, False, False, FALLBACK_SOURCE)
        k = int(min(np.searchsorted(self.mjd, mjd, side="right") - 1, self.mjd.size - 2))
        f = (mjd - self.mjd[k]) / (self.mjd[k + 1] - self.mjd[k])
        du = self.dut1_s[k + 1] - self.dut1_s[k]
        du -= np.round(du)  # a leap second makes UT1 - UTC jump by 1 s; interpolate across it
        x = self.x_arcsec[k] + f * (self.x_arcsec[k + 1] - self.x_arcsec[k])
        y = self.y_arcsec[k] + f * (self.y_arcsec[k + 1] - self.y_arcsec[k])
        return EOP(float(self.dut1_s[k] + f * du), float(x * ARCSEC), float(y * ARCSEC), True,
                   bool(self.predicted[k] or self.predicted[k + 1]), str(self.path))


def _default_path() -> Path | None:
    spec = _import_util.find_spec("astropy_iers_data")
    if spec is None or not spec.submodule_search_locations:
        return None
    p = Path(next(iter(spec.submodule_search_locations))) / "data" / "finals2000A.all"
    return p if p.is_file() else None


@lru_cache(maxsize=1)
def default_table() -> EOPTable | None:
    """The table shipped in ``astropy-iers-data`` if installed, else None (read once per process)."""
    p = _default_path()
    return EOPTable(p) if p is not None else None


def eop_at(epoch: Epoch, table: EOPTable | None | str = "default") -> EOP:
    """EOP at ``epoch`` from ``table`` (``"default"``: :func:`default_table`; None: the fallback)."""
    if isinstance(table, str):
        if table != "default":
            raise ValueError(f"EOP table {table!r} is not known; pass an EOPTable, None or 'default'.")
        table = default_table()
    if table is None:
        return EOP(0.0, 0.0, 0.0, False, False, FALLBACK_SOURCE)
    return table.at(epoch)
