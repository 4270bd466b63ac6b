"""Rotations: direction cosine matrices, quaternions, Euler angles, axis-angle.

Conventions (fixed for the whole project):

* Quaternions are scalar-first ``[w, x, y, z]``, unit norm, Hamilton algebra.
* ``q_BN`` is the attitude of frame B relative to N and is *defined by its matrix*:
  ``v_B = dcm(q_BN) @ v_N`` (a passive, frame-to-frame matrix).
* ``compose(q_CB, q_BN) = q_CN`` with ``dcm(q_CN) = dcm(q_CB) @ dcm(q_BN)``. Under the Hamilton
  product this is ``q_BN (x) q_CB``; nobody has to remember that, they call ``compose``.
* Kinematics: ``dq_BN/dt = 0.5 * q_BN (x) [0, omega_BN_B]``.
* Euler sequence ``"ijk"`` with angles ``(a1, a2, a3)`` means: rotate the frame about axis i by a1,
  then about the new j by a2, then about the new k by a3, so
  ``dcm = M_k(a3) @ M_j(a2) @ M_i(a1)`` with ``M_n`` the elementary frame rotation (Schaub &
  Junkins, *Analytical Mechanics of Space Systems*, sec. 3.2). ``"321"`` is yaw-pitch-roll,
  ``"313"`` precession-nutation-spin.
* Outputs keep ``w >= 0`` (``q`` and ``-q`` are the same attitude).

Every function broadcasts over leading axes. Inputs that claim to be unit quaternions are checked:
a non-unit or non-finite quaternion raises ``ValueError`` instead of producing a skewed matrix.
"""

from __future__ import annotations

import numpy as np

import quat_floats

#: How far from unit norm an input quaternion may be. Renormalised integrator output is within
#: 1e-15; anything beyond 1e-6 is a bug upstream (or a scenario typo), not round-off.
UNIT_NORM_TOLERANCE = 1e-6

EULER_SEQUENCES = (
    "121", "123", "131", "132", "212", "213", "231", "232", "312", "313", "321", "323",
)


def _as_quat(q, name: str = "q") -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.shape[-1:] != (4,):
        raise ValueError(f"{name} must have shape (..., 4) as [w, x, y, z]; got shape {q.shape}.")
    return q


def check_unit(q, name: str = "q", tolerance: float = UNIT_NORM_TOLERANCE) -> np.ndarray:
    """Return ``q`` as an array after checking it is finite and of unit norm.

    Raises ``ValueError`` naming ``name``, the norm found and the tolerance allowed.
    """
    q = _as_quat(q, name)
    if not np.all(np.isfinite(q)):
        raise ValueError(f"{name} = {q.tolist()} contains NaN or infinity; a quaternion must be finite.")
    norm = np.linalg.norm(q, axis=-1)
    err = np.max(np.abs(norm - 1.0)) if norm.size else 0.0
    if err > tolerance:
        raise ValueError(
            f"{name} has norm {float(np.ravel(norm)[np.argmax(np.abs(np.ravel(norm) - 1.0))]):.9g}; "
            f"a unit quaternion [w, x, y, z] is required (|norm - 1| <= {tolerance:g}). "
            "Normalise it with sim.rotations.normalize if that is what you meant."
        )
    return q


def normalize(q) -> np.ndarray:
    """Scale quaternions to unit norm and make ``w >= 0``. Refuses zero or non-finite input."""
    q = _as_quat(q)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(q)) or np.any(norm == 0.0):
        raise ValueError("cannot normalise a zero or non-finite quaternion.")
    return canonical(q / norm)


def canonical(q) -> np.ndarray:
    """Return the sign of ``q`` with ``w >= 0`` (the same attitude)."""
    q = np.asarray(q, dtype=float)
    return np.where(q[..., :1] < 0.0, -q, q)


# The Hamilton product written out on floats (or arrays): the one copy, shared with drivers (quat_floats). The
# float-tuple steppers and compositions call it, and :func:`hamilton` below.
hamilton_floats = quat_floats.hamilton


def hamilton(p, q) -> np.ndarray:
    """Hamilton product ``p (x) q`` of scalar-first quaternions ``(..., 4)`` (no unit-norm check)."""
    p = np.moveaxis(np.asarray(p, dtype=float), -1, 0)
    q = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack(hamilton_floats(p, q), axis=-1)


