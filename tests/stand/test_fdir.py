"""The reference ADCS's FDIR (stand.adcs.fdir) in a closed loop of fake host drivers over sim's truth (no device
kinds): a wheel that does not follow its commands is isolated, a failed gyro hands the rate to the tracker, a lying
tracker is rejected by the innovation gate, a silent device is reported; each against the same loop without the
FDIR (``fdir = False``)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from sim.rotations import angle_between, compose, quat_from_axis_angle
from stand.adcs.fdir import (
    DEVICE_LOST,
    GYRO_FAILED,
    TRACKER_REJECTED,
    WHEEL_ISOLATED,
    GyroMonitor,
    rate_from_attitudes,
)
from stand.adcs.modes import FINE_POINTING
from stand.adcs.pointing import PointingController, default_wheel_axes_B
from stand.adcs.quat import qmul

from .adcs_harness import INERTIA, Q_GB, Q_TB, FakeGyro, FakeTracker, FakeWheel, Loop

ARCSEC = math.radians(1.0 / 3600.0)
Q_R = quat_from_axis_angle(np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8]), 1.0)
MAX_TORQUE = 0.05


class BrokenGyro(FakeGyro):
    """The harness's gyro that, from ``at_s``, repeats its last sample (``stuck``) or says nothing (``silent``)."""

    def __init__(self, loop, how: str, at_s: float):
        super().__init__(loop)
        self.how, self.at_s, self.last = how, at_s, None

    def take_rate(self):
        if self.loop.truth.t_s < self.at_s or self.last is None:
            self.last = super().take_rate()
            return self.last
        return None if self.how == "silent" else self.last


class LyingTracker(FakeTracker):
    """From ``at_s`` its solutions are turned by ``angle_rad`` about body x, still flagged valid (misidentified
    stars)."""

    def __init__(self, loop, at_s: float, angle_rad: float):
        super().__init__(loop)
        self.at_s, self.turn = at_s, quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), angle_rad)

    def take_solution(self):
        sol = super().take_solution()
        if self.loop.truth.t_s >= self.at_s:
            return SimpleNamespace(q_TN=tuple(compose(self.turn, sol.q_TN)), valid=True, time_us=sol.time_us)
        return sol


class SeizedWheel(FakeWheel):
    """From ``at_s`` the rotor gets none of the commanded torque (the harness's wheels are ideal torque sources)."""

    def __init__(self, loop, i, at_s: float):
        super().__init__(loop, i)
        self.at_s = at_s

    def command_torque(self, torque_Nm):
        super().command_torque(torque_Nm)
        if self.loop.truth.t_s >= self.at_s:
            self.command = 0.0


def _loop(axes=None, speeds=None, noise=2 * ARCSEC, max_torque=MAX_TORQUE) -> Loop:
    return Loop(compose(quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), math.radians(0.2)), Q_R), axes=axes,
                speeds=speeds, tracker_noise_rad=noise, seed=5, max_torque=max_torque)


def _controller(loop, fdir: bool, **extra) -> PointingController:
    options = dict(inertia_kg_m2=INERTIA, star_tracker="st", star_tracker_q_TB=list(Q_TB), gyro="imu",
                   gyro_q_SB=list(Q_GB), wheels=[f"rw{i}" for i in range(len(loop.wheels))], wheel_inertia_kg_m2=0.02,
                   max_wheel_torque_Nm=loop.max_torque, guidance="inertial", q_RN=list(Q_R), initial_mode=FINE_POINTING,
                   tracker_sigma_rad=[2 * ARCSEC, 2 * ARCSEC], fdir=fdir)
    options.update(extra)
    return PointingController(loop.devices, 0.1, **options)


def _run(loop, ctl, duration_s):
    log = {"t": [], "err": [], "fdir": []}

    def record(lp, c):
        log["t"].append(lp.truth.t_s)
        log["err"].append(angle_between(np.array(lp.truth.q), Q_R))
        log["fdir"].append(c.telemetry()[-1])

    loop.run(ctl, duration_s, ctl_every=2, record=record)
    return {k: np.array(v) for k, v in log.items()}


def test_rate_from_attitudes_inverts_a_constant_rate_turn():
    w_B, dt = np.array([0.01, -0.02, 0.005]), 0.5
    half = 0.5 * np.linalg.norm(w_B) * dt
    q1 = quat_from_axis_angle(np.array([0.0, 0.6, 0.8]), 0.4)
    q2 = np.array(qmul(q1, np.concatenate(([math.cos(half)], math.sin(half) * w_B / np.linalg.norm(w_B)))))
    np.testing.assert_allclose(rate_from_attitudes(q1, q2, dt), w_B, rtol=1e-12)
    np.testing.assert_allclose(rate_from_attitudes(q1, -q2, dt), w_B, rtol=1e-12)  # either sign of a quaternion


