"""sim.rotations against the conventions in its docstring and an independent library (scipy's Rotation)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from sim import rotations as rot

ATOL = 1e-12


def scipy_dcm(angles, seq):
    """Passive DCM for our sequence convention from scipy's intrinsic active rotation."""
    axes = "".join("XYZ"[int(c) - 1] for c in seq)
    return np.swapaxes(Rotation.from_euler(axes, angles).as_matrix(), -1, -2)


def random_quats(n, seed=0):
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_design_example_plus_90_about_z_maps_x_to_minus_y():
    q = [np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]
    np.testing.assert_allclose(rot.dcm(q) @ [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], atol=ATOL)
    np.testing.assert_allclose(rot.quat_from_axis_angle([0, 0, 1], np.pi / 2), q, atol=ATOL)


def test_dcm_matches_design_formula_and_scipy():
    q = random_quats(500)
    # scipy uses scalar-last, active rotations: our dcm is the transpose of its matrix.
    ref = np.swapaxes(Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix(), -1, -2)
    np.testing.assert_allclose(rot.dcm(q), ref, atol=ATOL)


def test_compose_order():
    q_CB, q_BN = random_quats(200, 1), random_quats(200, 2)
    np.testing.assert_allclose(rot.dcm(rot.compose(q_CB, q_BN)), rot.dcm(q_CB) @ rot.dcm(q_BN), atol=ATOL)


def test_conjugate_is_inverse_and_outputs_keep_w_nonnegative():
    q = random_quats(100, 3)
    np.testing.assert_allclose(rot.dcm(rot.conjugate(q)), np.swapaxes(rot.dcm(q), -1, -2), atol=ATOL)
    assert np.all(rot.quat_from_dcm(rot.dcm(q))[:, 0] >= 0)
    assert np.all(rot.compose(q, q)[:, 0] >= 0)


def test_quat_from_dcm_round_trip_including_180_degree_turns():
    q = np.vstack([random_quats(300, 4), [[0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [0, 0.6, 0.8, 0]]])
    back = rot.quat_from_dcm(rot.dcm(q))
    np.testing.assert_allclose(rot.dcm(back), rot.dcm(q), atol=ATOL)


@pytest.mark.parametrize("seq", rot.EULER_SEQUENCES)
def test_euler_matches_scipy_and_round_trips(seq):
    rng = np.random.default_rng(int(seq))
    ang = rng.uniform(-np.pi, np.pi, (400, 3))
    ang[:, 1] = rng.uniform(0, np.pi, 400) if seq[0] == seq[2] else rng.uniform(-np.pi / 2, np.pi / 2, 400)
    q = rot.quat_from_euler(ang, seq)
    np.testing.assert_allclose(rot.dcm(q), scipy_dcm(ang, seq), atol=ATOL)
    back = rot.euler_from_quat(q, seq)
    # Away from gimbal lock the angles themselves come back (wrapped to (-pi, pi]).
    away = np.abs(np.cos(ang[:, 1]) if seq[0] != seq[2] else np.sin(ang[:, 1])) > 1e-3
    np.testing.assert_allclose(np.angle(np.exp(1j * (back - ang)))[away], 0.0, atol=1e-9)


@pytest.mark.parametrize("seq", rot.EULER_SEQUENCES)
@pytest.mark.parametrize("which", [0, 1])
def test_euler_at_gimbal_lock_still_reproduces_the_attitude(seq, which):
    lock = ((0.0, np.pi) if seq[0] == seq[2] else (np.pi / 2, -np.pi / 2))[which]
    ang = np.array([[0.7, lock, -0.4], [-2.9, lock, 2.2], [0.0, lock, 0.0]])
    q = rot.quat_from_euler(ang, seq)
    back = rot.euler_from_quat(q, seq)
    np.testing.assert_allclose(back[:, 2], 0.0, atol=1e-12)  # documented: a3 := 0 at lock
    np.testing.assert_allclose(rot.dcm(rot.quat_from_euler(back, seq)), rot.dcm(q), atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(
    lambda v: np.linalg.norm(v) > 1e-3), st.sampled_from(rot.EULER_SEQUENCES))
def test_euler_round_trip_property(v, seq):
    q = rot.normalize(np.array(v))
    back = rot.quat_from_euler(rot.euler_from_quat(q, seq), seq)
    assert rot.angle_between(q, back) < 1e-7


def test_axis_angle_round_trip_and_identity():
    q = random_quats(200, 5)
    axis, angle = rot.axis_angle(q)
    np.testing.assert_allclose(rot.dcm(rot.quat_from_axis_angle(axis, angle)), rot.dcm(q), atol=ATOL)
    ax0, a0 = rot.axis_angle([1.0, 0, 0, 0])
    assert a0 == 0.0 and np.allclose(ax0, [1, 0, 0])


@pytest.mark.parametrize("bad", [[1.0, 0.1, 0, 0], [np.nan, 0, 0, 0], [0.0, 0, 0, 0]])
def test_non_unit_or_nan_quaternion_is_refused(bad):
    with pytest.raises(ValueError, match="q"):
        rot.dcm(bad)


def test_bad_sequence_is_named():
    with pytest.raises(ValueError, match="'311'"):
        rot.quat_from_euler([0, 0, 0], "311")
