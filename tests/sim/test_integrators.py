"""sim.attitude.propagate(method=...): every integrator against the closed form, order, guards."""

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from sim import attitude as att
from sim import integrators as ig
from sim.integrators import METHODS, UnstableMethodWarning
from sim.rotations import angle_between, dcm
from sim.torque_free import TorqueFreeBody

DEG = np.pi / 180.0
I = [10.0, 20.0, 30.0]
Q0 = [1.0, 0.0, 0.0, 0.0]
W_SEP = [0.01, 0.5, 0.01]  # the near-separatrix case of `stand bench accuracy`
W_FAST = [20.0 * np.sin(4 * DEG), 0.0, 20.0 * np.cos(4 * DEG)]  # 20 rad/s, 4 deg off the major axis


def _err_deg(method, h, T, w0=W_SEP, **kw):
    t, q, w = att.propagate(I, Q0, w0, T, h, method, **kw)
    return float(angle_between(q[-1], TorqueFreeBody(I, Q0, w0).attitude(T))) / DEG


def test_rk4_at_0_1_s_near_separatrix_meets_the_acceptance():
    assert _err_deg("rk4", 0.1, 600.0) <= 2e-4


def test_rkmk4_at_0_1_s_near_separatrix_meets_the_acceptance():
    assert _err_deg("rkmk4", 0.1, 600.0) <= 1e-3


@pytest.mark.parametrize("method", ["rk4", "rkmk4"])
def test_fourth_order_methods_converge_at_order_four(method):
    e1, e2 = _err_deg(method, 0.16, 300.0), _err_deg(method, 0.08, 300.0)
    assert 3.5 <= np.log2(e1 / e2) <= 4.5


def test_implicit_midpoint_is_second_order_and_conserves_energy():
    e1, e2 = _err_deg("implicit_midpoint", 0.016, 20.0), _err_deg("implicit_midpoint", 0.008, 20.0)
    assert 1.7 <= np.log2(e1 / e2) <= 2.3
    t, q, w = att.propagate(I, Q0, W_SEP, 20.0, 0.01, "implicit_midpoint")
    T = att.kinetic_energy(I, w)
    assert np.max(np.abs(T / T[0] - 1.0)) < 1e-13
    assert np.max(np.abs(np.linalg.norm(q, axis=1) - 1.0)) < 1e-13  # Cayley: round-off only


def test_dop853_follows_its_tolerance():
    assert _err_deg("dop853", 600.0, 600.0, rtol=1e-11, atol=1e-13) < 1e-5
    rep = {}
    t, q, w = att.propagate(I, Q0, W_SEP, 10.0, 0.5, "dop853", rtol=1e-9, report=rep)
    assert len(t) == 21 and rep["rhs_evals"] > 0


def test_trapezoid_warns_and_is_far_less_accurate_than_rk4():
    with pytest.warns(UnstableMethodWarning):
        e = _err_deg("trapezoid", 0.01, 60.0)
    assert e > 100 * _err_deg("rk4", 0.01, 60.0)


def test_trapezoid_on_fast_spin_is_refused_for_its_instability():
    with pytest.warns(UnstableMethodWarning), pytest.raises(ValueError, match="unstable"):
        att.propagate(I, Q0, W_FAST, 600.0, 2e-4, "trapezoid")


def test_fast_spin_at_1_ms_stays_accurate():
    # 60 s (190 revolutions); the bench runs the full 600 s acceptance (<= 1e-3 deg).
    assert _err_deg("rk4", 1e-3, 60.0, W_FAST) < 1e-4


@pytest.mark.parametrize("method", ["rk4", "rkmk4", "rk8", "trapezoid", "implicit_midpoint"])
def test_fast_spin_step_of_0_1_s_is_refused_naming_the_limit(method):
    with pytest.raises(ValueError, match=r"step_s <= .* s here") as err:
        att.propagate(I, Q0, W_FAST, 10.0, 0.1, method)
    assert "20 rad/s" in str(err.value) and "nutation" in str(err.value)


def test_fast_spin_step_of_0_1_s_is_subdivided_on_request_and_reports_n():
    rep = {}
    t, q, w = att.propagate(I, Q0, W_FAST, 2.0, 0.1, subdivide=True, report=rep)
    assert rep["substeps"] == 20 and rep["internal_step_s"] == pytest.approx(0.005)
    assert np.all(np.isfinite(q)) and len(t) == 21
    assert angle_between(q[-1], TorqueFreeBody(I, Q0, W_FAST).attitude(2.0)) < 1e-3 * DEG