def compose(q_CB, q_BN) -> np.ndarray:
    """Attitude of C relative to N from C rel. B and B rel. N: ``dcm(result) == dcm(q_CB) @ dcm(q_BN)``."""
    return canonical(hamilton(check_unit(q_BN, "q_BN"), check_unit(q_CB, "q_CB")))


def conjugate(q) -> np.ndarray:
    """Inverse rotation: ``conjugate(q_BN) == q_NB``."""
    q = _as_quat(q)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def dcm(q) -> np.ndarray:
    """Direction cosine matrix ``(..., 3, 3)`` of a unit quaternion: ``v_B = dcm(q_BN) @ v_N``."""
    q = check_unit(q)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        (
            np.stack((1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)), axis=-1),
            np.stack((2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)), axis=-1),
            np.stack((2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)), axis=-1),
        ),
        axis=-2,
    )


def check_dcm(C, name: str = "dcm", tolerance: float = 1e-9) -> np.ndarray:
    """Return ``C`` after checking it is a proper rotation (orthonormal, determinant +1)."""
    C = np.asarray(C, dtype=float)
    if C.shape[-2:] != (3, 3):
        raise ValueError(f"{name} must have shape (..., 3, 3); got shape {C.shape}.")
    if not np.all(np.isfinite(C)):
        raise ValueError(f"{name} contains NaN or infinity; a rotation matrix must be finite.")
    err = np.max(np.abs(C @ np.swapaxes(C, -1, -2) - np.eye(3))) if C.size else 0.0
    if err > tolerance or np.any(np.linalg.det(C) < 0):
        raise ValueError(
            f"{name} is not a proper rotation matrix (|C C^T - I| = {err:.3g}, allowed {tolerance:g}, "
            "and the determinant must be +1)."
        )
    return C


def quat_from_dcm(C) -> np.ndarray:
    """Unit quaternion (``w >= 0``) of a rotation matrix; Shepperd's method, stable for every angle."""
    C = check_dcm(C)
    tr = np.trace(C, axis1=-2, axis2=-1)
    d = np.stack((tr, C[..., 0, 0], C[..., 1, 1], C[..., 2, 2]), axis=-1)
    k = np.argmax(d, axis=-1)
    # Four candidate formulas; each is well conditioned when its own diagonal term is the largest.
    c01, c10 = C[..., 0, 1], C[..., 1, 0]
    c02, c20 = C[..., 0, 2], C[..., 2, 0]
    c12, c21 = C[..., 1, 2], C[..., 2, 1]
    cands = np.stack(
        (
            np.stack((1 + tr, c12 - c21, c20 - c02, c01 - c10), axis=-1),
            np.stack((c12 - c21, 1 + 2 * C[..., 0, 0] - tr, c01 + c10, c20 + c02), axis=-1),
            np.stack((c20 - c02, c01 + c10, 1 + 2 * C[..., 1, 1] - tr, c12 + c21), axis=-1),
            np.stack((c01 - c10, c20 + c02, c12 + c21, 1 + 2 * C[..., 2, 2] - tr), axis=-1),
        ),
        axis=-2,
    )
    q = np.take_along_axis(cands, k[..., None, None], axis=-2)[..., 0, :]
    return canonical(q / np.linalg.norm(q, axis=-1, keepdims=True))


def quat_from_axis_angle(axis, angle) -> np.ndarray:
    """Quaternion of a frame rotation by ``angle`` (rad) about ``axis`` (need not be unit, not zero)."""
    axis = np.asarray(axis, dtype=float)
    angle = np.asarray(angle, dtype=float)
    n = np.linalg.norm(axis, axis=-1, keepdims=True)
    if np.any(n == 0.0) or not np.all(np.isfinite(axis)):
        raise ValueError(f"axis = {axis.tolist()} must be a finite non-zero vector.")
    half = 0.5 * angle[..., None]
    return canonical(np.concatenate((np.cos(half), np.sin(half) * axis / n), axis=-1))


def axis_angle(q) -> tuple[np.ndarray, np.ndarray]:
    """Unit axis and angle in [0, pi] of a unit quaternion. The axis is x for the identity."""
    q = canonical(check_unit(q))
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    # atan2 of the half-angle stays accurate at both 0 and pi, unlike acos(w).
    angle = 2.0 * np.arctan2(s, q[..., 0])
    safe = np.where(s[..., None] > 0.0, v / np.where(s[..., None] > 0.0, s[..., None], 1.0), [1.0, 0.0, 0.0])
    return safe, angle


