"""Attitude from matched vector pairs: weighted SVD solution of Wahba's problem and its covariance.

Given unit vectors ``b_S`` measured in the tracker frame and the matching catalog directions
``r_N`` (GCRS), find ``q_SN`` minimising ``sum_i a_i |b_i - dcm(q_SN) r_i|^2`` (Markley 1988, SVD
method): ``B = sum_i a_i b_i r_i^T = U S V^T``, ``dcm = U diag(1, 1, det U det V) V^T``.

Covariance (Shuster's QUEST measurement model, each ``b_i`` carrying isotropic noise of ``sigma_i``
rad perpendicular to itself): the small rotation error ``dtheta_S`` (tracker frame, rad) of the
estimate has covariance ``P = (sum_i (I - b_i b_i^T) / sigma_i^2)^-1``. The per-star sigmas are
known only up to a common factor (they come from a photometric model), so the factor is estimated
from the post-fit residuals, ``s^2 = sum_i a_i |res_i|^2 / (2 n - 3)`` (two residual components per
star, three attitude parameters), and ``P`` is scaled by it. The error convention is
``dcm(q_est) = exp(-[dtheta x]) dcm(q_true)``, i.e. ``dtheta`` is the small rotation that takes the
true tracker frame to the estimated one, in tracker axes; ``dtheta_z`` is the roll about the boresight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["AttitudeEstimate", "estimate_attitude", "estimate_attitude_robust", "estimate_attitude_robust_weighted",
           "attitude_error_S", "wahba_dcm"]


@dataclass(frozen=True)
class AttitudeEstimate:
    """``q_SN`` (scalar first, w >= 0), covariance ``cov_S`` (3, 3) of the rotation error in tracker
    axes (rad^2), its cross-boresight sigma ``sqrt(P_xx + P_yy)`` (rad: RMS angle between estimated
    and true boresight) and roll sigma ``sqrt(P_zz)`` (rad), and per-pair residual angles (rad)."""

    q_SN: np.ndarray
    dcm_SN: np.ndarray
    cov_S: np.ndarray
    sigma_cross_rad: float
    sigma_roll_rad: float
    residual_rad: np.ndarray


try:
    # The kernel np.linalg.svd itself calls for a real double matrix (LAPACK's dgesdd through numpy's gufunc), called
    # without the wrapper's argument handling and error-state context, which cost twice the decomposition of a 3 x 3
    # matrix: the same call on the same matrix, so the same bits (tests/star_screen/test_tracking.py compares them).
    from numpy.linalg._umath_linalg import svd_f as _svd_kernel
except ImportError:  # a numpy that moved it: its public wrapper, the same results
    _svd_kernel = None


def svd3(B: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``np.linalg.svd(B)`` of a float64 ``B`` (3, 3): (U, singular values, V^T), the same bits, and the same
    refusals: ``LinAlgError`` for a matrix with NaN (or one LAPACK could not decompose), NaN results for one with
    inf."""
    if _svd_kernel is None:
        return np.linalg.svd(B)
    values = B.ravel().tolist()
    if any(map(math.isnan, values)):
        raise np.linalg.LinAlgError("SVD did not converge")
    U, s, Vt = _svd_kernel(B, signature="d->ddd")
    if math.isnan(s[0]) and all(map(math.isfinite, values)):  # a failed decomposition comes back as NaN
        raise np.linalg.LinAlgError("SVD did not converge")
    return U, s, Vt


