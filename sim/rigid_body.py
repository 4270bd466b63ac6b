"""The rigid body: inertia checks, Euler's equations with quaternion kinematics, RK4, step limits.

State: ``q_BN`` (scalar-first unit quaternion, body B relative to inertial N) and ``omega_BN_B``
(rad/s, body components). Equations:

    I domega/dt = tau - omega x (I omega)
    dq/dt = 0.5 * q (x) [0, omega]

:class:`RigidBody` works on Python floats, not numpy arrays: for 3-vectors a numpy call costs
about a microsecond of overhead, more than the arithmetic, and a step runs tens of thousands of
times per simulated orbit. :func:`sim.attitude.propagate` wraps it with numpy in and out.

Accuracy guard: an explicit integrator on a spinning body is accurate only while the rotation per
step and the nutation phase per step are small. :func:`max_step_s` gives the largest step for a
body rate and :func:`check_step` refuses a larger one with a message naming the limit rather than
letting a silently wrong attitude through (RK4 is 160 deg wrong just below its stability limit).

This module sits below :mod:`sim.integrators` and :mod:`sim.attitude` (which re-exports its names)
and imports neither, so the imports between the three go one way.
"""

from __future__ import annotations

import math

import numpy as np

import compiled_paths

#: Euler's equations, RK4 and the environment's torques on floats: compiled where the install could.
_step = compiled_paths.load("sim.body_step")
#: The error every fixed-step stepper raises when its new state at ``t`` (s) is not finite.
non_finite_state = _step.non_finite_state

#: Largest rotation (and nutation phase) per RK4 step, rad. At 0.1 rad per step the local error
#: of RK4 is ~(0.1)^5/120 ~ 1e-7 rad, so a 10^5-step run stays at the 1e-3 deg level.
MAX_ANGLE_PER_STEP_RAD = 0.1


def check_inertia(inertia, name: str = "inertia_kg_m2", triangle: bool = True) -> np.ndarray:
    """Return a validated 3x3 inertia matrix (kg m^2) from a 3-vector of principal moments or 3x3.

    Refuses, with the field name and the value: non-finite, non-symmetric, not positive definite,
    and principal moments that violate the triangle inequality (I1 + I2 >= I3 for every
    permutation: no physical body does; equality, a flat plate, is accepted). ``triangle=False``
    skips only that last test, for the inertia of a body with its wheels' spin inertia taken out
    (:mod:`sim.wheels`), which is a matrix of the equations rather than of one rigid body.
    """
    I = np.asarray(inertia, dtype=float)
    if I.shape == (3,):
        I = np.diag(I)
    if I.shape != (3, 3):
        raise ValueError(f"{name} must be 3 principal moments or a 3x3 matrix; got shape {I.shape}.")
    if not np.all(np.isfinite(I)):
        raise ValueError(f"{name} = {I.tolist()} contains NaN or infinity.")
    scale = float(np.max(np.abs(I))) or 1.0
    if np.max(np.abs(I - I.T)) > 1e-9 * scale:
        raise ValueError(f"{name} = {I.tolist()} is not symmetric; an inertia matrix must be.")
    moments = np.linalg.eigvalsh(I)
    if moments[0] <= 0.0:
        raise ValueError(
            f"{name} has principal moments {moments.tolist()} kg m^2; all must be positive."
        )
    if triangle and moments[0] + moments[1] < moments[2] * (1.0 - 1e-12):
        raise ValueError(
            f"{name} has principal moments {moments.tolist()} kg m^2, which violate the triangle "
            f"inequality: {moments[0]:.6g} + {moments[1]:.6g} < {moments[2]:.6g}. No rigid body has "
            "such an inertia; the smallest two must add up to at least the largest (a flat plate "
            "is the limit)."
        )
    return I


def nutation_rate(inertia, omega, triangle: bool = True) -> float:
    """Upper estimate (rad/s) of the body-frame nutation frequency for rate ``omega``.

    For a torque-free body spinning near principal axis k the body-frame nutation frequency is
    ``|omega| sqrt((Ik - Ii)(Ik - Ij) / (Ii Ij))``; the maximum over the three axes bounds it.
    """
    m = np.sort(np.linalg.eigvalsh(check_inertia(inertia, triangle=triangle)))
    w = float(np.linalg.norm(omega))
    rates = []
    for k in range(3):
        i, j = [a for a in range(3) if a != k]
        rates.append(math.sqrt(abs((m[k] - m[i]) * (m[k] - m[j])) / (m[i] * m[j])))
    return w * max(rates)


