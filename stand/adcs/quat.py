"""Quaternion products and matrices for one quaternion at a time, without the per-call checks of
:mod:`sim.rotations` (whose broadcasting and validation cost ~20 us per call, more than the arithmetic), and the
one check the ADCS modules make of a 3-vector input (:func:`finite3`).

Same conventions (scalar-first Hamilton, ``v_B = dcm(q_BN) @ v_N``); callers pass unit quaternions they
have already validated or normalised themselves.
"""

from __future__ import annotations

import numpy as np

from sim.rotations import hamilton_floats


def finite3(v, name: str, error: type[ValueError]) -> np.ndarray:
    """``v`` as a (3,) float array; ``error`` (the calling module's own) naming ``name`` unless it is 3 finite
    numbers."""
    a = np.asarray(v, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise error(f"{name} = {np.asarray(v).tolist()} must be 3 finite numbers.")
    return a


def qmul(p, q) -> np.ndarray:
    """Hamilton product ``p (x) q``."""
    return np.array(hamilton_floats(tuple(p), tuple(q)))


def conj(q) -> np.ndarray:
    return np.array((q[0], -q[1], -q[2], -q[3]))


def positive(q) -> np.ndarray:
    """The same attitude with ``w >= 0``."""
    return -q if q[0] < 0.0 else q


def dcm1(q) -> np.ndarray:
    """``dcm(q)`` for one unit quaternion."""
    w, x, y, z = (float(c) for c in q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)],
                     [2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)],
                     [2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)]])


def error(q_BN, q_RN) -> np.ndarray:
    """``q_BR = compose(q_BN, conjugate(q_RN))`` with ``w >= 0``: ``q_RN^-1 (x) q_BN`` in Hamilton order."""
    return positive(np.array(hamilton_floats((q_RN[0], -q_RN[1], -q_RN[2], -q_RN[3]), tuple(q_BN))))


def cross(a, b) -> np.ndarray:
    """``a x b`` for two 3-vectors (numpy.cross costs ~10 us per call on 3-vectors)."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array((a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0))
