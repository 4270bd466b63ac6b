"""The attitude step on floats: Euler's equations, the quaternion kinematics, classical RK4 and the environment's
magnetic and gravity-gradient torques. The one source of the default scenario's hot path. With reaction wheels, the
gyrostat's terms beside it (:class:`Gyrostat`, the wheels' stage torque, which the RK4 step calls at C level as it
calls :class:`EnvironmentTorque`; ``axes_sum``, ``momentum_after``, ``fastest_rate``, ``relative_speeds``), used by
:mod:`sim.wheels` and :class:`sim.truth.TruthModel`.

Plain Python, and compiled by Cython in pure-Python mode where the install has a C compiler (``compiled_paths``
lists it; docs/fast_paths.md): the ``cython.*`` declarations below give the compiled build C doubles and direct C
calls between the functions, and do nothing in plain Python. Both builds do the same IEEE-754 operations in the same
order (setup.py compiles without contraction and fast-math, and without cdivision), so they agree to the bit; the
tests run both.

:class:`sim.rigid_body.RigidBody` and :class:`sim.truth.TruthModel` take this module through
``compiled_paths.load("sim.body_step")``; nothing else imports it directly.

Sequences the step reads are tuples: a list raises TypeError (its contents could change while it is read), and a
tuple cannot change.
"""

from __future__ import annotations

import cython
from cython.cimports.libc.math import isfinite, sqrt  # C's when compiled, Python's math otherwise: the same


@cython.cfunc
@cython.inline
@cython.exceptval(-1)
def _need_tuple(x: object, n: cython.Py_ssize_t, what: str) -> cython.int:
    """Refuse anything but a tuple of ``n`` items for ``what``."""
    if type(x) is not tuple or len(x) != n:
        raise TypeError(f"{what} must be a tuple of {n} floats; got {x!r}.")
    return 0


@cython.cfunc
@cython.inline
def _rotate(qw: cython.double, qx: cython.double, qy: cython.double, qz: cython.double, vx: cython.double,
            vy: cython.double, vz: cython.double) -> tuple[cython.double, cython.double, cython.double]:
    # dcm(q) v = v - 2w (u x v) + 2 u x (u x v), u = (x, y, z)
    cx = qy * vz - qz * vy
    cy = qz * vx - qx * vz
    cz = qx * vy - qy * vx
    return (vx - 2.0 * (qw * cx - (qy * cz - qz * cy)),
            vy - 2.0 * (qw * cy - (qz * cx - qx * cz)),
            vz - 2.0 * (qw * cz - (qx * cy - qy * cx)))


@cython.locals(qw=cython.double, qx=cython.double, qy=cython.double, qz=cython.double, vx=cython.double,
               vy=cython.double, vz=cython.double)
def rotate_to_body(q, v):
    """``dcm(q) @ v`` on float tuples (v_N -> v_B for q = q_BN), without building the matrix."""
    qw, qx, qy, qz = q
    vx, vy, vz = v
    return _rotate(qw, qx, qy, qz, vx, vy, vz)


def non_finite_state(t: float, h: float) -> FloatingPointError:
    """The error every fixed-step stepper raises when its new state at ``t`` (s) is not finite."""
    return FloatingPointError(
        f"attitude integration produced a non-finite state at t = {t:.9g} s (step {h:g} s); the "
        "step is too large for the dynamics or a torque is non-finite."
    )