def wahba_dcm(b_S, r_N, a, ba=None) -> np.ndarray:
    """``dcm_SN`` minimising ``sum a_i |b_i - dcm r_i|^2`` (SVD method; no covariance, no checks).

    ``ba``: ``b_S * a[:, None]`` when the caller already has it."""
    B = (b_S * a[:, None] if ba is None else ba).T @ r_N
    U, _, Vt = svd3(B)
    M = U @ Vt
    (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = M.tolist()
    if a0 * (b1 * c2 - b2 * c1) - a1 * (b0 * c2 - b2 * c0) + a2 * (b0 * c1 - b1 * c0) > 0:
        return M
    # det(U V^T) = -1: flip the axis of the smallest singular value (a proper rotation is required).
    return M - 2.0 * np.outer(U[:, 2], Vt[2])


def _quat_from_orthonormal(C: np.ndarray) -> np.ndarray:
    """Quaternion (w >= 0) of one proper rotation matrix; Shepperd's method on Python floats.

    ``C`` comes out of the SVD solution orthonormal to rounding, so the validation in
    :func:`sim.rotations.quat_from_dcm` (which the tests compare against) is skipped for speed."""
    (c00, c01, c02), (c10, c11, c12), (c20, c21, c22) = C.tolist()
    tr = c00 + c11 + c22
    k = max(range(4), key=(tr, c00, c11, c22).__getitem__)
    if k == 0:
        q = (1 + tr, c12 - c21, c20 - c02, c01 - c10)
    elif k == 1:
        q = (c12 - c21, 1 + 2 * c00 - tr, c01 + c10, c20 + c02)
    elif k == 2:
        q = (c20 - c02, c01 + c10, 1 + 2 * c11 - tr, c12 + c21)
    else:
        q = (c01 - c10, c20 + c02, c12 + c21, 1 + 2 * c22 - tr)
    v = np.array(q)
    v /= math.sqrt(float(v @ v))
    return -v if v[0] < 0 else v


def _inv_sym3(a: float, b: float, c: float, d: float, e: float, f: float, scale: float = 1.0):
    """Inverse, times ``scale``, of the symmetric 3 x 3 matrix with upper triangle ``a b c / d e / f``, in closed form
    (adjugate over determinant) on Python floats: (the matrix, its diagonal as floats); all ``inf * scale`` when it is
    singular (fewer than two distinct directions). Each element is ``(adjugate * (1 / det)) * scale``, the bits of
    numpy scaling the inverse in place."""
    A, B, C = d * f - e * e, c * e - b * f, b * e - c * d
    det = a * A + b * B + c * C
    if not (abs(det) > 1e-300 and math.isfinite(det)) or abs(det) <= 1e-12 * max(a * d * f, 1e-300):
        v = math.inf * scale
        return np.full((3, 3), v), (v, v, v)
    D, E, G = a * f - c * c, b * c - a * e, a * d - b * b
    s = 1.0 / det
    A, B, C, D, E, G = A * s * scale, B * s * scale, C * s * scale, D * s * scale, E * s * scale, G * s * scale
    return np.array(((A, B, C), (B, D, E), (C, E, G))), (A, D, G)


def estimate_attitude(b_S, r_N, sigma_rad=None, *, scale_from_residuals: bool = True) -> AttitudeEstimate:
    """Weighted least-squares attitude from ``n >= 2`` pairs of unit vectors ``(n, 3)``.

    ``sigma_rad``: per-pair measurement sigma (rad), scalar or ``(n,)``; default 1 (equal weights).
    ``scale_from_residuals``: scale the covariance by the residual variance factor (needs n >= 3;
    with fewer pairs the given sigmas are taken as absolute).

    One SVD of the 3 x 3 attitude profile matrix; the information matrix
    ``F = sum_i a_i (I - b_i b_i^T)`` is inverted in closed form (it is symmetric 3 x 3).
    """
    b = np.asarray(b_S, dtype=float).reshape(-1, 3)
    r = np.asarray(r_N, dtype=float).reshape(-1, 3)
    n = len(b)
    if n < 2 or len(r) != n:
        raise ValueError(f"estimate_attitude needs at least 2 matched pairs of equal count; got {n} and {len(r)}.")
    if sigma_rad is None:
        a = np.ones(n)
    else:
        sig = np.asarray(sigma_rad, dtype=float)
        a = np.broadcast_to(1.0 / sig**2, (n,)) if sig.ndim == 0 else 1.0 / sig**2
        if a.shape != (n,):
            raise ValueError(f"sigma_rad has shape {sig.shape}; it must be a scalar or one sigma per pair ({n},).")
    ba = b * a[:, None]
    C = wahba_dcm(b, r, a, ba)
    res = b - r @ C.T
    return _finish(b, a, ba, C, np.einsum("ij,ij->i", res, res), scale_from_residuals)


def _finish(b, a, ba, C, res2, scale_from_residuals: bool = True) -> AttitudeEstimate:
    """Covariance, quaternion and sigmas of the SVD solution ``C`` (``a``: weights ``1 / sigma^2``,
    ``ba``: ``b * a[:, None]``, ``res2``: squared residuals)."""
    n = len(b)
    # F = sum_i a_i (I - b_i b_i^T): its upper triangle on Python floats, (sum a) - (b^T a b)_jk on the diagonal and
    # -(b^T a b)_jk off it (the same roundings as negating the product and adding the sum to its diagonal in numpy).
    (g00, g01, g02), (_, g11, g12), (_, _, g22) = (ba.T @ b).tolist()
    total = float(a.sum())
    scale = float(a @ res2) / (2 * n - 3) if scale_from_residuals and n >= 3 else 1.0
    P, (p00, p11, p22) = _inv_sym3(total - g00, -g01, -g02, total - g11, -g12, total - g22, scale)
    q = _quat_from_orthonormal(C)
    sc = math.sqrt(max(p00 + p11, 0.0))
    sr = math.sqrt(max(p22, 0.0))
    return AttitudeEstimate(q, C, P, sc, sr, np.sqrt(res2))


def estimate_attitude_robust(b_S: np.ndarray, r_N: np.ndarray, sigma_rad: np.ndarray, gate: float):
    """:func:`estimate_attitude` (``(n, 3)`` float arrays, ``(n,)`` sigmas, n >= 3) with gross
    outliers left out: returns (estimate, kept indices into the pairs, or ``None`` when all are kept).

    Normalised residuals ``z = |res| / sigma`` of a first fit are Rayleigh distributed with scale
    ``s = median(z) / sqrt(2 ln 2)``; pairs with ``z > gate s`` are dropped and the rest refit."""
    a = 1.0 / sigma_rad**2
    return estimate_attitude_robust_weighted(b_S, r_N, a, b_S * a[:, None], gate)


def estimate_attitude_robust_weighted(b_S: np.ndarray, r_N: np.ndarray, a: np.ndarray, ba: np.ndarray, gate: float):
    """:func:`estimate_attitude_robust` with the weights ``a = 1 / sigma^2`` and ``ba = b_S * a[:, None]`` given (a
    caller that gathers the pairs can compute them in the same pass)."""
    C = wahba_dcm(b_S, r_N, a, ba)
    res = b_S - r_N @ C.T
    res2 = np.einsum("ij,ij->i", res, res)
    z2 = res2 * a
    h = len(z2) // 2
    med = float(np.partition(z2, h)[h])  # the (upper) median of z^2
    keep = None
    if med > 0.0:
        bad = z2 > (gate / 1.1774100225154747) ** 2 * med
        if bad.any():
            keep = np.flatnonzero(~bad)
            b_S, r_N, a, ba = b_S[keep], r_N[keep], a[keep], ba[keep]
            C = wahba_dcm(b_S, r_N, a, ba)
            res = b_S - r_N @ C.T
            res2 = np.einsum("ij,ij->i", res, res)
    return _finish(b_S, a, ba, C, res2), keep


def attitude_error_S(q_est_SN, q_true_SN) -> np.ndarray:
    """Small rotation ``dtheta`` (rad, tracker axes, ``(..., 3)``) with
    ``dcm(q_est) = exp(-[dtheta x]) dcm(q_true)``: x, y cross-boresight, z roll."""
    from sim.rotations import dcm

    E = dcm(q_est_SN) @ np.swapaxes(dcm(q_true_SN), -1, -2)
    # exp(-[t x]) = I - [t x] + ...; [t x] = [[0, -tz, ty], [tz, 0, -tx], [-ty, tx, 0]]
    v = 0.5 * np.stack((E[..., 1, 2] - E[..., 2, 1], E[..., 2, 0] - E[..., 0, 2], E[..., 0, 1] - E[..., 1, 0]), -1)
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    c = (np.trace(E, axis1=-2, axis2=-1)[..., None] - 1.0) / 2.0
    ang = np.arctan2(s, c)
    return np.where(s > 0, v / np.where(s > 0, s, 1.0) * ang, 0.0)
