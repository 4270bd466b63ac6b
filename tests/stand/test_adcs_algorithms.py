"""The reference ADCS algorithms as pure functions: TRIAD, QUEST against a brute-force Wahba solution, the MEKF's
consistency, guidance frames and rates, control law, wheel distribution, momentum dumping, mode logic."""

import math

import numpy as np
import pytest

from sim.frames import dcm_lvlh_gcrs
from sim.orbit import propagate_kepler
from sim.rotations import angle_between, compose, conjugate, dcm, hamilton, quat_from_axis_angle, quat_from_dcm
from stand.adcs import control as ctl
from stand.adcs import guidance as gd
from stand.adcs.determination import MEKF, FilterError, quest, triad
from stand.adcs.modes import DETUMBLE, FINE_POINTING, SUN_ACQUISITION, ModeConfig, ModeManager

ARCSEC = math.radians(1.0 / 3600.0)


def _random_quat(rng, angle=None):
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return quat_from_axis_angle(axis, rng.uniform(0.0, math.pi) if angle is None else angle)


def _rotvec(v):
    a = float(np.linalg.norm(v))
    return np.array([1.0, 0.0, 0.0, 0.0]) if a == 0 else np.concatenate(([math.cos(a / 2)], math.sin(a / 2) * v / a))


def wahba_svd(b, r, a):
    """Markley's SVD solution of Wahba's problem (brute force, for comparison only)."""
    B = (a[:, None] * b).T @ r
    U, _, Vt = np.linalg.svd(B)
    d = np.linalg.det(U) * np.linalg.det(Vt)
    return U @ np.diag([1.0, 1.0, d]) @ Vt


# -- determination -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("angle", [None, None, None, math.pi - 1e-6, math.pi])
def test_quest_equals_the_svd_solution_of_wahbas_problem_with_noise_and_weights(angle):
    rng = np.random.default_rng(11 if angle is None else 12)
    for _ in range(20):
        q = _random_quat(rng, angle)
        n = int(rng.integers(2, 8))
        r = rng.normal(size=(n, 3))
        r /= np.linalg.norm(r, axis=1)[:, None]
        b = r @ dcm(q).T + rng.normal(0.0, 1e-3, (n, 3))
        a = rng.uniform(0.1, 2.0, n)
        expected = quat_from_dcm(wahba_svd(b / np.linalg.norm(b, axis=1)[:, None], r, a))
        assert angle_between(quest(b, r, a), expected) < 1e-9


def test_triad_matches_the_first_vector_exactly_and_the_truth_without_noise():
    rng = np.random.default_rng(5)
    q = _random_quat(rng)
    r1, r2 = np.array([1.0, 0.2, -0.3]), np.array([0.1, 1.0, 0.4])
    b1, b2 = dcm(q) @ r1, dcm(q) @ r2
    assert angle_between(triad(b1, b2, r1, r2), q) < 1e-14
    noisy = triad(b1, b2 + np.array([0.0, 0.01, 0.0]), r1, r2)
    np.testing.assert_allclose(dcm(noisy) @ (r1 / np.linalg.norm(r1)), b1 / np.linalg.norm(b1), atol=1e-14)


@pytest.mark.parametrize(("call", "match"), [
    (lambda: triad([1, 0, 0], [1, 1e-4, 0], [1, 0, 0], [0, 1, 0]), "parallel"),
    (lambda: triad([1, 0, 0], [0, 1, 0], [math.nan, 0, 0], [0, 1, 0]), "r1_N .* NaN"),
    (lambda: quest([[1, 0, 0], [0, 1, 0]], [[1, 0, 0], [0, 0, 0]]), "zero vector"),
    (lambda: quest([[1, 0, 0], [2, 0, 0]], [[1, 0, 0], [3, 0, 0]]), "parallel"),
    (lambda: quest([[1, 0, 0], [0, 1, 0]], [[1, 0, 0], [0, 1, 0]], [1.0, -1.0]), "weights"),
    (lambda: MEKF([1, 0, 0, 0]).propagate([0.0, math.nan, 0.0], 0.1), "omega_meas_B"),
    (lambda: MEKF([1, 0, 0, 0]).update_attitude([math.nan, 0, 0, 1], 1e-8), "q_BN_meas"),
    (lambda: MEKF([1, 0, 0, 0]).update_attitude([1, 0, 0, 0], [1e-8, -1.0, 1e-8]), "R_B"),
    (lambda: MEKF([1, 0, 0, 0]).propagate([0.0, 0.0, 0.0], -0.1), "dt_s"),
])
def test_determination_refuses_bad_input_in_one_sentence(call, match):
    with pytest.raises(FilterError, match=match):
        call()


