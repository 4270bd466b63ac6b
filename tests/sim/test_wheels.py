"""Reaction wheels in the rigid-body equations: closed forms, invariants, an independent reference, the guard."""

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from sim import wheels as W
from sim.rotations import angle_between, dcm, quat_from_axis_angle
from sim.truth import TruthModel

ARCSEC = math.pi / 180.0 / 3600.0
REF = Path(__file__).parents[2] / "fixtures" / "reference" / "wheels"
Q0 = (1.0, 0.0, 0.0, 0.0)


def _reference_module():
    spec = importlib.util.spec_from_file_location("wheels_reference", REF / "make_reference.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("source", ["", "basilisk_"])  # scipy DOP853 and Basilisk 2.12.1 (RK4 at 0.01 s)
@pytest.mark.parametrize(("name", "method", "step", "att_arcsec", "rate_tol", "speed_tol"), [
    ("orthogonal", "rk4", 0.05, 1e-3, 1e-9, 1e-9),
    ("pyramid", "rk4", 0.05, 1e-3, 1e-9, 1e-9),
    ("orthogonal", "rk8", 0.25, 1e-6, 1e-12, 1e-10),
    ("pyramid", "rk8", 0.25, 1e-6, 1e-12, 1e-10),
])
def test_matches_the_independent_references(source, name, method, step, att_arcsec, rate_tol, speed_tol):
    mr = _reference_module()
    case = mr.CASES[name]
    ref = np.loadtxt(REF / f"{source}{name}.csv", delimiter=",")
    cluster = W.WheelCluster(case["axes"], case["J"])
    q0 = np.asarray(case["q0"]) / np.linalg.norm(case["q0"])

    def held(t):  # the reference holds each torque over HOLD_S; the step divides it
        return case["u"](mr.HOLD_S * math.floor(t / mr.HOLD_S + 1e-9))

    t, q, w, speeds = W.propagate(case["inertia"], cluster, q0, case["w0"], case["Omega0"], mr.DURATION_S, step,
                                  wheel_torque_Nm=held, method=method)
    idx = np.round(ref[:, 0] / step).astype(int)
    np.testing.assert_allclose(t[idx], ref[:, 0], atol=1e-9)
    assert np.max(angle_between(q[idx], ref[:, 1:5])) < att_arcsec * ARCSEC
    assert np.max(np.abs(w[idx] - ref[:, 5:8])) < rate_tol
    assert np.max(np.abs(speeds[idx] - ref[:, 8:])) < speed_tol


def _pyramid(J=0.02):
    tilt = math.acos(1.0 / math.sqrt(3.0))
    az = np.radians([0.0, 90.0, 180.0, 270.0])
    axes = np.stack((math.sin(tilt) * np.cos(az), math.sin(tilt) * np.sin(az), np.full(4, math.cos(tilt))))
    return W.WheelCluster(axes, [J] * 4)


INERTIA = [[14.0, 0.5, -0.3], [0.5, 18.0, 0.2], [-0.3, 0.2, 11.0]]


def test_total_angular_momentum_is_conserved_in_the_inertial_frame_whatever_the_motor_torques():
    cluster = _pyramid()
    rng = np.random.default_rng(3)
    torques = rng.normal(0.0, 0.2, (400, 4))

    def tau(t):  # a new random torque every 0.05 s
        return torques[int(t / 0.05 + 1e-9)]

    drift = []
    for step in (0.05, 0.025):
        t, q, w, speeds = W.propagate(INERTIA, cluster, Q0, [0.05, -0.02, 0.03], [200.0, -100.0, 50.0, 0.0], 19.95,
                                      step, wheel_torque_Nm=tau)
        H_N = np.einsum("nji,nj->ni", dcm(q), W.angular_momentum_B(INERTIA, cluster, w, speeds))
        drift.append(np.max(np.abs(H_N - H_N[0])) / np.linalg.norm(H_N[0]))
    assert np.min(np.ptp(speeds, axis=0)) > 5.0  # the wheels really were driven
    # RK4 keeps this nonlinear invariant to its truncation error only (it falls as step^4); the wheel torques
    # themselves neither add nor remove momentum.
    assert drift[0] < 2e-11
    assert drift[1] < drift[0] / 10.0


def test_free_wheels_keep_the_energy_and_the_momentum_magnitude():
    cluster = W.WheelCluster(np.eye(3), [0.01, 0.01, 0.01])
    t, q, w, speeds = W.propagate(INERTIA, cluster, Q0, [0.1, 0.05, -0.08], [300.0, -150.0, 80.0], 100.0, 0.02)
    E = W.kinetic_energy(INERTIA, cluster, w, speeds)
    H = np.linalg.norm(W.angular_momentum_B(INERTIA, cluster, w, speeds), axis=1)
    assert np.max(np.abs(E / E[0] - 1.0)) < 1e-10
    assert np.max(np.abs(H / H[0] - 1.0)) < 1e-10
    assert np.ptp(w[:, 0]) > 1e-3  # the body really nutates under the wheels' gyroscopic torque


def test_energy_exchange_equals_the_motor_work_on_the_relative_speed():
    # d/dt (kinetic energy) = sum_i tau_i Omega_i (the motor works on the rotor's speed relative to the body).
    cluster = _pyramid()
    tau = (0.03, -0.02, 0.01, 0.025)
    step = 0.005
    t, q, w, speeds = W.propagate(INERTIA, cluster, Q0, [0.05, -0.02, 0.03], [200.0, -100.0, 50.0, 10.0], 20.0,
                                  step, wheel_torque_Nm=tau)
    E = W.kinetic_energy(INERTIA, cluster, w, speeds)
    power = speeds @ np.asarray(tau)
    work = np.concatenate(([0.0], np.cumsum(0.5 * step * (power[1:] + power[:-1]))))
    change = E - E[0]
    assert abs(change[-1]) > 1.0  # a real exchange, not a rounding of zero
    assert np.max(np.abs(change - work)) < 1e-6 * np.max(np.abs(change))


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_single_wheel_spin_up_about_a_principal_axis_follows_the_closed_form(axis):
    # Body at rest, one wheel on principal axis k, motor torque tau: the body turns the other way with
    # I_s omega = -tau t (I_s = I_kk - J), the wheel speeds up relative to the body by tau t (1/J + 1/I_s),
    # and the attitude is a rotation about k by -tau t^2 / (2 I_s).
    I = [10.0, 20.0, 30.0]
    J, tau = 0.05, 0.02
    cluster = W.WheelCluster(np.eye(3)[:, [axis]], [J])
    t, q, w, speeds = W.propagate(I, cluster, Q0, [0.0, 0.0, 0.0], [0.0], 60.0, 0.1, wheel_torque_Nm=[tau])
    Is = I[axis] - J
    expected_w = np.zeros((t.size, 3))
    expected_w[:, axis] = -tau * t / Is
    np.testing.assert_allclose(w, expected_w, rtol=1e-13, atol=1e-18)
    np.testing.assert_allclose(speeds[:, 0], tau * t * (1.0 / J + 1.0 / Is), rtol=1e-13)
    expected_q = quat_from_axis_angle(np.eye(3)[axis], -tau * t ** 2 / (2.0 * Is))
    assert np.max(angle_between(q, expected_q)) < 1e-10  # rad, RK4 on a quadratic angle


def test_the_step_guard_counts_the_wheel_momentum():
    # At rest the body alone would take any step; 2 N m s of wheel momentum on inertia >= 10 kg m^2 gives a
    # gyroscopic nutation of up to 0.2 rad/s, so 0.1 rad per step allows 0.5 s.
    cluster = W.WheelCluster(np.eye(3)[:, [2]], [0.01])
    with pytest.raises(ValueError, match=r"wheel momentum of 2 N m s.*step_s <= 0\.\d+ s"):
        W.propagate([10.0, 20.0, 30.0], cluster, Q0, [0.0, 0.0, 0.0], [200.0], 10.0, 1.0)
    W.propagate([10.0, 20.0, 30.0], cluster, Q0, [0.0, 0.0, 0.0], [200.0], 10.0, 0.45)
    # Spinning the wheel up during the run is caught when the momentum gets there.
    with pytest.raises(ValueError, match=r"reached|wheel momentum"):
        W.propagate([10.0, 20.0, 30.0], cluster, Q0, [0.0, 0.0, 0.0], [0.0], 200.0, 0.45, wheel_torque_Nm=[0.02])


def test_gyroscopic_nutation_frequency_matches_the_linearised_closed_form():
    # Small transverse rate, wheel momentum h along principal z: the rates rotate at h / sqrt(I1s I2s).
    I, J, Om = [10.0, 20.0, 30.0], 0.01, 300.0
    cluster = W.WheelCluster(np.eye(3)[:, [2]], [J])
    t, q, w, speeds = W.propagate(I, cluster, Q0, [1e-5, 0.0, 0.0], [Om], 200.0, 0.02)
    h = J * Om
    freq = h / math.sqrt(I[0] * I[1])  # I_s equals I about x and y (the wheel spins about z)
    crossings = t[1:][np.diff(np.sign(w[:, 0])) != 0]
    measured = math.pi / np.mean(np.diff(crossings))
    assert measured == pytest.approx(freq, rel=1e-3)


def _truth(wheels=None, speeds=None, torques=()):
    r = 6778137.0
    return TruthModel(inertia=INERTIA, q_BN=Q0, omega_BN_B=(0.01, -0.02, 0.015), r_N=(r, 0.0, 0.0),
                      v_N=(0.0, math.sqrt(3.986004418e14 / r), 0.0), step_ns=50_000_000, gravity="point",
                      torques=torques, wheels=wheels, wheel_speeds_rad_s=speeds)


def test_truth_model_with_wheels_steps_as_the_wheel_propagator_does():
    cluster = _pyramid()
    tau = (0.01, -0.02, 0.005, 0.0)
    truth = _truth(cluster, (100.0, 50.0, -20.0, 0.0))
    for _ in range(200):
        truth.step((0.0, 0.0, 0.0), tau)
    t, q, w, speeds = W.propagate(INERTIA, cluster, Q0, (0.01, -0.02, 0.015), (100.0, 50.0, -20.0, 0.0), 10.0,
                                  0.05, wheel_torque_Nm=tau)
    assert truth.q == pytest.approx(tuple(q[-1]), abs=1e-15)
    # Same equations and stepper; only the stage times differ (relative to the step there, absolute here).
    np.testing.assert_allclose(truth.w, w[-1], rtol=1e-13)
    np.testing.assert_allclose(truth.wheel_speeds_rad_s, speeds[-1], rtol=1e-14)
    H = W.angular_momentum_B(INERTIA, cluster, w[-1], speeds[-1])
    np.testing.assert_allclose(truth.angular_momentum_B(), H, rtol=1e-13)


def _relative_speeds(truth, cluster):
    """Omega = h / J - a . omega per wheel, from the truth's state, written out independently of the truth."""
    A = np.asarray(cluster.spin_axes_B, float)  # 3 x n, one column per wheel
    return tuple(float(h / j - A[:, i] @ np.asarray(truth.w))
                 for i, (h, j) in enumerate(zip(truth.h_wheels, cluster.inertia, strict=True)))


def test_wheel_speeds_are_computed_once_per_state_and_follow_every_state_change():
    # Each wheel device reads its speed several times a tick: one state gives one tuple, not a new one per read.
    cluster = _pyramid()
    truth = _truth(cluster, (100.0, 50.0, -20.0, 0.0))
    first = truth.wheel_speeds_rad_s
    assert truth.wheel_speeds_rad_s is first
    np.testing.assert_allclose(first, _relative_speeds(truth, cluster), rtol=1e-15, atol=1e-12)
    truth.step((0.0, 0.0, 0.0), (0.01, -0.02, 0.005, 0.0))  # a step: new speeds
    stepped = truth.wheel_speeds_rad_s
    assert stepped != first
    np.testing.assert_allclose(stepped, _relative_speeds(truth, cluster), rtol=1e-15, atol=1e-12)
    truth.w = (0.1, 0.0, 0.0)  # a state put in from outside (a test, a tool): never answered from the cache
    np.testing.assert_allclose(truth.wheel_speeds_rad_s, _relative_speeds(truth, cluster), rtol=1e-15, atol=1e-12)
    assert truth.wheel_speeds_rad_s != stepped


def test_truth_model_with_wheels_and_gravity_gradient_conserves_nothing_it_should_not():
    # Internal wheel torques leave the inertial momentum alone; gravity gradient changes it.
    cluster = _pyramid()
    free = _truth(cluster, (100.0, 50.0, -20.0, 0.0))
    gg = _truth(cluster, (100.0, 50.0, -20.0, 0.0), torques=("gravity_gradient",))

    def H_N(tr):
        return dcm(np.array(tr.q)).T @ np.array(tr.angular_momentum_B())

    H0 = H_N(free)
    for _ in range(400):
        free.step((0.0, 0.0, 0.0), (0.02, -0.01, 0.0, 0.01))
        gg.step((0.0, 0.0, 0.0), (0.02, -0.01, 0.0, 0.01))
    assert np.max(np.abs(H_N(free) - H0)) < 1e-11 * np.linalg.norm(H0)
    assert np.max(np.abs(H_N(gg) - H0)) > 1e-7


def test_truth_model_guard_names_the_wheel_momentum_and_the_scenario_field():
    cluster = W.WheelCluster(np.eye(3)[:, [2]], [0.05])
    with pytest.raises(ValueError, match=r"dynamics\.step_s = 0\.05 s .*wheel momentum of 30\.0\d* N m s"):
        _truth(cluster, (600.0,))  # 30 N m s on I_min ~ 11 kg m^2: ~2.7 rad/s gyroscopic rate
    truth = _truth(cluster, (10.0,))  # 0.5 N m s: fine at 0.05 s
    with pytest.raises(ValueError, match=r"dynamics\.step_s .*wheel momentum"):
        for _ in range(20000):  # the motor spins the wheel up until the guard trips
            truth.step((0.0, 0.0, 0.0), (0.5,))


def test_truth_model_without_wheels_refuses_wheel_input():
    truth = _truth()
    assert truth.wheel_speeds_rad_s == ()
    with pytest.raises(ValueError, match="without wheels"):
        truth.step((0.0, 0.0, 0.0), (0.1,))
    with pytest.raises(ValueError, match="wheel_speeds_rad_s"):
        _truth(None, (1.0, 2.0, 3.0))


@pytest.mark.parametrize(("axes", "J", "match"), [
    (np.eye(3) * 2.0, [0.01] * 3, "unit vector"),
    (np.ones((4, 3)) / math.sqrt(3.0), [0.01] * 3, "3 x n"),
    (np.eye(3), [0.01, 0.01], "one spin inertia per wheel"),
    (np.eye(3), [0.01, -0.01, 0.01], "finite and positive"),
    (np.full((3, 3), np.nan), [0.01] * 3, "NaN"),
])
def test_wheel_cluster_input_errors_are_named(axes, J, match):
    with pytest.raises(ValueError, match=match):
        W.WheelCluster(axes, J)


def test_bad_wheel_inputs_are_named():
    cluster = W.WheelCluster(np.eye(3), [0.01] * 3)
    with pytest.raises(ValueError, match="speeds_rad_s"):
        W.propagate(INERTIA, cluster, Q0, [0.0] * 3, [1.0, 2.0], 1.0, 0.1)
    with pytest.raises(ValueError, match="wheel_torque_Nm"):
        W.propagate(INERTIA, cluster, Q0, [0.0] * 3, [0.0] * 3, 1.0, 0.1, wheel_torque_Nm=[0.0, math.nan, 0.0])
    with pytest.raises(ValueError, match="must include the wheels"):
        W.WheelCluster(np.eye(3), [20.0] * 3).hub_inertia([10.0, 10.0, 10.0])
    truth = _truth(W.WheelCluster(np.eye(3), [0.01] * 3))
    with pytest.raises(ValueError, match="3 finite torques"):
        truth.step((0.0, 0.0, 0.0), (0.0, 0.0))
