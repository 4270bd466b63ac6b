"""The float math of one star-tracker exposure: the check of the truth the stand hands the emulator, the exclusion
test of a bright body and the attitude noise as a small rotation (composed onto the truth by the Hamilton product
of ``quat_floats``, the copy ``sim`` shares). The one source of this part of the tracker's hot path
(:mod:`drivers.star_tracker.measurement` exports it).

Plain Python, and compiled by Cython in pure-Python mode where the install has a C compiler (``compiled_paths``
lists it; docs/fast_paths.md): the ``cython.*`` declarations give the compiled build C doubles and do nothing in
plain Python. Both builds do the same IEEE-754 operations in the same order with the same C library functions
(setup.py compiles without contraction and fast-math), so they agree to the bit and raise the same errors; the
tests run both. The checks convert with ``float()`` as before (a numpy scalar, an int or a numeric
string is taken), so the value that reaches a C double is Python's float of it; :func:`small_rotation` takes
floats (the emulator hands them nothing else).
"""

from __future__ import annotations

import math

import cython
from cython.cimports.libc.math import acos, cos, sin, sqrt  # C's when compiled, Python's math otherwise: the same

_INF = cython.declare(cython.double, math.inf)


@cython.locals(x=cython.double, y=cython.double, z=cython.double, angle=cython.double, s=cython.double)
def small_rotation(v) -> tuple:
    """The quaternion of the rotation vector ``v`` (rad)."""
    x, y, z = v
    angle = sqrt(x * x + y * y + z * z)
    if angle < 1e-300:
        return (1.0, 0.0, 0.0, 0.0)
    if angle == _INF:  # Python's math.sin and cos refuse an infinite angle; C's would give NaN
        raise ValueError("math domain error")
    s = sin(0.5 * angle) / angle
    return (cos(0.5 * angle), x * s, y * s, z * s)


@cython.locals(x=cython.double, y=cython.double, z=cython.double, norm=cython.double, c=cython.double)
def in_field(direction, radius, exclusion):
    """Is a body of angular radius ``radius`` (rad) at ``direction`` (tracker axes) within ``exclusion`` (rad) of
    the boresight (+z)? A body the stand left out (None) never is."""
    if direction is None:
        return False
    a, b, d = direction
    x, y, z = float(a), float(b), float(d)
    norm = sqrt(x * x + y * y + z * z)
    if not norm > 0:
        return False
    c = z / norm
    if not c < 1.0:  # clipped to acos's domain as min(1.0, max(-1.0, c)) would, a NaN to 1.0
        c = 1.0
    elif c < -1.0:
        c = -1.0
    return acos(c) - radius < exclusion


@cython.locals(qw=cython.double, qx=cython.double, qy=cython.double, qz=cython.double, n=cython.double,
               wx=cython.double, wy=cython.double, wz=cython.double, rate=cython.double)
def checked_truth(truth, t_e) -> tuple:
    """(q_TN normalised, |omega_TN_T| rad/s) of what the measurement source returned at ``t_e``; ValueError naming
    what is allowed when it is not a TrackerTruth with a unit quaternion, a finite rate and sigmas in [0, pi]."""
    try:
        a, b, c, d = truth.q_TN
        qw, qx, qy, qz = float(a), float(b), float(c), float(d)
        n = sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        if not 0.5 <= n < _INF:  # a NaN fails the comparison too
            raise ValueError
        a, b, c = truth.omega_TN_T
        wx, wy, wz = float(a), float(b), float(c)
        rate = sqrt(wx * wx + wy * wy + wz * wz)
        if not rate < _INF:
            raise ValueError
        sigma_cross, sigma_roll = truth.sigma_cross_rad, truth.sigma_roll_rad
        if sigma_cross is not None and not 0.0 <= float(sigma_cross) <= math.pi:
            raise ValueError
        if sigma_roll is not None and not 0.0 <= float(sigma_roll) <= math.pi:
            raise ValueError
    except (TypeError, ValueError, AttributeError):
        raise ValueError(
            f"measurement_source({t_e!r}) must return a TrackerTruth with a unit quaternion q_TN (4 numbers), "
            f"a finite omega_TN_T (3 numbers, rad/s) and sigmas from 0 to pi rad (or None); got {truth!r}."
        ) from None
    return (qw / n, qx / n, qy / n, qz / n), rate
