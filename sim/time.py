"""Simulation time.

Sim time is an integer count of nanoseconds since the scenario epoch: no drift, exact rate ratios,
bit-for-bit repeatable. The epoch is UTC (ISO 8601 in scenario files). Astronomy needs split Julian
dates (two floats whose sum is the date, so that 1 ns stays resolvable), in TT for ephemerides and
precession-nutation and in UT1 for Earth rotation; the UTC -> TAI -> TT and UTC -> UT1 steps use
ERFA (the engine behind astropy), so leap seconds are handled from ERFA's built-in table.

The stand injects clocks; nothing here reads the wall clock.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from datetime import UTC, datetime

import erfa

NS_PER_S = 1_000_000_000
NS_PER_DAY = 86_400 * NS_PER_S
#: ERFA's leap-second table ends a few years after its release; beyond it ERFA warns "dubious year"
#: and assumes no new leap second. That is the documented fallback here too, so the warning is
#: silenced rather than turned into an error (pytest runs with warnings as errors).
_DUBIOUS = re.compile(".*dubious year.*")


class ignore_dubious_year(warnings.catch_warnings):  # lower case, used like warnings.catch_warnings
    """``with ignore_dubious_year():`` silences ERFA's "dubious year" warning (and only it) inside.

    The one place ``sim`` decides this: every ERFA time-scale call (``dtf2d``, ``utctai``,
    ``taiutc``, ``utcut1``, ``d2dtf``, ``jd2cal``, ...) runs inside it. A subclass rather than a
    generator-based context manager: it costs about 0.7 us less per use, and ``Epoch.jd_utc``
    runs in every field and frame evaluation.
    """

    def __enter__(self):
        entered = super().__enter__()
        warnings.filterwarnings("ignore", message=_DUBIOUS.pattern)
        return entered


def seconds_to_ns(seconds: float) -> int:
    """Round a duration in seconds to whole nanoseconds (the sim's time unit)."""
    return int(round(float(seconds) * NS_PER_S))


def _norm(jd1: float, jd2: float) -> tuple[float, float]:
    """Keep jd1 a whole-and-a-half day number and |jd2| < 1 so no digits are lost in sums."""
    whole = float(int(jd2))
    return jd1 + whole, jd2 - whole


@dataclass(frozen=True)
class Epoch:
    """An instant: a UTC epoch plus an integer nanosecond offset of uniform (SI) time.

    ``epoch + seconds`` advances in SI seconds (TAI), so leap seconds inside a run are honoured.
    ``dut1_s`` is UT1 - UTC at the epoch (0 when no IERS data is given; that costs up to 0.9 s of
    Earth rotation, 13.5 arcsec: pass the real value for star-tracker-grade Earth pointing).
    """

    tai1: float
    tai2: float
    offset_ns: int = 0
    dut1_s: float = 0.0

    @classmethod
    def from_iso(cls, text: str, dut1_s: float = 0.0) -> Epoch:
        """Parse an ISO 8601 UTC time such as ``2026-03-20T12:00:00Z`` (fractional seconds allowed)."""
        try:
            dt = datetime.fromisoformat(str(text).strip())
        except ValueError:
            raise ValueError(
                f"epoch {text!r} is not an ISO 8601 UTC time; write it like '2026-03-20T12:00:00Z'."
            ) from None
        if dt.tzinfo is not None:
            if dt.utcoffset() != UTC.utcoffset(None):
                raise ValueError(f"epoch {text!r} must be in UTC (end it with 'Z' or '+00:00').")
        if not 1900 <= dt.year <= 2100:
            raise ValueError(f"epoch {text!r} has year {dt.year}; years 1900 to 2100 are supported.")
        if not -1.0 <= dut1_s <= 1.0:
            raise ValueError(f"dut1_s = {dut1_s} s is outside [-1, 1] s, the range IERS keeps UT1 - UTC in.")
        sec = dt.second + dt.microsecond * 1e-6
        with ignore_dubious_year():
            u1, u2 = erfa.dtf2d("UTC", dt.year, dt.month, dt.day, dt.hour, dt.minute, sec)
            t1, t2 = erfa.utctai(u1, u2)
        t1, t2 = _norm(float(t1), float(t2))
        return cls(t1, t2, 0, float(dut1_s))

    # --- arithmetic -------------------------------------------------------------------------
    def __add__(self, seconds: float) -> Epoch:
        return self.add_ns(seconds_to_ns(seconds))

    def add_ns(self, ns: int) -> Epoch:
        """The instant ``ns`` nanoseconds (SI) later."""
        return Epoch(self.tai1, self.tai2, self.offset_ns + int(ns), self.dut1_s)

    def __sub__(self, other: Epoch) -> float:
        """Seconds from ``other`` to ``self``."""
        if not isinstance(other, Epoch):
            return NotImplemented
        days = (self.tai1 - other.tai1) + (self.tai2 - other.tai2)
        return days * 86400.0 + (self.offset_ns - other.offset_ns) / NS_PER_S

    # --- split Julian dates -------------------------------------------------------------------
    @property
    def jd_tai(self) -> tuple[float, float]:
        days, rem = divmod(self.offset_ns, NS_PER_DAY)
        return _norm(self.tai1 + days, self.tai2 + rem / NS_PER_DAY)

    @property
    def jd_tt(self) -> tuple[float, float]:
        """Terrestrial Time as a split Julian date (TT = TAI + 32.184 s)."""
        a, b = self.jd_tai
        return _norm(a, b + 32.184 / 86400.0)

    @property
    def jd_utc(self) -> tuple[float, float]:
        """UTC as a split quasi-Julian date (ERFA's convention inside a leap second)."""
        a, b = self.jd_tai
        with ignore_dubious_year():
            u1, u2 = erfa.taiutc(a, b)
        return float(u1), float(u2)

    @property
    def jd_ut1(self) -> tuple[float, float]:
        """UT1 as a split Julian date, using ``dut1_s`` (UT1 - UTC).

        ERFA's UTC date is stretched on a leap-second day (86401 s to the day), so adding
        ``dut1_s / 86400`` to it would be up to a second off there; ``erfa.utcut1`` accounts for it.
        """
        u1, u2 = self.jd_utc
        with ignore_dubious_year():
            a, b = erfa.utcut1(u1, u2, self.dut1_s)
        return _norm(float(a), float(b))

    @property
    def iso(self) -> str:
        """UTC as ISO 8601 with microseconds, e.g. ``2026-03-20T12:00:00.000000Z``."""
        u1, u2 = self.jd_utc
        with ignore_dubious_year():
            y, m, d, hmsf = erfa.d2dtf("UTC", 6, u1, u2)
        h, mi, s, f = (int(x) for x in hmsf)
        return f"{int(y):04d}-{int(m):02d}-{int(d):02d}T{h:02d}:{mi:02d}:{s:02d}.{f:06d}Z"

    @property
    def decimal_year(self) -> float:
        """Decimal year in TT (what field models such as IGRF interpolate over)."""
        a, b = self.jd_tt
        return 2000.0 + ((a - 2451545.0) + b) / 365.25

    def __repr__(self) -> str:
        return f"Epoch({self.iso!r})"
