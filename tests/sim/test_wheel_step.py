"""sim.wheel_step, a reaction wheel's motor and rotor step on floats: its compiled twin (Cython, compiled_paths) and the
plain module give the same results to the bit, on random states and on the edges where C and Python could part
(ties at the torque limit and the speed cap, signed zeros, the stick test, zero crossings inside the step)."""

from __future__ import annotations

import math
import random
import struct

import pytest

import sim.wheel_step as plain
from tests.oracles import build_fixtures

compiled, build = build_fixtures("sim.wheel_step")


def _bits(values) -> tuple:
    return tuple(struct.pack("<d", v) for v in values)


def _rotors(rng: random.Random):
    """(inertia, coulomb, viscous, static): frictionless, Coulomb only, viscous only (tiny to large), stiction."""
    yield 0.0796, 0.0, 0.0, 0.0
    yield 2e-3, 1e-4, 0.0, 1e-4
    yield 2e-3, 0.0, 1e-12, 0.0
    yield 2e-3, 5e-5, 1e-6, 2e-4
    yield 2e-3, 5e-5, 0.05, 1e-4  # k t well above the series' threshold
    for _ in range(40):
        coulomb = rng.choice((0.0, rng.uniform(0, 1e-3)))
        yield (rng.uniform(1e-4, 1.0), coulomb, rng.choice((0.0, rng.uniform(0, 1e-2), 10 ** rng.uniform(-14, 0))),
               coulomb + rng.choice((0.0, rng.uniform(0, 1e-3))))


def _motor_cases(seed: int):
    rng = random.Random(seed)
    for inertia, coulomb, viscous, static in _rotors(rng):
        max_torque, max_speed = rng.choice(((0.2, 628.0), (4e-3, 6000.0 * math.pi / 30.0)))
        rolloff = 0.1 * max_speed
        for decay, mean in ((0.0, 0.0), (math.exp(-2.0), -math.expm1(-2.0) / 2.0)):
            edges_w = (0.0, -0.0, max_speed, -max_speed, 0.95 * max_speed, 1e-300, -1e-300, 1.2 * max_speed)
            edges_u = (0.0, -0.0, max_torque, -max_torque, 2 * max_torque, -2 * max_torque, static, -static,
                       coulomb, 1e-300)
            for w0 in (*edges_w, *(rng.uniform(-1.1, 1.1) * max_speed for _ in range(6))):
                for u in (*edges_u, *(rng.uniform(-1.5, 1.5) * max_torque for _ in range(4))):
                    tau0 = rng.choice((0.0, -0.0, u, rng.uniform(-1, 1) * max_torque))
                    h = rng.choice((0.1, 0.01, 1.0, 10.0))
                    yield (inertia, coulomb, viscous, static, max_torque, max_speed, rolloff, decay, mean, w0, tau0, u,
                           h)


def test_compiled_and_plain_motor_steps_agree_to_the_bit(compiled) -> None:
    n = 0
    for args in _motor_cases(41):
        a, b = compiled.motor_step(*args), plain.motor_step(*args)
        assert _bits(a) == _bits(b), args
        rotor = args[:4] + (args[9], args[11], args[12])
        assert _bits(compiled.rotor_advance(*rotor)) == _bits(plain.rotor_advance(*rotor)), rotor
        torque = (args[11], args[9], args[4], args[5], args[6])
        assert _bits((compiled.available_torque(*torque),)) == _bits((plain.available_torque(*torque),)), torque
        n += 1
    assert n > 10_000


def test_the_rotor_sticks_crosses_zero_once_and_never_gains_energy_from_friction(build) -> None:
    # Coulomb 1e-4 N m, breakaway 2e-4 N m on J = 2e-3 kg m^2: 0.5 rad/s decays to 0 in 10 s without a motor.
    w, body, friction = build.rotor_advance(2e-3, 1e-4, 0.0, 2e-4, 0.5, 0.0, 20.0)
    assert w == 0.0 and math.copysign(1.0, w) == 1.0  # lands exactly on +0 and sticks there
    assert friction == pytest.approx(0.5 * 2e-3 * 0.5 ** 2, rel=1e-12) and body == pytest.approx(-2e-3 * -0.5 / 20.0)
    # A motor torque below breakaway keeps it stuck; above it, the wheel slips the motor's way.
    assert build.rotor_advance(2e-3, 1e-4, 0.0, 2e-4, 0.0, 1.5e-4, 1.0)[0] == 0.0
    assert build.rotor_advance(2e-3, 1e-4, 0.0, 2e-4, 0.0, -3e-4, 1.0)[0] < 0.0
    # Braking through zero: it stops at zero within the step and slips the other way for the rest (Coulomb only:
    # -0.1 rad/s under +3e-4 N m, friction helping, loses (3e-4 + 1e-4) / 2e-3 = 0.2 rad/s^2 and stops after 0.5 s,
    # then gains (3e-4 - 1e-4) / 2e-3 = 0.1 rad/s^2 for the last 1.5 s).
    w, _, friction = build.rotor_advance(2e-3, 1e-4, 0.0, 1e-4, -0.1, 3e-4, 2.0)
    assert w == pytest.approx(0.15, rel=1e-12) and friction > 0.0


def test_the_motor_clips_rolls_off_and_caps_the_speed(build) -> None:
    # frictionless rotor J = 0.1, limit 0.2 N m, rated 100 rad/s with a 10 rad/s roll-off band, no lag
    args = (0.1, 0.0, 0.0, 0.0, 0.2, 100.0, 10.0, 0.0, 0.0)
    assert build.available_torque(0.5, 0.0, 0.2, 100.0, 10.0) == 0.2  # clipped, keeping the sign
    assert build.available_torque(-0.5, 0.0, 0.2, 100.0, 10.0) == -0.2
    assert build.available_torque(0.2, 95.0, 0.2, 100.0, 10.0) == pytest.approx(0.1)  # half-way through the band
    assert build.available_torque(-0.2, 95.0, 0.2, 100.0, 10.0) == -0.2  # braking keeps the full torque
    # at 99.99 rad/s the band leaves 0.1 % of the torque: 2e-4 N m for 1 s on J = 0.1 adds 2e-3 rad/s
    w1, tau, body, _ = build.motor_step(*args, 99.99, 0.0, 0.2, 1.0)
    assert w1 == pytest.approx(99.992, rel=1e-12) and tau == pytest.approx(2e-4, rel=1e-9)
    assert body == -0.1 * (w1 - 99.99) / 1.0
    # started beyond the rated speed (a spin-up by the body), driving further gets no torque: the speed stays
    w1, _, _, _ = build.motor_step(0.1, 0.0, 0.0, 0.0, 0.2, 100.0, 200.0, 0.0, 0.0, 120.0, 0.0, 0.2, 1.0)
    assert w1 == 120.0