def _simulate_mekf(seed, n_steps, dt=0.1, every=10, arw=2e-5, rrw=1e-7, sigma_st=10 * ARCSEC):
    """Truth rotating with a varying rate; gyro with bias random walk and white noise at 1/dt; tracker every
    `every` steps. Returns per-step attitude errors (rad, body), filter covariances and the bias error."""
    rng = np.random.default_rng(seed)
    q = _random_quat(rng)
    bias = np.array([1e-4, -2e-4, 5e-5])
    f = MEKF(hamilton(q, _rotvec(np.radians([1.0, -0.5, 0.7]))), sigma_attitude_rad=math.radians(2.0),
             sigma_bias_rad_s=5e-4, arw_rad_s05=arw, rrw_rad_s15=rrw)
    errors, covs = [], []
    for k in range(n_steps):
        t = k * dt
        w = np.array([0.01 * math.sin(0.01 * t), 0.005, -0.008 * math.cos(0.02 * t)])
        f.propagate(w + bias + arw / math.sqrt(dt) * rng.normal(size=3), dt)
        q = hamilton(q, _rotvec(w * dt))
        bias = bias + rrw * math.sqrt(dt) * rng.normal(size=3)
        if k % every == every - 1:
            f.update_attitude(hamilton(q, _rotvec(sigma_st * rng.normal(size=3))), sigma_st ** 2)
        dq = hamilton(conjugate(f.q), q)
        errors.append(2.0 * dq[1:] * np.sign(dq[0]))
        covs.append(f.P.copy())
    return np.array(errors), np.array(covs), f.bias - bias, f


def test_mekf_three_sigma_bounds_hold_the_true_error_at_least_99_percent_of_the_time():
    errors, covs, bias_err, f = _simulate_mekf(seed=7, n_steps=6000)
    sigma = np.sqrt(np.diagonal(covs, axis1=1, axis2=2)[:, :3])
    coverage = np.mean(np.abs(errors) <= 3.0 * sigma, axis=0)
    assert np.all(coverage >= 0.99), coverage
    # Normalised estimation error squared: chi-square with 3 degrees of freedom, mean 3 when consistent.
    nees = np.einsum("ni,nij,nj->n", errors, np.linalg.inv(covs[:, :3, :3]), errors)
    assert 2.4 < np.mean(nees) < 3.6
    assert np.all(np.abs(bias_err) < 3.0 * np.sqrt(np.diag(f.P)[3:]))
    assert np.max(np.abs(bias_err)) < 5e-6  # from 2e-4 rad/s unknown to a few urad/s


def test_mekf_covariance_stays_symmetric_and_positive_definite():
    _, covs, _, _ = _simulate_mekf(seed=3, n_steps=1500, every=3)
    assert np.array_equal(covs, np.transpose(covs, (0, 2, 1)))
    assert np.min(np.linalg.eigvalsh(covs)) > 0.0


def test_mekf_vector_updates_converge_without_a_tracker():
    rng = np.random.default_rng(9)
    q = _random_quat(rng)
    f = MEKF(hamilton(q, _rotvec(np.radians([3.0, -2.0, 4.0]))), sigma_attitude_rad=math.radians(5.0))
    sun, mag = np.array([0.3, 0.9, -0.2]), np.array([-0.5, 0.1, 0.85])
    for _ in range(50):
        f.propagate([0.0, 0.0, 0.0], 1.0)
        for r in (sun, mag):
            b = dcm(q) @ (r / np.linalg.norm(r)) + rng.normal(0.0, 1e-4, 3)
            f.update_vector(b, r, 1e-4)
    assert angle_between(f.q, q) < 3.0 * float(np.max(f.sigma3_attitude_rad))
    assert angle_between(f.q, q) < 1e-4


def test_mekf_gate_rejects_an_outlier_and_counts_it():
    f = MEKF([1.0, 0.0, 0.0, 0.0], sigma_attitude_rad=1e-4)
    assert not f.update_attitude(quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), 0.1), 1e-8, gate_sigma=5.0)
    assert f.rejected == 1 and f.updates == 0


# -- guidance -------------------------------------------------------------------------------------------------

R0 = np.array([6878137.0, 0.0, 0.0])
V0 = np.array([0.0, 5000.0, 5500.0])


def _rate_from_frames(C_m, C_p, C0, dt):
    W = -(C_p - C_m) / (2.0 * dt) @ C0.T
    return 0.5 * np.array([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]])


