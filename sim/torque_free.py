"""Closed-form motion of a torque-free rigid body (Jacobi elliptic functions): the attitude oracle.

Rates (Landau & Lifshitz, *Mechanics*, section 37). Work in a principal frame with moments
I1 < I2 < I3, angular momentum H = |I omega| and energy T. The quantity D = H^2 / (2 T) lies in
[I1, I3]; the polhode circulates round the major axis (c = 3) when D > I2 and round the minor
axis (c = 1) when D < I2; e is the other extreme axis, m = 2 the middle one. Then

    omega_e = s a cn(u),   omega_m = b sn(u),   omega_c = s c dn(u),   u = lam t + u0,

    a^2 = 2T (Ic - D) / (Ie (Ic - Ie)),   b^2 = 2T (Ic - D) / (Im (Ic - Im)),
    c^2 = 2T (D - Ie) / (Ic (Ic - Ie)),   lam^2 = 2T (Ic - Im)(D - Ie) / (Ie Im Ic),
    k^2 = (Im - Ie)(Ic - D) / ((Ic - Im)(D - Ie)),  1 - k^2 = (Ic - Ie)(D - Im) / ((Ic - Im)(D - Ie)),

with s = sign(omega_c) (constant on a branch). Both branches use the same formulas because
Euler's equations give kappa_e < 0 < kappa_m on both (checked in the tests against DOP853), so no
relabelling of the rates is needed. Every difference such as 2T (D - I2) is computed as a sum of
terms of one sign, sum_i I_i (I_i - I2) omega_i^2, so nothing cancels near the separatrix, and
1 - k^2 goes to ``ellipkm1`` directly.

Attitude. Let L be the inertial frame whose z axis is the angular momentum. In a body-fixed
frame F whose z axis is the circulating axis (a cyclic relabelling of the principal axes, so F
stays right-handed), ``dcm_FL = R3(psi) R1(theta) R3(phi)``: theta and psi follow from the body
angular-momentum direction h_F = (sin theta sin psi, sin theta cos psi, cos theta), and
phi' = H (h_x^2 / Ix + h_y^2 / Iy) / (h_x^2 + h_y^2) is integrated by quadrature (Gauss-Legendre
on panels of one period of phi', multiplied out over whole periods). This is the "semi-exact"
solution of Celledoni, Fasso, Saefstroem & Zanna (2008).

Special cases: equal moments (axisymmetric) use the trigonometric solution (k = 0: sn = sin,
cn = cos, dn = 1, phi' constant); a spin exactly about a principal axis is a uniform rotation;
a state exactly on the separatrix (D = I2, k = 1, infinite period) is refused.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ellipj, ellipkinc, ellipkm1

from .rigid_body import check_inertia
from .rotations import canonical, check_unit, dcm, quat_from_dcm

#: Relative distance |D - I2| / I2 below which a state counts as on the separatrix. There the
#: period is infinite (K(k) ~ ln(4 / sqrt(1 - k^2))) and the elliptic parameter rounds to 1.
SEPARATRIX_TOLERANCE = 1e-14

#: Smallest complementary parameter 1 - k^2 the closed form accepts. Measured (inertia (1, 2, 1.5)
#: and (10, 20, 30)): at 1 - k^2 = 4e-11 and 9.6e-11 the energy is off by 1e19 to 1e23 relative after
#: 2000 to 1e5 s (the elliptic functions lose their digits far from t = 0), while from 1.3e-10 on it
#: stays exact to 6e-16 over 1e5 s. Below the limit the body is refused, never silently wrong.
NEAR_SEPARATRIX_M1 = 1e-10

#: Moments closer than this (relative) are treated as equal: the body is axisymmetric.
AXISYMMETRIC_TOLERANCE = 1e-14

_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(20)
_PANELS = 64


def _rot1(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack((np.stack((o, z, z), -1), np.stack((z, c, s), -1), np.stack((z, -s, c), -1)), -2)


def _rot3(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack((np.stack((c, s, z), -1), np.stack((-s, c, z), -1), np.stack((z, z, o), -1)), -2)


class TorqueFreeBody:
    """Exact torque-free motion from ``(q_BN, omega_BN_B)`` at t = 0 for ``inertia`` (kg m^2).

    ``inertia`` is 3 principal moments or a symmetric 3x3 matrix in body axes (any order, any
    orientation of the principal axes). ``omega(t)`` gives rad/s in body axes, ``attitude(t)``
    the unit quaternion q_BN (w >= 0), ``state(t)`` both; ``t`` in s, scalar or array.
    """

    def __init__(self, inertia, q_BN, omega_BN_B):
        I = check_inertia(inertia)
        q0 = check_unit(q_BN, "q_BN")
        w0 = np.asarray(omega_BN_B, dtype=float)
        if w0.shape != (3,) or not np.all(np.isfinite(w0)):
            raise ValueError(f"omega_BN_B = {omega_BN_B!r} must be 3 finite rates in rad/s.")
        moments, V = np.linalg.eigh(I)  # ascending; columns are principal axes in body components
        if np.linalg.det(V) < 0:
            V[:, 0] = -V[:, 0]
        # Snap near-equal moments to exactly equal, so the axisymmetric branch is taken cleanly.
        for i in range(2):
            if moments[i + 1] - moments[i] <= AXISYMMETRIC_TOLERANCE * moments[2]:
                moments[i + 1] = moments[i]
        self.moments = moments
        self._R_PB = V.T  # principal (sorted) axes from body axes, proper rotation
        self._dcm_BN0 = dcm(q0)
        wp = self._R_PB @ w0
        I1, I2, I3 = moments
        two_t = float(np.sum(moments * wp * wp))
        self.energy = 0.5 * two_t
        self.momentum = float(np.linalg.norm(moments * wp))
        self._kind = "elliptic"
        if self.momentum == 0.0:
            self._kind = "rest"
            self._omega_P = wp
            return
        # 2T (D - I_j) for each axis j, as sums of one-signed terms (no cancellation).
        d_minus = [float(np.sum(moments * (moments - moments[j]) * wp * wp)) for j in range(3)]
        if not np.any(np.cross(moments * wp, wp)):
            # omega parallel to I omega: a spin exactly about a principal axis (including the
            # middle one, or any axis of a symmetric plane or a sphere). Euler's equations give
            # exactly zero derivative, so omega is constant and the body turns uniformly.
            self._kind = "uniform"
            self._omega_P = wp
            return
        if abs(d_minus[1]) <= SEPARATRIX_TOLERANCE * I2 * two_t and I1 < I2 < I3:
            raise ValueError(
                f"the state omega_BN_B = {w0.tolist()} rad/s lies on the separatrix of inertia "
                f"{moments.tolist()} kg m^2: D = H^2/(2T) equals the middle moment I2 to within "
                f"{SEPARATRIX_TOLERANCE:g} relative (|D - I2| / I2 = {abs(d_minus[1]) / (two_t * I2):.3g}). "
                "There the elliptic parameter k^2 is 1 and the period infinite, so the closed form "
                "does not apply; integrate numerically (method='dop853') instead."
            )
        # Major-axis branch when D > I2 (an oblate body, I1 = I2, always lands here; a prolate one,
        # I2 = I3, always on the minor-axis branch).
        c = 2 if d_minus[1] > 0 else 0
        e = 2 - c
        m = 1
        Ic, Ie, Im = moments[c], moments[e], moments[m]
        ic_minus_d = -d_minus[c]  # 2T (Ic - D) with the sign of (Ic - D)
        d_minus_e = d_minus[e]
        if ic_minus_d == 0.0 or d_minus_e == 0.0:
            # The off-axis part underflows (e.g. 1e-179 rad/s): a principal-axis spin in double.
            self._kind = "uniform"
            self._omega_P = wp
            return
        # Amplitudes; each ratio is positive on its branch.
        self._a = math.sqrt(ic_minus_d / (Ie * (Ic - Ie)))
        self._b = math.sqrt(ic_minus_d / (Im * (Ic - Im))) if Ic != Im else 0.0
        self._c = math.sqrt(d_minus_e / (Ic * (Ic - Ie)))
        if Ie == Im:
            # Axisymmetric about c: the transverse rate turns at lam = (Ic - Ie) omega_c / Ie.
            self._k2, self._m1 = 0.0, 1.0
            self._lam = abs((Ic - Ie) / Ie) * self._c
            self._b = self._a
        else:
            self._lam = math.sqrt((Ic - Im) * d_minus_e / (Ie * Im * Ic))
            self._k2 = (Im - Ie) * ic_minus_d / ((Ic - Im) * d_minus_e)
            self._m1 = (Ic - Ie) * d_minus[m] / ((Ic - Im) * d_minus_e)
            if abs(self._m1) < NEAR_SEPARATRIX_M1:
                raise ValueError(
                    f"the state omega_BN_B = {w0.tolist()} rad/s is too close to the separatrix of inertia "
                    f"{moments.tolist()} kg m^2 for the closed form: 1 - k^2 = {self._m1:.3g}, and below "
                    f"{NEAR_SEPARATRIX_M1:g} scipy's Jacobi elliptic functions lose all accuracy within a few "
                    "periods (energy errors grow without bound); integrate numerically (method='dop853')."
                )
        self._s = 1.0 if wp[c] > 0 else -1.0
        self._axes = (e, m, c)
        self._quarter = float(ellipkm1(self._m1)) if self._k2 > 0 else 0.5 * math.pi
        phi0 = math.atan2(wp[m] / self._b, self._s * wp[e] / self._a)
        self._u0 = float(ellipkinc(phi0, self._k2)) if self._k2 > 0 else phi0
        # Body frame F: a cyclic relabelling of P with the circulating axis as z (right-handed).
        perm = [(c + 1) % 3, (c + 2) % 3, c]
        self._R_FP = np.eye(3)[perm]
        self._IF = moments[perm]
        # Quadrature of phi' over one period 2K of u (sn^2, cn^2 have period 2K), on panels.
        period = 2.0 * self._quarter
        edges = np.linspace(0.0, period, _PANELS + 1)
        self._edges = edges
        self._panel_int = self._integrate_phidot(edges[:-1], edges[1:])
        self._cum = np.concatenate(([0.0], np.cumsum(self._panel_int)))
        self._phi_u0 = self._G(np.array([self._u0]))[0]
        h0 = self._h_F(np.array([self._u0]))[0]
        self._dcm_LN = self._dcm_FL(h0, 0.0).T @ self._R_FP @ self._R_PB @ self._dcm_BN0

    # -- rates -------------------------------------------------------------------------------
    def _sncndn(self, u):
        if self._k2 == 0.0:
            return np.sin(u), np.cos(u), np.ones_like(u)
        # Reduce by the period 4K first: ellipj loses digits for large arguments.
        u = np.fmod(u, 4.0 * self._quarter)
        sn, cn, dn, _ = ellipj(u, self._k2)
        return sn, cn, dn

    def _omega_P_u(self, u):
        sn, cn, dn = self._sncndn(u)
        e, m, c = self._axes
        w = np.empty(np.shape(u) + (3,))
        w[..., e] = self._s * self._a * cn
        w[..., m] = self._b * sn
        w[..., c] = self._s * self._c * dn
        return w

    def _h_F(self, u):
        """Unit angular-momentum direction in F for parameter values u."""
        hP = self._omega_P_u(u) * self.moments
        return (hP @ self._R_FP.T) / self.momentum

    def _phidot(self, u):
        h = self._h_F(u)
        hx2, hy2 = h[..., 0] ** 2, h[..., 1] ** 2
        den = hx2 + hy2
        safe = np.where(den > 0, den, 1.0)
        # At sin(theta) = 0 the ratio tends to a value between H/Ix and H/Iy; the node never lands
        # exactly there off a principal-axis spin (handled separately), so this is a guard only.
        return np.where(den > 0, self.momentum * (hx2 / self._IF[0] + hy2 / self._IF[1]) / safe,
                        self.momentum / self._IF[0])

    def _integrate_phidot(self, lo, hi):
        lo = np.asarray(lo, dtype=float)
        hi = np.asarray(hi, dtype=float)
        half = 0.5 * (hi - lo)
        mid = 0.5 * (hi + lo)
        u = mid[..., None] + half[..., None] * _GL_NODES
        return half * np.sum(self._phidot(u) * _GL_WEIGHTS, axis=-1)

    def _G(self, u):
        """Integral of phi' du from 0 to u (rad times the u scale), exact to quadrature precision."""
        period = 2.0 * self._quarter
        n = np.floor(u / period)
        r = u - n * period
        width = period / _PANELS
        j = np.clip((r / width).astype(int), 0, _PANELS - 1)
        start = self._edges[j]
        return n * self._cum[-1] + self._cum[j] + self._integrate_phidot(start, r)

    @staticmethod
    def _dcm_FL(h, phi):
        theta = np.arctan2(np.hypot(h[..., 0], h[..., 1]), h[..., 2])
        psi = np.arctan2(h[..., 0], h[..., 1])
        return _rot3(psi) @ _rot1(theta) @ _rot3(np.asarray(phi, dtype=float))

    # -- public ------------------------------------------------------------------------------
    def omega(self, t) -> np.ndarray:
        """Body rate omega_BN_B (rad/s) at time(s) ``t`` (s)."""
        t = np.asarray(t, dtype=float)
        if self._kind != "elliptic":
            wP = np.broadcast_to(self._omega_P, t.shape + (3,))
        else:
            wP = self._omega_P_u(self._lam * t + self._u0)
        return wP @ self._R_PB  # R_PB^T applied on the right-hand side of row vectors

    def attitude(self, t) -> np.ndarray:
        """Attitude q_BN (unit, w >= 0) at time(s) ``t`` (s)."""
        return self.state(t)[0]

    def state(self, t):
        """``(q_BN, omega_BN_B)`` at time(s) ``t`` (s)."""
        t = np.asarray(t, dtype=float)
        w = self.omega(t)
        if self._kind == "rest":
            return np.broadcast_to(quat_from_dcm(self._dcm_BN0), t.shape + (4,)).copy(), w
        if self._kind == "uniform":
            wn = float(np.linalg.norm(self._omega_P))
            axis_B = self._R_PB.T @ self._omega_P / wn
            # Rotation of B about a fixed axis: dcm_BN(t) = R_axis(wn t) dcm_BN(0) (passive).
            ang = wn * t
            c, s = np.cos(ang)[..., None, None], np.sin(ang)[..., None, None]
            K = np.array([[0.0, axis_B[2], -axis_B[1]], [-axis_B[2], 0.0, axis_B[0]],
                          [axis_B[1], -axis_B[0], 0.0]])
            R = c * np.eye(3) + (1 - c) * np.outer(axis_B, axis_B) + s * K
            return canonical(quat_from_dcm(R @ self._dcm_BN0)), w
        u = self._lam * t + self._u0
        phi = (self._G(u) - self._phi_u0) / self._lam
        C_FL = self._dcm_FL(self._h_F(u), phi)
        C_BN = self._R_PB.T @ self._R_FP.T @ C_FL @ self._dcm_LN
        return quat_from_dcm(C_BN), w

    @property
    def k2(self) -> float:
        """Elliptic parameter k^2 (0 for axisymmetric bodies; -> 1 at the separatrix)."""
        return getattr(self, "_k2", 0.0)

    @property
    def period_s(self) -> float:
        """Period of the body rates (s): 4K / lam (inf for a uniform spin or rest)."""
        if self._kind != "elliptic":
            return math.inf
        return 4.0 * self._quarter / self._lam


def propagate_exact(inertia, q_BN, omega_BN_B, t):
    """Exact ``(q, omega)`` of a torque-free body at times ``t`` (s); see :class:`TorqueFreeBody`."""
    return TorqueFreeBody(inertia, q_BN, omega_BN_B).state(t)
