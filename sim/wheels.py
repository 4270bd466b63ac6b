"""Reaction wheels in the rigid-body equations: a gyrostat with wheel speeds in the state.

Model. ``n`` balanced wheels with unit spin axes ``A`` (3 x n, columns in body axes) and spin
inertias ``J`` (kg m^2). ``inertia`` is the whole spacecraft's inertia (kg m^2, body axes, wheels
included as if locked), the one a mass-properties sheet gives. Wheel speeds ``Omega`` (rad/s) are
relative to the body, as a tachometer reads them. Total angular momentum (body components):

    H_B = I omega + A J Omega

With ``I_s = I - A J A^T`` (the spin inertias taken out) and the wheels' absolute spin momenta
``h = J (Omega + A^T omega)``, H_B = I_s omega + A h and the equations are (Schaub & Junkins,
*Analytical Mechanics of Space Systems*, sec. 4.5, the gyrostat with reaction wheels; Hughes,
*Spacecraft Attitude Dynamics*, ch. 3):

    I_s domega/dt = -omega x (I_s omega + A h) - A tau + T_ext
    dh/dt = tau

where ``tau`` (N m, one per wheel) is the net torque on each rotor about its spin axis: motor torque
minus bearing friction, which the motor model (:class:`sim.actuators.ReactionWheel` and its
motor) computes. ``tau`` is held over each step (zero-order hold, as the dipole is), so within a
step ``h(t) = h0 + tau t`` exactly; only the body rate and attitude are integrated, with the wheel
terms added to the torque at every stage. Any fixed-step method of :mod:`sim.integrators` runs on
it unchanged. The wheel torques are internal: they move momentum between rotors and body and add
none, so the inertial total momentum drifts only by the integrator's truncation error (with RK4 it
falls 16-fold when the step halves; tests/sim/test_wheels.py).

The step guard counts the wheels: their momentum stiffens the body gyroscopically, with a
nutation frequency up to ``|A h| / I_min`` (:func:`sim.rigid_body.gyroscopic_rate`).

Rotor angles are not in the state (balanced wheels exert no torque that depends on them).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

import compiled_paths

from .integrators import check_method, max_angle_rad, stepper
from .rigid_body import RigidBody, check_inertia, check_step, check_step_value, max_step_s
from .rotations import check_unit

__all__ = ["WheelCluster", "WheeledBody", "angular_momentum_B", "kinetic_energy", "propagate"]

#: The wheels' terms of the attitude step (their stage torque, which the compiled RK4 step calls at C level, ``A @
#: values``, the momentum update, the step guard's rate): beside that step in sim.body_step, compiled where built.
_body_step = compiled_paths.load("sim.body_step")


class WheelCluster:
    """Spin axes ``spin_axes_B`` (3 x n: one unit column per wheel, body axes) and spin inertias
    ``inertia_kg_m2`` (n values, kg m^2). Three orthogonal wheels are ``numpy.eye(3)``; a four-wheel
    pyramid has four columns tilted from its axis."""

    def __init__(self, spin_axes_B, inertia_kg_m2):
        A = np.asarray(spin_axes_B, dtype=float)
        if A.ndim != 2 or A.shape[0] != 3 or A.shape[1] < 1:
            raise ValueError(f"spin_axes_B has shape {A.shape}; it must be 3 x n, one spin axis per column "
                             "(body axes).")
        if not np.all(np.isfinite(A)):
            raise ValueError(f"spin_axes_B = {A.tolist()} contains NaN or infinity.")
        norms = np.linalg.norm(A, axis=0)
        if np.max(np.abs(norms - 1.0)) > 1e-9:
            raise ValueError(f"spin_axes_B has column norms {norms.tolist()}; every spin axis must be a unit vector "
                             "(|norm - 1| <= 1e-9).")
        J = np.atleast_1d(np.asarray(inertia_kg_m2, dtype=float))
        if J.shape != (A.shape[1],):
            raise ValueError(f"inertia_kg_m2 has {J.size} values for {A.shape[1]} wheels; give one spin inertia "
                             "per wheel.")
        if not np.all(np.isfinite(J)) or np.any(J <= 0.0):
            raise ValueError(f"inertia_kg_m2 = {J.tolist()} kg m^2; every spin inertia must be finite and positive.")
        self.spin_axes_B = A
        self.inertia = J
        self.n = A.shape[1]

    def hub_inertia(self, inertia) -> np.ndarray:
        """``I_s = I - A J A^T``: the spacecraft inertia with the wheels' spin inertia taken out."""
        I = check_inertia(inertia)
        Is = I - (self.spin_axes_B * self.inertia) @ self.spin_axes_B.T
        if np.linalg.eigvalsh(Is)[0] <= 1e-9 * float(np.max(np.abs(I))):
            raise ValueError(f"inertia_kg_m2 = {I.tolist()} is too small for wheels of spin inertia "
                             f"{self.inertia.tolist()} kg m^2: with their spin inertia taken out nothing is left; "
                             "the spacecraft inertia must include the wheels.")
        return Is

    def absolute_momentum(self, speeds_rad_s, omega_BN_B) -> np.ndarray:
        """Wheel spin momenta ``J (Omega + A^T omega)`` (N m s), ``(..., n)``."""
        w = np.asarray(omega_BN_B, dtype=float)
        return self.inertia * (np.asarray(speeds_rad_s, dtype=float) + w @ self.spin_axes_B)

    def speeds(self, h_abs, omega_BN_B) -> np.ndarray:
        """Wheel speeds relative to the body (rad/s) from absolute spin momenta ``h_abs`` (N m s)."""
        return np.asarray(h_abs, dtype=float) / self.inertia - np.asarray(omega_BN_B, dtype=float) @ self.spin_axes_B