@pytest.mark.parametrize("method", ["rk4", "rkmk4", "rk8", "implicit_midpoint"])
def test_constant_torque_spins_up_a_sphere_linearly(method):
    tau = np.array([0.0, 0.0, 1e-3])
    t, q, w = att.propagate([0.1, 0.1, 0.1], Q0, [0.0, 0.0, 0.0], 10.0, 0.01, method,
                            torque=lambda t, q, w: tau)
    np.testing.assert_allclose(w[:, 2], 1e-2 * t, rtol=1e-12, atol=1e-15)
    # Attitude: rotation about z by 0.5 alpha t^2.
    ang = 2 * np.arctan2(q[-1, 3], q[-1, 0])
    assert abs(ang - 0.5 * 1e-2 * 100.0) < (1e-8 if method == "implicit_midpoint" else 1e-12)


@pytest.mark.parametrize("method", METHODS)
def test_runs_are_bit_identical_when_repeated(method):
    kw = {"max_angle_rad": 0.1} if method in ("trapezoid", "implicit_midpoint") else {}
    with pytest.warns(UnstableMethodWarning) if method == "trapezoid" else _nothing():
        a = att.propagate(I, Q0, W_SEP, 20.0, 0.1, method, **kw)
    with pytest.warns(UnstableMethodWarning) if method == "trapezoid" else _nothing():
        b = att.propagate(I, Q0, W_SEP, 20.0, 0.1, method, **kw)
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x, y)


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


@pytest.mark.parametrize(("method", "bound"), [("rk4", 1e-7), ("rkmk4", 1e-7), ("rk8", 1e-9),
                                               ("implicit_midpoint", 1e-5)])
def test_torque_free_conserves_inertial_momentum(method, bound):
    # Second-order implicit midpoint keeps |H| and T exactly but not the direction of H_N.
    t, q, w = att.propagate(I, Q0, W_SEP, 100.0, 0.01, method)
    H_N = np.einsum("nji,nj->ni", dcm(q), w @ np.diag(I))
    assert np.max(np.linalg.norm(H_N - H_N[0], axis=1)) / np.linalg.norm(H_N[0]) < bound


def test_unknown_method_is_named():
    with pytest.raises(ValueError, match="allowed: rk4, rkmk4, dop853"):
        att.propagate(I, Q0, W_SEP, 1.0, 0.1, "euler")


# -- rk8 (Cooper-Verner 8th order, 11 stages) ------------------------------------------------------

def _trees(max_order):
    """Rooted trees up to ``max_order`` nodes as canonical nested tuples of children."""
    def grow(t):
        out = [tuple(sorted(t + ((),)))]
        for k, child in enumerate(t):
            out += [tuple(sorted(t[:k] + (c,) + t[k + 1:])) for c in grow(child)]
        return out
    levels = [{()}]
    for _ in range(max_order - 1):
        levels.append({g for t in levels[-1] for g in grow(t)})
    return [t for level in levels for t in level]


def test_rk8_tableau_satisfies_every_order_condition_up_to_eight():
    A = np.zeros((11, 11))
    for i, row in enumerate(ig.RK8_A):
        A[i, :len(row)] = row
    b, c = np.array(ig.RK8_B), np.array(ig.RK8_C)
    np.testing.assert_allclose(A.sum(axis=1), c, atol=1e-15)

    def stage_weights(t):  # Phi_i(t): product over children of A Phi(child)
        v = np.ones(11)
        for child in t:
            v = v * (A @ stage_weights(child))
        return v

    def size(t):
        return 1 + sum(size(x) for x in t)

    def density(t):
        return size(t) * np.prod([density(x) for x in t])

    trees = _trees(8)
    assert len(trees) == 200  # 1 + 1 + 2 + 4 + 9 + 20 + 48 + 115
    worst = max(abs(b @ stage_weights(t) - 1.0 / density(t)) for t in trees)
    assert worst < 1e-13


