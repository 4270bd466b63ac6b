"""The reference ADCS's per-period arithmetic on plain floats (stand.adcs.quat, the MEKF's transition and 3 x 3
inverse) pinned against independent numpy and scipy implementations at 1e-12: quaternions against
scipy.spatial.transform.Rotation, matrix operations against numpy.linalg, the error transition against the matrix
exponential of the continuous error dynamics (scipy.linalg.expm)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from stand.adcs import quat
from stand.adcs.control import ControlError, control_torque
from stand.adcs.determination import MEKF, FilterError, _transition

RNG = np.random.default_rng(2026)
QUATS = [q / np.linalg.norm(q) for q in RNG.normal(size=(20, 4))]
VECS = list(RNG.normal(size=(20, 3)) * 10.0 ** RNG.integers(-6, 3, size=(20, 1)))


def _scipy(q) -> Rotation:
    """Our scalar-first ``q_BN`` as scipy's rotation (scalar last)."""
    return Rotation.from_quat([q[1], q[2], q[3], q[0]])


def _same_attitude(q, ref_xyzw, tol=1e-12):
    ref = np.array([ref_xyzw[3], *ref_xyzw[:3]])
    q = np.asarray(q)
    assert min(np.max(np.abs(q - ref)), np.max(np.abs(q + ref))) <= tol


@pytest.mark.parametrize("i", range(len(QUATS) - 1))
def test_qmul_conj_and_dcm_match_scipy(i):
    p, q = QUATS[i], QUATS[i + 1]
    _same_attitude(quat.qmul(p, q), (_scipy(p) * _scipy(q)).as_quat())
    _same_attitude(quat.conj(p), _scipy(p).inv().as_quat())
    # dcm(q_BN) maps N components to B components: the transpose of scipy's active rotation matrix.
    np.testing.assert_allclose(quat.dcm1(p), _scipy(p).as_matrix().T, rtol=0, atol=1e-12)
    np.testing.assert_allclose(quat.rotation_vector(p), _scipy(quat.positive(p)).as_rotvec(), rtol=0, atol=1e-12)
    _same_attitude(quat.error(p, q), (_scipy(q).inv() * _scipy(p)).as_quat())
    assert quat.positive(-p)[0] >= 0.0 and quat.positive(p)[0] >= 0.0
    np.testing.assert_allclose(quat.normalised(3.0 * p), p, rtol=0, atol=1e-15)


def test_rotation_vector_of_identity_and_of_a_half_turn():
    assert quat.rotation_vector((1.0, 0.0, 0.0, 0.0)) == (0.0, 0.0, 0.0)
    np.testing.assert_allclose(quat.rotation_vector((0.0, 0.0, 1.0, 0.0)), (0.0, math.pi, 0.0), atol=1e-15)


@pytest.mark.parametrize("i", range(len(VECS) - 1))
def test_vector_and_matrix_helpers_match_numpy(i):
    a, b = VECS[i], VECS[i + 1]
    M = RNG.normal(size=(3, 3)) + 3.0 * np.eye(3)
    scale = np.linalg.norm(a) * np.linalg.norm(b)
    np.testing.assert_allclose(quat.cross(a, b), np.cross(a, b), rtol=0, atol=1e-15 * scale)
    assert quat.dot(a, b) == pytest.approx(float(np.dot(a, b)), rel=0, abs=1e-15 * scale)
    assert quat.norm(a) == pytest.approx(float(np.linalg.norm(a)), rel=1e-15)
    np.testing.assert_allclose(quat.add(a, b), a + b, rtol=1e-15)
    np.testing.assert_allclose(quat.sub(a, b), a - b, rtol=1e-15)
    np.testing.assert_allclose(quat.scale(-2.5, a), -2.5 * a, rtol=1e-15)
    rows = quat.mat3(M)
    np.testing.assert_allclose(quat.mv(rows, a), M @ a, rtol=1e-12)
    np.testing.assert_allclose(quat.mtv(rows, a), M.T @ a, rtol=1e-12)
    np.testing.assert_allclose(quat.inv3(rows), np.linalg.inv(M), rtol=1e-12, atol=1e-14)


def test_inv3_of_a_covariance_like_matrix_matches_numpy():
    # The MEKF inverts S = P_attitude + R: symmetric, positive definite, entries near 1e-10 rad^2.
    A = RNG.normal(size=(3, 3))
    S = 1e-10 * (A @ A.T + np.diag([1.0, 1.0, 25.0]))
    np.testing.assert_allclose(quat.inv3(quat.mat3(S)), np.linalg.inv(S), rtol=1e-12)


@pytest.mark.parametrize("v", [(1.0, 2.0), (1.0, 2.0, 3.0, 4.0), [[1.0], [2.0], [3.0]], np.ones((3, 1)),
                               (1.0, math.nan, 0.0), (math.inf, 0.0, 0.0), ("a", "b", "c"), None, 3.0])
