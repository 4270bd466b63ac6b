"""sim.actuators: exact discrete updates of stiff sub-models against their analytic solutions."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.actuators import CoilLR, FlexibleMode, ReactionWheel


def test_coil_tau_1ms_at_10ms_step_is_exact():
    # docs/numerical_methods.md D1: L = 50 mH, R = 50 ohm (tau = 1 ms), 10 Hz random +-5 V, 10 ms step.
    coil = CoilLR(0.05, 50.0)
    assert coil.tau_s == pytest.approx(1e-3)
    rng = np.random.default_rng(1)
    volts = rng.uniform(-5.0, 5.0, 20)  # one command per 0.1 s
    i, err = 0.0, 0.0
    i_cmd_start = 0.0
    for v in volts:
        for j in range(1, 11):
            i = float(coil.step(i, v, 0.01))
            # Analytic: one exponential from the start of this command interval.
            exact = v / 50.0 + (i_cmd_start - v / 50.0) * math.exp(-(j * 0.01) / 1e-3)
            err = max(err, abs(i - exact))
        i_cmd_start = i
    assert err <= 1e-12
    assert coil.max_explicit_step_s < 0.01  # RK4 in the ODE would be unstable at this step


def test_coil_broadcasts_over_three_rods_and_gives_dipole():
    coil = CoilLR(0.05, 50.0, turns_area_m2=2.0)
    i = coil.step(np.zeros(3), [5.0, -5.0, 0.0], 1.0)
    np.testing.assert_allclose(coil.dipole(i), [0.2, -0.2, 0.0], rtol=1e-15)


def test_wheel_below_coulomb_stops_and_stays_at_exactly_zero():
    # docs/numerical_methods.md D2: J = 2e-4, tau_c = 5e-4, u = -2e-4, Omega0 = 2 rad/s, 10 ms step.
    J, tc, c, u = 2e-4, 5e-4, 1e-6, -2e-4
    wheel = ReactionWheel(J, tc, viscous_nms=c)
    w, ws, fr = 2.0, [], []
    for _ in range(300):
        w, _, e = wheel.step(w, u, 0.01)
        ws.append(w)
        fr.append(e)
    ws = np.array(ws)
    # Analytic stop time of J w' = u - tc - c w from 2 rad/s.
    w_inf = (u - tc) / c
    t_stop = J / c * math.log((2.0 - w_inf) / (0.0 - w_inf))
    k_stop = int(np.argmax(ws == 0.0))
    assert abs((k_stop + 1) * 0.01 - t_stop) < 0.01
    assert np.all(ws[k_stop:] == 0.0)  # sticks: no chatter, no creep
    assert np.all(ws >= 0.0)
    assert min(fr) >= 0.0


def test_wheel_above_breakaway_reverses_once_and_follows_the_exponential():
    J, tc, c, u = 2e-4, 5e-4, 1e-5, -8e-4
    wheel = ReactionWheel(J, tc, viscous_nms=c, static_nm=6e-4)
    w, ws = 1.0, []
    for _ in range(200):
        w, _, _ = wheel.step(w, u, 0.05)
        ws.append(w)
    signs = np.sign(ws)
    assert np.count_nonzero(np.diff(signs[signs != 0]) != 0) == 1  # one reversal, no chatter
    # After reversal: J w' = u + tc - c w, exact exponential towards (u + tc)/c.
    w_inf = (u + tc) / c
    t0 = J / c * math.log((1.0 - (u - tc) / c) / (0.0 - (u - tc) / c))
    t = 10.0
    assert ws[-1] == pytest.approx(w_inf * (1 - math.exp(-c / J * (t - t0))), rel=1e-9)


@settings(max_examples=40, deadline=None)
@given(w0=st.floats(-50.0, 50.0), h=st.floats(1e-4, 0.5),
       tc=st.floats(0.0, 1e-3), c=st.floats(0.0, 1e-4))
def test_wheel_friction_never_adds_energy_when_unpowered(w0, h, tc, c):
    wheel = ReactionWheel(2e-4, tc, viscous_nms=c)
    w = w0
    for _ in range(20):
        w_new, torque, e = wheel.step(w, 0.0, h)
        assert abs(w_new) <= abs(w) and w_new * w >= 0.0  # monotone, never through zero
        assert e >= 0.0
        assert torque == pytest.approx(-2e-4 * (w_new - w) / h)
        w = w_new


def test_wheel_inputs_are_named():
    with pytest.raises(ValueError, match="static_nm"):
        ReactionWheel(1e-4, 1e-3, static_nm=1e-4)
    with pytest.raises(ValueError, match="h_s"):
        ReactionWheel(1e-4, 1e-3).step(1.0, 0.0, 0.0)


@pytest.mark.parametrize(("f_hz", "zeta"), [(2.0, 0.005), (40.0, 0.002)])
def test_flexible_mode_matches_the_damped_oscillator(f_hz, zeta):
    mode = FlexibleMode(f_hz, zeta)
    wn = 2 * math.pi * f_hz
    wd = wn * math.sqrt(1 - zeta ** 2)
    x0 = np.array([1e-3, 0.02])
    x = x0.copy()
    h = 0.01
    for _ in range(200):
        x = mode.step(x, 0.0, h)
    t = 2.0
    eta = math.exp(-zeta * wn * t) * (x0[0] * math.cos(wd * t) + (x0[1] + zeta * wn * x0[0]) / wd * math.sin(wd * t))
    assert x[0] == pytest.approx(eta, abs=1e-12 * np.abs(x0).max())
    ratio = mode.energy(x) / (mode.energy(x0) * 1.0)
    # Modal energy of the exact solution decays by about exp(-2 zeta wn t) (averaged); D4 criterion.
    assert 0.5 < ratio / math.exp(-2 * zeta * wn * t) < 2.0
    assert mode.max_explicit_step_s == pytest.approx(2 * math.sqrt(2) / wn)  # RK4 limit, D4


def test_flexible_mode_settles_to_static_deflection_under_constant_force():
    mode = FlexibleMode(5.0, 0.3)
    x = np.zeros(2)
    for _ in range(500):
        x = mode.step(x, 2.0, 0.01)
    assert x[0] == pytest.approx(2.0 / (2 * math.pi * 5.0) ** 2, rel=1e-12)


# -- wheel motor ------------------------------------------------------------------------------------

from sim.actuators import (  # noqa: E402
    PYRAMID_EQUAL_TILT_DEG,
    WheelMotor,
    WheelState,
    wheel_spin_axes_B,
    wheel_torque_distribution,
)


def _lagged_speed(u, J, T, t):
    """Frictionless rotor from rest under a step command u through a first-order lag T."""
    return u / J * (t - T * (1.0 - math.exp(-t / T)))


@pytest.mark.parametrize("h", [0.01, 0.1, 1.0])
def test_motor_lag_is_exact_at_any_step(h):
    J, T, u = 1e-4, 0.05, 2e-3
    motor = WheelMotor(ReactionWheel(J, 0.0), max_torque_Nm=4e-3, max_speed_rad_s=1e4, time_constant_s=T)
    state = WheelState(0.0, 0.0)
    for k in range(1, int(round(2.0 / h)) + 1):
        state, _, _ = motor.step(state, u, h)
        t = k * h
        assert state.omega_rad_s == pytest.approx(_lagged_speed(u, J, T, t), rel=1e-12, abs=1e-12)
        assert state.motor_torque_Nm == pytest.approx(u * (1 - math.exp(-t / T)), rel=1e-12)


def test_torque_command_is_clipped_to_the_rating_keeping_its_sign():
    motor = WheelMotor(ReactionWheel(1e-4, 0.0), max_torque_Nm=4e-3, max_speed_rad_s=1e4)
    state, body, _ = motor.step(WheelState(0.0, 0.0), -1.0, 0.5)
    assert state.omega_rad_s == pytest.approx(-4e-3 * 0.5 / 1e-4, rel=1e-12)
    assert body == pytest.approx(4e-3, rel=1e-12)  # the body feels the opposite


@pytest.mark.parametrize("h", [0.001, 0.05, 2.0])
def test_back_emf_roll_off_holds_the_rated_speed_at_any_step(h):
    J, wmax = 2e-5, 600.0
    motor = WheelMotor(ReactionWheel(J, 1e-5, viscous_nms=1e-8), max_torque_Nm=2e-3, max_speed_rad_s=wmax,
                       rolloff_rad_s=60.0)
    state = WheelState(0.0, 0.0)
    speeds = []
    for _ in range(int(round(20.0 / h))):
        state, _, _ = motor.step(state, 2e-3, h)
        speeds.append(state.omega_rad_s)
    assert max(speeds) <= wmax
    # Steady state where the rolled-off torque meets friction: tau_max (wmax - w)/roll = tau_c + c w.
    w_ss = (2e-3 * wmax / 60.0 - 1e-5) / (2e-3 / 60.0 + 1e-8)
    assert speeds[-1] == pytest.approx(w_ss, rel=1e-3 if h <= 0.05 else 2e-2)
    # braking keeps the full torque
    assert motor.available_torque(599.0, -5.0) == -2e-3 and motor.available_torque(599.0, 5.0) < 2e-3 * 0.02


@pytest.mark.parametrize("h", [0.01, 0.1, 1.0])
def test_speed_mode_reaches_the_command_without_overshoot(h):
    motor = WheelMotor(ReactionWheel(1e-4, 2e-4, viscous_nms=1e-7), max_torque_Nm=4e-3, max_speed_rad_s=600.0,
                       time_constant_s=0.02, speed_loop_s=0.2)
    state = WheelState(0.0, 0.0)
    speeds = []
    for _ in range(int(round(10.0 / h))):
        state, _, _ = motor.step_speed(state, 300.0, h)
        speeds.append(state.omega_rad_s)
    assert max(speeds) <= 300.0 * (1 + 1e-6)
    assert speeds[-1] == pytest.approx(300.0, rel=1e-6)
    assert np.all(np.diff(speeds) >= -1e-12)  # monotone approach


def test_momentum_given_to_the_body_equals_the_rotors_loss_exactly():
    J = 3e-5
    motor = WheelMotor(ReactionWheel(J, 5e-5, viscous_nms=2e-7, static_nm=8e-5), max_torque_Nm=3e-3,
                       max_speed_rad_s=500.0, time_constant_s=0.03)
    rng = np.random.default_rng(4)
    state = WheelState(10.0, 0.0)
    impulse = 0.0
    for u in rng.uniform(-4e-3, 4e-3, 300):
        state, body, fr = motor.step(state, u, 0.1)
        impulse += body * 0.1
        assert fr >= 0.0
    assert impulse == pytest.approx(-J * (state.omega_rad_s - 10.0), rel=1e-9, abs=1e-15)


def test_spin_axis_layouts_and_the_torque_distribution():
    np.testing.assert_array_equal(wheel_spin_axes_B("orthogonal"), np.eye(3))
    A = wheel_spin_axes_B("pyramid")
    np.testing.assert_allclose(np.linalg.norm(A, axis=1), 1.0, rtol=1e-15)
    # equal tilt: every wheel contributes 1/sqrt(3) to every body axis it leans towards
    np.testing.assert_allclose(A[:, 2], 1 / math.sqrt(3), rtol=1e-12)
    assert PYRAMID_EQUAL_TILT_DEG == pytest.approx(54.7356, abs=1e-4)
    D = wheel_torque_distribution(A)
    tau = np.array([1e-3, -2e-3, 5e-4])
    np.testing.assert_allclose(A.T @ (D @ tau), tau, atol=1e-18)
    with pytest.raises(ValueError, match="spanning 3-D"):
        wheel_torque_distribution(A[:2])
    with pytest.raises(ValueError, match="'orthogonal'"):
        wheel_spin_axes_B("tetrahedron")


def test_wheel_motor_inputs_are_named():
    with pytest.raises(ValueError, match="max_torque_Nm"):
        WheelMotor(ReactionWheel(1e-4, 1e-4), max_torque_Nm=0.0, max_speed_rad_s=100.0)
    with pytest.raises(ValueError, match="breakaway friction"):
        WheelMotor(ReactionWheel(1e-4, 1e-3), max_torque_Nm=5e-4, max_speed_rad_s=100.0)
    with pytest.raises(ValueError, match="rolloff_rad_s"):
        WheelMotor(ReactionWheel(1e-4, 1e-4), 1e-3, 100.0, rolloff_rad_s=200.0)
