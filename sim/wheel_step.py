"""A reaction wheel's step on floats: the rotor with Coulomb and viscous friction and stiction (Karnopp stick/slip,
solved in closed form between sign changes) and the motor in front of it (torque limit, back-EMF roll-off, first-order
lag). The one source of :class:`sim.actuators.ReactionWheel` and :class:`sim.actuators.WheelMotor`'s arithmetic,
which keep the checks, the faults and the caches and call these functions with every constant passed in.

Plain Python, and compiled by Cython in pure-Python mode where the install has a C compiler (``compiled_paths`` lists
it; docs/fast_paths.md): the ``cython.*`` declarations give the compiled build C doubles and direct C calls between
the functions, and do nothing in plain Python. Both builds do the same IEEE-754 operations in the same order (setup.py
compiles without contraction and fast-math, and without cdivision), so they agree to the bit; the tests run both.
``min`` and ``max`` are written out as the comparisons Python's builtins make (the later value only when strictly
beyond), so a tie keeps the same operand, signed zero included, in both builds.

The arguments are finite floats, the step ``h`` > 0: the callers check them (:mod:`sim.actuators`).
"""

from __future__ import annotations

import math

import cython
from cython.cimports.libc.math import copysign, exp, expm1, log1p  # C's when compiled, Python's math otherwise

INF = cython.declare(cython.double, math.inf)


@cython.cfunc
@cython.inline
def _segment(inertia: cython.double, coulomb: cython.double, viscous: cython.double, w0: cython.double,
             s: cython.double, u: cython.double, t: cython.double) -> tuple[cython.double, cython.double]:
    """Speed and integral of speed after time t slipping with sign s (no crossing inside)."""
    # Omega(t) = w0 e^(-kt) + b phi(t), phi = (1 - e^(-kt)) / k, k = c / J, b = (u - tau_c s) / J;
    # series for small kt, so no 0/0 or inf/inf for negligible (even subnormal) viscosity.
    k: cython.double = viscous / inertia
    b: cython.double = (u - coulomb * s) / inertia
    kt: cython.double = k * t
    phi: cython.double
    psi: cython.double
    if kt < 1e-5:
        phi = t * (1.0 - kt / 2.0 + kt * kt / 6.0)
        psi = t * t * (0.5 - kt / 6.0 + kt * kt / 24.0)  # integral of phi from 0 to t
    else:
        phi = -expm1(-kt) / k
        psi = (t - phi) / k
    return w0 * exp(-kt) + b * phi, w0 * phi + b * psi


@cython.cfunc
@cython.inline
def _time_to_zero(inertia: cython.double, coulomb: cython.double, viscous: cython.double, w0: cython.double,
                  s: cython.double, u: cython.double) -> cython.double:
    """Time (s) for a slipping wheel to reach Omega = 0, or inf if it does not decelerate to 0."""
    k: cython.double = viscous / inertia
    b: cython.double = (u - coulomb * s) / inertia
    if w0 * b >= 0.0:
        return INF  # accelerating (or coasting without friction): never reaches zero
    x: cython.double = -k * w0 / b  # > 0
    if x < 1e-5:
        return (-w0 / b) * (1.0 - x / 2.0 + x * x / 3.0)
    return log1p(x) / k


