"""Rigid-body attitude propagation: ``propagate`` runs one of :mod:`sim.integrators` over a time grid.

State: ``q_BN`` (scalar-first unit quaternion, body B relative to inertial N) and ``omega_BN_B``
(rad/s, body components); the equations, the float-tuple RK4 step and the step limits live in
:mod:`sim.rigid_body` and are importable from here too (``check_inertia``, ``check_step``,
``max_step_s``, ``nutation_rate``, ``RigidBody``, ``MAX_ANGLE_PER_STEP_RAD``, ``angular_momentum_B``,
``kinetic_energy``). Imports go one way: attitude -> integrators -> rigid_body.

Accuracy guard: explicit RK4 on a spinning body is accurate only while the rotation per step and
the nutation phase per step are small. ``max_step_s`` gives the largest step for a body rate;
``propagate`` and the stand refuse a larger one with a message naming the limit rather than
returning a silently wrong attitude (RK4 is 160 deg wrong just below its stability limit).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from . import integrators as ig
from .rigid_body import (
    MAX_ANGLE_PER_STEP_RAD,
    RigidBody,
    angular_momentum_B,
    check_inertia,
    check_step,
    check_step_value,
    kinetic_energy,
    max_step_s,
    nutation_rate,
)
from .rotations import check_unit

__all__ = [
    "MAX_ANGLE_PER_STEP_RAD",
    "RigidBody",
    "angular_momentum_B",
    "check_inertia",
    "check_step",
    "kinetic_energy",
    "max_step_s",
    "nutation_rate",
    "propagate",
]


def propagate(inertia, q_BN, omega_BN_B, duration_s: float, step_s: float, method: str = "rk4",
              torque: Callable | None = None, *, subdivide: bool = False, rtol: float = 1e-10,
              atol: float = 1e-12, max_angle_rad: float | None = None, report: dict | None = None):
    """Integrate the rigid body from ``(q_BN, omega_BN_B)`` over ``duration_s``.

    Returns ``(t, q, omega)``: arrays over the output times ``0, step, 2 step, ..., duration``
    (a shorter last step lands exactly on ``duration_s``). ``torque(t, q, omega) -> (3,)`` N m in
    body axes, re-evaluated at every stage. ``method`` is one of ``sim.integrators.METHODS``:
    "rk4" (default), "rkmk4", "dop853" (``rtol``/``atol``; ``step_s`` is then only the output
    grid), "rk8" (Cooper-Verner 8th order, fixed step), "trapezoid" (warns with
    ``UnstableMethodWarning``), "implicit_midpoint".

    Step guard (fixed-step methods): the rotation and nutation phase per step must stay below
    ``sim.integrators.max_angle_rad(method)`` rad (override with ``max_angle_rad``, an explicit
    acceptance of the error, which also lifts the trapezoid error limit). A larger step is
    refused with a message naming the limit, at the start and whenever torques spin the body
    up; with ``subdivide=True`` each output step is split into n equal substeps (n chosen at the
    start) instead. ``report``, if a dict, receives
    ``method``, ``substeps`` (n), ``internal_step_s`` and ``rhs_evals``. Also refuses a non-unit or
    non-finite quaternion, non-finite rates and inertia that no rigid body has.
    """
    ig.check_method(method)
    body = RigidBody(inertia)
    q, w = _initial_state(q_BN, omega_BN_B)
    q = ig.unit_start(q, method)
    times = _output_times(duration_s, step_s)
    if method == "dop853":
        qa, wa, nfev = ig.dop853(body, q, w, np.array(times), torque, rtol, atol)
        if report is not None:
            report.update(method=method, substeps=None, internal_step_s=None, rhs_evals=nfev)
        qa[qa[:, 0] < 0] *= -1.0
        return np.array(times), qa, wa
    angle = ig.max_angle_rad(method) if max_angle_rad is None else float(max_angle_rad)
    limit = max_step_s(body.inertia, w, angle)
    n_sub = 1
    if step_s > limit:
        if subdivide:
            n_sub = math.ceil(step_s / limit - 1e-9)
        else:
            _refuse_step(body.inertia, w, step_s, limit, angle, method)
    h_int = step_s / n_sub
    if method == "trapezoid":
        _check_trapezoid(body.inertia, w, step_s, h_int, (len(times) - 1) * n_sub, max_angle_rad)
    step = ig.stepper(body, method)
    qs = [q]
    ws = [w]
    torque_fn = None
    if torque is not None:
        def torque_fn(t, qq, ww):
            return tuple(float(x) for x in torque(t, np.array(qq), np.array(ww)))
    limit_sq = (angle / h_int) ** 2 * (1.0 + 1e-9)
    for k in range(1, len(times)):
        h = (times[k] - times[k - 1]) / n_sub
        t = times[k - 1]
        for j in range(n_sub):
            q, w = step(q, w, h, torque_fn, t + j * h)
        if w[0] * w[0] + w[1] * w[1] + w[2] * w[2] > limit_sq:
            if max_step_s(body.inertia, w, angle) < h_int:
                _refuse_step(body.inertia, w, h_int, max_step_s(body.inertia, w, angle), angle, method,
                             at_s=times[k])
        qs.append(q)
        ws.append(w)
    if report is not None:
        stages = {"rk4": 4, "rkmk4": 4, "rk8": 11, "trapezoid": 2, "implicit_midpoint": None}[method]
        report.update(method=method, substeps=n_sub, internal_step_s=h_int,
                      rhs_evals=None if stages is None else stages * n_sub * (len(times) - 1))
    qa = np.array(qs)
    qa[qa[:, 0] < 0] *= -1.0
    return np.array(times), qa, np.array(ws)



def _initial_state(q_BN, omega_BN_B) -> tuple[tuple, tuple]:
    """The state as tuples of floats, refused unless the quaternion is unit and the rates finite."""
    q = tuple(float(x) for x in check_unit(q_BN, "q_BN"))
    w = tuple(float(x) for x in np.asarray(omega_BN_B, dtype=float).ravel())
    if len(w) != 3 or not all(math.isfinite(x) for x in w):
        raise ValueError(f"omega_BN_B = {omega_BN_B!r} must be 3 finite rates in rad/s.")
    return q, w


def _output_times(duration_s, step_s) -> list[float]:
    """``0, step, 2 step, ...`` up to ``duration_s``, with a shorter last step landing exactly on it."""
    if not (isinstance(duration_s, int | float) and math.isfinite(duration_s) and duration_s >= 0):
        raise ValueError(f"duration_s = {duration_s!r}; it must be a finite number of seconds >= 0.")
    check_step_value(step_s)
    n_full = int(math.floor(duration_s / step_s + 1e-9))
    times = [k * step_s for k in range(n_full + 1)]
    if duration_s - times[-1] > 1e-9 * step_s:
        times.append(float(duration_s))
    return times


def _check_trapezoid(inertia, w, step_s, h_int, n_steps, max_angle_rad) -> None:
    """Warn that the trapezoid rule is unstable, and refuse a run whose nutation error it would put above
    ``HEUN_MAX_ERROR`` (unless ``max_angle_rad`` accepts the error explicitly)."""
    ig.warn_unstable(step_s)
    lam = nutation_rate(inertia, w)
    err = ig.heun_error(lam, h_int, n_steps)
    if err > ig.HEUN_MAX_ERROR and max_angle_rad is None:
        raise ValueError(
            f"method 'trapezoid' at {h_int:g} s would put a nutation error of {err:.3g} rad on this "
            f"body (lambda = {lam:.6g} rad/s) over the run (limit {ig.HEUN_MAX_ERROR:g} rad): the "
            "explicit trapezoid rule is unstable for undamped oscillations and only second order. "
            "Use 'rk4' or a much smaller step."
        )

def _refuse_step(inertia, w, step_s, limit, angle, method, at_s=None):
    wn = float(math.sqrt(sum(x * x for x in w)))
    lam = nutation_rate(inertia, w)
    when = "" if at_s is None else f" (reached at t = {at_s:.6g} s)"
    raise ValueError(
        f"step_s = {step_s:g} s is too large for a body rate of {wn:.6g} rad/s ({math.degrees(wn):.4g} "
        f"deg/s) and a nutation frequency of {lam:.6g} rad/s{when}: method {method!r} stays accurate "
        f"only while the rotation and nutation phase per step are at most {angle:g} rad, i.e. "
        f"step_s <= {limit:.3g} s here. Use a smaller step, or subdivide=True to split each step."
    )