def test_nadir_reference_is_lvlh_and_its_rate_is_the_frames_derivative():
    q, w = gd.nadir(R0, V0)
    C = dcm(q)
    np.testing.assert_allclose(C, dcm_lvlh_gcrs(R0, V0), atol=1e-15)
    np.testing.assert_allclose(C.T @ [0, 0, 1], -R0 / np.linalg.norm(R0), atol=1e-15)  # z to nadir
    dt = 0.5
    (rm, vm), (rp, vp) = propagate_kepler(R0, V0, -dt), propagate_kepler(R0, V0, dt)
    expected = _rate_from_frames(dcm_lvlh_gcrs(rm, vm), dcm_lvlh_gcrs(rp, vp), C, dt)
    np.testing.assert_allclose(w, expected, atol=1e-9)
    assert abs(w[0]) < 1e-15 and abs(w[2]) < 1e-15 and w[1] < 0


def test_sun_pointing_puts_the_axis_on_the_sun():
    sun = np.array([1.4e11, -3.0e10, 2.0e10])
    q, w = gd.sun_pointing(sun, [0.0, 0.0, 1.0], sun_axis_B=[0.0, 1.0, 0.0])
    np.testing.assert_allclose(dcm(q).T @ [0.0, 1.0, 0.0], sun / np.linalg.norm(sun), atol=1e-15)
    assert np.all(w == 0.0)
    with pytest.raises(gd.GuidanceError, match="parallel"):
        gd.sun_pointing([1.0, 0.0, 0.0], [1.0, 1e-4, 0.0])


def test_target_pointing_boresight_and_rate_against_the_propagated_geometry():
    omega_e = np.array([0.0, 0.0, 7.292115e-5])
    target = np.array([6378137.0 * math.cos(0.3), 0.0, 6378137.0 * math.sin(0.3)])
    q, w = gd.target_pointing(R0, V0, target, np.cross(omega_e, target))
    los = target - R0
    np.testing.assert_allclose(dcm(q) @ (los / np.linalg.norm(los)), [0.0, 0.0, 1.0], atol=1e-14)

    def frame(t):
        r, v = propagate_kepler(R0, V0, t) if t else (R0, V0)
        c, s = math.cos(omega_e[2] * t), math.sin(omega_e[2] * t)
        tgt = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ target  # the Earth turns the target
        return gd.pointing_frame(tgt - r, np.cross(R0, V0), (0, 0, 1), (1, 0, 0))

    expected = _rate_from_frames(frame(-0.1), frame(0.1), frame(0.0), 0.1)
    np.testing.assert_allclose(w, expected, rtol=1e-4, atol=1e-9)
    assert np.linalg.norm(w) > 1e-3  # a real slew rate over a nearby target


# -- control ----------------------------------------------------------------------------------------------------

PYRAMID = np.stack((np.sqrt(2 / 3) * np.cos(np.radians([0, 90, 180, 270])),
                    np.sqrt(2 / 3) * np.sin(np.radians([0, 90, 180, 270])), np.full(4, np.sqrt(1 / 3))))


@pytest.mark.parametrize("axes", [np.eye(3), PYRAMID])
def test_wheel_distribution_gives_the_torque_with_the_minimum_norm(axes):
    d = ctl.WheelDistribution(axes)
    tau = np.array([0.01, -0.02, 0.005])
    u = d.motor_torques(tau)
    np.testing.assert_allclose(d.body_torque(u), tau, atol=1e-16)
    if axes.shape[1] == 4:
        null = np.array([1.0, -1.0, 1.0, -1.0]) / 2.0  # the pyramid's null vector
        assert abs(null @ u) < 1e-16
        np.testing.assert_allclose(d.null[:, 0] * np.sign(d.null[0, 0]), null, atol=1e-15)


def test_null_space_term_manages_momentum_without_torquing_the_body():
    d = ctl.WheelDistribution(PYRAMID)
    speeds = np.array([50.0, 120.0, -30.0, 80.0])
    u0 = d.motor_torques([0.01, 0.0, 0.0])
    u = d.motor_torques([0.01, 0.0, 0.0], speeds, 0.02, speed_target_rad_s=100.0, null_gain_per_s=0.1)
    np.testing.assert_allclose(d.body_torque(u), [0.01, 0.0, 0.0], atol=1e-16)
    n = d.null[:, 0]
    # The null-space torque moves the speeds' null-space component towards the target's.
    assert (n @ (u - u0)) * (n @ (speeds - 100.0)) < 0.0


