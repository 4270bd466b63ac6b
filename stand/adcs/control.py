"""Attitude control: error kinematics, MRP and quaternion feedback with gyroscopic compensation, wheel torque
distribution with null-space momentum management, and magnetic momentum dumping.

Frames: B body, R reference (guidance), N inertial. ``q_BR = compose(q_BN, conjugate(q_RN))`` is the
attitude error; ``omega_BR_B = omega_BN_B - dcm(q_BR) @ omega_RN_R``.

Control law (Schaub & Junkins, *Analytical Mechanics of Space Systems*, ch. 8, the MRP feedback law with
the reaction-wheel gyroscopic term; Wie, *Space Vehicle Dynamics and Control*, ch. 7, for the quaternion
form): the torque the body needs is

    u_B = -K e - P omega_BR_B + omega x (I omega + A J Omega)
          + I (domega_RN_B/dt - omega x omega_RN_B)

with ``e`` = the error MRP ``sigma_BR`` (``"mrp"``, shadow set so |sigma| <= 1: the short way round) or
``2 sign(q0) q_vec`` (``"quaternion"``). ``K``, ``P`` are gains (scalar or 3 x 3); :func:`pd_gains` designs
them from a natural frequency and damping ratio (linearised: MRP ~ angle / 4, 2 q_vec ~ angle).

Wheels give the body ``-A u`` for motor torques ``u`` (N m on each rotor); :class:`WheelDistribution` solves
``-A u = u_B`` with the minimum-norm pseudo-inverse and adds a null-space term (four or more wheels) that
drives the wheel speeds towards a bias speed without torquing the body, then scales the whole vector
down if a wheel would exceed its torque limit (the direction of the body torque is kept).

Momentum dumping (:func:`dumping_dipole`): ``m = k (h_err x b) / |b|^2`` gives the magnetic torque
``m x b = -k h_err_perp``: the component of the excess wheel momentum across the field is removed
(the component along the field cannot be, at this instant).
"""

from __future__ import annotations

import math
from functools import partial
from operator import truediv

import numpy as np

from sim.rotations import canonical, compose, conjugate

from .quat import Vec3, add, cross, dcm1, dot, error, finite3, finite4, mv, scale, sub

__all__ = ["WheelDistribution", "attitude_error", "control_torque", "dumping_dipole", "mrp", "pd_gains"]

LAWS = ("mrp", "quaternion")


class ControlError(ValueError):
    """Control input that cannot be used (NaN, wrong shape, bad gains)."""


#: ``_vec(v, name)``: ``v`` as 3 finite floats, else a ControlError naming ``name`` (finite3 with this module's error;
#: a partial, not a wrapper function: five of these a period, each a Python call less).
_vec = partial(finite3, error=ControlError)


def check_gain(g, name: str) -> np.ndarray:
    """A gain as a 3 x 3 matrix from a positive scalar, 3 positive values or a positive definite matrix."""
    a = np.asarray(g, dtype=float)
    a = np.eye(3) * float(a) if a.ndim == 0 else (np.diag(a) if a.shape == (3,) else a)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)) or np.linalg.eigvalsh(0.5 * (a + a.T))[0] <= 0.0:
        raise ControlError(f"{name} must be a positive scalar, 3 positive values or a positive definite 3 x 3 matrix.")
    return a


def _gain(g, name: str) -> np.ndarray:
    # A 3 x 3 array is taken as already checked (pd_gains and check_gain return them): this runs every period.
    if isinstance(g, np.ndarray) and g.shape == (3, 3):
        return g
    return check_gain(g, name)


def attitude_error(q_BN, q_RN) -> np.ndarray:
    """``q_BR`` (w >= 0): the body's attitude relative to the reference."""
    return compose(q_BN, conjugate(q_RN))


def mrp(q) -> np.ndarray:
    """Modified Rodrigues parameters of ``q`` (shadow set chosen so |sigma| <= 1, the short rotation)."""
    q = canonical(np.asarray(q, dtype=float))
    return q[1:] / (1.0 + q[0])


