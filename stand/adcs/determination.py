"""Attitude determination: TRIAD, QUEST, and a multiplicative extended Kalman filter with gyro bias.

Conventions: ``q_BN`` scalar-first Hamilton, ``v_B = dcm(q_BN) @ v_N``; observation vectors ``*_B`` are
body-frame unit vectors, reference vectors ``*_N`` inertial (GCRS) unit vectors.

* :func:`triad`: the deterministic two-vector solution (Black 1964); the first pair is matched exactly.
* :func:`quest`: Shuster & Oh's QUEST (1981) for Wahba's problem with any number of weighted vectors:
  Newton-Raphson on Davenport's characteristic equation from lambda = sum of weights, then the optimal
  quaternion in closed form; near 180 deg (the closed form's singularity) Shuster's method of
  sequential rotations re-solves with the reference frame turned 180 deg about a body axis.
* :class:`MEKF`: the multiplicative EKF of Lefferts, Markley & Shuster (1982) as in Markley &
  Crassidis, *Fundamentals of Spacecraft Attitude Determination and Control* (2014), ch. 6: the state is
  the quaternion estimate and the gyro bias; the 6 x 6 covariance is of the attitude error ``a`` (rad,
  body axes: ``q = q_est (x) [1, a/2]``) and the bias error. Propagation uses the gyro rate minus the
  bias estimate (exact quaternion increment for a constant rate over the step), the closed-form error
  transition matrix and Farrenkopf's discrete process noise for angle random walk ``arw`` (rad/s^0.5)
  and rate random walk ``rrw`` (rad/s^1.5). Updates with a star-tracker quaternion or a unit vector use
  the Joseph form, and the covariance is symmetrised and checked after every step.

Every function refuses NaN or infinite inputs, zero vectors and degenerate geometry with one sentence
naming the argument.
"""

from __future__ import annotations

import math
from functools import partial

import numpy as np

from sim.rotations import canonical, compose, quat_from_dcm

from .quat import (
    Quat,
    Vec3,
    add,
    conj,
    dcm1,
    finite3,
    finite4,
    inv3,
    mv,
    norm,
    normalised,
    positive,
    qmul,
    rotation_vector,
    sub,
)

__all__ = ["MEKF", "FilterError", "quest", "triad"]


class FilterError(ValueError):
    """Input the estimator cannot use (NaN, zero vector, degenerate geometry, a covariance gone bad)."""