def test_finite3_refuses_anything_but_three_finite_numbers(v):
    with pytest.raises(ValueError, match="must be 3 finite numbers"):
        quat.finite3(v, "omega_B", ValueError)


def test_finite3_gives_floats():
    assert quat.finite3(np.array([1, 2, 3]), "v", ValueError) == (1.0, 2.0, 3.0)
    assert all(type(c) is float for c in quat.finite3([np.float32(1.5), 2, 3.0], "v", ValueError))


@pytest.mark.parametrize(("w", "dt"), [((0.01, -0.02, 0.005), 0.1), ((0.3, 0.1, -0.2), 0.5), ((1e-7, 0.0, 2e-7), 0.1),
                                       ((0.0, 0.0, 0.0), 0.1)])
def test_error_transition_is_the_exponential_of_the_error_dynamics(w, dt):
    """Phi = expm(F dt) with F = [[-[w x], -I], [0, 0]] (Markley & Crassidis eq. 6.76): both the closed form and
    its small-angle series (below 1e-4 rad a step, where the series' truncation is below 1e-18)."""
    x, y, z = w
    W = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    F = np.zeros((6, 6))
    F[:3, :3], F[:3, 3:] = -W, -np.eye(3)
    np.testing.assert_allclose(_transition(w, math.sqrt(x * x + y * y + z * z), dt), expm(F * dt), rtol=0, atol=1e-12)


def _mekf_numpy(q0, omegas, measurements, dt, R, arw, rrw, sigma0, sigma_b):
    """The MEKF written directly in numpy and scipy (no stand.adcs helper): the reference for the float version."""
    q = _scipy(q0)
    b = np.zeros(3)
    P = np.diag([sigma0 ** 2] * 3 + [sigma_b ** 2] * 3)
    v2, u2 = arw ** 2, rrw ** 2
    Q = np.block([[(v2 * dt + u2 * dt ** 3 / 3) * np.eye(3), -(u2 * dt ** 2 / 2) * np.eye(3)],
                  [-(u2 * dt ** 2 / 2) * np.eye(3), u2 * dt * np.eye(3)]])
    H = np.hstack((np.eye(3), np.zeros((3, 3))))
    out = []
    for w_meas, q_meas in zip(omegas, measurements, strict=True):
        w = w_meas - b
        q = q * Rotation.from_rotvec(w * dt)  # body-frame increment: q (x) exp(w dt / 2)
        F = np.zeros((6, 6))
        F[:3, :3] = -np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
        F[:3, 3:] = -np.eye(3)
        Phi = expm(F * dt)
        P = Phi @ P @ Phi.T + Q
        z = (q.inv() * _scipy(q_meas)).as_rotvec()
        K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
        dx = K @ z
        IKH = np.eye(6) - K @ H
        P = IKH @ P @ IKH.T + K @ R @ K.T
        q = q * Rotation.from_quat([*(0.5 * dx[:3]), 1.0])  # from_quat normalises
        b = b + dx[3:]
        xyzw = q.as_quat()
        out.append((np.array([xyzw[3], *xyzw[:3]]) * (1.0 if xyzw[3] >= 0 else -1.0), b.copy(), P.copy()))
    return out


def test_mekf_on_floats_matches_a_numpy_scipy_mekf():
    dt, arw, rrw, sigma0, sigma_b = 0.1, 1e-5, 1e-7, 1e-3, 1e-4
    R = np.diag([1e-10, 1e-10, 2.5e-9])
    truth = Rotation.from_rotvec([0.3, -0.2, 0.1])
    w_true = np.array([0.01, -0.004, 0.02])
    rng = np.random.default_rng(7)
    omegas, meas = [], []
    for _ in range(50):
        truth = truth * Rotation.from_rotvec(w_true * dt)
        omegas.append(w_true + np.array([2e-5, -1e-5, 3e-5]) + rng.normal(scale=1e-5, size=3))
        noisy = truth * Rotation.from_rotvec(rng.normal(scale=1e-5, size=3))
        xyzw = noisy.as_quat()
        meas.append(np.array([xyzw[3], *xyzw[:3]]))
    xyzw = (truth * Rotation.from_rotvec([1e-3, -2e-3, 5e-4])).as_quat()
    q0 = np.array([xyzw[3], *xyzw[:3]])
    q0 = q0 if q0[0] >= 0 else -q0
    f = MEKF(q0, sigma_attitude_rad=sigma0, sigma_bias_rad_s=sigma_b, arw_rad_s05=arw, rrw_rad_s15=rrw)
    ref = _mekf_numpy(q0, omegas, meas, dt, R, arw, rrw, sigma0, sigma_b)
    for w, qm, (q_ref, b_ref, P_ref) in zip(omegas, meas, ref, strict=True):
        f.propagate(w, dt)
        assert f.update_attitude(qm, R)
        np.testing.assert_allclose(f.q, q_ref, rtol=0, atol=1e-12)
        # The bias is learnt from residuals of 1e-5 rad: the two versions' round-off in the attitude (1e-16 rad) comes
        # back in it divided by about a period, so it agrees to 2.2e-12 of its size here (measured), not 1e-12.
        np.testing.assert_allclose(f.bias, b_ref, rtol=0, atol=5e-12 * float(np.max(np.abs(b_ref))))
        np.testing.assert_allclose(f.P, P_ref, rtol=0, atol=1e-12 * float(np.max(np.abs(P_ref))))


