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