@cython.cclass
class BodyDynamics:
    """Euler's equations and RK4 for one inertia matrix ``I`` (kg m^2) and its inverse ``Ii``, nine floats each,
    row by row."""

    i00: cython.double
    i01: cython.double
    i02: cython.double
    i10: cython.double
    i11: cython.double
    i12: cython.double
    i20: cython.double
    i21: cython.double
    i22: cython.double
    j00: cython.double
    j01: cython.double
    j02: cython.double
    j10: cython.double
    j11: cython.double
    j12: cython.double
    j20: cython.double
    j21: cython.double
    j22: cython.double

    def __init__(self, I, Ii):
        _need_tuple(I, 9, "I")
        _need_tuple(Ii, 9, "Ii")
        self.i00, self.i01, self.i02, self.i10, self.i11, self.i12, self.i20, self.i21, self.i22 = I
        self.j00, self.j01, self.j02, self.j10, self.j11, self.j12, self.j20, self.j21, self.j22 = Ii

    @cython.cfunc
    def _derivatives(self, qw: cython.double, qx: cython.double, qy: cython.double, qz: cython.double,
                     wx: cython.double, wy: cython.double, wz: cython.double, tx: cython.double, ty: cython.double,
                     tz: cython.double) -> tuple[cython.double, cython.double, cython.double, cython.double,
                                                 cython.double, cython.double, cython.double]:
        # I domega/dt = tau - omega x (I omega);  dq/dt = 0.5 q (x) [0, omega]
        hx = self.i00 * wx + self.i01 * wy + self.i02 * wz
        hy = self.i10 * wx + self.i11 * wy + self.i12 * wz
        hz = self.i20 * wx + self.i21 * wy + self.i22 * wz
        rx = tx - (wy * hz - wz * hy)
        ry = ty - (wz * hx - wx * hz)
        rz = tz - (wx * hy - wy * hx)
        return (0.5 * (-qx * wx - qy * wy - qz * wz), 0.5 * (qw * wx + qy * wz - qz * wy),
                0.5 * (qw * wy - qx * wz + qz * wx), 0.5 * (qw * wz + qx * wy - qy * wx),
                self.j00 * rx + self.j01 * ry + self.j02 * rz, self.j10 * rx + self.j11 * ry + self.j12 * rz,
                self.j20 * rx + self.j21 * ry + self.j22 * rz)

    @cython.locals(qw=cython.double, qx=cython.double, qy=cython.double, qz=cython.double, wx=cython.double,
                   wy=cython.double, wz=cython.double, tx=cython.double, ty=cython.double, tz=cython.double)
    def derivatives(self, q, w, tau):
        """(dq/dt, domega/dt) as float tuples for quaternion q, rate w and torque tau."""
        qw, qx, qy, qz = q
        wx, wy, wz = w
        tx, ty, tz = tau
        a0, a1, a2, a3, b0, b1, b2 = self._derivatives(qw, qx, qy, qz, wx, wy, wz, tx, ty, tz)
        return (a0, a1, a2, a3), (b0, b1, b2)

    @cython.cfunc
    def _stage(self, torque: object, t: cython.double, qw: cython.double, qx: cython.double, qy: cython.double,
               qz: cython.double, wx: cython.double, wy: cython.double,
               wz: cython.double) -> tuple[cython.double, cython.double, cython.double, cython.double,
                                           cython.double, cython.double, cython.double]:
        """The state's derivatives at one RK4 stage, under ``torque`` at stage time ``t``."""
        tx: cython.double = 0.0
        ty: cython.double = 0.0
        tz: cython.double = 0.0
        if isinstance(torque, EnvironmentTorque):  # compiled: a C call, no tuples
            tx, ty, tz = cython.cast(EnvironmentTorque, torque)._at(t, qw, qx, qy, qz)
        elif isinstance(torque, Gyrostat):  # a spacecraft with wheels: the same, the environment's inside it
            tx, ty, tz = cython.cast(Gyrostat, torque)._at(t, qw, qx, qy, qz, wx, wy, wz)
        elif torque is not None:
            tx, ty, tz = torque(t, (qw, qx, qy, qz), (wx, wy, wz))
        return self._derivatives(qw, qx, qy, qz, wx, wy, wz, tx, ty, tz)

    @cython.locals(q0=cython.double, q1=cython.double, q2=cython.double, q3=cython.double, w0=cython.double,
                   w1=cython.double, w2=cython.double)
    def rk4(self, q, w, h: cython.double, torque=None, t: cython.double = 0.0):
        """One classical RK4 step of length ``h`` (s) from ``t``; the torque is re-evaluated at every stage.

        ``torque(t, q, w) -> (tx, ty, tz)`` in N m, body frame (an :class:`EnvironmentTorque` or any callable);
        ``None`` means torque-free. Returns the renormalised quaternion and the rate as float tuples; raises
        :func:`non_finite_state` when the new state is not finite."""
        _need_tuple(q, 4, "q")
        _need_tuple(w, 3, "w")
        q0, q1, q2, q3 = q
        w0, w1, w2 = w
        h2 = 0.5 * h
        a0, a1, a2, a3, b0, b1, b2 = self._stage(torque, t, q0, q1, q2, q3, w0, w1, w2)
        c0, c1, c2, c3, d0, d1, d2 = self._stage(torque, t + h2, q0 + h2 * a0, q1 + h2 * a1, q2 + h2 * a2,
                                                 q3 + h2 * a3, w0 + h2 * b0, w1 + h2 * b1, w2 + h2 * b2)
        e0, e1, e2, e3, g0, g1, g2 = self._stage(torque, t + h2, q0 + h2 * c0, q1 + h2 * c1, q2 + h2 * c2,
                                                 q3 + h2 * c3, w0 + h2 * d0, w1 + h2 * d1, w2 + h2 * d2)
        k0, k1, k2, k3, m0, m1, m2 = self._stage(torque, t + h, q0 + h * e0, q1 + h * e1, q2 + h * e2,
                                                 q3 + h * e3, w0 + h * g0, w1 + h * g1, w2 + h * g2)
        h6 = h / 6.0
        n0 = q0 + h6 * (a0 + 2.0 * (c0 + e0) + k0)
        n1 = q1 + h6 * (a1 + 2.0 * (c1 + e1) + k1)
        n2 = q2 + h6 * (a2 + 2.0 * (c2 + e2) + k2)
        n3 = q3 + h6 * (a3 + 2.0 * (c3 + e3) + k3)
        v0 = w0 + h6 * (b0 + 2.0 * (d0 + g0) + m0)
        v1 = w1 + h6 * (b1 + 2.0 * (d1 + g1) + m1)
        v2 = w2 + h6 * (b2 + 2.0 * (d2 + g2) + m2)
        n = sqrt(n0 * n0 + n1 * n1 + n2 * n2 + n3 * n3)
        if not (isfinite(n) and isfinite(v0) and isfinite(v1) and isfinite(v2)):
            raise non_finite_state(t + h, h)
        return (n0 / n, n1 / n, n2 / n, n3 / n), (v0, v1, v2)