def _vectors(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.shape[-1:] != (3,):
        raise FilterError(f"{name} has shape {a.shape}; 3-vectors (..., 3) are expected.")
    if not np.all(np.isfinite(a)):
        raise FilterError(f"{name} = {a.tolist()} contains NaN or infinity.")
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    if np.any(n == 0.0):
        raise FilterError(f"{name} contains a zero vector; directions must be non-zero.")
    return a / n


def _skew(v) -> np.ndarray:
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def _quat(q, name: str) -> Quat:
    """``q`` normalised, as 4 floats; refused unless it is 4 finite numbers of norm within 1e-3 of 1."""
    (w, x, y, z), n = finite4(q, name, FilterError)
    if abs(n - 1.0) > 1e-3:
        raise FilterError(f"{name} has norm {n:.6g}; a unit quaternion is expected.")
    return w / n, x / n, y / n, z / n


#: Smallest sine of the angle between TRIAD's two vectors (0.57 deg): below it the second axis is noise.
TRIAD_MIN_SINE = 1e-2


def triad(b1_B, b2_B, r1_N, r2_N) -> np.ndarray:
    """``q_BN`` mapping ``r1_N`` exactly onto ``b1_B`` and ``r2_N`` as near ``b2_B`` as the pair allows."""
    b1, b2 = _vectors(b1_B, "b1_B"), _vectors(b2_B, "b2_B")
    r1, r2 = _vectors(r1_N, "r1_N"), _vectors(r2_N, "r2_N")
    for name, u, v in (("b1_B, b2_B", b1, b2), ("r1_N, r2_N", r1, r2)):
        s = float(np.linalg.norm(np.cross(u, v)))
        if s < TRIAD_MIN_SINE:
            raise FilterError(f"{name} are {math.degrees(math.asin(min(s, 1.0))):.3g} deg from parallel; TRIAD needs "
                              f"at least {math.degrees(math.asin(TRIAD_MIN_SINE)):.2g} deg between its two vectors.")

    def frame(u, v):
        t2 = np.cross(u, v)
        t2 /= np.linalg.norm(t2)
        return np.column_stack((u, t2, np.cross(u, t2)))

    return quat_from_dcm(frame(b1, b2) @ frame(r1, r2).T)


#: QUEST re-solves with a rotated reference frame when the closed form's scalar part falls below this
#: fraction of the quaternion's norm (the 180 deg singularity, Shuster's sequential rotations).
QUEST_ROTATE_BELOW = 0.1
QUEST_NEWTON_ITER = 50


def quest(b_B, r_N, weights=None) -> np.ndarray:
    """``q_BN`` minimising Wahba's loss ``sum a_i |b_i - dcm(q) r_i|^2`` (Shuster's QUEST).

    ``b_B``, ``r_N``: ``(n, 3)`` observed and reference directions (normalised here), ``n >= 2`` and not all
    parallel; ``weights``: ``n`` positive numbers (default equal).
    """
    b, r = _vectors(b_B, "b_B"), _vectors(r_N, "r_N")
    if b.ndim != 2 or b.shape != r.shape or b.shape[0] < 2:
        raise FilterError(f"b_B {b.shape} and r_N {r.shape} must both be (n, 3) with n >= 2 pairs.")
    a = np.ones(b.shape[0]) if weights is None else np.asarray(weights, dtype=float)
    if a.shape != (b.shape[0],) or not np.all(np.isfinite(a)) or np.any(a <= 0.0):
        raise FilterError(f"weights = {np.asarray(weights).tolist()}; give {b.shape[0]} finite positive weights.")
    if np.linalg.matrix_rank(b, tol=1e-6) < 2 or np.linalg.matrix_rank(r, tol=1e-6) < 2:
        raise FilterError("b_B or r_N are all parallel; QUEST needs at least two non-parallel directions.")
    q, ratio = _quest_once(b, r, a)
    if ratio >= QUEST_ROTATE_BELOW:
        return q
    best = (ratio, q)
    for k in range(3):
        # Turn the reference frame 180 deg about axis k: r' = R_k r, solve for A' = A R_k^T, then A = A' R_k.
        flip = np.ones(3)
        flip[[i for i in range(3) if i != k]] = -1.0
        qk, ratio_k = _quest_once(b, r * flip, a)
        if ratio_k > best[0]:
            e = np.zeros(4)
            e[1 + k] = 1.0
            best = (ratio_k, compose(qk, e))
    return canonical(best[1])


def _quest_once(b, r, a):
    B = (a[:, None] * b).T @ r
    S = B + B.T
    z = np.sum(a[:, None] * np.cross(b, r), axis=0)
    sigma = float(np.trace(B))
    # trace(adj S): the sum of the principal 2 x 2 minors (no inverse, so a singular S is fine).
    kappa = float(S[1, 1] * S[2, 2] - S[1, 2] * S[2, 1] + S[0, 0] * S[2, 2] - S[0, 2] * S[2, 0]
                  + S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0])
    delta = float(np.linalg.det(S))
    ca = sigma * sigma - kappa
    cb = sigma * sigma + z @ z
    cc = delta + z @ S @ z
    cd = z @ S @ S @ z
    lam = float(np.sum(a))
    for _ in range(QUEST_NEWTON_ITER):
        f = lam ** 4 - (ca + cb) * lam ** 2 - cc * lam + (ca * cb + cc * sigma - cd)
        df = 4.0 * lam ** 3 - 2.0 * (ca + cb) * lam - cc
        step = f / df if df != 0.0 else 0.0
        lam -= step
        if abs(step) <= 1e-15 * max(lam, 1.0):
            break
    alpha = lam * lam - sigma * sigma + kappa
    beta = lam - sigma
    gamma = (lam + sigma) * alpha - delta
    x = (alpha * np.eye(3) + beta * S + S @ S) @ z
    q = np.concatenate(([gamma], x))
    n = float(np.linalg.norm(q))
    # At 180 deg gamma and x both vanish (their size scales as lambda^3 otherwise) and their ratio is round-off.
    if not n > 1e-8 * lam ** 3:
        return np.array([1.0, 0.0, 0.0, 0.0]), 0.0
    return canonical(q / n), abs(gamma) / n


