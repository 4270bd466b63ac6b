"""Environment models: geomagnetic field, Sun, Moon, shadow.

The geomagnetic field here is the centred (tilted) dipole given by the degree-1 Gauss
coefficients; it is exact for what it is and is what BENCHMARKS.md's comparison case uses. The full
IGRF-14 model arrives with the environment issue and takes over wherever a scenario does not ask
for the dipole.
"""

from __future__ import annotations

import numpy as np

from .constants import R_IGRF

#: Degree-1 IGRF Gauss coefficients (nT) of BENCHMARKS.md's comparison case.
DIPOLE_G10_NT = -30926.0
DIPOLE_G11_NT = -2318.0
DIPOLE_H11_NT = 5817.0


def dipole_field_itrs(r_itrs, g10_nT: float = DIPOLE_G10_NT, g11_nT: float = DIPOLE_G11_NT,
                      h11_nT: float = DIPOLE_H11_NT, r_ref_m: float = R_IGRF) -> np.ndarray:
    """Field (T) of the degree-1 geomagnetic potential at Earth-fixed positions ``r_itrs`` (m).

    With ``g = (g11, h11, g10)`` the potential is ``V = a^3 (g . r) / r^3``, so
    ``B = -grad V = a^3 (3 (g . r_hat) r_hat - g) / r^3``. At the north pole this is
    ``2 g10`` along +z, i.e. pointing down into the Earth for the present-day negative g10.
    """
    r = np.asarray(r_itrs, dtype=float)
    g = np.array([g11_nT, h11_nT, g10_nT]) * 1e-9
    rn = np.linalg.norm(r, axis=-1, keepdims=True)
    if np.any(rn < 0.5 * r_ref_m) or not np.all(np.isfinite(r)):
        raise ValueError(
            "magnetic field requested at a position inside the Earth or non-finite "
            f"(|r| = {float(np.min(rn)):.6g} m; at least {0.5 * r_ref_m:.6g} m is allowed)."
        )
    rhat = r / rn
    return (r_ref_m / rn) ** 3 * (3.0 * np.sum(g * rhat, axis=-1, keepdims=True) * rhat - g)


def magnetic_field_itrs(epoch, r_itrs, model: str = "dipole") -> np.ndarray:
    """Geomagnetic field (T, ITRS components) at ``r_itrs`` (m) and ``epoch``.

    ``model="dipole"`` is the centred dipole above (time-independent).
    """
    if model == "dipole":
        return dipole_field_itrs(r_itrs)
    raise ValueError(f"magnetic field model {model!r} is not available; allowed: 'dipole'.")
