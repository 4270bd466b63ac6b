"""sim.body_step, the one source of the attitude step: its compiled twin (Cython, compiled_paths) and the plain module
give the same states to the bit, refuse the same inputs, and the truth model runs the build compiled_paths chose.

This file and tests/drivers/test_dbc_packer.py are the bit-equality tests `.ci/run` runs a second time with
``STAND_NATIVE=0``: the comparisons import both builds directly, and the truth model then runs the plain one."""

from __future__ import annotations

import math

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


def _step(module, q, w, h, I, Ii, dipole, fields, positions, magnetic=True, gravity_gradient=True, callback=False):
    body = module.BodyDynamics(I, Ii)
    environment = module.EnvironmentTorque(body, h, MU_EARTH, magnetic, gravity_gradient)
    environment.set_step(dipole, fields, positions)
    torque = (lambda t, qq, ww: environment(t, qq, ww)) if callback else environment
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
