"""Centred dipole field, torques and frames against closed forms."""

import numpy as np
import pytest

from sim import environment as env
from sim import frames, torques
from sim.constants import R_IGRF
from sim.rotations import dcm
from sim.time import Epoch
from sim.truth import rotate_to_body


def potential(r, g):
    rn = np.linalg.norm(r)
    return R_IGRF**3 * np.dot(g, r) / rn**3


def test_dipole_field_is_minus_gradient_of_the_degree_1_potential():
    g = np.array([env.DIPOLE_G11_NT, env.DIPOLE_H11_NT, env.DIPOLE_G10_NT]) * 1e-9
    rng = np.random.default_rng(0)
    for r in rng.normal(size=(20, 3)) * 7e6:
        eps = 1.0
        grad = [(potential(r + eps * e, g) - potential(r - eps * e, g)) / (2 * eps) for e in np.eye(3)]
        np.testing.assert_allclose(env.dipole_field_itrs(r), -np.array(grad), rtol=1e-7, atol=1e-15)


def test_dipole_field_at_the_north_pole_is_2_g10_downward():
    b = env.dipole_field_itrs([0.0, 0.0, R_IGRF])
    np.testing.assert_allclose(b, [-env.DIPOLE_G11_NT * 1e-9, -env.DIPOLE_H11_NT * 1e-9,
                                   2 * env.DIPOLE_G10_NT * 1e-9], rtol=1e-12)
    assert b[2] < 0  # points into the Earth in the north


def test_field_inside_the_earth_is_refused():
    with pytest.raises(ValueError, match="inside the Earth"):
        env.dipole_field_itrs([0.0, 0.0, 1e6])


def test_torques_match_their_definitions():
    m, b = np.array([0.1, -0.2, 0.05]), np.array([2e-5, 1e-5, -3e-5])
    np.testing.assert_allclose(torques.magnetic_torque(m, b), np.cross(m, b))
    inertia = np.diag([0.02, 0.02, 0.01])
    # r along a principal axis: no gravity-gradient torque.
    np.testing.assert_allclose(torques.gravity_gradient_torque(inertia, [7e6, 0, 0]), 0.0, atol=1e-20)
    r = np.array([7e6, 1e6, -2e6])
    expected = 3 * 3.986004418e14 / np.linalg.norm(r) ** 5 * np.cross(r, inertia @ r)
    np.testing.assert_allclose(torques.gravity_gradient_torque(inertia, r), expected, rtol=1e-12)


def test_rotate_to_body_equals_dcm():
    rng = np.random.default_rng(1)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        v = rng.normal(size=3)
        np.testing.assert_allclose(rotate_to_body(tuple(q), tuple(v)), dcm(q) @ v, atol=1e-14)


def test_earth_rotation_interpolation_matches_c2t06a_to_a_milliarcsecond():
    e = Epoch.from_iso("2026-03-20T12:00:00Z", dut1_s=0.02)
    rot = frames.EarthRotation(e, "iau2006")
    ts = np.array([0.0, 13.7, 299.9, 1234.5, 5677.0])
    got = rot.dcm_itrs_gcrs(ts)
    for t, C in zip(ts, got, strict=True):
        ref = frames.dcm_itrs_gcrs(e + float(t))
        err = np.linalg.norm(C @ ref.T - np.eye(3)) / np.sqrt(2)  # small-angle, no acos floor
        assert np.degrees(err) * 3.6e6 < 1.0  # mas


def test_precession_makes_sidereal_time_alone_wrong_by_about_0_37_deg_in_2026():
    e = Epoch.from_iso("2026-06-01T00:00:00Z")
    full = frames.dcm_itrs_gcrs(e)
    import erfa

    gmst = erfa.gmst06(*e.jd_ut1, *e.jd_tt)
    err = np.degrees(np.arccos(np.clip((np.trace(full @ frames.rotation_z(gmst).T) - 1) / 2, -1, 1)))
    assert 0.3 < err < 0.45


def test_local_frames_are_right_handed_and_point_where_named():
    r = np.array([7e6, 0.0, 0.0])
    v = np.array([0.0, 7.5e3, 0.0])
    L = frames.dcm_lvlh_gcrs(r, v)
    np.testing.assert_allclose(L @ (-r / 7e6), [0, 0, 1], atol=1e-15)  # z to nadir
    np.testing.assert_allclose(L @ [0, 1, 0], [1, 0, 0], atol=1e-15)  # x along-track
    R = frames.dcm_rsw_gcrs(r, v)
    np.testing.assert_allclose(R @ [1, 0, 0], [1, 0, 0], atol=1e-15)
    for C in (L, R, frames.dcm_esd_itrs([1e6, 2e6, 6e6])):
        np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-14)
        assert np.linalg.det(C) == pytest.approx(1.0)
    E = frames.dcm_esd_itrs([7e6, 0, 0])
    np.testing.assert_allclose(E, [[0, 1, 0], [0, 0, -1], [-1, 0, 0]], atol=1e-15)


def test_truth_model_stage_torque_equals_the_torque_functions():
    from sim.attitude import check_inertia
    from sim.truth import TruthModel

    inertia = check_inertia([[0.02, 0.001, 0.0], [0.001, 0.025, 0.0], [0.0, 0.0, 0.015]])
    rot = frames.EarthRotation(Epoch.from_iso("2026-03-20T12:00:00Z"), "uniform")
    truth = TruthModel(inertia=inertia, q_BN=[1.0, 0.0, 0.0, 0.0], omega_BN_B=[0.01, 0.02, 0.03],
                       r_N=[7e6, 1e5, -2e5], v_N=[0.0, 7.5e3, 1.0e3], step_ns=100_000_000,
                       field_itrs=lambda t, r: env.dipole_field_itrs(r), earth_rotation=rot)
    field_N, r_N = truth.track.field(0), truth.track.position(0)
    truth._environment.set_step((0.1, -0.05, 0.2), tuple(field_N) * 3, tuple(r_N) * 3)
    q = np.array([0.8, 0.2, -0.4, 0.4])
    q /= np.linalg.norm(q)
    got = truth._environment(0.0, tuple(q), (0.0, 0.0, 0.0))
    expected = (torques.magnetic_torque([0.1, -0.05, 0.2], dcm(q) @ field_N)
                + torques.gravity_gradient_torque(inertia, dcm(q) @ r_N))
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-20)