def angle_between(q1, q2) -> np.ndarray:
    """Rotation angle (rad, in [0, pi]) that takes attitude ``q1`` to ``q2``."""
    d = np.abs(np.sum(check_unit(q1, "q1") * check_unit(q2, "q2"), axis=-1))
    diff = hamilton(conjugate(q1), q2)
    return 2.0 * np.arctan2(np.linalg.norm(diff[..., 1:], axis=-1), d)


def _check_seq(seq: str) -> tuple[int, int, int]:
    if not isinstance(seq, str) or seq not in EULER_SEQUENCES:
        raise ValueError(
            f"Euler sequence {seq!r} is not one of the 12 valid sequences {', '.join(EULER_SEQUENCES)} "
            "(axes 1, 2, 3; no axis repeated twice in a row)."
        )
    return int(seq[0]) - 1, int(seq[1]) - 1, int(seq[2]) - 1


def quat_from_euler(angles, seq: str) -> np.ndarray:
    """Quaternion of Euler angles ``(..., 3)`` (rad) for sequence ``seq`` (e.g. ``"321"``, ``"313"``)."""
    i, j, k = _check_seq(seq)
    angles = np.asarray(angles, dtype=float)
    if angles.shape[-1:] != (3,):
        raise ValueError(f"angles must have shape (..., 3); got shape {angles.shape}.")
    eye = np.eye(3)
    q1 = quat_from_axis_angle(eye[i], angles[..., 0])
    q2 = quat_from_axis_angle(eye[j], angles[..., 1])
    q3 = quat_from_axis_angle(eye[k], angles[..., 2])
    # dcm = M_k(a3) M_j(a2) M_i(a1)  <=>  q = q_i (x) q_j (x) q_k under the passive convention.
    return canonical(hamilton(hamilton(q1, q2), q3))


def euler_from_quat(q, seq: str) -> np.ndarray:
    """Euler angles ``(..., 3)`` for sequence ``seq`` of a unit quaternion.

    Ranges: a1 and a3 in (-pi, pi]; a2 in [-pi/2, pi/2] for Tait-Bryan sequences (i, j, k all
    different) and in [0, pi] for proper Euler sequences (i == k). At gimbal lock (a2 = +-pi/2,
    resp. 0 or pi) only a1 +- a3 is defined: a3 is set to 0 and the whole angle goes to a1, so
    ``quat_from_euler(euler_from_quat(q))`` is still ``q``.
    """
    i, j, k = _check_seq(seq)
    C = dcm(q)
    if i != k:
        # Tait-Bryan. sign = +1 for cyclic order (1,2,3), (2,3,1), (3,1,2).
        s = 1.0 if (j - i) % 3 == 1 else -1.0
        sin2 = np.clip(s * C[..., k, i], -1.0, 1.0)
        a2 = np.arcsin(sin2)
        a1 = np.arctan2(-s * C[..., k, j], C[..., k, k])
        a3 = np.arctan2(-s * C[..., j, i], C[..., i, i])
        # Near lock arcsin loses digits; recompute a2 from both components for accuracy.
        cos2 = np.hypot(C[..., k, j], C[..., k, k])
        a2 = np.arctan2(sin2, cos2)
        locked = cos2 < 1e-9
        if np.any(locked):
            # a3 := 0; then C[j] row gives a1 (see module docstring).
            m = 3 - i - j  # the third axis
            a1_lock = np.arctan2(s * C[..., j, m], C[..., j, j])
            a1 = np.where(locked, a1_lock, a1)
            a3 = np.where(locked, 0.0, a3)
    else:
        m = 3 - i - j
        s = 1.0 if (j - i) % 3 == 1 else -1.0
        cos2 = np.clip(C[..., i, i], -1.0, 1.0)
        sin2 = np.hypot(C[..., i, j], C[..., i, m])
        a2 = np.arctan2(sin2, cos2)
        a1 = np.arctan2(C[..., i, j], -s * C[..., i, m])
        a3 = np.arctan2(C[..., j, i], s * C[..., m, i])
        locked = sin2 < 1e-9
        if np.any(locked):
            a1_lock = np.arctan2(s * C[..., j, m], C[..., j, j])
            a1 = np.where(locked, a1_lock, a1)
            a3 = np.where(locked, 0.0, a3)
    return np.stack((a1, a2, a3), axis=-1)


def rotate(q, v) -> np.ndarray:
    """``dcm(q) @ v`` broadcast over leading axes (vector in N components -> B components)."""
    return np.einsum("...ij,...j->...i", dcm(q), np.asarray(v, dtype=float))
