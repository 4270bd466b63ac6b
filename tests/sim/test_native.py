"""sim._native.rk4_magnetic_gg (sim/_native.c) against its Python original, sim.truth.rk4_magnetic_gg: the same
state to the bit on random and extreme inputs, the same refusal of a non-finite state."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim import truth
from sim.constants import MU_EARTH
from tests.oracles import require_compiled


@pytest.fixture(scope="module", autouse=True)
def _compiled() -> None:
    require_compiled(truth.NATIVE, "sim._native")


def _args(rng: np.random.Generator, scale_w: float, scale_m: float):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    A = rng.normal(size=(3, 3))
    inertia = A @ A.T + np.eye(3) * rng.uniform(1e-4, 10.0)
    r = rng.normal(size=9) * 7e6
    return (tuple(q.tolist()), tuple((rng.normal(size=3) * scale_w).tolist()), float(rng.uniform(1e-4, 2.0)),
            tuple(inertia.ravel().tolist()), tuple(np.linalg.inv(inertia).ravel().tolist()),
            tuple((rng.normal(size=3) * scale_m).tolist()), (rng.normal(size=9) * 5e-5).tolist(), r.tolist())


def test_the_compiled_step_is_the_python_step_to_the_bit() -> None:
    from sim._native import rk4_magnetic_gg as native

    rng = np.random.default_rng(11)
    checked = 0
    for k in range(3000):
        # from a slow, lightly actuated body to a fast tumble with a large dipole (stiff for the step)
        args = _args(rng, scale_w=10.0 ** rng.uniform(-6, 1), scale_m=10.0 ** rng.uniform(-6, 2))
        expected = truth.rk4_magnetic_gg(*args, MU_EARTH)
        got = native(*args, MU_EARTH)
        assert got == expected, k
        checked += expected is not None
    assert checked > 2900


def test_both_refuse_a_state_that_is_not_finite() -> None:
    from sim._native import rk4_magnetic_gg as native

    args = list(_args(np.random.default_rng(2), 1.0, 1.0))
    for bad in ((math.inf, 0.0, 0.0), (math.nan, 0.0, 0.0), (1e200, -1e200, 1e200)):
        args[5] = bad  # a dipole that blows the rates up
        assert truth.rk4_magnetic_gg(*args) is None
        assert native(*args, MU_EARTH) is None


def test_the_compiled_step_checks_its_arguments() -> None:
    from sim._native import rk4_magnetic_gg as native

    args = list(_args(np.random.default_rng(3), 1.0, 1.0))
    with pytest.raises(TypeError, match="9 arguments"):
        native(*args)
    args[6] = args[6][:6]
    with pytest.raises(TypeError, match="fields_N must be a tuple or list of 9 floats"):
        native(*args, MU_EARTH)
    args = list(_args(np.random.default_rng(3), 1.0, 1.0))
    args[0] = ("a", 0.0, 0.0, 0.0)
    with pytest.raises(TypeError):
        native(*args, MU_EARTH)


def test_the_truth_model_runs_the_compiled_step() -> None:
    """What `stand bench loop` reports: the default scenario's step is the compiled one in this install."""
    assert truth._rk4_magnetic_gg is not truth.rk4_magnetic_gg