def _tableau_step(body, q, w, h, torque, t):
    """A generic Runge-Kutta step driven by RK8_A/B/C (slow reference for the unrolled code)."""
    y = np.array(list(q) + list(w))
    ks = []
    for i in range(11):
        yi = y + h * sum((a * k for a, k in zip(ig.RK8_A[i], ks, strict=False) if a), np.zeros(7))
        qi, wi = tuple(yi[:4]), tuple(yi[4:])
        dq, dw = body.derivatives(qi, wi, torque(t + ig.RK8_C[i] * h, qi, wi))
        ks.append(np.array(dq + dw))
    yn = y + h * sum(bi * k for bi, k in zip(ig.RK8_B, ks, strict=True))
    return yn[:4] / np.linalg.norm(yn[:4]), yn[4:]


@pytest.mark.parametrize("inertia", [I, [[12.0, 1.5, -0.7], [1.5, 20.0, 2.0], [-0.7, 2.0, 29.0]]])
def test_rk8_unrolled_step_equals_the_tableau(inertia):
    # Diagonal inertia takes the principal-axis form, the full matrix the general one; a torque
    # depending on t, q and omega checks the stage times and states passed to it.
    body = att.RigidBody(inertia)

    def torque(t, q, w):
        return (0.3 * np.sin(t) + q[1], 0.2 * w[0] * w[2], -0.1 * t + q[3] * w[1])

    q = tuple(np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2]))
    w = (0.2, -0.4, 0.35)
    for h in (0.05, 0.5):
        qa, wa = ig.stepper(body, "rk8")(q, w, h, torque, 1.7)
        qb, wb = _tableau_step(body, q, w, h, torque, 1.7)
        np.testing.assert_allclose(qa, qb, rtol=0, atol=1e-14)
        np.testing.assert_allclose(wa, wb, rtol=0, atol=1e-14)
        qc, wc = ig.rk8_step(body, q, w, h, torque, 1.7)
        assert qc == qa and wc == wa


def test_rk8_converges_at_order_eight():
    # 60 s keeps round-off (~1e-11 deg) far below the errors (4e-6 and 1.4e-8 deg); over 600 s the
    # near-separatrix error grows faster than linearly and the apparent order is ~8.8.
    e1, e2 = _err_deg("rk8", 0.8, 60.0), _err_deg("rk8", 0.4, 60.0)
    assert 7.3 <= np.log2(e1 / e2) <= 8.7


RK8_REF = Path(__file__).resolve().parents[2] / "fixtures" / "reference" / "rk8" / "torqued_120s.csv"
RK8_REF_INERTIA = {"principal": [10.0, 20.0, 30.0], "general": [[12.0, 1.5, -0.7], [1.5, 20.0, 2.0], [-0.7, 2.0, 29.0]]}


def _rk8_ref_torque(t, q, w):
    """The torque of fixtures/reference/rk8/make_rk8_reference.py (N m, body axes)."""
    return (0.05 * np.sin(0.7 * t) - 0.02 * w[0] + 0.01 * q[1], 0.03 * np.cos(0.4 * t) - 0.02 * w[1] + 0.01 * q[2],
            -0.04 * np.sin(0.25 * t) - 0.02 * w[2] + 0.01 * q[3])


@pytest.mark.parametrize("case", ["principal", "general"])
def test_rk8_matches_the_dop853_reference_under_torque(case):
    """scipy's DOP853 at rtol 1e-13 on a torqued body (fixtures/reference/rk8/README.md, where the bounds come
    from): within 5e-9 deg and 1.5e-11 rad/s at 0.25 s steps, and the error falls as h^8 from 0.5 s."""
    with RK8_REF.open() as fh:
        rows = [r for r in csv.DictReader(line for line in fh if not line.startswith("#")) if r["case"] == case]
    ref = np.array([[float(r[k]) for k in ("t_s", "qw", "qx", "qy", "qz", "w1_rad_s", "w2_rad_s", "w3_rad_s")]
                    for r in rows])
    assert len(ref) == 61 and ref[-1, 0] == 120.0
    q0 = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])
    worst = {}
    for h in (0.5, 0.25):
        t, q, w = att.propagate(RK8_REF_INERTIA[case], q0, [0.2, -0.4, 0.35], 120.0, h, "rk8", torque=_rk8_ref_torque)
        idx = np.searchsorted(t, ref[:, 0] - 1e-9)
        np.testing.assert_allclose(t[idx], ref[:, 0], rtol=0, atol=1e-9)
        worst[h] = (float(np.max(angle_between(q[idx], ref[:, 1:5]))) / DEG, float(np.max(np.abs(w[idx] - ref[:, 5:]))))
    assert worst[0.25][0] <= 5e-9 and worst[0.25][1] <= 1.5e-11, worst
    assert 7.5 <= np.log2(worst[0.5][0] / worst[0.25][0]) <= 9.5, worst


