"""A pointing plug-in template: star tracker, gyro and reaction wheels through their host drivers.

Copy this file, rename the class, replace the estimator and the control law with your own. Use it from a scenario
that has a star tracker, a gyro and three or more reaction wheels::

    [controller]
    kind = "plugin"
    rate_hz = 10.0
    module = "pointing_template:PointingTemplate"
    path = "../examples"                          # the folder holding it, relative to the scenario file
    options = { q_RN = [1.0, 0.0, 0.0, 0.0] }     # the mission's choices only: the spacecraft comes from the stand

Everything the scenario says of the spacecraft (inertia, mounts, wheel axes, rotor inertias, ratings) arrives
in ``spacecraft`` (``stand.controllers.spacecraft.Spacecraft``, docs/plugins.md): no option repeats it. The
criteria ``pointing_error_arcsec_p95_after`` and ``knowledge_error_arcsec_p95_after`` read the columns
``adcs_q_RN`` (the commanded attitude) and ``adcs_q_BN_est`` (the estimate) this class records; a scenario with
those criteria and a plug-in that does not record them is refused by ``stand check``.

Conventions (docs/conventions.md): quaternions scalar first, ``q_XY`` the attitude of frame X relative to Y,
``dcm(q_XY) @ v_Y = v_X``; ``q_SB`` a device's frame relative to the body; SI units.
"""

from __future__ import annotations

import math

import numpy as np

from sim.rotations import compose, conjugate, dcm


class PointingTemplate:
    def __init__(self, devices, period_s, spacecraft, q_RN=(1.0, 0.0, 0.0, 0.0), natural_frequency_rad_s=0.15,
                 damping_ratio=0.9):
        self.period_s = period_s
        # What the stand tells of the spacecraft: the first tracker and gyro, every wheel.
        tracker, gyro = spacecraft.of_kind("star_tracker")[0], spacecraft.of_kind("gyro")[0]
        self.tracker, self.gyro = devices[tracker.name], devices[gyro.name]
        self.wheels = [devices[w.name] for w in spacecraft.wheels]
        self.q_BT = conjugate(tracker.q_SB)            # body relative to the tracker frame
        self.dcm_BS_gyro = dcm(gyro.q_SB).T            # gyro axes -> body axes
        self.inertia = np.array(spacecraft.inertia_kg_m2)
        self.A = spacecraft.wheel_axes_B()             # 3 x n: the body torque is -A @ wheel torques
        self.J = np.array([w.inertia_kg_m2 for w in spacecraft.wheels])
        self.max_torque = min(w.max_torque_Nm for w in spacecraft.wheels)
        self.A_pinv = np.linalg.pinv(self.A)
        wn, zeta = natural_frequency_rad_s, damping_ratio
        self.Kp, self.Kd = wn * wn * self.inertia, 2.0 * zeta * wn * self.inertia
        self.q_RN = np.asarray(q_RN, dtype=float)
        self.q_BN_est = None                           # no estimate before the first valid solution
        self.omega_B = np.zeros(3)
        self.speeds = np.zeros(len(self.wheels))
        self.torques = np.zeros(len(self.wheels))

    # -- what the stand records and the criteria read ----------------------------------------------------------

    def telemetry_columns(self):
        return [("adcs_q_BN_est", 4, ""), ("adcs_sigma3_B", 3, "rad"), ("adcs_q_RN", 4, ""), ("adcs_mode", 1, ""),
                ("fsw.wheel_torque_cmd", len(self.wheels), "N m")]

    def telemetry(self):
        est = tuple(self.q_BN_est) if self.q_BN_est is not None else (math.nan,) * 4
        mode = 0.0 if self.q_BN_est is None else 1.0
        # No filter here, so no 3-sigma: NaN leaves it out of knowledge_within_3sigma_fraction.
        return (*est, *(math.nan,) * 3, *self.q_RN, mode, *self.torques)

    # -- once per control period -------------------------------------------------------------------------------

    def update(self, t_s):
        rate = self.gyro.take_rate()                   # None when nothing new arrived
        if rate is not None and rate.valid:            # else keep the last rate
            self.omega_B = self.dcm_BS_gyro @ np.asarray(rate.omega_rad_s)
        for i, wheel in enumerate(self.wheels):
            speed = wheel.take_speed()                 # rad/s relative to the body, or None
            if speed is not None and speed.valid:
                self.speeds[i] = float(speed)
        sol = self.tracker.take_solution()
        if sol is not None and sol.valid:
            self.q_BN_est = compose(self.q_BT, sol.q_TN)   # tracker frame in GCRS -> body in GCRS
        elif self.q_BN_est is not None:               # propagate on the gyro between solutions
            half = 0.5 * self.period_s * self.omega_B
            dq = np.array([1.0, *half]) / math.sqrt(1.0 + half @ half)
            self.q_BN_est = compose(dq, self.q_BN_est)
        if self.q_BN_est is None:
            torque_B = -self.Kd @ self.omega_B          # no attitude yet: damp the rate
        else:
            q_BR = compose(self.q_BN_est, conjugate(self.q_RN))
            torque_B = -self.Kp @ (2.0 * q_BR[1:]) - self.Kd @ self.omega_B
        # Gyroscopic compensation with the wheels' momentum, then the wheel torques: body torque = -A @ torques.
        h_B = self.inertia @ self.omega_B + self.A @ (self.J * (self.speeds + self.A.T @ self.omega_B))
        torque_B = torque_B + np.cross(self.omega_B, h_B)
        torques = -self.A_pinv @ torque_B
        peak = np.max(np.abs(torques))
        if peak > self.max_torque:                     # keep the direction, respect the rating
            torques *= self.max_torque / peak
        self.torques = torques
        for wheel, tau in zip(self.wheels, torques, strict=True):
            wheel.command_torque(float(tau))           # N m on the rotor about its spin axis

    def close(self):
        """Called once at the end of the run (optional)."""