def pd_gains(inertia, natural_frequency_rad_s: float, damping_ratio: float = 0.9, law: str = "mrp"):
    """``(K, P)`` matrices giving each principal axis the natural frequency and damping ratio (small errors)."""
    if law not in LAWS:
        raise ControlError(f"law = {law!r}; allowed: {', '.join(LAWS)}.")
    wn, zeta = float(natural_frequency_rad_s), float(damping_ratio)
    if not (math.isfinite(wn) and wn > 0.0 and math.isfinite(zeta) and zeta > 0.0):
        raise ControlError(f"natural_frequency_rad_s = {natural_frequency_rad_s!r} and damping_ratio = "
                           f"{damping_ratio!r} must be finite and positive.")
    I = np.asarray(inertia, dtype=float)
    I = np.diag(I) if I.shape == (3,) else I
    scale = 4.0 if law == "mrp" else 1.0  # error ~ angle / 4 (MRP) or ~ angle (2 q_vec)
    return scale * wn * wn * I, 2.0 * zeta * wn * I


def control_torque(q_BN, omega_BN_B, q_RN, omega_RN_R, inertia, K, P, h_wheels_B=(0.0, 0.0, 0.0),
                   domega_RN_R=(0.0, 0.0, 0.0), law: str = "mrp") -> Vec3:
    """The torque ``u_B`` (N m, body) that makes the body track the reference; see the module docstring.

    ``h_wheels_B``: the wheels' momentum ``A J Omega`` (N m s, body), for the gyroscopic compensation.
    """
    if law not in LAWS:
        raise ControlError(f"law = {law!r}; allowed: {', '.join(LAWS)}.")
    w = _vec(omega_BN_B, "omega_BN_B")
    I = np.asarray(inertia, dtype=float)
    I = (np.diag(I) if I.shape == (3,) else I).tolist()
    q_BR = error(_unit4(q_BN, "q_BN"), _unit4(q_RN, "q_RN"))
    C_BR = dcm1(q_BR)
    w_RN_B = mv(C_BR, _vec(omega_RN_R, "omega_RN_R"))
    dw = sub(w, w_RN_B)
    d = 1.0 + q_BR[0]  # w >= 0: the short way round
    e = (q_BR[1] / d, q_BR[2] / d, q_BR[3] / d) if law == "mrp" else scale(2.0, q_BR[1:])
    H = add(mv(I, w), _vec(h_wheels_B, "h_wheels_B"))
    feedback = sub(scale(-1.0, mv(_gain(K, "K").tolist(), e)), mv(_gain(P, "P").tolist(), dw))
    return add(add(feedback, cross(w, H)),
               mv(I, sub(mv(C_BR, _vec(domega_RN_R, "domega_RN_R")), cross(w, w_RN_B))))


def _unit4(q, name: str) -> tuple[float, float, float, float]:
    q, n = finite4(q, name, ControlError)
    if abs(n - 1.0) > 1e-6:
        raise ControlError(f"{name} has norm {n:.9g}; a unit quaternion is required.")
    return q


