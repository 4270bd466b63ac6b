"""Attitude integrators for ``sim.attitude.propagate(method=...)`` and their step guards.

Methods (state: unit quaternion q_BN, body rate omega_BN_B in rad/s; torque re-evaluated at every
stage or iterate):

``"rk4"``
    classical RK4 on (q, omega), q renormalised after each step (``RigidBody.rk4_step``). Default.
``"rkmk4"``
    Runge-Kutta-Munthe-Kaas of order 4 on SO(3) x R^3: the rotation increment Theta (rad, body
    axes) is integrated with Theta' = dexp^-1_Theta(omega) truncated after the second commutator,
    omega + Theta x omega / 2 + Theta x (Theta x omega) / 12 (enough for order 4), and
    q <- q (x) exp(Theta / 2). q stays unit to round-off without projection.
``"rk8"``
    Cooper & Verner's explicit 8th-order, 11-stage Runge-Kutta method at a fixed step on (q, omega),
    q renormalised after each step (:func:`rk8_step`; tableau :data:`RK8_A`, :data:`RK8_B`,
    :data:`RK8_C` from :mod:`sim.rk8_tableau`, unrolled in the generated :mod:`sim.rk8_generated`).
    About twice the cost of an RK4 step, usable at up to 5x the RK4 step: the fast route to
    1e-4 ... 1e-9 deg on the separatrix benchmark.
``"trapezoid"``
    the seed paper's explicit trapezoid rule (Heun), q renormalised; kept for comparison only. Its
    amplification on an undamped oscillation is |R(iy)|^2 = 1 + y^4 / 4 > 1 for every step, so
    it always emits :class:`UnstableMethodWarning` and is refused when its predicted nutation error
    over the run (phase lag plus growth) exceeds ``HEUN_MAX_ERROR``.
``"implicit_midpoint"``
    Gauss-Legendre order 2 (A-stable, conserves energy and |H| of the free body): Newton on omega
    with a convergence check, Cayley update of q (norm-preserving). For stiff subsystems; on the
    rigid body it is stable but only second-order accurate.
``"dop853"``
    scipy ``solve_ivp`` Dormand-Prince 8(5,3) with ``rtol``/``atol``, dense output evaluated at
    the requested grid; outputs are renormalised. Offline reference: about 14 us per RHS call.

Step guard. Fixed-step methods are accurate only while the rotation and the nutation phase per
step are small: ``max_step_s`` in :mod:`sim.rigid_body` bounds both by ``MAX_ANGLE_PER_STEP_RAD``
(0.1 rad) for the fourth-order methods and ``RK8_ANGLE_RAD`` (0.5 rad, measured) for ``"rk8"``;
second-order methods get ``SECOND_ORDER_ANGLE_RAD`` (0.01 rad), because their phase error per step
is (angle)^3 / 12 instead of (angle)^5 / 120.
A larger step is refused with a message naming the limit, or, with ``subdivide=True``, each output
step is split into the smallest number n of equal substeps that satisfies the limit and n is
reported.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable

import numpy as np

from .rigid_body import MAX_ANGLE_PER_STEP_RAD, check_finite_state
from .rk8_generated import rk8_general_step, rk8_principal_step
from .rk8_tableau import RK8_A as RK8_A  # re-exported: the tableau's public name stays here too
from .rk8_tableau import RK8_B as RK8_B
from .rk8_tableau import RK8_C as RK8_C
from .rotations import hamilton_floats

#: Methods ``propagate`` accepts, in the order the bench reports them.
METHODS = ("rk4", "rkmk4", "dop853", "rk8", "trapezoid", "implicit_midpoint")

#: The methods that keep |q| as it starts (a Lie-group update or a Cayley map) instead of renormalising each step
#: as "rk4", "rk8" and "trapezoid" do: they must start from a unit quaternion (:func:`unit_start`).
NORM_PRESERVING = frozenset({"rkmk4", "implicit_midpoint"})

#: Largest rotation and nutation phase per step for second-order methods (rad): their local phase
#: error is ~angle^3 / 12, so 0.01 rad gives ~1e-7 rad per step, the RK4 level at 0.1 rad.
SECOND_ORDER_ANGLE_RAD = 0.01

#: Largest rotation and nutation phase per step for "rk8" (rad). Measured (diag(10, 20, 30) kg m^2,
#: torque-free): at 0.5 rad per step its error is that of RK4 at RK4's 0.1 rad (near the separatrix
#: over 600 s, 1.2e-3 deg; 20 rad/s fast spin over 60 s, 4e-3 deg against RK4's 1.1e-2 deg); at
#: 0.7 rad it is 20x worse, at 1 rad 400x, and it is lost (tens of degrees) beyond 1.5 rad.
RK8_ANGLE_RAD = 0.5

#: Explicit trapezoid: refused when the predicted nutation error over the run exceeds this (rad):
#: phase error N y^3 / 6 plus amplitude growth exp(N y^4 / 8) - 1 for N steps, y = lambda h.
HEUN_MAX_ERROR = 1e-3

#: Newton iterations of the implicit midpoint rule before it gives up (it converges in 3-5 at any
#: step the guard admits); tolerance on the rate update relative to |omega| + 1e-300.
NEWTON_MAX_ITER = 50
NEWTON_RTOL = 4e-16


class UnstableMethodWarning(UserWarning):
    """The chosen integrator is unstable for undamped oscillations (the explicit trapezoid rule).

    It is kept only to reproduce the seed paper; expect errors about 1e4 times those of RK4 at the
    same step, growing without bound on long runs.
    """


def max_angle_rad(method: str) -> float:
    """Accuracy limit on rotation and nutation phase per step (rad) for a fixed-step method."""
    if method == "rk8":
        return RK8_ANGLE_RAD
    return SECOND_ORDER_ANGLE_RAD if method in ("trapezoid", "implicit_midpoint") else MAX_ANGLE_PER_STEP_RAD


def check_method(method: str) -> str:
    if method not in METHODS:
        raise ValueError(f"method = {method!r} is not an attitude integrator; allowed: {', '.join(METHODS)}.")
    return method


def unit_start(q, method: str) -> tuple:
    """The starting quaternion ``q`` (float tuple) as ``method`` needs it: normalised for a norm-preserving method.

    A scenario's quaternion typed to 8 digits is 1 +- 1e-8 from unit and passes the unit check. The renormalising
    methods correct that on their first step; "rkmk4" and "implicit_midpoint" would carry the norm through the run
    (in the pointing scenario it left a floor of 2.6e-8 arcsec under RKMK4's error). Left alone for the others, so
    their trajectories keep their bits.
    """
    if method not in NORM_PRESERVING:
        return q
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


# -- fixed-step steppers on float tuples (same calling convention as RigidBody.rk4_step) ---------

def _qmul_exp(q, th0, th1, th2):
    """q (x) exp([th] / 2): a rotation increment of angle |th| about the body axis th."""
    a = math.sqrt(th0 * th0 + th1 * th1 + th2 * th2)
    if a < 1e-4:
        # Taylor series: exact to round-off here, and no 0/0 at a = 0.
        a2 = a * a
        c = 1.0 - a2 / 8.0 + a2 * a2 / 384.0
        s = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0
    else:
        c = math.cos(0.5 * a)
        s = math.sin(0.5 * a) / a
    return hamilton_floats(q, (c, s * th0, s * th1, s * th2))


def rkmk4_step(body, q, w, h, torque: Callable | None = None, t: float = 0.0):
    """One RKMK4 step of length ``h`` (s); returns (q, omega) as float tuples."""
    f = body.derivatives
    zero = (0.0, 0.0, 0.0)
    w0, w1, w2 = w

    def dexpinv(t0, t1, t2, v0, v1, v2):
        # omega + Theta x omega / 2 + Theta x (Theta x omega) / 12 (body-frame right trivialisation).
        c0, c1, c2 = t1 * v2 - t2 * v1, t2 * v0 - t0 * v2, t0 * v1 - t1 * v0
        d0, d1, d2 = t1 * c2 - t2 * c1, t2 * c0 - t0 * c2, t0 * c1 - t1 * c0
        return v0 + 0.5 * c0 + d0 / 12.0, v1 + 0.5 * c1 + d1 / 12.0, v2 + 0.5 * c2 + d2 / 12.0

    _, (b0, b1, b2) = f(q, w, torque(t, q, w) if torque else zero)
    k1 = (w0, w1, w2)  # dexpinv at Theta = 0 is the identity
    h2 = 0.5 * h
    th = (h2 * k1[0], h2 * k1[1], h2 * k1[2])
    ws = (w0 + h2 * b0, w1 + h2 * b1, w2 + h2 * b2)
    qs = _qmul_exp(q, *th)
    _, (d0, d1, d2) = f(qs, ws, torque(t + h2, qs, ws) if torque else zero)
    k2 = dexpinv(*th, *ws)
    th = (h2 * k2[0], h2 * k2[1], h2 * k2[2])
    ws = (w0 + h2 * d0, w1 + h2 * d1, w2 + h2 * d2)
    qs = _qmul_exp(q, *th)
    _, (e0, e1, e2) = f(qs, ws, torque(t + h2, qs, ws) if torque else zero)
    k3 = dexpinv(*th, *ws)
    th = (h * k3[0], h * k3[1], h * k3[2])
    ws = (w0 + h * e0, w1 + h * e1, w2 + h * e2)
    qs = _qmul_exp(q, *th)
    _, (g0, g1, g2) = f(qs, ws, torque(t + h, qs, ws) if torque else zero)
    k4 = dexpinv(*th, *ws)
    h6 = h / 6.0
    th = tuple(h6 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]) for i in range(3))
    wn = (w0 + h6 * (b0 + 2.0 * (d0 + e0) + g0), w1 + h6 * (b1 + 2.0 * (d1 + e1) + g1),
          w2 + h6 * (b2 + 2.0 * (d2 + e2) + g2))
    qn = _qmul_exp(q, *th)
    check_finite_state(qn, wn, t + h, h)
    return qn, wn


# -- rk8: Cooper & Verner's 8th-order, 11-stage explicit Runge-Kutta method --------------------------

def rk8_step(body, q, w, h, torque: Callable | None = None, t: float = 0.0):
    """One step of Cooper & Verner's 8th-order, 11-stage Runge-Kutta method; q renormalised.

    Source: G. J. Cooper and J. H. Verner, "Some explicit Runge-Kutta methods of high order",
    SIAM J. Numer. Anal. 9(3), 389-405 (1972): the tableau :data:`RK8_C`, :data:`RK8_A`,
    :data:`RK8_B` (nodes 1/2 and (7 +- sqrt(21)) / 14). When this was written the values were checked
    against all 200 order conditions up to order 8 in 40-digit arithmetic (residuals below 1e-40), and
    ``tests/sim/test_integrators.py`` checks every order condition to round-off and that the
    unrolled code equals a generic Runge-Kutta step driven by the tableau.

    Same calling convention as ``RigidBody.rk4_step``: ``torque(t, q, w) -> (tx, ty, tz)`` N m
    (body axes) re-evaluated at every stage, ``None`` = torque-free; returns float tuples. The 11
    stages are written out on floats with the Euler equations and the quaternion kinematics inlined
    and h folded into the derivative (no numpy, no per-stage tuples or calls): about 12-13 us per
    step against about 7 us for ``rk4_step`` (torque-free, diagonal inertia). A body with diagonal
    inertia takes the cheaper principal-axis form of Euler's equations (about 15 % faster than the
    general form). :func:`stepper` binds the inertia once; this function re-derives it on every call.
    """
    return stepper(body, "rk8")(q, w, h, torque, t)


def _principal(body):
    """(e, g) for the principal-axis RK8 form, or None when the inertia is not diagonal."""
    i00, i01, i02, i10, i11, i12, i20, i21, i22 = body._I
    if i01 or i02 or i10 or i12 or i20 or i21:
        return None
    return ((i11 - i22) / i00, (i22 - i00) / i11, (i00 - i11) / i22), (1.0 / i00, 1.0 / i11, 1.0 / i22)


def trapezoid_step(body, q, w, h, torque: Callable | None = None, t: float = 0.0):
    """One explicit trapezoid (Heun) step, q renormalised. Unstable for undamped modes."""
    f = body.derivatives
    zero = (0.0, 0.0, 0.0)
    a, b = f(q, w, torque(t, q, w) if torque else zero)
    qp = tuple(q[i] + h * a[i] for i in range(4))
    wp = tuple(w[i] + h * b[i] for i in range(3))
    c, d = f(qp, wp, torque(t + h, qp, wp) if torque else zero)
    qn = tuple(q[i] + 0.5 * h * (a[i] + c[i]) for i in range(4))
    wn = tuple(w[i] + 0.5 * h * (b[i] + d[i]) for i in range(3))
    check_finite_state(qn, wn, t + h, h)
    n = math.sqrt(sum(x * x for x in qn))
    return tuple(x / n for x in qn), wn


def _cayley(q, h, m0, m1, m2):
    """q (x) cay(h omega / 2): the implicit midpoint rule for q' = q (x) [0, omega] / 2, exactly."""
    # (1 - h/4 Omega)^-1 (1 + h/4 Omega) as a quaternion: (1 + v)(1 - v)^-1 with v = h omega / 4,
    # i.e. [1 - |v|^2, 2 v] / (1 + |v|^2). Unit norm by construction.
    v0, v1, v2 = 0.25 * h * m0, 0.25 * h * m1, 0.25 * h * m2
    vv = v0 * v0 + v1 * v1 + v2 * v2
    s = 1.0 / (1.0 + vv)
    return hamilton_floats(q, ((1.0 - vv) * s, 2.0 * v0 * s, 2.0 * v1 * s, 2.0 * v2 * s))