class MEKF:
    """Multiplicative EKF for ``q_BN`` and the gyro bias (rad/s, body axes).

    ``sigma_attitude_rad``, ``sigma_bias_rad_s``: initial 1-sigma per axis. ``arw_rad_s05`` (angle random walk,
    rad/s^0.5 = rad/sqrt(s)) and ``rrw_rad_s15`` (rate random walk, rad/s^1.5) describe the gyro:
    omega_meas = omega + bias + white noise, bias' = white noise.
    """

    def __init__(self, q_BN, bias_rad_s=(0.0, 0.0, 0.0), sigma_attitude_rad: float = 0.1,
                 sigma_bias_rad_s: float = 1e-4, arw_rad_s05: float = 1e-5, rrw_rad_s15: float = 1e-7):
        self.q: Quat = positive(_quat(q_BN, "q_BN"))
        self.bias: Vec3 = _finite3(bias_rad_s, "bias_rad_s")
        for name, v in (("sigma_attitude_rad", sigma_attitude_rad), ("sigma_bias_rad_s", sigma_bias_rad_s)):
            if not (math.isfinite(v) and v > 0.0):
                raise FilterError(f"{name} = {v!r}; it must be a finite positive 1-sigma.")
        for name, v in (("arw_rad_s05", arw_rad_s05), ("rrw_rad_s15", rrw_rad_s15)):
            if not (math.isfinite(v) and v >= 0.0):
                raise FilterError(f"{name} = {v!r}; it must be a finite noise density >= 0.")
        self.P = np.diag([sigma_attitude_rad ** 2] * 3 + [sigma_bias_rad_s ** 2] * 3)
        self.arw = float(arw_rad_s05)
        self.rrw = float(rrw_rad_s15)
        self.omega_B: Vec3 = (0.0, 0.0, 0.0)  # last bias-corrected rate (rad/s)
        self.updates = 0
        self.rejected = 0
        self._Q: dict[float, np.ndarray] = {}
        self._R_checked: tuple = (None, None)  # (the dtype and bytes of the caller's matrix, its checked copy)

    # -- outputs ------------------------------------------------------------------------------------
    @property
    def sigma3_attitude_rad(self) -> Vec3:
        """3-sigma of the attitude error per body axis (rad)."""
        d = self.P.diagonal().tolist()
        return 3.0 * math.sqrt(d[0]), 3.0 * math.sqrt(d[1]), 3.0 * math.sqrt(d[2])

    @property
    def sigma3_bias_rad_s(self) -> Vec3:
        d = self.P.diagonal().tolist()
        return 3.0 * math.sqrt(d[3]), 3.0 * math.sqrt(d[4]), 3.0 * math.sqrt(d[5])

    # -- propagation --------------------------------------------------------------------------------
    def propagate(self, omega_meas_B, dt_s: float) -> None:
        """Advance ``dt_s`` seconds with the gyro rate ``omega_meas_B`` (rad/s, body axes) held over the step."""
        if not (math.isfinite(dt_s) and dt_s >= 0.0):
            raise FilterError(f"dt_s = {dt_s!r}; the propagation step must be a finite number of seconds >= 0.")
        w = sub(_finite3(omega_meas_B, "omega_meas_B"), self.bias)
        self.omega_B = w
        if dt_s == 0.0:
            return
        wn = norm(w)
        half = 0.5 * wn * dt_s
        # sin(x)/x with its series near 0, so a zero rate is exact and never divides by zero.
        s = 0.5 * dt_s * (1.0 - half * half / 6.0) if half < 1e-4 else math.sin(half) / wn
        self.q = positive(normalised(qmul(self.q, (math.cos(half), s * w[0], s * w[1], s * w[2]))))
        Phi = _transition(w, wn, dt_s)
        Q = self._Q.get(dt_s)
        if Q is None:
            v2, u2 = self.arw ** 2, self.rrw ** 2
            Q = np.zeros((6, 6))
            Q[:3, :3] = (v2 * dt_s + u2 * dt_s ** 3 / 3.0) * _EYE3
            Q[:3, 3:] = Q[3:, :3] = -(u2 * dt_s ** 2 / 2.0) * _EYE3
            Q[3:, 3:] = u2 * dt_s * _EYE3
            if len(self._Q) < 64:  # a loop uses one or two step lengths
                self._Q[dt_s] = Q
        self._set_P(Phi @ self.P @ Phi.T + Q, "propagation")

    # -- updates ------------------------------------------------------------------------------------
    def update_attitude(self, q_BN_meas, R_B, gate_sigma: float | None = None, gate_slack_rad2: float = 0.0) -> bool:
        """Update with a measured ``q_BN`` (e.g. a star tracker's, through its mount) whose error has covariance
        ``R_B`` (rad^2, body axes: 3 x 3, or 3 variances, or one variance). With ``gate_sigma``, a measurement
        whose residual exceeds that many sigma (chi-square on 3 dof) is rejected and counted; returns whether used.
        ``gate_slack_rad2`` (rad^2) is added to each axis's variance for the gate only (not the update): the error
        the model leaves out, such as a solution's age times the body rate.
        """
        qm = _quat(q_BN_meas, "q_BN_meas")
        z = rotation_vector(qmul(conj(self.q), qm))  # the residual's rotation vector
        src, checked = self._R_checked
        # A controller passes the same matrix every period: its checks (an eigenvalue solve) run once. The key is
        # the matrix's bytes with its type and shape: the same bytes are the same numbers (a -0.0 for a 0.0, or
        # another dtype, only costs a check again; a matrix with a NaN is refused, never kept).
        key = (R_B.dtype.str, R_B.tobytes()) if isinstance(R_B, np.ndarray) and R_B.shape == (3, 3) else None
        if key is None or key != src:
            checked = _covariance(R_B, "R_B")
            if key is not None:
                self._R_checked = (key, checked)
        return self._update(np.array(z), None, checked, gate_sigma, gate_slack_rad2)

    def update_vector(self, b_B, r_N, sigma_rad: float, gate_sigma: float | None = None) -> bool:
        """Update with a measured unit direction ``b_B`` of the reference direction ``r_N`` (sun, field), with
        1-sigma ``sigma_rad`` per axis across the direction."""
        b, r = _vectors(b_B, "b_B"), _vectors(r_N, "r_N")
        if not (math.isfinite(sigma_rad) and sigma_rad > 0.0):
            raise FilterError(f"sigma_rad = {sigma_rad!r}; it must be a finite positive 1-sigma.")
        pred = np.array(mv(dcm1(self.q), r))
        H = np.zeros((3, 6))
        H[:, :3] = _skew(pred)
        # The unit-vector noise lies across the direction; the small along-axis term keeps R invertible.
        R = sigma_rad ** 2 * (np.eye(3) - np.outer(pred, pred)) + (1e-3 * sigma_rad) ** 2 * np.eye(3)
        return self._update(b - pred, H, R, gate_sigma)

    def _update(self, z, H, R, gate_sigma, gate_slack_rad2: float = 0.0) -> bool:
        """The Kalman update with residual ``z``, measurement matrix ``H`` (None: an attitude measurement, ``[I 0]``,
        whose products are slices of P: the same numbers without the matrix products) and covariance ``R``."""
        P = self.P
        PHt = P[:, :3] if H is None else P @ H.T
        S = (PHt[:3] if H is None else H @ PHt) + R
        Sinv = np.array(inv3(S.tolist()))  # 3 x 3 by its adjugate: np.linalg.inv costs more than the arithmetic
        if gate_sigma is not None:
            limit = gate_sigma ** 2 * len(z)
            # The slack only widens the gate: a residual inside it without the slack needs no second inverse.
            if float(z @ Sinv @ z) > limit and (
                    gate_slack_rad2 <= 0.0
                    or float(z @ np.array(inv3((S + gate_slack_rad2 * _EYE3).tolist())) @ z) > limit):
                self.rejected += 1
                return False
        K = PHt @ Sinv
        dx = (K @ z).tolist()
        if H is None:
            IKH = _EYE6.copy()
            IKH[:, :3] -= K
        else:
            IKH = _EYE6 - K @ H
        self._set_P(IKH @ P @ IKH.T + K @ R @ K.T, "update")  # Joseph form
        self.q = positive(normalised(qmul(self.q, (1.0, 0.5 * dx[0], 0.5 * dx[1], 0.5 * dx[2]))))
        self.bias = add(self.bias, dx[3:])
        self.updates += 1
        return True

    def _set_P(self, P, where: str) -> None:
        P = 0.5 * (P + P.T)
        d = P.diagonal().tolist()
        # min() of floats after the finite check: the same test as numpy's min of the diagonal, without a reduction.
        if not np.isfinite(P).all() or min(d) <= 0.0:
            raise FilterError(f"the MEKF covariance lost positive definiteness in the {where} (diagonal "
                              f"{d}); check the noise settings and the measurement covariances.")
        self.P = P