def gyroscopic_rate(inertia, h_wheels_B, triangle: bool = True) -> float:
    """Upper estimate (rad/s) of the nutation frequency that wheel momentum ``h_wheels_B`` (N m s, body axes)
    gives the body: ``|h| / I_min``.

    Linearised about rest, I domega/dt = -omega x h has frequency ``|h| / sqrt(Ii Ij)`` for h along
    principal axis k; ``|h| / I_min`` bounds it for any direction.
    """
    if h_wheels_B is None:
        return 0.0
    h = float(np.linalg.norm(h_wheels_B))
    return h / float(np.linalg.eigvalsh(check_inertia(inertia, triangle=triangle))[0]) if h else 0.0


def max_step_s(inertia, omega, max_angle_rad: float = MAX_ANGLE_PER_STEP_RAD, h_wheels_B=None,
               triangle: bool = True) -> float:
    """Largest RK4 step (s) that keeps rotation and nutation phase per step below ``max_angle_rad``.

    ``h_wheels_B`` (N m s, body axes): the wheels' spin momentum, whose gyroscopic stiffness adds
    :func:`gyroscopic_rate` to the body's own nutation frequency.
    """
    nut = nutation_rate(inertia, omega, triangle) + gyroscopic_rate(inertia, h_wheels_B, triangle)
    fastest = max(float(np.linalg.norm(omega)), nut)
    return math.inf if fastest == 0.0 else max_angle_rad / fastest


def check_step_value(step_s, name: str = "step_s") -> None:
    """Refuse an integration step that is not a positive, finite number of seconds."""
    if not (isinstance(step_s, int | float) and math.isfinite(step_s) and step_s > 0):
        raise ValueError(f"{name} = {step_s!r}; the integration step must be a positive number of seconds.")


def check_step(inertia, omega, step_s: float, name: str = "step_s", max_angle_rad: float = MAX_ANGLE_PER_STEP_RAD,
               method: str = "RK4", h_wheels_B=None, triangle: bool = True) -> None:
    """Raise ``ValueError`` naming the limit when ``step_s`` is too large for rate ``omega`` (and wheel
    momentum ``h_wheels_B``, N m s body axes, when the body carries wheels)."""
    check_step_value(step_s, name)
    limit = max_step_s(inertia, omega, max_angle_rad, h_wheels_B, triangle)
    if step_s > limit:
        w = float(np.linalg.norm(omega))
        wheels = "" if h_wheels_B is None else (
            f" and a wheel momentum of {float(np.linalg.norm(h_wheels_B)):.6g} N m s (gyroscopic rate "
            f"{gyroscopic_rate(inertia, h_wheels_B, triangle):.6g} rad/s)")
        raise ValueError(
            f"{name} = {step_s:g} s is too large for a body rate of {w:.6g} rad/s "
            f"({math.degrees(w):.4g} deg/s){wheels}: {method} stays accurate only while the rotation and nutation "
            f"phase per step are at most {max_angle_rad:g} rad, i.e. {name} <= {limit:.3g} s "
            "here. Use a smaller step."
        )


class RigidBody:
    """Euler's equations and an RK4 step on plain floats for one inertia matrix.

    ``derivatives(q, w, tau) -> (dq/dt, domega/dt)`` (float tuples for quaternion q, rate w and torque tau) and
    ``rk4_step(q, w, h, torque=None, t=0.0) -> (q, w)`` (one classical RK4 step of length ``h``, the torque
    ``torque(t, q, w) -> (tx, ty, tz)`` in N m, body frame, re-evaluated at every stage; the quaternion
    renormalised; q and w tuples) are those of ``sim.body_step.BodyDynamics`` (``dynamics``), the one source of the
    attitude step, compiled where the install could (docs/fast_paths.md).
    """

    def __init__(self, inertia, triangle: bool = True):
        I = check_inertia(inertia, triangle=triangle)
        Ii = np.linalg.inv(I)
        self.inertia = I
        self.inertia_inv = Ii
        self._I = tuple(float(x) for x in I.ravel())
        self._Ii = tuple(float(x) for x in Ii.ravel())
        self.dynamics = _step.BodyDynamics(self._I, self._Ii)
        self.derivatives = self.dynamics.derivatives
        self.rk4_step = self.dynamics.rk4


def check_finite_state(q, w, t: float, h: float) -> None:
    """Raise :func:`non_finite_state` unless every component of ``q`` and ``w`` is finite."""
    if not all(math.isfinite(x) for x in q) or not all(math.isfinite(x) for x in w):
        raise non_finite_state(t, h)


def angular_momentum_B(inertia, omega_BN_B) -> np.ndarray:
    """Angular momentum ``I omega`` (N m s, body components)."""
    return np.einsum("ij,...j->...i", check_inertia(inertia), np.asarray(omega_BN_B, dtype=float))


def kinetic_energy(inertia, omega_BN_B) -> np.ndarray:
    """Rotational kinetic energy 0.5 omega . I omega (J)."""
    w = np.asarray(omega_BN_B, dtype=float)
    return 0.5 * np.sum(w * angular_momentum_B(inertia, w), axis=-1)