def test_torque_limit_scales_the_whole_command_and_keeps_its_direction():
    d = ctl.WheelDistribution(np.eye(3), max_torque_Nm=0.01)
    u = d.motor_torques([0.04, -0.02, 0.01])
    np.testing.assert_allclose(u, -np.array([0.04, -0.02, 0.01]) / 4.0, atol=1e-17)
    with pytest.raises(ctl.ControlError, match="span"):
        ctl.WheelDistribution([[1, 0, 0], [0, 1, 0], [0, 0, 0]])


def test_dumping_dipole_removes_the_momentum_across_the_field():
    b = np.array([2e-5, -1e-5, 3e-5])
    h = np.array([0.02, 0.01, -0.005])
    m = ctl.dumping_dipole(b, h, 0.01)
    torque = np.cross(m, b)
    h_perp = h - b * (b @ h) / (b @ b)
    np.testing.assert_allclose(torque, -0.01 * h_perp, rtol=1e-12)
    assert torque @ h < 0.0
    assert np.max(np.abs(ctl.dumping_dipole(b, h, 0.01, max_dipole_A_m2=1.0))) <= 1.0 + 1e-15


def test_control_law_compensates_the_gyroscopic_torque_and_feeds_back_errors():
    I = np.diag([10.0, 12.0, 8.0])
    K, P = ctl.pd_gains(I, 0.1, 0.9)
    w = np.array([0.01, -0.02, 0.03])
    h = np.array([0.1, 0.2, -0.1])
    q = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), 0.3)
    # On the reference, turning with it: only the gyroscopic term remains.
    u = ctl.control_torque(q, w, q, w, I, K, P, h)
    np.testing.assert_allclose(u, np.cross(w, I @ w + h), atol=1e-15)
    # A small error about x is fed back as -K angle / 4 (MRP) or -K angle (2 q_vec) with the designed
    # stiffness wn^2 I either way.
    e = 1e-4
    qb = compose(quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), e), q)
    for law in ctl.LAWS:
        Kl, Pl = ctl.pd_gains(I, 0.1, 0.9, law)
        u = ctl.control_torque(qb, np.zeros(3), q, np.zeros(3), I, Kl, Pl, law=law)
        np.testing.assert_allclose(u, [-0.01 * 10.0 * e, 0.0, 0.0], rtol=1e-6, atol=1e-15)


# -- modes ------------------------------------------------------------------------------------------------------

def test_mode_sequence_detumble_sun_fine_with_outage_fallback_and_hysteresis():
    m = ModeManager(ModeConfig(hold_s=5.0, fine_entry_solutions=3, outage_s=10.0))
    fast, mid, slow = math.radians(3.0), math.radians(1.0), math.radians(0.1)
    t = 0.0
    for _ in range(20):  # between the exit (0.5) and entry (2) rates: stays where it is
        assert m.update(t, mid, False) == DETUMBLE
        t += 1.0
    for _ in range(5):
        assert m.update(t, slow, False) == DETUMBLE
        t += 1.0
    assert m.update(t, slow, False) == SUN_ACQUISITION
    t += 1.0
    assert m.update(t, mid, True, 1e-4) == SUN_ACQUISITION  # rate between 0.3 and 2 deg/s: no detumble either
    for _ in range(2):
        t += 1.0
        assert m.update(t, slow, True, 1e-4) == SUN_ACQUISITION
    t += 1.0
    assert m.update(t, slow, True, 1e-4) == FINE_POINTING
    for _ in range(10):  # a tracker outage shorter than outage_s: fine pointing on the gyro
        t += 1.0
        assert m.update(t, slow, False, 1e-4) == FINE_POINTING and m.gyro_only
    t += 1.0
    assert m.update(t, slow, False, 1e-4) == SUN_ACQUISITION
    assert "outage" in m.transitions[-1][3]
    t += 1.0
    m.update(t, slow, True, 1e-4)
    t += 1.0
    m.update(t, slow, False, 1e-4)  # an interruption restarts the count
    for _ in range(2):
        t += 1.0
        assert m.update(t, slow, True, 1e-4) == SUN_ACQUISITION
    t += 1.0
    assert m.update(t, slow, True, 1e-4) == FINE_POINTING
    t += 1.0
    assert m.update(t, slow, True, math.radians(1.0)) == SUN_ACQUISITION  # filter 3-sigma too large
    t += 1.0
    assert m.update(t, fast, True, 1e-4) == DETUMBLE
    with pytest.raises(ValueError, match="hysteresis"):
        ModeConfig(detumble_entry_rate_rad_s=0.01, detumble_exit_rate_rad_s=0.02)