@cython.cfunc
def _advance(inertia: cython.double, coulomb: cython.double, viscous: cython.double, static: cython.double,
             w: cython.double, u: cython.double, h: cython.double) -> tuple[cython.double, cython.double]:
    """The rotor's speed after ``h`` seconds with motor torque ``u`` held, and the energy friction dissipated."""
    w_start: cython.double = w
    remaining: cython.double = h
    motor_work: cython.double = 0.0
    s: cython.double
    t0: cython.double
    integral: cython.double
    w_new: cython.double
    _i: cython.int
    for _i in range(3):  # at most: slip to zero, then stick or slip the other way
        if remaining <= 0.0:
            break
        if w == 0.0:
            if abs(u) <= static:
                break  # stuck: friction balances the motor; the wheel stays at exactly 0
            s = 1.0 if u > 0.0 else -1.0
        else:
            s = 1.0 if w > 0.0 else -1.0
        t0 = _time_to_zero(inertia, coulomb, viscous, w, s, u) if w != 0.0 else INF
        if t0 < remaining:
            w_new, integral = _segment(inertia, coulomb, viscous, w, s, u, t0)
            motor_work += u * integral
            w = 0.0  # land exactly on zero: the stick test decides what happens next
            remaining -= t0
        else:
            w_new, integral = _segment(inertia, coulomb, viscous, w, s, u, remaining)
            if w_new * s < 0.0:
                w_new = 0.0  # round-off at the crossing: never overshoot through zero
            motor_work += u * integral
            w = w_new
            remaining = 0.0
    d_energy: cython.double = 0.5 * inertia * (w * w - w_start * w_start)
    friction: cython.double = motor_work - d_energy
    return w, (0.0 if 0.0 > friction else friction)  # max(friction, 0.0)


def rotor_advance(inertia: cython.double, coulomb: cython.double, viscous: cython.double, static: cython.double,
                  w: cython.double, u: cython.double, h: cython.double) -> tuple:
    """:meth:`sim.actuators.ReactionWheel.step` on checked floats: ``(omega, body_torque_Nm, friction_J)``."""
    w_end: cython.double
    friction: cython.double
    w_end, friction = _advance(inertia, coulomb, viscous, static, w, u, h)
    return w_end, -inertia * (w_end - w) / h, friction


@cython.cfunc
@cython.inline
def _available(u: cython.double, w: cython.double, max_torque: cython.double, max_speed: cython.double,
               rolloff: cython.double) -> cython.double:
    lo: cython.double = -max_torque
    u = lo if lo > u else u  # max(u, -max_torque)
    u = max_torque if max_torque < u else u  # min(u, max_torque)
    room: cython.double
    if u * w > 0.0:  # driving the speed up: the back-EMF limits the torque near w_max
        room = (max_speed - abs(w)) / rolloff
        room = 0.0 if 0.0 > room else room
        u *= 1.0 if 1.0 < room else room
    return u


def available_torque(u: cython.double, w: cython.double, max_torque: cython.double, max_speed: cython.double,
                     rolloff: cython.double) -> cython.double:
    """:meth:`sim.actuators.WheelMotor.available_torque`: command ``u`` clipped to +-``max_torque`` and, driving the
    speed ``w`` up, rolled off linearly over the last ``rolloff`` before ``max_speed``."""
    return _available(u, w, max_torque, max_speed, rolloff)


def motor_step(inertia: cython.double, coulomb: cython.double, viscous: cython.double, static: cython.double,
               max_torque: cython.double, max_speed: cython.double, rolloff: cython.double, decay: cython.double,
               mean: cython.double, w0: cython.double, tau0: cython.double, u_cmd: cython.double,
               h: cython.double) -> tuple:
    """:meth:`sim.actuators.WheelMotor.step` of a healthy wheel on checked floats, the lag's factors ``decay`` and
    ``mean`` given: ``(omega, motor_torque_Nm, body_torque_Nm, friction_J)``."""
    u: cython.double = _available(u_cmd, w0, max_torque, max_speed, rolloff)
    tau_end: cython.double = u + (tau0 - u) * decay
    tau_mean: cython.double = u + (tau0 - u) * mean
    w1: cython.double
    friction: cython.double
    w1, friction = _advance(inertia, coulomb, viscous, static, w0, tau_mean, h)
    aw0: cython.double = abs(w0)
    cap: cython.double = aw0 if aw0 > max_speed else max_speed  # max(max_speed, |w0|)
    if abs(w1) > cap and tau_mean * w1 > 0.0:
        w1 = copysign(cap, w1)  # the back-EMF allows no more within this step
    return w1, tau_end, -inertia * (w1 - w0) / h, friction