@cython.cclass
class EnvironmentTorque:
    """Magnetic (m x B) and gravity-gradient (3 mu / r^5 r x I r) torque over one dynamics step of ``h`` s, as
    ``torque(t, q, w)`` for a stepper: stage time 0 reads the step's first half-step point, a time before ``h`` the
    middle one, else the last. :meth:`set_step` gives each step its dipole (A m^2, body axes) and the inertial field
    (T) and position (m) at the three points (nine floats each, a tuple; None for a torque not in the list)."""

    body: BodyDynamics
    h: cython.double
    gm3: cython.double
    magnetic: cython.bint
    gravity_gradient: cython.bint
    mx: cython.double
    my: cython.double
    mz: cython.double
    fields: tuple
    positions: tuple

    def __init__(self, body: BodyDynamics, h: cython.double, mu: cython.double, magnetic: cython.bint,
                 gravity_gradient: cython.bint):
        self.body = body
        self.h = h
        self.gm3 = 3.0 * mu
        self.magnetic = magnetic
        self.gravity_gradient = gravity_gradient
        self.mx = self.my = self.mz = 0.0
        self.fields = self.positions = None

    def set_step(self, dipole_B, fields_N, positions_N) -> None:
        """The dipole held over the next step and the field and position at its three half-step points."""
        _need_tuple(dipole_B, 3, "dipole_B")
        if self.magnetic:
            _need_tuple(fields_N, 9, "fields_N")
        if self.gravity_gradient:
            _need_tuple(positions_N, 9, "positions_N")
        self.mx, self.my, self.mz = dipole_B
        self.fields, self.positions = fields_N, positions_N

    @cython.cfunc
    def _at(self, t: cython.double, qw: cython.double, qx: cython.double, qy: cython.double,
            qz: cython.double) -> tuple[cython.double, cython.double, cython.double]:
        o: cython.Py_ssize_t = 0 if t == 0.0 else (3 if t < self.h else 6)
        tx: cython.double = 0.0
        ty: cython.double = 0.0
        tz: cython.double = 0.0
        if self.magnetic:
            f = self.fields
            bx, by, bz = _rotate(qw, qx, qy, qz, f[o], f[o + 1], f[o + 2])
            tx = self.my * bz - self.mz * by
            ty = self.mz * bx - self.mx * bz
            tz = self.mx * by - self.my * bx
        if self.gravity_gradient:
            p = self.positions
            b = self.body
            rx, ry, rz = _rotate(qw, qx, qy, qz, p[o], p[o + 1], p[o + 2])
            ix = b.i00 * rx + b.i01 * ry + b.i02 * rz
            iy = b.i10 * rx + b.i11 * ry + b.i12 * rz
            iz = b.i20 * rx + b.i21 * ry + b.i22 * rz
            r2 = rx * rx + ry * ry + rz * rz
            c = self.gm3 / (r2 * r2 * sqrt(r2))
            tx = tx + c * (ry * iz - rz * iy)
            ty = ty + c * (rz * ix - rx * iz)
            tz = tz + c * (rx * iy - ry * ix)
        return (tx, ty, tz)

    @cython.locals(qw=cython.double, qx=cython.double, qy=cython.double, qz=cython.double)
    def __call__(self, t, q, w):
        """The torque (N m, body axes) at stage time ``t`` (s within the step) for stage state (q, w)."""
        qw, qx, qy, qz = q
        return self._at(t, qw, qx, qy, qz)