def implicit_midpoint_step(body, q, w, h, torque: Callable | None = None, t: float = 0.0):
    """One implicit midpoint step: omega by Newton with a convergence check, q by Cayley."""
    # Plain floats and Cramer's rule: numpy on 3x3 systems costs ~10x more than the arithmetic.
    i00, i01, i02, i10, i11, i12, i20, i21, i22 = body._I
    j00, j01, j02, j10, j11, j12, j20, j21, j22 = body._Ii
    w0, w1, w2 = w
    m0, m1, m2 = w
    scale = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2) + 1e-300
    tm = t + 0.5 * h
    hh = 0.5 * h
    tx = ty = tz = 0.0
    for _ in range(NEWTON_MAX_ITER):
        if torque:
            qm = _cayley(q, hh, m0, m1, m2)  # attitude at the half step, for the torque
            tx, ty, tz = torque(tm, qm, (m0, m1, m2))
        hx = i00 * m0 + i01 * m1 + i02 * m2
        hy = i10 * m0 + i11 * m1 + i12 * m2
        hz = i20 * m0 + i21 * m1 + i22 * m2
        rx = tx - (m1 * hz - m2 * hy)
        ry = ty - (m2 * hx - m0 * hz)
        rz = tz - (m0 * hy - m1 * hx)
        # Residual of the midpoint equation in the midpoint rate: m = w + h/2 f(m).
        g0 = m0 - w0 - hh * (j00 * rx + j01 * ry + j02 * rz)
        g1 = m1 - w1 - hh * (j10 * rx + j11 * ry + j12 * rz)
        g2 = m2 - w2 - hh * (j20 * rx + j21 * ry + j22 * rz)
        # d r / d m = -([m x] I - [h x]) = A; Jacobian J = 1 - h/2 Ii A. The torque's derivative is
        # neglected (quasi-Newton), so a torqued step converges linearly rather than quadratically.
        a00, a01, a02 = -(-m2 * i10 + m1 * i20), -(-m2 * i11 + m1 * i21 + hz), -(-m2 * i12 + m1 * i22 - hy)
        a10, a11, a12 = -(m2 * i00 - m0 * i20 - hz), -(m2 * i01 - m0 * i21), -(m2 * i02 - m0 * i22 + hx)
        a20, a21, a22 = -(-m1 * i00 + m0 * i10 + hy), -(-m1 * i01 + m0 * i11 - hx), -(-m1 * i02 + m0 * i12)
        J00 = 1.0 - hh * (j00 * a00 + j01 * a10 + j02 * a20)
        J01 = -hh * (j00 * a01 + j01 * a11 + j02 * a21)
        J02 = -hh * (j00 * a02 + j01 * a12 + j02 * a22)
        J10 = -hh * (j10 * a00 + j11 * a10 + j12 * a20)
        J11 = 1.0 - hh * (j10 * a01 + j11 * a11 + j12 * a21)
        J12 = -hh * (j10 * a02 + j11 * a12 + j12 * a22)
        J20 = -hh * (j20 * a00 + j21 * a10 + j22 * a20)
        J21 = -hh * (j20 * a01 + j21 * a11 + j22 * a21)
        J22 = 1.0 - hh * (j20 * a02 + j21 * a12 + j22 * a22)
        c00 = J11 * J22 - J12 * J21
        c01 = J12 * J20 - J10 * J22
        c02 = J10 * J21 - J11 * J20
        det = J00 * c00 + J01 * c01 + J02 * c02
        d0 = (g0 * c00 + g1 * (J02 * J21 - J01 * J22) + g2 * (J01 * J12 - J02 * J11)) / det
        d1 = (g0 * c01 + g1 * (J00 * J22 - J02 * J20) + g2 * (J02 * J10 - J00 * J12)) / det
        d2 = (g0 * c02 + g1 * (J01 * J20 - J00 * J21) + g2 * (J00 * J11 - J01 * J10)) / det
        m0, m1, m2 = m0 - d0, m1 - d1, m2 - d2
        dmax = max(abs(d0), abs(d1), abs(d2))
        if not math.isfinite(dmax):
            break
        if dmax <= NEWTON_RTOL * scale:
            wn = (2.0 * m0 - w0, 2.0 * m1 - w1, 2.0 * m2 - w2)
            qn = _cayley(q, h, m0, m1, m2)
            check_finite_state(qn, wn, t + h, h)
            return qn, wn
    raise FloatingPointError(
        f"implicit midpoint: Newton did not converge in {NEWTON_MAX_ITER} iterations at t = {t:.9g} s "
        f"(step {h:g} s, |omega| = {scale:.6g} rad/s); reduce step_s."
    )


