"""Sun, Moon and Earth ephemerides (geometric, geocentric GCRS) and stellar aberration.

Models (ERFA, the engine behind astropy):

* Earth heliocentric and barycentric position and velocity: ``erfa.epv00`` (VSOP2000-based,
  about 0.01 arcsec for the Sun direction; valid 1900-2100).
* Moon: ``erfa.moon98`` (Meeus' simplified ELP, about 10 arcsec in direction, 1900-2100).

All positions are *geometric* (no light time, no aberration) and in metres; velocities in m/s.
The frame is the BCRS/GCRS axes (ICRS orientation), the frame of the star catalog.

Every function takes ``epoch`` as a :class:`sim.time.Epoch`, a sequence of them, or a split TT
Julian date ``(jd1, jd2)`` of broadcastable arrays; results have shape ``(..., 3)`` over the
epochs. Nothing here reads the wall clock.
"""

from __future__ import annotations

import math

import erfa
import numpy as np

from sim.constants import AU, C_LIGHT, DAY_S
from sim.time import Epoch

__all__ = [
    "jd_tt_arrays",
    "earth_pv_bcrs",
    "earth_pv_heliocentric",
    "sun_position_gcrs",
    "moon_position_gcrs",
    "aberrate",
    "EphemerisTrack",
    "sun_position_gcrs_analytic",
    "SUN_ANALYTIC_ERROR_ARCSEC",
    "TRACK_STEP_S",
]

_AU_PER_DAY = AU / DAY_S


def jd_tt_arrays(epoch) -> tuple[np.ndarray, np.ndarray]:
    """Split TT Julian date arrays of an Epoch, a sequence of Epochs or a ``(jd1, jd2)`` pair."""
    if isinstance(epoch, Epoch):
        a, b = epoch.jd_tt
        return np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if isinstance(epoch, tuple) and len(epoch) == 2 and not isinstance(epoch[0], Epoch):
        return np.asarray(epoch[0], dtype=float), np.asarray(epoch[1], dtype=float)
    try:
        pairs = [e.jd_tt for e in epoch]
    except (TypeError, AttributeError):
        raise TypeError(
            f"epoch must be a sim.time.Epoch, a sequence of them or a split TT Julian date (jd1, jd2); "
            f"got {type(epoch).__name__}."
        ) from None
    arr = np.asarray(pairs, dtype=float).reshape(-1, 2)
    return arr[:, 0], arr[:, 1]


def earth_pv_heliocentric(epoch) -> tuple[np.ndarray, np.ndarray]:
    """Earth position (m) and velocity (m/s) relative to the Sun, ICRS axes."""
    jd1, jd2 = jd_tt_arrays(epoch)
    pvh, _ = erfa.epv00(jd1, jd2)
    return pvh["p"] * AU, pvh["v"] * _AU_PER_DAY


def earth_pv_bcrs(epoch) -> tuple[np.ndarray, np.ndarray]:
    """Earth position (m) and velocity (m/s) relative to the solar-system barycentre (BCRS)."""
    jd1, jd2 = jd_tt_arrays(epoch)
    _, pvb = erfa.epv00(jd1, jd2)
    return pvb["p"] * AU, pvb["v"] * _AU_PER_DAY


def sun_position_gcrs(epoch) -> np.ndarray:
    """Geometric position of the Sun relative to the Earth's centre, m, GCRS axes, ``(..., 3)``."""
    r_EarthSun, _ = earth_pv_heliocentric(epoch)
    return -r_EarthSun


def moon_position_gcrs(epoch) -> np.ndarray:
    """Geometric position of the Moon relative to the Earth's centre, m, GCRS axes, ``(..., 3)``."""
    jd1, jd2 = jd_tt_arrays(epoch)
    pv = erfa.moon98(jd1, jd2)
    return pv["p"] * AU


