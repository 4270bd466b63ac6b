"""External torques on the body (N m, body components).

Both functions broadcast over leading axes and are plain numpy; the per-stage hot path in
``sim.truth.TruthModel._torque`` writes the same two formulas on floats, and
``tests/sim/test_environment.py`` proves they agree.
"""

from __future__ import annotations

import numpy as np

from .constants import MU_EARTH


def magnetic_torque(dipole_B_A_m2, b_B_T) -> np.ndarray:
    """Torque of a magnetic dipole ``m`` (A m^2) in a field ``B`` (T): ``m x B``."""
    return np.cross(np.asarray(dipole_B_A_m2, dtype=float), np.asarray(b_B_T, dtype=float))


def gravity_gradient_torque(inertia, r_B_m, mu: float = MU_EARTH) -> np.ndarray:
    """Gravity-gradient torque ``3 mu / |r|^5 (r x I r)`` for position ``r`` of the body relative
    to the Earth's centre in *body* components (m)."""
    r = np.asarray(r_B_m, dtype=float)
    I = np.asarray(inertia, dtype=float)
    Ir = np.einsum("ij,...j->...i", I, r)
    rn = np.linalg.norm(r, axis=-1, keepdims=True)
    return 3.0 * mu / rn**5 * np.cross(r, Ir)
