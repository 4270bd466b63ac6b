"""Basilisk's inertial MRP feedback on reaction wheels as a plug-in
(``module = "stand.adcs.mrp_feedback:MrpFeedback"``): the flight code of
``fixtures/scenarios/wheel_pointing_basilisk.toml``, which reproduces Basilisk 2.12.1's example
``scenarioAttitudeFeedbackRW`` through the stand's devices (``fixtures/reference/basilisk/README.md``).

It is the chain of Basilisk modules that example flies, written from their documented equations:

* ``inertial3D``: a fixed reference attitude ``sigma_RN`` (omega_RN = 0, domega_RN = 0);
* ``attTrackingError``: sigma_BR = sigma_BN relative to sigma_RN (the short way round, |sigma_BR| <= 1),
  omega_BR_B = omega_BN_B;
* ``mrpFeedback`` without its integral term (Ki < 0): L_r = -K sigma_BR - P omega_BR_B. Its other terms are
  -[omega_RN + Ki z]~ (I omega + sum h_s g_s) and I (omega x omega_RN - domega_RN): with an inertial reference
  and no integral term both are zero, so the wheel speeds it reads do not enter and this plug-in does not read them;
* ``rwMotorTorque`` on the three body axes: u_s = -G_s^T (G_s G_s^T)^-1 L_r, one motor torque per wheel (a positive
  u_s speeds the rotor up and torques the body by -u_s g_s, as a wheel's ``command_torque`` does).

Navigation is the devices': the attitude from the star tracker's solution (``q_TN`` through the tracker's mount),
the rate from the gyro (through its mount). Basilisk's ``simpleNav`` is perfect; the stand's ideal gyro and
noise-free tracker differ from it only by their wire's resolution (2^-14 deg/s, float32). When the tracker has no
valid solution in a period, the attitude is carried forward on the gyro's rate over the period.

Per-period work is on floats and tuples (no numpy): it runs every control period.
"""

from __future__ import annotations

import math

import numpy as np

from sim.rotations import conjugate, dcm, hamilton_floats

__all__ = ["MrpFeedback", "mrp_from_quat"]


def mrp_from_quat(q) -> tuple:
    """The MRP ``q_vec / (1 + q_w)`` of the short rotation (the quaternion's sign with q_w >= 0): |sigma| <= 1."""
    w, x, y, z = q
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    d = 1.0 + w
    return (x / d, y / d, z / d)


def _quat_from_mrp(sigma) -> tuple:
    s1, s2, s3 = (float(v) for v in sigma)
    s = s1 * s1 + s2 * s2 + s3 * s3
    d = 1.0 + s
    return ((1.0 - s) / d, 2.0 * s1 / d, 2.0 * s2 / d, 2.0 * s3 / d)