def aberrate(u_N, v_obs_N) -> np.ndarray:
    """Apparent unit direction of light arriving along natural direction ``u_N`` (unit, ``(..., 3)``)
    for an observer moving with barycentric velocity ``v_obs_N`` (m/s, ``(3,)`` or ``(..., 3)``).

    Special-relativistic formula (the one in ``erfa.ab`` without the small solar-potential term):
    ``p' = (bm1 p + (1 + p.V / (1 + bm1)) V) / (1 + p.V)``, with ``V = v / c`` and
    ``bm1 = sqrt(1 - |V|^2)``. The shift is ``|V| sin(angle to apex)``: up to 20.5 arcsec for the
    Earth's orbit plus up to 5.2 arcsec for a low orbit.
    """
    u = np.asarray(u_N, dtype=float)
    V = np.asarray(v_obs_N, dtype=float) / C_LIGHT
    bm1 = np.sqrt(1.0 - np.sum(V * V, axis=-1, keepdims=True))
    pdv = np.sum(u * V, axis=-1, keepdims=True)
    p = (bm1 * u + (1.0 + pdv / (1.0 + bm1)) * V) / (1.0 + pdv)
    return p / np.linalg.norm(p, axis=-1, keepdims=True)


#: Default grid steps of :class:`EphemerisTrack` (s). With ERFA's positions *and velocities* at the
#: nodes, cubic Hermite interpolation errs by about h^4 |d4r/dt4| / 384. Measured against the direct
#: ERFA call over 3 days: Moon at 1 h 0.97 m (0.0006 arcsec), Sun at 6 h 0.12 m (1e-7 arcsec);
#: ``tests/sim/test_sun_moon.py`` keeps both under 0.01 arcsec.
TRACK_STEP_S = {"sun": 6 * 3600.0, "moon": 3600.0}