def _check_vector(v, n: int, name: str, unit: str) -> tuple:
    a = np.atleast_1d(np.asarray(v, dtype=float)).ravel()
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} = {v!r}; it must be {n} finite values in {unit}.")
    return tuple(float(x) for x in a)


class WheeledBody:
    """The gyrostat's equations bound once for one spacecraft inertia and one wheel cluster.

    :meth:`step` advances ``(q_BN, omega_BN_B, h_abs)`` by one step with the wheel torques held;
    it is what :class:`sim.truth.TruthModel` and :func:`propagate` call.
    """

    def __init__(self, inertia, wheels: WheelCluster, method: str = "rk4"):
        self.wheels = wheels
        self.inertia = check_inertia(inertia)
        self.hub = RigidBody(wheels.hub_inertia(inertia), triangle=False)
        self.method = check_method(method)
        self.max_angle = max_angle_rad(method)
        self._step = stepper(self.hub, method)
        self._A = tuple(tuple(float(x) for x in col) for col in wheels.spin_axes_B.T)  # per wheel (ax, ay, az)
        self._J = tuple(float(x) for x in wheels.inertia)
        eig = np.linalg.eigvalsh(self.hub.inertia)
        self._inv_imin = 1.0 / float(eig[0])
        self._nutation_per_rate = _nutation_per_rate(self.hub.inertia)

    def axes_sum(self, values) -> tuple:
        """``A @ values`` on floats (3 components); ValueError unless one value per wheel."""
        return _body_step.axes_sum(self._A, values)

    def step(self, q, w, h_abs, tau, dt: float, torque: Callable | None = None, t: float = 0.0):
        """One step of length ``dt`` (s) with net wheel torques ``tau`` (N m per wheel) held.

        ``torque(t, q, w)``: external torque (N m, body), re-evaluated at every stage, with ``t`` as the
        stepper passes it (``t`` at the step start plus the stage offset). Returns float tuples
        ``(q, w, h_abs)``.
        """
        # The stage torque: the environment's minus the wheels' gyroscopic torque and reaction (compiled where built).
        qn, wn = self._step(q, w, dt, _body_step.gyrostat(self._A, h_abs, tau, torque, t), t)
        return qn, wn, _body_step.momentum_after(h_abs, tau, dt)

    def fastest_rate(self, w, h_abs) -> float:
        """Rotation or nutation rate (rad/s) the step guard bounds: max(|omega|, nutation + |A h| / I_min)."""
        return _body_step.fastest_rate(self._A, w, h_abs, self._inv_imin, self._nutation_per_rate)

    def check_step(self, w, h_abs, dt: float, name: str = "step_s") -> None:
        """Refuse ``dt`` when it is too large for rate ``w`` and wheel momentum ``h_abs``, naming the limit."""
        check_step(self.hub.inertia, w, dt, name, self.max_angle, self.method, h_wheels_B=self.axes_sum(h_abs),
                   triangle=False)

    def max_step_s(self, w, h_abs) -> float:
        return max_step_s(self.hub.inertia, w, self.max_angle, self.axes_sum(h_abs), triangle=False)


def _nutation_per_rate(hub_inertia) -> float:
    """``nutation_rate(I, omega) / |omega|`` (the bound scales with |omega|)."""
    m = np.sort(np.linalg.eigvalsh(hub_inertia))
    rates = []
    for k in range(3):
        i, j = [a for a in range(3) if a != k]
        rates.append(math.sqrt(abs((m[k] - m[i]) * (m[k] - m[j])) / (m[i] * m[j])))
    return max(rates)