@pytest.mark.parametrize("fdir", [True, False])
def test_a_wheel_that_stops_answering_its_commands_is_isolated_and_three_carry_the_pointing(fdir):
    loop = _loop(axes=default_wheel_axes_B(4), speeds=[30.0, -20.0, 10.0, 5.0], max_torque=0.01)
    loop.wheels[2] = loop.devices["rw2"] = SeizedWheel(loop, 2, at_s=40.0)
    ctl = _controller(loop, fdir)
    _run(loop, ctl, 40.0)
    # At the fault the reference steps 5 deg about x: the slew needs rw0 and rw2 (the pyramid's x pair), and rw2
    # gives nothing.
    ctl.q_RN = compose(quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), math.radians(5.0)), Q_R)
    log = _run(loop, ctl, 200.0)
    err = angle_between(np.array(loop.truth.q), ctl.q_RN)
    if fdir:
        assert ctl.fdir.isolated == [2] and np.all(log["fdir"][log["t"] >= 42.0].astype(int) & WHEEL_ISOLATED)
        assert any("rw2 isolated" in what for _, what in ctl.fdir.events)
        assert ctl.last_wheel_cmd[2] == 0.0
        assert err < 30 * ARCSEC, err / ARCSEC
    else:
        assert np.all(log["fdir"] == 0.0) and ctl.last_wheel_cmd[2] != 0.0


def test_a_stuck_gyro_hands_the_rate_to_the_tracker():
    results = {}
    for fdir in (True, False):
        loop = _loop()
        loop.gyro = loop.devices["imu"] = BrokenGyro(loop, "stuck", at_s=20.0)
        ctl = _controller(loop, fdir)
        loop.truth.w = (0.0, 0.0, 0.0)
        log = _run(loop, ctl, 200.0)
        results[fdir] = (log, ctl)
    log, ctl = results[True]
    assert ctl.fdir.gyro.failed and "stuck" in ctl.fdir.gyro.why
    after = log["t"] >= 25.0
    assert np.all(log["fdir"][after].astype(int) & GYRO_FAILED)
    assert np.all(log["fdir"][log["t"] < 20.0] == 0.0)
    assert np.max(log["err"][log["t"] >= 100.0]) < 60 * ARCSEC, np.max(log["err"][log["t"] >= 100.0]) / ARCSEC
    log_off, _ = results[False]
    # Without it the controller damps a frozen rate: the pointing drifts off.
    assert np.max(log_off["err"][log_off["t"] >= 100.0]) > 10 * np.max(log["err"][log["t"] >= 100.0])


def test_a_silent_gyro_is_reported_lost_and_failed():
    loop = _loop()
    loop.gyro = loop.devices["imu"] = BrokenGyro(loop, "silent", at_s=20.0)
    ctl = _controller(loop, True, fdir_lost_s=2.0)
    log = _run(loop, ctl, 60.0)
    flags = log["fdir"].astype(int)
    assert np.all(flags[log["t"] < 22.0] == 0)
    assert np.all(flags[log["t"] >= 22.5] & (GYRO_FAILED | DEVICE_LOST) == GYRO_FAILED | DEVICE_LOST)
    assert "imu" in ctl.fdir.lost and any("imu lost" in what for _, what in ctl.fdir.events)


def test_a_lying_tracker_is_rejected_by_the_innovation_gate():
    results = {}
    for fdir in (True, False):
        loop = _loop()
        loop.tracker = loop.devices["st"] = LyingTracker(loop, at_s=50.0, angle_rad=math.radians(0.3))
        ctl = _controller(loop, fdir, sigma_bias_rad_s=1e-5)
        results[fdir] = (_run(loop, ctl, 90.0), ctl)
    log, ctl = results[True]
    lying = log["t"] >= 50.5
    assert np.all(log["fdir"][lying].astype(int) & TRACKER_REJECTED)
    assert ctl.filter.rejected > 300
    assert np.max(log["err"][lying]) < 60 * ARCSEC  # held on the gyro
    log_off, _ = results[False]
    assert np.max(log_off["err"][log_off["t"] >= 80.0]) > math.radians(0.2)  # the lie is where it points now


def test_the_frozen_output_check_counts_identical_samples_and_can_be_turned_off():
    on, off = GyroMonitor(stuck_samples=10), GyroMonitor(stuck_samples=0)
    for _ in range(9):
        on.sample((1e-3, 0.0, 0.0), True)
        off.sample((1e-3, 0.0, 0.0), True)
    assert not on.failed
    on.sample((1e-3, 0.0, 0.0), True)
    assert on.failed and on.why == "stuck: 10 identical samples"
    for _ in range(100):
        off.sample((1e-3, 0.0, 0.0), True)
    assert not off.failed
    for k in range(10):  # ten live samples bring it back
        on.sample((1e-3 + (k + 1) * 1e-9, 0.0, 0.0), True)
    assert not on.failed