def stepper(body, method: str):
    """The one-step function ``(q, w, h, torque, t) -> (q, w)`` of a fixed-step method."""
    if method == "rk4":
        return body.rk4_step
    if method == "rkmk4":
        return lambda q, w, h, torque=None, t=0.0: rkmk4_step(body, q, w, h, torque, t)
    if method == "rk8":
        diag = _principal(body)
        if diag is not None:
            e, g = diag
            return lambda q, w, h, torque=None, t=0.0: rk8_principal_step(q, w, h, torque, t, e, g)
        inertia, inertia_inv = body._I, body._Ii
        return lambda q, w, h, torque=None, t=0.0: rk8_general_step(q, w, h, torque, t, inertia, inertia_inv)
    if method == "trapezoid":
        return lambda q, w, h, torque=None, t=0.0: trapezoid_step(body, q, w, h, torque, t)
    if method == "implicit_midpoint":
        return lambda q, w, h, torque=None, t=0.0: implicit_midpoint_step(body, q, w, h, torque, t)
    raise ValueError(f"method = {method!r} is not a fixed-step method.")


def heun_error(nutation_rad_s: float, step_s: float, n_steps: int) -> float:
    """Predicted nutation error (rad, relative) of the explicit trapezoid rule over ``n_steps``.

    Per step on an undamped oscillation of frequency lambda (y = lambda h) the rule's phase lags
    by y^3 / 6 and its amplitude grows by sqrt(1 + y^4 / 4).
    """
    y = nutation_rad_s * step_s
    return n_steps * y ** 3 / 6.0 + math.expm1(n_steps * math.log1p(y ** 4 / 4.0) / 2.0)