@cython.cclass
class Gyrostat:
    """The torque the body's equations take at each stage of one step of a spacecraft with wheels
    (:meth:`sim.wheels.WheeledBody.step`): ``torque(ts, q, w)`` (the environment's: an :class:`EnvironmentTorque`, any
    callable, or None for none) minus the wheels' gyroscopic torque ``w x (h0 + tau s)`` and their reaction ``tau``, in
    body axes, ``s = ts - t`` into the step. :meth:`BodyDynamics.rk4` calls it without a Python call at each stage (and
    it the environment's torque the same way), as it calls an :class:`EnvironmentTorque`.

    ``h`` = ``A h_abs`` and ``u`` = ``A tau`` (N m s, N m: the wheels' absolute momentum and net rotor torque summed on
    the body axes at the step's start), ``t`` (s) the step's start as the stepper passes it."""

    hx: cython.double
    hy: cython.double
    hz: cython.double
    ux: cython.double
    uy: cython.double
    uz: cython.double
    t: cython.double
    torque: object

    def __init__(self, hx: cython.double, hy: cython.double, hz: cython.double, ux: cython.double, uy: cython.double,
                 uz: cython.double, torque: object, t: cython.double):
        self.hx, self.hy, self.hz = hx, hy, hz
        self.ux, self.uy, self.uz = ux, uy, uz
        self.torque = torque
        self.t = t

    @cython.cfunc
    def _at(self, ts: cython.double, qw: cython.double, qx: cython.double, qy: cython.double, qz: cython.double,
            wx: cython.double, wy: cython.double, wz: cython.double) -> tuple[cython.double, cython.double,
                                                                               cython.double]:
        s: cython.double = ts - self.t  # time into the step: h(s) = h0 + tau s exactly
        bx: cython.double = self.hx + self.ux * s
        by: cython.double = self.hy + self.uy * s
        bz: cython.double = self.hz + self.uz * s
        tx: cython.double = 0.0
        ty: cython.double = 0.0
        tz: cython.double = 0.0
        torque = self.torque
        if isinstance(torque, EnvironmentTorque):
            tx, ty, tz = cython.cast(EnvironmentTorque, torque)._at(ts, qw, qx, qy, qz)
        elif torque is not None:
            tx, ty, tz = torque(ts, (qw, qx, qy, qz), (wx, wy, wz))
        return (tx - (wy * bz - wz * by) - self.ux, ty - (wz * bx - wx * bz) - self.uy,
                tz - (wx * by - wy * bx) - self.uz)

    @cython.locals(qw=cython.double, qx=cython.double, qy=cython.double, qz=cython.double, wx=cython.double,
                   wy=cython.double, wz=cython.double)
    def __call__(self, ts: cython.double, qs, ws):
        """The stage torque (N m, body axes) at stage time ``ts`` (s) for stage state (q, w): what any stepper calls."""
        qw, qx, qy, qz = qs
        wx, wy, wz = ws
        return self._at(ts, qw, qx, qy, qz, wx, wy, wz)


@cython.cfunc
@cython.inline
def _as_tuple(values: object) -> tuple:
    """``values`` when a tuple, else a tuple copy (a list or an array) that cannot change while it is read."""
    return values if type(values) is tuple else tuple(values)


@cython.cfunc
@cython.locals(n=cython.Py_ssize_t, i=cython.Py_ssize_t, x=cython.double, y=cython.double, z=cython.double,
               ax=cython.double, ay=cython.double, az=cython.double, v=cython.double)
def _axes_sum(axes: tuple, values: tuple) -> tuple[cython.double, cython.double, cython.double]:
    n = len(axes)
    if len(values) != n:
        raise ValueError(f"{len(values)} values for {n} wheels; give one per wheel.")
    x = y = z = 0.0
    for i in range(n):
        ax, ay, az = axes[i]
        v = values[i]
        x += ax * v
        y += ay * v
        z += az * v
    return x, y, z


