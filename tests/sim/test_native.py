"""sim.body_step, the one source of the attitude step: its compiled twin (Cython, compiled_paths) and the plain module
give the same states to the bit, refuse the same inputs, and the truth model runs the build compiled_paths chose.

This file and tests/drivers/test_dbc_packer.py are the bit-equality tests `.ci/run` runs a second time with
``STAND_NATIVE=0``: the comparisons import both builds directly, and the truth model then runs the plain one."""

from __future__ import annotations

import math
import random
import struct

import numpy as np
import pytest

import compiled_paths
import sim.body_step as plain
from sim import rigid_body
from sim import truth as truth_mod
from sim.constants import MU_EARTH
from tests.oracles import build_fixtures, require_compiled

compiled, build = build_fixtures("sim.body_step")


def _state(rng: np.random.Generator, scale_w: float, scale_m: float):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    A = rng.normal(size=(3, 3))
    inertia = A @ A.T + np.eye(3) * rng.uniform(1e-4, 10.0)
    return (tuple(q.tolist()), tuple((rng.normal(size=3) * scale_w).tolist()), float(rng.uniform(1e-4, 2.0)),
            tuple(inertia.ravel().tolist()), tuple(np.linalg.inv(inertia).ravel().tolist()),
            tuple((rng.normal(size=3) * scale_m).tolist()), tuple((rng.normal(size=9) * 5e-5).tolist()),
            tuple((rng.normal(size=9) * 7e6).tolist()))


def _step(module, q, w, h, I, Ii, dipole, fields, positions, magnetic=True, gravity_gradient=True, callback=False,
          wheels=None, inner="environment"):
    """One RK4 step under the environment's torque; with ``wheels`` (the six sums ``A h`` and ``A tau``), a spacecraft
    with wheels: a Gyrostat around the environment's torque as ``inner`` says (``"none"``, ``"environment"``: the
    EnvironmentTorque itself, ``"callable"``: a Python callable around it). ``callback``: the stage torque handed to
    the step wrapped in a Python callable (the general path every other stepper takes), not as itself."""
    body = module.BodyDynamics(I, Ii)
    environment = module.EnvironmentTorque(body, h, MU_EARTH, magnetic, gravity_gradient)
    environment.set_step(dipole, fields, positions)
    stage = environment
    if wheels is not None:
        around = {"none": None, "environment": environment,
                  "callable": lambda t, qq, ww: environment(t, qq, ww)}[inner]
        stage = module.Gyrostat(*wheels, around, 0.0)
    torque = (lambda t, qq, ww: stage(t, qq, ww)) if callback else stage
    try:
        return body.rk4(q, w, h, torque, 0.0)
    except FloatingPointError as exc:
        return str(exc)


def test_the_compiled_step_is_the_python_step_to_the_bit(compiled) -> None:
    rng = np.random.default_rng(11)
    finite = 0
    for k in range(3000):
        # from a slow, lightly actuated body to a fast tumble with a large dipole (stiff for the step)
        args = _state(rng, scale_w=10.0 ** rng.uniform(-6, 1), scale_m=10.0 ** rng.uniform(-6, 2))
        torques = [(True, True), (True, False), (False, True)][k % 3]
        expected = _step(plain, *args, *torques)
        assert _step(compiled, *args, *torques) == expected, k
        # a torque given as a Python callable (the general path: other integrators, wheels, body torques)
        assert _step(compiled, *args, *torques, callback=True) == expected, k
        finite += not isinstance(expected, str)
    assert finite > 2900


def test_both_refuse_a_state_that_is_not_finite(build) -> None:
    args = list(_state(np.random.default_rng(2), 1.0, 1.0))
    for bad in ((math.inf, 0.0, 0.0), (math.nan, 0.0, 0.0), (1e200, -1e200, 1e200)):
        args[5] = bad  # a dipole that blows the rates up
        assert "non-finite state" in _step(build, *args)


class _ClearsOnFloat(float):
    """A number whose conversion empties the list it sits in (the old C read the list's items after that)."""

    def __new__(cls, value, victim):
        self = super().__new__(cls, value)
        self.victim = victim
        return self

    def __float__(self):
        self.victim.clear()
        return float(self)