def test_control_torque_on_floats_matches_the_textbook_law_in_numpy():
    q_BN, q_RN = QUATS[0], QUATS[1]
    w, w_RN, dw_RN, h = VECS[0] * 1e-3 / np.linalg.norm(VECS[0]), np.array([1e-3, 0.0, -2e-3]), \
        np.array([1e-6, 2e-6, 0.0]), np.array([0.01, -0.02, 0.005])
    I = np.array([[1.2, 0.02, -0.01], [0.02, 1.5, 0.015], [-0.01, 0.015, 1.0]])
    K, P = 0.09 * I, 0.27 * I
    q_BR = (_scipy(q_RN).inv() * _scipy(q_BN)).as_quat()  # x, y, z, w
    q_BR = q_BR if q_BR[3] >= 0 else -q_BR
    C_BR = _scipy(np.array([q_BR[3], *q_BR[:3]])).as_matrix().T
    sigma = q_BR[:3] / (1.0 + q_BR[3])
    w_RN_B = C_BR @ w_RN
    want = (-K @ sigma - P @ (w - w_RN_B) + np.cross(w, I @ w + h) + I @ (C_BR @ dw_RN - np.cross(w, w_RN_B)))
    got = control_torque(q_BN, w, q_RN, w_RN, I, K, P, h, dw_RN)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * float(np.max(np.abs(want))))
    with pytest.raises(ControlError, match="q_RN"):
        control_torque(q_BN, w, [1.0, 0.0, math.nan, 0.0], w_RN, I, K, P)


@pytest.mark.parametrize("q", [[1.0, 0.0, 0.0], [1.0, math.nan, 0.0, 0.0], np.ones((4, 1)), "abcd"])
def test_mekf_refuses_a_bad_quaternion_by_name(q):
    with pytest.raises(FilterError, match="q_BN_meas"):
        MEKF([1.0, 0.0, 0.0, 0.0]).update_attitude(q, 1e-8)


def test_motor_torques_on_floats_match_the_pseudo_inverse_in_numpy():
    from stand.adcs.control import WheelDistribution

    tilt = math.acos(1.0 / math.sqrt(3.0))
    az = np.radians([0.0, 90.0, 180.0, 270.0])
    A = np.stack((math.sin(tilt) * np.cos(az), math.sin(tilt) * np.sin(az), np.full(4, math.cos(tilt))))
    d = WheelDistribution(A, max_torque_Nm=0.01)
    for t in (VECS[0] * 1e-3 / np.linalg.norm(VECS[0]), np.array([0.02, -0.01, 0.03])):  # inside and over the limit
        want = -np.linalg.pinv(A) @ t
        want = want / max(1.0, float(np.max(np.abs(want))) / 0.01)
        np.testing.assert_allclose(d.motor_torques(t), want, rtol=0, atol=1e-12 * float(np.max(np.abs(want))))


@pytest.mark.parametrize("sample", [np.ones((3, 1)), [1.0, 2.0], [1.0, math.nan, 0.0], [math.inf, 0.0, 0.0], "abc",
                                    None])
def test_a_gyro_sample_that_is_not_three_finite_numbers_is_dropped(sample):
    from stand.adcs.pointing import _finite3_or_none

    assert _finite3_or_none(sample) is None


@pytest.mark.parametrize("q", [np.ones((4, 1)) / 2.0, [1.0, 0.0, 0.0], [1.1, 0.0, 0.0, 0.0], [math.nan, 0, 0, 1], None])
def test_a_tracker_quaternion_that_is_not_a_finite_unit_quaternion_is_dropped(q):
    from stand.adcs.pointing import _unit_quat_or_none

    assert _unit_quat_or_none(q) is None


def test_a_good_tracker_quaternion_is_normalised():
    from stand.adcs.pointing import _unit_quat_or_none

    q = np.array([1.0005, 0.0, 0.0, 0.0])
    assert _unit_quat_or_none(q) == (1.0, 0.0, 0.0, 0.0)
