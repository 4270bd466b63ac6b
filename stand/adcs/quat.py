"""Quaternions, 3-vectors and 3 x 3 matrices of the reference ADCS as plain floats, one at a time.

The flight code handles one attitude, one rate and one 3 x 3 matrix per control period: a numpy call on three
numbers costs more than the arithmetic (np.linalg.norm, np.cross, np.all(np.isfinite) each take microseconds), so
these helpers work on tuples of floats (and tuples of rows for matrices), which also compile as they are. Same
conventions as :mod:`sim.rotations` (scalar-first Hamilton, ``v_B = dcm(q_BN) @ v_N``); callers pass unit
quaternions they have already validated or normalised themselves. :func:`finite3` is the one check the ADCS modules
make of a 3-vector input.
"""

from __future__ import annotations

import math

import numpy as np

from sim.rotations import hamilton_floats

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]


def finite3(v, name: str, error: type[ValueError]) -> Vec3:
    """``v`` as 3 floats; ``error`` (the calling module's own) naming ``name`` unless it is 3 finite numbers."""
    try:
        if isinstance(v, np.ndarray) and v.shape != (3,):
            raise ValueError
        x, y, z = v
        x, y, z = float(x), float(y), float(z)
    except (TypeError, ValueError):
        raise error(f"{name} = {np.asarray(v, dtype=object).tolist()} must be 3 finite numbers.") from None
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise error(f"{name} = {[x, y, z]} must be 3 finite numbers.")
    return x, y, z


def finite4(q, name: str, error: type[ValueError]) -> tuple[Quat, float]:
    """``q`` as 4 floats [w, x, y, z] and its norm; ``error`` (the calling module's own) naming ``name`` unless it is
    4 finite numbers. Each caller decides which norms it takes."""
    try:
        if isinstance(q, np.ndarray) and q.shape != (4,):
            raise ValueError
        a, b, c, d = q
        w, x, y, z = float(a), float(b), float(c), float(d)
    except (TypeError, ValueError):
        w = x = y = z = math.nan
    if not (math.isfinite(w) and math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise error(f"{name} = {np.asarray(q, dtype=object).tolist()} must be 4 finite numbers [w, x, y, z].")
    return (w, x, y, z), math.sqrt(w * w + x * x + y * y + z * z)


#: Hamilton product ``p (x) q``: the shared one itself, not a wrapper (a call less each time the filter composes).
qmul = hamilton_floats


def conj(q) -> Quat:
    return q[0], -q[1], -q[2], -q[3]


def positive(q) -> Quat:
    """The same attitude with ``w >= 0``."""
    return (-q[0], -q[1], -q[2], -q[3]) if q[0] < 0.0 else (q[0], q[1], q[2], q[3])


def normalised(q) -> Quat:
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return q[0] / n, q[1] / n, q[2] / n, q[3] / n


def dcm1(q) -> Mat3:
    """``dcm(q)`` for one unit quaternion, as three rows."""
    w, x, y, z = q
    return ((1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)),
            (2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)),
            (2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)))


def error(q_BN, q_RN) -> Quat:
    """``q_BR = compose(q_BN, conjugate(q_RN))`` with ``w >= 0``: ``q_RN^-1 (x) q_BN`` in Hamilton order."""
    return positive(hamilton_floats(conj(q_RN), q_BN))


def rotation_vector(q) -> Vec3:
    """The rotation vector (rad) of ``q``, the short way round (``2 atan2`` keeps it exact at large angles)."""
    w, x, y, z = positive(q)
    vn = math.sqrt(x * x + y * y + z * z)
    if vn == 0.0:
        return 0.0, 0.0, 0.0
    k = 2.0 * math.atan2(vn, w) / vn
    return x * k, y * k, z * k


def cross(a, b) -> Vec3:
    """``a x b`` for two 3-vectors."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


def dot(a, b) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def norm(a) -> float:
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def add(a, b) -> Vec3:
    return a[0] + b[0], a[1] + b[1], a[2] + b[2]


def sub(a, b) -> Vec3:
    return a[0] - b[0], a[1] - b[1], a[2] - b[2]


def scale(k: float, a) -> Vec3:
    return k * a[0], k * a[1], k * a[2]


def mat3(m) -> Mat3:
    """A 3 x 3 array (or nested sequence) as three rows of floats."""
    return tuple((float(r[0]), float(r[1]), float(r[2])) for r in m)


def mv(m, v) -> Vec3:
    """``m @ v`` for a 3 x 3 matrix given as three rows: each row's :func:`dot` with ``v``, in the same order."""
    x, y, z = v
    (a, b, c), (d, e, f), (g, h, i) = m
    return a * x + b * y + c * z, d * x + e * y + f * z, g * x + h * y + i * z


def mtv(m, v) -> Vec3:
    """``m.T @ v`` for a 3 x 3 matrix given as three rows."""
    x, y, z = v
    return (m[0][0] * x + m[1][0] * y + m[2][0] * z, m[0][1] * x + m[1][1] * y + m[2][1] * z,
            m[0][2] * x + m[1][2] * y + m[2][2] * z)


def inv3(m) -> Mat3:
    """The inverse of a non-singular 3 x 3 matrix (three rows) by its adjugate."""
    (a, b, c), (d, e, f), (g, h, i) = m
    A, B, C = e * i - f * h, f * g - d * i, d * h - e * g  # cofactors of the first row
    det = a * A + b * B + c * C
    return ((A / det, (c * h - b * i) / det, (b * f - c * e) / det),
            (B / det, (a * i - c * g) / det, (c * d - a * f) / det),
            (C / det, (b * g - a * h) / det, (a * e - b * d) / det))