def test_a_list_in_place_of_a_tuple_raises_type_error(build) -> None:
    """The old C read a list's items while converting them: an item whose __float__ cleared the list was read after
    it was freed. Every sequence the step reads is a tuple now (immutable); a list is refused before any item is
    read, in both builds."""
    q, w, h, I, Ii, dipole, fields, positions = _state(np.random.default_rng(3), 1.0, 1.0)
    body = build.BodyDynamics(I, Ii)
    environment = build.EnvironmentTorque(body, h, MU_EARTH, True, True)
    victim: list = []
    victim.extend([_ClearsOnFloat(x, victim) for x in fields])
    with pytest.raises(TypeError, match="fields_N must be a tuple of 9 floats"):
        environment.set_step(dipole, victim, positions)
    with pytest.raises(TypeError, match="positions_N must be a tuple of 9 floats"):
        environment.set_step(dipole, fields, list(positions))
    with pytest.raises(TypeError, match="dipole_B must be a tuple of 3 floats"):
        environment.set_step(list(dipole), fields, positions)
    with pytest.raises(TypeError, match="fields_N must be a tuple of 9 floats"):
        environment.set_step(dipole, fields[:6], positions)
    environment.set_step(dipole, fields, positions)
    victim = []
    victim.extend([_ClearsOnFloat(x, victim) for x in q])
    with pytest.raises(TypeError, match="q must be a tuple of 4 floats"):
        body.rk4(victim, w, h, environment)
    with pytest.raises(TypeError, match="w must be a tuple of 3 floats"):
        body.rk4(q, list(w), h, environment)
    with pytest.raises(TypeError, match="I must be a tuple of 9 floats"):
        build.BodyDynamics(list(I), Ii)
    assert len(victim) == 4  # nothing read it


def _truth():
    from sim import environment as env
    from sim import frames
    from sim.attitude import check_inertia
    from sim.time import Epoch

    inertia = check_inertia([[0.02, 0.001, -0.0005], [0.001, 0.025, 0.0002], [-0.0005, 0.0002, 0.015]])
    rot = frames.EarthRotation(Epoch.from_iso("2026-03-20T12:00:00Z"), "uniform")
    return truth_mod.TruthModel(inertia=inertia, q_BN=[0.8, 0.2, -0.4, 0.4], omega_BN_B=[0.1, -0.2, 0.15],
                                r_N=[7e6, 1e5, -2e5], v_N=[0.0, 7.5e3, 1.0e3], step_ns=100_000_000,
                                field_itrs=lambda t, r: env.dipole_field_itrs(r), earth_rotation=rot)


def test_the_truth_model_gives_the_same_states_on_either_build(compiled, monkeypatch) -> None:
    """2500 steps of a tumbling body with a changing dipole, across an orbit-chunk boundary (2000 steps at 0.1 s):
    every state bit for bit the same whichever build the truth model runs."""
    runs = []
    for module in (plain, compiled):
        monkeypatch.setattr(rigid_body, "_step", module)
        monkeypatch.setattr(truth_mod, "_step", module)
        model, rng, states = _truth(), np.random.default_rng(3), []
        assert type(model._environment) is module.EnvironmentTorque
        for k in range(2500):
            model.step(tuple(rng.uniform(-0.2, 0.2, 3).tolist()) if k % 7 else (0.0, 0.0, 0.0))
            states.append((model.q, model.w))
        runs.append(states)
    assert runs[0] == runs[1]


def test_the_stand_runs_the_build_compiled_paths_chose() -> None:
    """What summary.json and `stand bench loop` report: the compiled twin unless STAND_NATIVE=0 (or no build)."""
    chosen = compiled_paths.load("sim.body_step")
    assert rigid_body._step is chosen and truth_mod._step is chosen
    assert type(_truth()._environment) is chosen.EnvironmentTorque
    expected = "compiled" if compiled_paths.native_allowed() else "python"
    if expected == "compiled":
        require_compiled("sim.body_step")
    assert compiled_paths.active()["sim.body_step"] == expected


def _bits(values) -> tuple:
    return tuple(struct.pack("<d", v) for v in values)


def test_compiled_and_plain_gyrostat_stage_torques_agree_to_the_bit(compiled) -> None:
    rng = random.Random(43)

    def environment(ts, qs, ws):  # any torque callable, as sim.truth passes one
        return (1e-6 * ts + qs[0] * 1e-7, -2e-6 * ws[1], 3e-7 * qs[3] - ws[2] * 1e-9)

    for _ in range(2000):
        h = [rng.uniform(-50, 50) for _ in range(3)]
        u = [rng.choice((0.0, -0.0, rng.uniform(-0.2, 0.2))) for _ in range(3)]
        t = rng.choice((0.0, rng.uniform(0, 1e4)))
        ts = t + rng.choice((0.0, 0.05, 0.1))
        qs = tuple(rng.uniform(-1, 1) for _ in range(4))
        ws = tuple(rng.choice((0.0, -0.0, rng.uniform(-0.1, 0.1))) for _ in range(3))
        for torque in (None, environment):
            a = compiled.Gyrostat(*h, *u, torque, t)(ts, qs, ws)
            b = plain.Gyrostat(*h, *u, torque, t)(ts, qs, ws)
            assert _bits(a) == _bits(b), (h, u, t, ts, qs, ws, torque)