class WheelDistribution:
    """Motor torques of ``n >= 3`` wheels (spin axes as columns of ``spin_axes_B``, 3 x n) for a body torque."""

    def __init__(self, spin_axes_B, max_torque_Nm=None):
        A = np.asarray(spin_axes_B, dtype=float)
        if A.ndim != 2 or A.shape[0] != 3 or not np.all(np.isfinite(A)):
            raise ControlError(f"spin_axes_B has shape {A.shape}; it must be 3 x n finite spin axes (columns).")
        if np.linalg.matrix_rank(A, tol=1e-9) < 3:
            raise ControlError(f"spin axes {A.T.tolist()} do not span three dimensions; the wheels cannot control "
                               "every axis.")
        self.A = A / np.linalg.norm(A, axis=0)
        self.n = A.shape[1]
        self.pinv = np.linalg.pinv(self.A)
        self._neg_pinv_rows = tuple(tuple(row) for row in (-self.pinv).tolist())  # u = -pinv @ torque, row by row
        _, _, Vt = np.linalg.svd(self.A)
        self.null = Vt[3:].T  # n x (n - 3) orthonormal basis of A's null space
        if max_torque_Nm is None:
            self.max_torque = None
        else:
            m = np.broadcast_to(np.asarray(max_torque_Nm, dtype=float), (self.n,)).copy()
            if not np.all(np.isfinite(m)) or np.any(m <= 0.0):
                raise ControlError(f"max_torque_Nm = {max_torque_Nm!r}; give finite positive limits (N m).")
            self.max_torque = m
        self._max_torque_list = None if self.max_torque is None else self.max_torque.tolist()

    def motor_torques(self, torque_B, speeds_rad_s=None, inertia_kg_m2=None, speed_target_rad_s=0.0,
                      null_gain_per_s: float = 0.0) -> np.ndarray:
        """Motor torques ``u`` (N m per rotor) with ``-A u = torque_B`` (before the limit scaling)."""
        t = _vec(torque_B, "torque_B")
        u = []
        for row in self._neg_pinv_rows:  # a loop, not a comprehension: no frame of its own each period (Python 3.11)
            u.append(dot(row, t))
        if null_gain_per_s > 0.0 and self.null.shape[1] and speeds_rad_s is not None:
            speeds = np.asarray(speeds_rad_s, dtype=float)
            J = np.broadcast_to(np.asarray(inertia_kg_m2, dtype=float), (self.n,))
            if speeds.shape != (self.n,) or not np.all(np.isfinite(speeds)):
                raise ControlError(f"speeds_rad_s = {np.asarray(speeds_rad_s).tolist()}; {self.n} speeds needed.")
            # A rotor torque in the null space changes the wheel momenta without torquing the body.
            want = -null_gain_per_s * J * (speeds - speed_target_rad_s)
            u = (np.array(u) + self.null @ (self.null.T @ want)).tolist()
        if self._max_torque_list is not None:
            # One limit per wheel (both lists have n items); map, not a generator: no frame resumed per wheel.
            ratio = max(map(truediv, map(abs, u), self._max_torque_list))
            if ratio > 1.0:
                u = [x / ratio for x in u]
        return np.array(u)

    def body_torque(self, motor_torques) -> np.ndarray:
        return -self.A @ np.asarray(motor_torques, dtype=float)

    def momentum_B(self, speeds_rad_s, inertia_kg_m2) -> np.ndarray:
        """Wheel momentum ``A J Omega`` (N m s, body axes)."""
        return self.A @ (np.asarray(inertia_kg_m2, dtype=float) * np.asarray(speeds_rad_s, dtype=float))


def dumping_dipole(b_B, h_err_B, gain_per_s: float, max_dipole_A_m2: float | None = None) -> Vec3:
    """Magnetorquer dipole (A m^2, body) that removes the excess wheel momentum ``h_err_B`` across the field.

    ``m = k (h_err x b) / |b|^2``; the torque ``m x b = -k (h_err - b (b . h_err) / |b|^2)``. Scaled down as a
    whole so no axis exceeds ``max_dipole_A_m2``.
    """
    b = _vec(b_B, "b_B")
    bb = dot(b, b)
    if bb == 0.0:
        raise ControlError("b_B is zero; no dipole can dump momentum without a field.")
    if not (math.isfinite(gain_per_s) and gain_per_s >= 0.0):
        raise ControlError(f"gain_per_s = {gain_per_s!r}; it must be finite and >= 0.")
    m = tuple(gain_per_s * c / bb for c in cross(_vec(h_err_B, "h_err_B"), b))
    if max_dipole_A_m2 is not None:
        peak = max(abs(c) for c in m)
        if peak > max_dipole_A_m2:
            m = scale(max_dipole_A_m2 / peak, m)
    return m