class MrpFeedback:
    """``MrpFeedback(devices, period_s, spacecraft, k_Nm=3.5, p_Nm_s=30.0, sigma_RN=(0, 0, 0))``: the first star
    tracker and gyro of the spacecraft description, every wheel. Gains as Basilisk's ``mrpFeedback.K`` (N m per
    unit MRP) and ``.P`` (N m s)."""

    def __init__(self, devices, period_s, spacecraft, k_Nm=3.5, p_Nm_s=30.0, sigma_RN=(0.0, 0.0, 0.0)):
        trackers, gyros = spacecraft.of_kind("star_tracker"), spacecraft.of_kind("gyro")
        if not trackers or not gyros or len(spacecraft.wheels) < 3:
            raise ValueError("MrpFeedback needs a star tracker, a gyro and at least three reaction wheels; the "
                             f"scenario has {len(trackers)}, {len(gyros)} and {len(spacecraft.wheels)}.")
        for name, value in (("k_Nm", k_Nm), ("p_Nm_s", p_Nm_s)):
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0.0):
                raise ValueError(f"controller.options.{name} = {value!r}; give a positive gain.")
        self.period_s = float(period_s)
        self.k, self.p = float(k_Nm), float(p_Nm_s)
        self.tracker, self.gyro = devices[trackers[0].name], devices[gyros[0].name]
        self.wheels = [devices[w.name] for w in spacecraft.wheels]
        self.q_BT = tuple(float(v) for v in conjugate(trackers[0].q_SB))  # q_BN = q_TN composed with q_BT
        self.dcm_BS = tuple(tuple(float(v) for v in row) for row in dcm(gyros[0].q_SB).T)
        self.q_NR = tuple(float(v) for v in conjugate(_quat_from_mrp(sigma_RN)))
        self.q_RN = conjugate(self.q_NR).tolist()
        # rwMotorTorque's minimum-norm map, once: u_s = -G_s^T (G_s G_s^T)^-1 L_r (n x 3)
        G = spacecraft.wheel_axes_B()
        self.map = tuple(tuple(float(v) for v in row) for row in -(G.T @ np.linalg.inv(G @ G.T)))
        self.q_BN = None  # the attitude the last period used
        self.omega_B = (0.0, 0.0, 0.0)
        self.sigma_BR = (math.nan,) * 3
        self._no_torque = (0.0,) * len(self.wheels)
        self.u_s = self._no_torque

    #: What its columns mean (the telemetry's schema and docs/telemetry_columns.md read it).
    column_meanings = {
        "adcs_q_BN_est": "the attitude it flies on, body relative to inertial, scalar first: the tracker's, carried "
                         "on the gyro's rate while no valid solution arrives (NaN before the first)",
        "adcs_q_RN": "the commanded (reference) attitude, relative to inertial, scalar first",
        "adcs_mode": "1 once it has an attitude (it then points), 0 before",
        "fsw.sigma_BR": "the attitude error MRP, body relative to the reference (shadow set, |sigma| <= 1)",
        "fsw.wheel_torque_cmd": "the motor torque commanded to each wheel, in the order of the scenario's wheels",
    }

    def telemetry_columns(self):
        return [("adcs_q_BN_est", 4, ""), ("adcs_q_RN", 4, ""), ("adcs_mode", 1, ""), ("fsw.sigma_BR", 3, ""),
                ("fsw.wheel_torque_cmd", len(self.wheels), "N m")]

    def telemetry(self):
        est = self.q_BN if self.q_BN is not None else (math.nan,) * 4
        return (*est, *self.q_RN, 0.0 if self.q_BN is None else 1.0, *self.sigma_BR, *self.u_s)

    def _navigate(self):
        """The body rate from the gyro (kept from the last sample when none arrived) and the attitude from the
        tracker, carried forward on that rate when the tracker has no valid solution this period."""
        rate = self.gyro.take_rate()
        if rate is not None and rate.valid:
            wx, wy, wz = rate.omega_rad_s
            (a, b, c), (d, e, f), (g, h, i) = self.dcm_BS
            self.omega_B = (a * wx + b * wy + c * wz, d * wx + e * wy + f * wz, g * wx + h * wy + i * wz)
        sol = self.tracker.take_solution()
        if sol is not None and sol.valid:
            self.q_BN = hamilton_floats(tuple(sol.q_TN), self.q_BT)
        elif self.q_BN is not None:
            wx, wy, wz = self.omega_B
            n = math.sqrt(wx * wx + wy * wy + wz * wz)
            half = 0.5 * n * self.period_s
            s = math.sin(half) / n if n > 0.0 else 0.5 * self.period_s
            self.q_BN = hamilton_floats(self.q_BN, (math.cos(half), s * wx, s * wy, s * wz))

    def update(self, t_s):
        self._navigate()
        if self.q_BN is None:  # no attitude yet: the wheels hold no torque
            self.u_s = self._no_torque
        else:
            s1, s2, s3 = self.sigma_BR = mrp_from_quat(hamilton_floats(self.q_NR, self.q_BN))
            wx, wy, wz = self.omega_B  # omega_BR_B: the reference does not turn
            k, p = self.k, self.p
            l1, l2, l3 = -k * s1 - p * wx, -k * s2 - p * wy, -k * s3 - p * wz
            u_s = []  # a loop, not a comprehension: no frame of its own every period (Python 3.11)
            for m1, m2, m3 in self.map:
                u_s.append(m1 * l1 + m2 * l2 + m3 * l3)
            self.u_s = tuple(u_s)
        for wheel, u in zip(self.wheels, self.u_s, strict=True):
            wheel.command_torque(u)
