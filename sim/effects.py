"""The effector interface: what an actuator does to the truth model, in one vocabulary.

An actuator (a magnetorquer, a reaction wheel, a thruster, a test rig's torque motor) gives the truth a list of
:class:`Effect`; the truth (:meth:`sim.truth.TruthModel.effector`) builds its step from them once, then reads each
effect once per dynamics step and holds what it read over the step. Whoever runs the truth never names an effect.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

#: The effector interface's vocabulary: what an actuator does to the truth, held over one dynamics step.
#:
#: * ``"dipole"``: a magnetic dipole, ``read() -> (mx, my, mz)`` in A m^2, body axes; the truth turns the sum of
#:   all dipoles into the torque m x B inside every integrator stage (the field at that stage's attitude);
#: * ``"torque"``: a torque on the body, ``read() -> (tx, ty, tz)`` in N m, body axes (a thruster pair, a test
#:   rig's torque motor), added to the environment's torques;
#: * ``"momentum_exchange"``: the net torque on one rotor of the truth's wheel cluster, ``read() -> float`` in N m
#:   about its spin axis (motor minus friction), ``target`` the rotor's column; the body takes the reaction.
EFFECT_TYPES = ("dipole", "torque", "momentum_exchange")


@dataclass(frozen=True)
class Effect:
    """One thing an actuator does to the truth: ``type`` (one of :data:`EFFECT_TYPES`), ``read`` (called once per
    dynamics step, after the actuator took in its commands; what it returns is held over the step) and ``target``
    (``"momentum_exchange"``: the rotor's column in the wheel cluster; None otherwise: the body)."""

    type: str
    read: Callable[[], Any]
    target: int | None = None
