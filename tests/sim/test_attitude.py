"""sim.attitude: closed-form solutions, conservation laws, convergence order and refusals."""

import numpy as np
import pytest

from sim import attitude as att
from sim.rotations import dcm

Q0 = [1.0, 0.0, 0.0, 0.0]


def test_axisymmetric_torque_free_rates_match_closed_form():
    # I1 = I2: omega3 is constant and (omega1 + i omega2) turns at lambda = (I3 - I1) omega3 / I1.
    I1, I3 = 0.02, 0.01
    w0 = np.array([0.1, -0.05, 0.3])
    t, q, w = att.propagate([I1, I1, I3], Q0, w0, 600.0, 0.05)
    lam = (I3 - I1) * w0[2] / I1
    z = (w0[0] + 1j * w0[1]) * np.exp(1j * lam * t)
    np.testing.assert_allclose(w[:, 0], z.real, atol=1e-9)
    np.testing.assert_allclose(w[:, 1], z.imag, atol=1e-9)
    np.testing.assert_allclose(w[:, 2], w0[2], atol=1e-14)


def test_torque_free_conserves_inertial_angular_momentum_and_energy():
    inertia = np.diag([10.0, 20.0, 30.0])
    t, q, w = att.propagate(inertia, Q0, [0.01, 0.5, 0.01], 600.0, 0.01)
    H_N = np.einsum("nji,nj->ni", dcm(q), w @ inertia)  # dcm^T (I w)
    assert np.max(np.abs(H_N - H_N[0])) / np.linalg.norm(H_N[0]) < 1e-8
    T = att.kinetic_energy(inertia, w)
    assert np.max(np.abs(T - T[0])) / T[0] < 1e-8
    assert np.max(np.abs(np.linalg.norm(q, axis=1) - 1.0)) < 1e-14


def test_rk4_converges_with_order_four():
    inertia = [10.0, 20.0, 30.0]
    w0 = [0.01, 0.5, 0.01]
    ref = att.propagate(inertia, Q0, w0, 60.0, 0.0025)
    errs = []
    for h in (0.04, 0.02):
        t, q, w = att.propagate(inertia, Q0, w0, 60.0, h)
        errs.append(np.linalg.norm(w[-1] - ref[2][-1]))
    order = np.log2(errs[0] / errs[1])
    assert 3.5 <= order <= 4.5, order


def test_spin_exactly_about_a_principal_axis_stays_there():
    t, q, w = att.propagate([1.0, 2.0, 3.0], Q0, [0.0, 0.0, 0.7], 100.0, 0.01)
    np.testing.assert_allclose(w, np.broadcast_to([0.0, 0.0, 0.7], w.shape), atol=1e-15)
    ang = 2 * np.arctan2(q[-1, 3], q[-1, 0])  # rotation about z
    assert abs(np.angle(np.exp(1j * (ang - 0.7 * 100.0)))) < 1e-10


def test_constant_torque_spins_up_a_sphere_linearly():
    tau = np.array([0.0, 0.0, 1e-3])
    t, q, w = att.propagate([0.1, 0.1, 0.1], Q0, [0.0, 0.0, 0.0], 10.0, 0.01, torque=lambda t, q, w: tau)
    np.testing.assert_allclose(w[:, 2], 1e-2 * t, rtol=1e-12, atol=1e-15)


def test_fixed_step_runs_are_bit_identical():
    a = att.propagate([10.0, 20.0, 30.0], Q0, [0.01, 0.5, 0.01], 50.0, 0.1)
    b = att.propagate([10.0, 20.0, 30.0], Q0, [0.01, 0.5, 0.01], 50.0, 0.1)
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x, y)


def test_a_step_too_large_for_the_spin_is_refused_with_the_limit():
    with pytest.raises(ValueError, match=r"step_s = 0.1 s is too large .* step_s <= 0.00"):
        att.propagate([10.0, 20.0, 30.0], Q0, [20.0, 0.0, 0.0], 1.0, 0.1)
    # and the same rate at 1 ms is accepted
    att.propagate([10.0, 20.0, 30.0], Q0, [20.0, 0.0, 0.0], 0.01, 0.001)


def test_spin_up_past_the_limit_during_a_run_is_refused():
    with pytest.raises(ValueError, match="too large"):
        att.propagate([0.01, 0.01, 0.01], Q0, [0.0, 0.0, 0.0], 100.0, 0.1,
                      torque=lambda t, q, w: np.array([0.0, 0.0, 1e-3]))


def test_flat_plate_inertia_is_accepted_and_beyond_it_refused():
    att.check_inertia([1.0, 2.0, 3.0])  # I1 + I2 = I3 exactly: a flat plate
    with pytest.raises(ValueError, match="triangle inequality"):
        att.check_inertia([1.0, 1.0, 3.0])


@pytest.mark.parametrize("bad, match", [
    ([0.02, -0.02, 0.01], "positive"),
    ([[1, 0.5, 0], [0, 1, 0], [0, 0, 1]], "not symmetric"),
    ([1.0, np.nan, 1.0], "NaN"),
    ([1.0, 2.0], "shape"),
])
def test_bad_inertia_is_named(bad, match):
    with pytest.raises(ValueError, match=match):
        att.check_inertia(bad)


@pytest.mark.parametrize("q", [[1.0, 0.1, 0.0, 0.0], [np.nan, 0.0, 0.0, 1.0]])
def test_non_unit_quaternion_is_refused(q):
    with pytest.raises(ValueError, match="q_BN"):
        att.propagate([1.0, 1.0, 1.0], q, [0.0, 0.0, 0.0], 1.0, 0.1)


@pytest.mark.parametrize("step", [0.0, -0.1, float("nan")])
def test_non_positive_step_is_refused(step):
    with pytest.raises(ValueError, match="step_s"):
        att.propagate([1.0, 1.0, 1.0], Q0, [0.0, 0.0, 0.0], 1.0, step)