def test_rk8_near_separatrix_agrees_with_the_closed_form():
    # Measured 2.6e-6 deg at 0.5 s; the 0.25 s error must follow h^8 from it (within 2x), above the
    # ~2e-9 deg floor where round-off and the closed form's own error (5e-10 deg) take over.
    e_half = _err_deg("rk8", 0.5, 600.0)
    e_quarter = _err_deg("rk8", 0.25, 600.0)
    assert e_half <= 5e-6
    assert e_quarter <= 2.0 * e_half / 2 ** 8 + 2e-9
    assert e_quarter <= 1.6e-8  # the RKF78 anchor of `stand bench accuracy` (README)


def test_rk8_step_guard_refuses_more_than_half_a_radian_per_step():
    assert ig.max_angle_rad("rk8") == 0.5
    # |omega| = 0.5002 rad/s and a nutation bound of the same size: the limit is 0.9996 s.
    with pytest.raises(ValueError, match=r"method 'rk8' .* at most 0.5 rad, i.e. step_s <= 1 s here"):
        att.propagate(I, Q0, W_SEP, 600.0, 1.2, "rk8")
    rep = {}
    t, q, w = att.propagate(I, Q0, W_SEP, 12.0, 1.2, "rk8", subdivide=True, report=rep)
    assert rep["substeps"] == 2 and rep["rhs_evals"] == 11 * 2 * 10
    t, q, w = att.propagate(I, Q0, W_SEP, 10.0, 0.99, "rk8")  # just inside the limit
    assert np.all(np.isfinite(q))


def test_rk8_non_finite_torque_is_reported():
    with pytest.raises(FloatingPointError, match="non-finite state"):
        att.propagate(I, Q0, W_SEP, 1.0, 0.5, "rk8", torque=lambda t, q, w: (np.nan, 0.0, 0.0))


# A quaternion typed to 8 digits, as scenarios give it (fixtures/scenarios/pointing_star_tracker.toml): its norm is
# 1 + 4.2e-8, inside the unit check's tolerance.
Q_8_DIGITS = (0.99965732, 0.01745241, -0.01745241, 0.00872654)


# Steps inside each method's guard; bounds about 2x the errors measured from the normalised start (9.7e-6 and
# 1.5e-3 deg). The implicit midpoint rule's Cayley update drifts 2.7e-14 in |q| over its 6000 steps.
@pytest.mark.parametrize(("method", "step_s", "bound_deg", "norm_drift"),
                         [("rkmk4", 0.1, 2e-5, 1e-14), ("implicit_midpoint", 0.01, 3e-3, 1e-13)])
def test_a_norm_preserving_method_starts_from_the_unit_quaternion(method, step_s, bound_deg, norm_drift):
    assert method in ig.NORM_PRESERVING
    assert abs(float(np.linalg.norm(Q_8_DIGITS)) - 1.0) > 4e-8
    _, q, _ = att.propagate(I, Q_8_DIGITS, W_SEP, 60.0, step_s, method)
    assert np.max(np.abs(np.linalg.norm(q, axis=1) - 1.0)) < norm_drift
    # Its attitude is that of the normalised quaternion: the closed form from there, to the method's accuracy.
    q0 = np.asarray(Q_8_DIGITS) / np.linalg.norm(Q_8_DIGITS)
    assert float(angle_between(q[-1], TorqueFreeBody(I, q0, W_SEP).attitude(60.0))) / DEG < bound_deg


@pytest.mark.parametrize("method", ["rkmk4", "implicit_midpoint", "rk4"])
def test_the_truth_model_keeps_a_unit_quaternion_whatever_its_integrator(method):
    from sim.truth import TruthModel

    truth = TruthModel(inertia=I, q_BN=Q_8_DIGITS, omega_BN_B=[0.01, 0.02, 0.03], r_N=(7.0e6, 0.0, 0.0),
                       v_N=(0.0, 7546.0, 0.0), step_ns=100_000_000, integrator=method, torques=())
    for _ in range(100):
        truth.step()
    assert abs(math.sqrt(sum(x * x for x in truth.q)) - 1.0) < 1e-14