def dop853(body, q0, w0, times, torque, rtol: float, atol: float):
    """Integrate with scipy DOP853 and return (q, omega) arrays on ``times`` (q renormalised)."""
    from scipy.integrate import solve_ivp

    f = body.derivatives
    zero = (0.0, 0.0, 0.0)

    def rhs(t, y):
        # Plain floats: numpy calls on 3-vectors cost more than the arithmetic (solve_ivp already
        # spends ~14 us per call of its own).
        v = y.tolist()
        dq, dw = f(v[:4], v[4:], tuple(float(x) for x in torque(t, y[:4], y[4:])) if torque else zero)
        return np.array(dq + dw)

    y0 = np.concatenate((np.asarray(q0, float), np.asarray(w0, float)))
    if times[-1] == 0.0:
        return y0[None, :4].copy(), y0[None, 4:].copy(), 0
    sol = solve_ivp(rhs, (0.0, float(times[-1])), y0, method="DOP853", t_eval=times, rtol=rtol,
                    atol=atol)
    if not sol.success or not np.all(np.isfinite(sol.y)):
        raise FloatingPointError(f"DOP853 failed: {sol.message} (rtol {rtol:g}, atol {atol:g}).")
    q = sol.y[:4].T
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    return q, sol.y[4:].T.copy(), int(sol.nfev)


def warn_unstable(step_s: float) -> None:
    warnings.warn(
        f"method 'trapezoid' (explicit trapezoid rule, step {step_s:g} s) amplifies every undamped "
        "oscillation (|R(iy)|^2 = 1 + y^4/4) and is kept only for comparison with the seed paper; "
        "use 'rk4'.",
        UnstableMethodWarning,
        stacklevel=3,
    )