def test_the_gyrostat_stage_torque_is_the_environments_minus_the_wheels(build) -> None:
    # h = (0, 0, 2) N m s on the body z axis, spinning about x at 0.1 rad/s: w x h = (0, -0.2, 0); tau = (0, 0, 0.1)
    # held 0.5 s into the step adds 0.05 N m s to h and takes its reaction -0.1 N m off z.
    g = build.Gyrostat(0.0, 0.0, 2.0, 0.0, 0.0, 0.1, lambda ts, q, w: (1.0, 2.0, 3.0), 10.0)
    assert g(10.5, (1.0, 0.0, 0.0, 0.0), (0.1, 0.0, 0.0)) == pytest.approx((1.0, 2.0 + 0.1 * 2.05, 3.0 - 0.1))


def test_the_wheeled_step_is_the_same_through_the_stage_call_and_a_callable_on_either_build(compiled) -> None:
    """The RK4 step calls a Gyrostat (and the EnvironmentTorque inside it) without a Python call at each stage: the
    states are bit for bit those of the general path, on both builds."""
    rng = np.random.default_rng(12)
    for k in range(1500):
        args = _state(rng, scale_w=10.0 ** rng.uniform(-6, 0), scale_m=10.0 ** rng.uniform(-6, 2))
        wheels = tuple((rng.normal(size=6) * 10.0 ** rng.uniform(-3, 2)).tolist())
        inner = ("none", "environment", "callable")[k % 3]
        expected = _step(plain, *args, callback=True, wheels=wheels, inner=inner)
        for module in (plain, compiled):
            assert _step(module, *args, wheels=wheels, inner=inner) == expected, (k, module)
        assert _step(compiled, *args, callback=True, wheels=wheels, inner=inner) == expected, k


def test_compiled_and_plain_axes_sums_agree_to_the_bit(compiled) -> None:
    rng = random.Random(44)
    for n in (1, 3, 4, 6):
        for _ in range(300):
            axes = tuple(tuple(rng.choice((0.0, -0.0, 1.0, rng.uniform(-1, 1))) for _ in range(3)) for _ in range(n))
            values = tuple(rng.choice((0.0, -0.0, rng.uniform(-100, 100), 1e-300)) for _ in range(n))
            assert _bits(compiled.axes_sum(axes, values)) == _bits(plain.axes_sum(axes, values)), (axes, values)
            assert _bits(compiled.axes_sum(axes, list(values))) == _bits(plain.axes_sum(axes, values))


def test_axes_sum_is_a_times_values_and_wants_one_value_per_wheel(build) -> None:
    axes = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.6, 0.8))
    assert build.axes_sum(axes, (2.0, 3.0, 5.0)) == (2.0, 6.0, 4.0)
    # every component starts from +0.0, as Python's sum does: a lone -0.0 product gives +0.0
    assert [math.copysign(1.0, c) for c in build.axes_sum(((-1.0, -1.0, -1.0),), (0.0,))] == [1.0, 1.0, 1.0]
    with pytest.raises(ValueError, match="2 values for 3 wheels"):
        build.axes_sum(axes, (1.0, 2.0))


def _wheel_terms(rng: random.Random, n: int):
    def value(scale):
        return rng.choice((0.0, -0.0, rng.uniform(-scale, scale), 1e-300, -1e-300))

    axes = tuple(tuple(rng.choice((0.0, -0.0, 1.0, rng.uniform(-1, 1))) for _ in range(3)) for _ in range(n))
    inertias = tuple(rng.uniform(1e-3, 0.2) for _ in range(n))
    return (axes, inertias, tuple(value(60.0) for _ in range(n)), tuple(value(0.3) for _ in range(n)),
            tuple(value(0.5) for _ in range(3)))


def test_the_wheels_terms_are_the_python_expressions_they_replace_to_the_bit(build) -> None:
    """momentum_after, fastest_rate and relative_speeds give, on both builds, the bits of the expressions
    sim.wheels and sim.truth computed them with before they were compiled (kept here as the reference)."""
    rng = random.Random(45)
    for n in (1, 3, 4):
        for _ in range(1000):
            axes, inertias, h, tau, w = _wheel_terms(rng, n)
            dt = rng.choice((0.1, 0.01, rng.uniform(1e-4, 1.0)))
            assert _bits(build.momentum_after(h, tau, dt)) == _bits(
                tuple([a + u * dt for a, u in zip(h, tau, strict=True)]))
            inv_imin, per_rate = rng.uniform(1e-3, 10.0), rng.choice((0.0, rng.uniform(0.0, 2.0)))
            wn = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
            hx, hy, hz = build.axes_sum(axes, h)
            expected = max(wn, wn * per_rate + math.sqrt(hx * hx + hy * hy + hz * hz) * inv_imin)
            assert _bits((build.fastest_rate(axes, w, h, inv_imin, per_rate),)) == _bits((expected,))
            w0, w1, w2 = w
            expected = tuple(a / j - (ax * w0 + ay * w1 + az * w2)
                             for a, j, (ax, ay, az) in zip(h, inertias, axes, strict=True))
            assert _bits(build.relative_speeds(axes, inertias, h, w)) == _bits(expected)


