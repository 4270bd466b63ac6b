"""Wheel physics faults of the motor model (issue 24): seized rotor, torque loss, motor off, friction rise; each
against the healthy wheel and, for the seizure, on the truth (the rotor's momentum goes to the body). A wheel with
every fault attribute at its neutral value steps to the same bits as one that never had a fault."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.actuators import SEIZURE_TORQUE_RATIO, ReactionWheel, WheelMotor, WheelState
from sim.truth import TruthModel
from sim.wheels import WheelCluster

J = 2e-3
TAU_MAX = 0.01
H = 0.1


def motor(coulomb=1e-4, viscous=2e-6, lag=0.05) -> WheelMotor:
    return WheelMotor(ReactionWheel(J, coulomb, viscous), TAU_MAX, 628.0, lag)


def run(m: WheelMotor, w0: float, u: float, steps: int) -> tuple[WheelState, list[float]]:
    state, bodies = WheelState(w0, 0.0), []
    for _ in range(steps):
        state, body, _ = m.step(state, u, H)
        bodies.append(body)
    return state, bodies


def test_a_seized_rotor_stops_within_the_seizure_torque_and_stays_stopped_whatever_the_command():
    m = motor()
    m.seized = True
    w0 = 50.0
    state, bodies = run(m, w0, 0.0, 1)
    # The bearing torque takes SEIZURE_TORQUE_RATIO * tau_max * h / J = 10 rad/s off each step.
    assert state.omega_rad_s == pytest.approx(w0 - SEIZURE_TORQUE_RATIO * TAU_MAX * H / J, rel=1e-12)
    state, bodies = run(m, state.omega_rad_s, TAU_MAX, 10)  # full drive: nothing moves the rotor
    assert state.omega_rad_s == 0.0
    # Every bit of momentum the rotor lost went to the body (body torque integrated over the steps).
    m2 = motor()
    m2.seized = True
    s, b = run(m2, w0, TAU_MAX, 20)
    assert s.omega_rad_s == 0.0 and sum(b) * H == pytest.approx(J * w0, rel=1e-12)


def test_torque_loss_scales_the_produced_torque():
    healthy, lossy = motor(coulomb=0.0, viscous=0.0, lag=0.0), motor(coulomb=0.0, viscous=0.0, lag=0.0)
    lossy.torque_scale = 0.3
    s_h, _ = run(healthy, 10.0, 4e-3, 10)
    s_l, _ = run(lossy, 10.0, 4e-3, 10)
    assert s_h.omega_rad_s - 10.0 == pytest.approx(4e-3 * 1.0 / J, rel=1e-12)
    assert s_l.omega_rad_s - 10.0 == pytest.approx(0.3 * 4e-3 * 1.0 / J, rel=1e-12)
    assert s_l.motor_torque_Nm == pytest.approx(0.3 * 4e-3, rel=1e-12)
    with pytest.raises(ValueError, match="torque_scale = 1.5; it must be a fraction from 0 to 1"):
        lossy.torque_scale = 1.5


def test_motor_off_leaves_only_friction():
    off, idle = motor(viscous=0.0), motor(viscous=0.0)
    off.motor_on = False
    s_off, _ = run(off, 20.0, TAU_MAX, 5)  # commanded full torque: none arrives
    s_idle, _ = run(idle, 20.0, 0.0, 5)  # the healthy wheel coasting with no command
    assert s_off.omega_rad_s == s_idle.omega_rad_s == pytest.approx(20.0 - 1e-4 * 0.5 / J, rel=1e-12)
    assert s_off.motor_torque_Nm == 0.0
    state, _, _ = off.step(WheelState(20.0, 5e-3), TAU_MAX, H)  # a torque still in the lag is dropped too
    assert state.motor_torque_Nm == 0.0 and state.omega_rad_s == pytest.approx(20.0 - 1e-4 * H / J, rel=1e-12)


def test_friction_rise_scales_the_bearing_friction():
    m = motor(coulomb=1e-4, viscous=0.0, lag=0.0)
    m.friction_scale = 5.0
    s, _ = run(m, 20.0, 0.0, 5)
    assert s.omega_rad_s == pytest.approx(20.0 - 5.0 * 1e-4 * 0.5 / J, rel=1e-12)
    m.friction_scale = 1.0  # cleared: the healthy wheel again
    assert not m._faulty
    with pytest.raises(ValueError, match="friction_scale = -1"):
        m.friction_scale = -1.0


def test_neutral_fault_attributes_step_to_the_same_bits():
    rng = np.random.default_rng(3)
    a, b = motor(), motor()
    b.friction_scale, b.seized, b.torque_scale, b.motor_on = 2.0, True, 0.5, False
    b.friction_scale, b.seized, b.torque_scale, b.motor_on = 1.0, False, 1.0, True
    sa = sb = WheelState(30.0, 0.0)
    for u in rng.uniform(-TAU_MAX, TAU_MAX, 200):
        sa, ba, fa = a.step(sa, u, H)
        sb, bb, fb = b.step(sb, u, H)
        assert (sa, ba, fa) == (sb, bb, fb)


def test_a_seized_wheel_hands_its_momentum_to_the_body_in_the_truth():
    """The truth reads the rotor's net torque (the momentum exchange): the body takes the rotor's momentum and the
    total is kept."""
    r = 6778137.0
    inertia = np.diag([1.2, 1.5, 1.0])
    truth = TruthModel(inertia=inertia, q_BN=(1.0, 0.0, 0.0, 0.0), omega_BN_B=(0.0, 0.0, 0.0), r_N=(r, 0.0, 0.0),
                       v_N=(0.0, math.sqrt(3.986004418e14 / r), 0.0), step_ns=100_000_000, gravity="point",
                       torques=(), wheels=WheelCluster(np.array([[0.0], [0.0], [1.0]]), [J]),
                       wheel_speeds_rad_s=(50.0,))
    h0 = np.array(truth.angular_momentum_B())
    assert h0 == pytest.approx([0.0, 0.0, J * 50.0], abs=1e-15)
    m = motor()
    m.seized = True
    tau = 0.0
    for _ in range(20):
        state, body, _ = m.step(WheelState(truth.wheel_speeds_rad_s[0], tau), TAU_MAX, H)
        tau = state.motor_torque_Nm
        truth.step((0.0, 0.0, 0.0), (-body,))
    assert abs(truth.wheel_speeds_rad_s[0]) < 1e-9  # the rotor stands still relative to the body
    np.testing.assert_allclose(truth.angular_momentum_B(), h0, rtol=1e-12, atol=1e-15)
    # I omega = h0 with the rotor locked: the body spins about z with the rotor's momentum.
    assert truth.w[2] == pytest.approx(J * 50.0 / 1.0, rel=1e-9)