_EYE3 = np.eye(3)
_EYE6 = np.eye(6)


def _transition(w: Vec3, wn: float, dt_s: float) -> np.ndarray:
    """The 6 x 6 error transition over ``dt_s`` at the constant rate ``w`` (``wn = |w|``): ``[[Phi11, Phi12], [0, I]]``,
    each block ``a I + b [w x] + c [w x]^2`` (Markley & Crassidis eq. 6.83; its series for small angles)."""
    th = wn * dt_s
    if th < 1e-4:
        Phi11 = _skew_poly(w, 1.0, -dt_s, 0.5 * dt_s ** 2)
        Phi12 = _skew_poly(w, -dt_s, 0.5 * dt_s ** 2, -(dt_s ** 3 / 6.0))
    else:
        c = (1.0 - math.cos(th)) / wn ** 2
        Phi11 = _skew_poly(w, 1.0, -(math.sin(th) / wn), c)
        Phi12 = _skew_poly(w, -dt_s, c, -((th - math.sin(th)) / wn ** 3))
    return np.array([(*Phi11[0], *Phi12[0]), (*Phi11[1], *Phi12[1]), (*Phi11[2], *Phi12[2]),
                     (0.0, 0.0, 0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 0.0, 0.0, 1.0)])


def _skew_poly(w: Vec3, a: float, b: float, c: float):
    """``a I + b [w x] + c [w x]^2`` as three rows (``[w x]^2 = w w^T - |w|^2 I``, written out)."""
    x, y, z = w
    return ((a - c * (y * y + z * z), -b * z + c * x * y, b * y + c * x * z),
            (b * z + c * x * y, a - c * (x * x + z * z), -b * x + c * y * z),
            (-b * y + c * x * z, b * x + c * y * z, a - c * (x * x + y * y)))


#: ``_finite3(v, name)``: ``v`` as 3 finite floats, else a FilterError naming ``name`` (a partial: no wrapper's call).
_finite3 = partial(finite3, error=FilterError)


def _covariance(R, name: str) -> np.ndarray:
    a = np.asarray(R, dtype=float)
    if a.shape in ((), (1,)):
        a = np.eye(3) * float(a)
    elif a.shape == (3,):
        a = np.diag(a)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        raise FilterError(f"{name} must be a variance, 3 variances or a 3 x 3 covariance (rad^2), finite.")
    a = 0.5 * (a + a.T)
    if np.linalg.eigvalsh(a)[0] <= 0.0:
        raise FilterError(f"{name} = {a.tolist()} is not positive definite.")
    return a