def test_the_wheels_terms_refuse_what_they_refused(build) -> None:
    axes = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match=r"^zip\(\) argument 2 is shorter than argument 1$"):
        build.momentum_after((1.0, 2.0, 3.0), (0.1, 0.2), 0.1)
    with pytest.raises(ValueError, match=r"^zip\(\) argument 2 is longer than argument 1$"):
        build.momentum_after((1.0, 2.0), (0.1, 0.2, 0.3), 0.1)
    assert build.momentum_after([1.0, 2.0], np.array([0.5, -0.5]), 0.5) == (1.25, 1.75)  # any sequence, as zip took
    with pytest.raises(ValueError, match="2 values for 3 wheels"):
        build.fastest_rate(axes, (0.0, 0.0, 0.0), (1.0, 2.0), 1.0, 1.0)
    with pytest.raises(ValueError, match="2 values for 3 wheels"):
        build.gyrostat(axes, (1.0, 2.0, 3.0), (1.0, 2.0), None, 0.0)
    with pytest.raises(ValueError, match="2 momenta and 3 inertias for 3 wheels"):
        build.relative_speeds(axes, (1.0, 1.0, 1.0), (1.0, 2.0), (0.0, 0.0, 0.0))


def test_finite_floats_says_yes_only_to_a_tuple_of_finite_floats(build) -> None:
    good = (1.0, -0.0, 1e-300)
    assert build.finite_floats(good, 3) is good
    for bad in ((1.0, 2.0), [1.0, 2.0, 3.0], (1.0, 2.0, math.nan), (1.0, math.inf, 0.0), (1.0, 2, 3.0),
                (1.0, np.float64(2.0), 3.0), (1.0, "2.0", 3.0), (True, 0.0, 0.0)):
        assert build.finite_floats(bad, 3) is None, bad


def test_the_gyrostat_of_a_step_sums_the_wheels_on_the_body_axes(build) -> None:
    axes = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.6, 0.8))

    def torque(ts, q, w):
        return (1.0, 2.0, 3.0)

    a = build.gyrostat(axes, [2.0, 3.0, 5.0], (0.1, 0.2, 0.3), torque, 10.0)
    b = build.Gyrostat(2.0, 6.0, 4.0, 0.1, 0.2 + 0.6 * 0.3, 0.8 * 0.3, torque, 10.0)
    for ts in (10.0, 10.05, 10.1):
        assert _bits(a(ts, (0.9, 0.1, -0.3, 0.3), (0.01, -0.02, 0.03))) == _bits(
            b(ts, (0.9, 0.1, -0.3, 0.3), (0.01, -0.02, 0.03)))


def test_the_truth_model_with_wheels_gives_the_same_states_on_either_build(compiled, monkeypatch) -> None:
    """2500 steps of a tumbling body with four pyramid wheels under changing rotor torques and a dipole, across an
    orbit-chunk boundary: every state and every wheel speed bit for bit the same whichever build runs."""
    from sim import wheels as wheels_mod
    from sim.actuators import wheel_spin_axes_B

    runs = []
    for module in (plain, compiled):
        monkeypatch.setattr(rigid_body, "_step", module)
        monkeypatch.setattr(truth_mod, "_step", module)
        monkeypatch.setattr(wheels_mod, "_body_step", module)
        model = truth_mod.TruthModel(
            inertia=[[0.02, 0.001, -0.0005], [0.001, 0.025, 0.0002], [-0.0005, 0.0002, 0.015]],
            q_BN=[0.8, 0.2, -0.4, 0.4], omega_BN_B=[0.1, -0.2, 0.15], r_N=[7e6, 1e5, -2e5], v_N=[0.0, 7.5e3, 1.0e3],
            step_ns=100_000_000,
            torques=("gravity_gradient",), wheels=wheels_mod.WheelCluster(wheel_spin_axes_B("pyramid").T, [1e-4] * 4),
            wheel_speeds_rad_s=[100.0, -50.0, 20.0, 0.0])
        rng, states = np.random.default_rng(4), []
        for k in range(2500):
            tau = tuple(rng.uniform(-1e-4, 1e-4, 4).tolist())
            model.step((0.0, 0.0, 0.0), tau if k % 5 else list(tau))  # a list takes the full check and conversion
            states.append((model.q, model.w, model.h_wheels, model.wheel_speeds_rad_s))
        runs.append(states)
    assert runs[0] == runs[1]