class EphemerisTrack:
    """Sun or Moon position over a run: ERFA on a coarse grid, cubic Hermite in between.

    ``body`` is ``"sun"`` or ``"moon"``; ``t_s`` are seconds (SI, TT rate) since ``epoch``. Grid
    nodes are computed lazily, once, only for the intervals asked for, so a scene that never asks
    never evaluates ERFA (``evaluations`` counts node computations). Per interpolated point this
    costs a few numpy operations instead of epv00's ~50-75 us.
    """

    def __init__(self, epoch: Epoch, body: str, step_s: float | None = None):
        if body not in TRACK_STEP_S:
            raise ValueError(f"ephemeris body {body!r} is not one of {sorted(TRACK_STEP_S)}.")
        self.epoch = epoch
        self.body = body
        self.step_s = float(TRACK_STEP_S[body] if step_s is None else step_s)
        if not 0.0 < self.step_s <= 86400.0:
            raise ValueError(f"ephemeris track step_s = {self.step_s} s is outside (0, 86400] s.")
        self._nodes: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.evaluations = 0

    def _pv(self, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        missing = sorted({int(x) for x in np.ravel(k)} - self._nodes.keys())
        if missing:
            tt1, tt2 = self.epoch.jd_tt
            jd2 = tt2 + np.array(missing, dtype=float) * self.step_s / DAY_S
            jd1 = np.full_like(jd2, tt1)
            if self.body == "sun":
                pvh, _ = erfa.epv00(jd1, jd2)
                p, v = -pvh["p"] * AU, -pvh["v"] * _AU_PER_DAY
            else:
                pv = erfa.moon98(jd1, jd2)
                p, v = pv["p"] * AU, pv["v"] * _AU_PER_DAY
            self.evaluations += len(missing)
            for i, kk in enumerate(missing):
                self._nodes[kk] = (p[i], v[i])
        flat = [self._nodes[int(x)] for x in np.ravel(k)]
        P = np.array([f[0] for f in flat]).reshape(np.shape(k) + (3,))
        V = np.array([f[1] for f in flat]).reshape(np.shape(k) + (3,))
        return P, V

    def position_gcrs(self, t_s) -> np.ndarray:
        """Geometric geocentric position (m, GCRS) at ``t_s`` seconds after the epoch, ``(..., 3)``."""
        t = np.asarray(t_s, dtype=float)
        if not np.all(np.isfinite(t)):
            raise ValueError("ephemeris track times t_s must be finite seconds since the epoch.")
        h = self.step_s
        k = np.floor(t / h).astype(np.int64)
        u = (t / h - k)[..., None]
        p0, v0 = self._pv(k)
        p1, v1 = self._pv(k + 1)
        return _hermite(u, h, p0, v0, p1, v1)

    def position_gcrs_floats(self, t_s: float) -> tuple[float, float, float]:
        """:meth:`position_gcrs` at one time as three floats, equal to its bits: the same :func:`_hermite` on each
        axis, without the ~20 numpy calls that cost 60-190 us for one point (a tracker asks once a second)."""
        if not math.isfinite(t_s):
            raise ValueError("ephemeris track times t_s must be finite seconds since the epoch.")
        h = self.step_s
        k = math.floor(t_s / h)
        u = t_s / h - k
        if k not in self._nodes or k + 1 not in self._nodes:
            self._pv(np.array([k, k + 1], dtype=np.int64))
        (p0, v0), (p1, v1) = self._nodes[k], self._nodes[k + 1]
        return tuple(_hermite(u, h, float(p0[i]), float(v0[i]), float(p1[i]), float(v1[i])) for i in range(3))


def _hermite(u, h, p0, v0, p1, v1):
    """Cubic Hermite between nodes (p0, v0) and (p1, v1) a step ``h`` apart, at the fraction ``u`` of it: on arrays
    or on floats (numpy's elementwise operations round as Python's float ones do, in the same order)."""
    u2, u3 = u * u, u * u * u
    return ((2 * u3 - 3 * u2 + 1) * p0 + (u3 - 2 * u2 + u) * h * v0
            + (-2 * u3 + 3 * u2) * p1 + (u3 - u2) * h * v1)


#: Measured worst direction error of :func:`sun_position_gcrs_analytic` against JPL DE421 over
#: 2000-2050 (``tests/sim/test_sun_moon.py`` keeps it under this bound), arcsec.
SUN_ANALYTIC_ERROR_ARCSEC = 50.0


def sun_position_gcrs_analytic(epoch) -> np.ndarray:
    """Cheap geometric Sun (m, GCRS): the Astronomical Almanac's low-precision formulae.

    Mean longitude and anomaly, two-term equation of centre, geometric (the AA's aberration of
    -20.5 arcsec is removed), precessed back from the equinox of date to J2000 by the general
    precession in longitude (5029.0966 arcsec per Julian century), ecliptic of J2000 (obliquity
    84381.406 arcsec) to GCRS axes (the 23 mas frame bias neglected). Measured against DE421 over
    2000-2050: 16 arcsec rms, 42 arcsec worst, distance within 1e-4 relative (bound kept by the
    tests: :data:`SUN_ANALYTIC_ERROR_ARCSEC`); vectorised, well under a microsecond per epoch in bulk.
    Use it for coarse sun sensors and eclipse flags, not for a star tracker's Sun exclusion edge.
    """
    jd1, jd2 = jd_tt_arrays(epoch)
    d = (jd1 - 2451545.0) + jd2
    T = d / 36525.0
    L = np.radians(280.460 + 20.5 / 3600.0 + 0.9856474 * d - 5029.0966 / 3600.0 * T)
    g = np.radians(357.528 + 0.9856003 * d)
    lam = L + np.radians(1.915) * np.sin(g) + np.radians(0.020) * np.sin(2 * g)
    R = (1.00014 - 0.01671 * np.cos(g) - 0.00014 * np.cos(2 * g)) * AU
    eps = np.radians(84381.406 / 3600.0)
    x = R * np.cos(lam)
    y = R * np.sin(lam)
    return np.stack((x, y * np.cos(eps), y * np.sin(eps)), axis=-1)