@cython.locals(x=cython.double, y=cython.double, z=cython.double)
def axes_sum(axes: tuple, values) -> tuple:
    """``A @ values`` on floats: ``axes`` the wheels' spin axes (a tuple of ``(ax, ay, az)`` in body axes, one per
    wheel), ``values`` one number per wheel; summed from 0.0 in the wheels' order. ValueError when the counts differ."""
    x, y, z = _axes_sum(axes, _as_tuple(values))
    return x, y, z


@cython.locals(hx=cython.double, hy=cython.double, hz=cython.double, ux=cython.double, uy=cython.double,
               uz=cython.double)
def gyrostat(axes: tuple, h_abs, tau, torque, t: cython.double) -> Gyrostat:
    """The :class:`Gyrostat` of one step: the wheels' absolute momenta ``h_abs`` (N m s) and net rotor torques ``tau``
    (N m) summed on the body axes (``axes_sum``), around the environment's ``torque``, from the step's start ``t``."""
    hx, hy, hz = _axes_sum(axes, _as_tuple(h_abs))
    ux, uy, uz = _axes_sum(axes, _as_tuple(tau))
    return Gyrostat(hx, hy, hz, ux, uy, uz, torque, t)


@cython.locals(n=cython.Py_ssize_t, i=cython.Py_ssize_t, h=cython.double, u=cython.double)
def momentum_after(h_abs, tau, dt: cython.double) -> tuple:
    """``h + tau dt`` per wheel: the wheels' absolute momenta (N m s) after ``dt`` seconds with ``tau`` (N m) held, a
    tuple of floats. A ValueError when the counts differ, in the words ``zip(strict=True)`` uses."""
    hs: tuple = _as_tuple(h_abs)
    us: tuple = _as_tuple(tau)
    n = len(hs)
    if len(us) != n:
        raise ValueError(f"zip() argument 2 is {'shorter' if len(us) < n else 'longer'} than argument 1")
    out = []
    for i in range(n):
        h = hs[i]
        u = us[i]
        out.append(h + u * dt)
    return tuple(out)


@cython.locals(wx=cython.double, wy=cython.double, wz=cython.double, wn=cython.double, hx=cython.double,
               hy=cython.double, hz=cython.double, nutation=cython.double)
def fastest_rate(axes: tuple, w, h_abs, inv_imin: cython.double, nutation_per_rate: cython.double):
    """The rotation or nutation rate (rad/s) a wheeled body's step guard bounds (:meth:`sim.wheels.WheeledBody.
    fastest_rate`): ``max(|w|, |w| nutation_per_rate + |A h_abs| inv_imin)``, ``inv_imin`` 1 / the hub's smallest
    principal inertia. ``max`` as Python's builtin makes it: the second only when strictly greater."""
    wx, wy, wz = w
    wn = sqrt(wx * wx + wy * wy + wz * wz)
    hx, hy, hz = _axes_sum(axes, _as_tuple(h_abs))
    nutation = wn * nutation_per_rate + sqrt(hx * hx + hy * hy + hz * hz) * inv_imin
    return nutation if nutation > wn else wn


@cython.locals(wx=cython.double, wy=cython.double, wz=cython.double, n=cython.Py_ssize_t, i=cython.Py_ssize_t,
               ax=cython.double, ay=cython.double, az=cython.double, h=cython.double, j=cython.double)
def relative_speeds(axes: tuple, inertias: tuple, h_abs: tuple, w) -> tuple:
    """The wheels' speeds relative to the body (rad/s), ``h / J - a . w`` per wheel, from their absolute momenta
    ``h_abs`` (N m s), spin inertias ``inertias`` (kg m^2) and axes, and the body rate ``w`` (rad/s)."""
    wx, wy, wz = w
    n = len(axes)
    if len(inertias) != n or len(h_abs) != n:
        raise ValueError(f"{len(h_abs)} momenta and {len(inertias)} inertias for {n} wheels; give one per wheel.")
    out = []
    for i in range(n):
        ax, ay, az = axes[i]
        h = h_abs[i]
        j = inertias[i]
        out.append(h / j - (ax * wx + ay * wy + az * wz))
    return tuple(out)


@cython.locals(n=cython.Py_ssize_t, i=cython.Py_ssize_t)
def finite_floats(values, n: cython.Py_ssize_t):
    """``values`` itself when it is a tuple of ``n`` finite numbers of type ``float`` exactly (so ``float()`` of each
    is itself), else None: the quick yes of a caller's check, which converts and checks in full otherwise."""
    if type(values) is not tuple or len(values) != n:
        return None
    for i in range(n):
        v = values[i]
        if type(v) is not float or not isfinite(v):
            return None
    return values
