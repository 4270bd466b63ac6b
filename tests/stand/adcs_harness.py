"""A closed loop for the reference ADCS without device kinds: fake host drivers (the plug-in API's method names)
over sim's truth model with reaction wheels."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from sim.rotations import compose, dcm, quat_from_axis_angle
from sim.truth import TruthModel
from sim.wheels import WheelCluster

INERTIA = [[10.0, 0.2, -0.1], [0.2, 12.0, 0.15], [-0.1, 0.15, 8.0]]
R_ORBIT = 6878137.0
V_ORBIT = math.sqrt(3.986004418e14 / R_ORBIT)
Q_TB = tuple(quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), math.radians(30.0)))  # tracker tilted off +z
Q_GB = tuple(quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), math.radians(90.0)))  # gyro turned about z


class FakeTracker:
    def __init__(self, loop):
        self.loop = loop
        self.outages: list[tuple[float, float]] = []  # (start_s, end_s): no valid solution inside

    def take_solution(self):
        t = self.loop.truth.t_s
        valid = not any(a <= t < b for a, b in self.outages)
        q = compose(Q_TB, self.loop.truth.q)  # q_TN
        if valid and self.loop.tracker_noise_rad > 0:
            err = self.loop.rng.normal(0.0, self.loop.tracker_noise_rad, 3)
            q = compose(quat_from_axis_angle(err / np.linalg.norm(err), np.linalg.norm(err)), q)
        return SimpleNamespace(q_TN=tuple(q), valid=valid, time_us=int(round(t * 1e6)))


class FakeGyro:
    def __init__(self, loop):
        self.loop = loop

    def take_rate(self):
        w = dcm(np.array(Q_GB)) @ (np.array(self.loop.truth.w) + self.loop.gyro_bias)
        return SimpleNamespace(omega_rad_s=tuple(w), valid=True, time_us=int(round(self.loop.truth.t_s * 1e6)))


class FakeWheel:
    def __init__(self, loop, i, as_sample=False):
        self.loop, self.i, self.as_sample = loop, i, as_sample
        self.command = 0.0

    def take_speed(self):
        s = self.loop.truth.wheel_speeds_rad_s[self.i]
        return SimpleNamespace(speed_rad_s=s, valid=True) if self.as_sample else s

    def command_torque(self, torque_Nm):
        if not math.isfinite(torque_Nm):
            raise ValueError("non-finite wheel torque")
        lim = self.loop.max_torque
        self.command = max(-lim, min(lim, float(torque_Nm)))


class FakeMagnetorquer:
    def __init__(self, loop):
        self.loop = loop
        self.dipole = (0.0, 0.0, 0.0)

    def take_sample(self):
        return SimpleNamespace(b_T=tuple(self.loop.truth.b_B()), valid=True, coil_active=False, seq=0)

    def command_dipole(self, m_A_m2, duration_s):
        if not all(math.isfinite(x) for x in m_A_m2) or duration_s < 0:
            raise ValueError("bad dipole command")
        self.dipole = tuple(float(x) for x in m_A_m2)


class FakeFineSunSensor:
    """Boresight body +z, 60 deg half-cone; the Sun fixed in GCRS."""

    def __init__(self, loop, sun_N):
        self.loop = loop
        self.sun_N = np.asarray(sun_N, dtype=float) / np.linalg.norm(sun_N)

    def take_sun(self):
        s = dcm(np.array(self.loop.truth.q)) @ self.sun_N
        valid = s[2] >= math.cos(math.radians(60.0))
        angles = (math.atan2(s[0], s[2]), math.atan2(s[1], s[2])) if valid else (math.nan, math.nan)
        return SimpleNamespace(angles_rad=angles, valid=bool(valid), intensity=1.0, time_us=0, seq=0)


class Loop:
    """Truth with wheels, fake devices, and the controller called every ``ctl_every`` dynamics steps."""

    def __init__(self, q0, w0=(0.0, 0.0, 0.0), axes=None, J=0.02, speeds=None, step_s=0.05, seed=1,
                 gyro_bias=(0.0, 0.0, 0.0), tracker_noise_rad=0.0, max_torque=0.05, magnetic=False,
                 inclination_deg=0.0):
        axes = np.eye(3) if axes is None else np.asarray(axes, dtype=float)
        n = axes.shape[1]
        field = rotation = None
        if magnetic:  # a tilted dipole on a uniformly turning Earth: the field a magnetorquer can push on
            from sim.environment import dipole_field_itrs
            from sim.frames import EarthRotation
            from sim.time import Epoch

            rotation = EarthRotation(Epoch.from_iso("2026-03-01T00:00:00Z"), "uniform")

            def field(t_s, r_itrs):
                return dipole_field_itrs(r_itrs)
        inc = math.radians(inclination_deg)
        self.truth = TruthModel(inertia=INERTIA, q_BN=q0, omega_BN_B=w0, r_N=(R_ORBIT, 0.0, 0.0),
                                v_N=(0.0, V_ORBIT * math.cos(inc), V_ORBIT * math.sin(inc)),
                                step_ns=int(round(step_s * 1e9)), gravity="point",
                                torques=("magnetic",) if magnetic else (), field_itrs=field, earth_rotation=rotation,
                                wheels=WheelCluster(axes, [J] * n),
                                wheel_speeds_rad_s=speeds if speeds is not None else [0.0] * n)
        self.rng = np.random.default_rng(seed)
        self.gyro_bias = np.asarray(gyro_bias, dtype=float)
        self.tracker_noise_rad = tracker_noise_rad
        self.max_torque = max_torque
        self.tracker = FakeTracker(self)
        self.gyro = FakeGyro(self)
        self.wheels = [FakeWheel(self, i, as_sample=(i % 2 == 1)) for i in range(n)]
        self.devices = {"st": self.tracker, "imu": self.gyro, **{f"rw{i}": w for i, w in enumerate(self.wheels)}}
        if magnetic:
            self.mtq = self.devices["mtq"] = FakeMagnetorquer(self)

    def run(self, controller, duration_s, ctl_every=2, record=None):
        n = int(round(duration_s / self.truth.h))
        for k in range(n):
            if k % ctl_every == 0:
                controller.update(self.truth.t_s)
                if record is not None:
                    record(self, controller)
            dipole = self.mtq.dipole if "mtq" in self.devices else (0.0, 0.0, 0.0)
            self.truth.step(dipole, tuple(w.command for w in self.wheels))