def angular_momentum_B(inertia, wheels: WheelCluster, omega_BN_B, speeds_rad_s) -> np.ndarray:
    """Total angular momentum ``I omega + A J Omega`` (N m s, body components), ``(..., 3)``."""
    I = check_inertia(inertia)
    w = np.asarray(omega_BN_B, dtype=float)
    return w @ I.T + (np.asarray(speeds_rad_s, dtype=float) * wheels.inertia) @ wheels.spin_axes_B.T


def kinetic_energy(inertia, wheels: WheelCluster, omega_BN_B, speeds_rad_s) -> np.ndarray:
    """Kinetic energy of body and rotors (J): ``0.5 omega.I_s omega + 0.5 sum h^2 / J``."""
    Is = wheels.hub_inertia(inertia)
    w = np.asarray(omega_BN_B, dtype=float)
    h = wheels.absolute_momentum(speeds_rad_s, w)
    return 0.5 * np.sum(w * (w @ Is.T), axis=-1) + 0.5 * np.sum(h * h / wheels.inertia, axis=-1)


def propagate(inertia, wheels: WheelCluster, q_BN, omega_BN_B, speeds_rad_s, duration_s: float, step_s: float,
              wheel_torque_Nm=None, method: str = "rk4", torque: Callable | None = None):
    """Integrate the spacecraft with wheels over ``duration_s`` at the fixed step ``step_s``.

    ``wheel_torque_Nm``: net torque on each rotor (N m), either ``n`` constants or a function of the step's
    start time ``t`` (s) returning ``n`` values, held over each step (zero-order hold); ``None`` is free
    wheels. ``torque(t, q, omega)``: external torque (N m, body axes), re-evaluated at every stage.
    ``method``: a fixed-step method of :mod:`sim.integrators`. Returns ``(t, q, omega, speeds)`` over the
    output times ``0, step, ..., duration`` with ``speeds`` relative to the body (rad/s). Refuses a step the
    guard (rotation, nutation and gyroscopic rate per step) does not allow, naming the limit.
    """
    if method == "dop853":
        raise ValueError("method = 'dop853' is not available with wheels (the wheel torques are held per step); "
                         "use a fixed-step method: rk4, rkmk4, rk8, trapezoid or implicit_midpoint.")
    body = WheeledBody(inertia, wheels, method)
    q = tuple(float(x) for x in check_unit(q_BN, "q_BN"))
    w = _check_vector(omega_BN_B, 3, "omega_BN_B", "rad/s")
    speeds = _check_vector(speeds_rad_s, wheels.n, "speeds_rad_s", "rad/s")
    if not (isinstance(duration_s, int | float) and math.isfinite(duration_s) and duration_s >= 0):
        raise ValueError(f"duration_s = {duration_s!r}; it must be a finite number of seconds >= 0.")
    check_step_value(step_s)
    if wheel_torque_Nm is None:
        zero = (0.0,) * wheels.n

        def tau_at(t):
            return zero
    elif callable(wheel_torque_Nm):
        def tau_at(t):
            return _check_vector(wheel_torque_Nm(t), wheels.n, f"wheel_torque_Nm({t:g})", "N m")
    else:
        const = _check_vector(wheel_torque_Nm, wheels.n, "wheel_torque_Nm", "N m")

        def tau_at(t):
            return const
    torque_fn = None
    if torque is not None:
        def torque_fn(t, qq, ww):
            return tuple(float(x) for x in torque(t, np.array(qq), np.array(ww)))
    n_full = int(math.floor(duration_s / step_s + 1e-9))
    times = [k * step_s for k in range(n_full + 1)]
    if duration_s - times[-1] > 1e-9 * step_s:
        times.append(float(duration_s))
    h = tuple(float(x) for x in wheels.absolute_momentum(speeds, w))
    body.check_step(w, h, step_s)
    qs, ws, hs = [q], [w], [h]
    for k in range(1, len(times)):
        t0 = times[k - 1]
        dt = times[k] - t0
        q, w, h = body.step(q, w, h, tau_at(t0), dt, torque_fn, t0)
        if body.fastest_rate(w, h) * dt > body.max_angle:
            body.check_step(w, h, dt)
        qs.append(q)
        ws.append(w)
        hs.append(h)
    qa, wa = np.array(qs), np.array(ws)
    qa[qa[:, 0] < 0] *= -1.0
    return np.array(times), qa, wa, wheels.speeds(np.array(hs), wa)
