"""drivers.star_tracker.exposure_math, the emulated tracker's exposure math: its compiled twin (Cython,
compiled_paths) and the plain module give the same floats to the bit, the same answers at the edges (NaN, infinity,
zero, numbers that are not floats) and the same errors; and both agree with a direct computation of what each
function means (an angle from the boresight, a rotation of a vector)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import drivers.star_tracker.exposure_math as plain
from drivers.star_tracker.measurement import TrackerTruth
from tests.oracles import build_fixtures

compiled, build = build_fixtures("drivers.star_tracker.exposure_math")

EDGES = (0.0, -0.0, 1.0, -1.0, 0.5, -2.0, 1e-300, 1e-160, 1e300, math.inf, -math.inf, math.nan)


def _bits(x):
    """What must be equal between the builds: each float's exact bits (its hex), and the container and types."""
    if isinstance(x, tuple):
        return tuple(_bits(v) for v in x)
    if isinstance(x, float):
        return ("float", x.hex())
    return (type(x).__name__, x)


def _outcome(fn, *args):
    try:
        return "ok", _bits(fn(*args))
    except Exception as exc:  # noqa: BLE001 - the error's type and message are what is compared
        if "unpack" in str(exc):  # a sequence of the wrong length: Cython words the same ValueError its own way
            return type(exc).__name__, "unpack"
        return type(exc).__name__, str(exc)


def _random_cases(n: int) -> list[tuple]:
    rng = np.random.default_rng(26)
    return [tuple(float(x) for x in row) for row in rng.standard_normal((n, 4)) * rng.choice([1e-7, 1.0, 1e3], (n, 1))]


def test_small_rotation_is_the_same_to_the_bit(compiled) -> None:
    for a in _random_cases(2000):
        assert _outcome(plain.small_rotation, a[:3]) == _outcome(compiled.small_rotation, a[:3])
    for x in EDGES:
        for v in ((x, 0.0, 0.0), (0.0, x, 1e-3), (x, x, x)):
            assert _outcome(plain.small_rotation, v) == _outcome(compiled.small_rotation, v), v


def test_in_field_is_the_same_to_the_bit_and_at_every_edge(compiled) -> None:
    cases = _random_cases(3000)
    for a in cases:
        for radius, exclusion in ((0.0, 0.0), (4.65e-3, 0.7), (1.15, 0.5), (math.nan, 0.5)):
            assert plain.in_field(a[:3], radius, exclusion) is compiled.in_field(a[:3], radius, exclusion)
    odd = (None, (1, 2, 3), ("0", "0", "1"), (np.float64(0.1), np.float32(0.2), np.int64(1)), (1.0, 2.0), ("x", 0, 1))
    for direction in odd + tuple((x, y, z) for x in EDGES for y in (0.0, math.nan) for z in EDGES):
        for radius, exclusion in ((0.0, 0.0), (0.1, 0.5), (np.float64(0.1), 0.5), (0.0, math.pi)):
            assert _outcome(plain.in_field, direction, radius, exclusion) == \
                _outcome(compiled.in_field, direction, radius, exclusion), (direction, radius, exclusion)


def test_in_field_is_the_angle_from_the_boresight_minus_the_radius(build) -> None:
    rng = np.random.default_rng(7)
    for v in rng.standard_normal((500, 3)):
        angle = float(np.arccos(np.clip(v[2] / np.linalg.norm(v), -1.0, 1.0)))
        for exclusion in (0.1, 0.8, 2.0):
            if abs(angle - 0.05 - exclusion) > 1e-9:  # off the edge, where rounding cannot decide
                assert build.in_field(tuple(v.tolist()), 0.05, exclusion) is (angle - 0.05 < exclusion)
    assert build.in_field(None, 0.0, math.pi) is False
    assert build.in_field((0.0, 0.0, 0.0), 0.0, math.pi) is False  # no direction at all: never in the field


def test_small_rotation_rotates_by_its_angle_about_its_axis(build) -> None:
    w, x, y, z = build.small_rotation((0.0, 0.0, 0.3))
    assert (w, x, y) == (math.cos(0.15), 0.0, 0.0) and z == pytest.approx(math.sin(0.15), rel=1e-15)
    assert build.small_rotation((0.0, 0.0, 0.0)) == (1.0, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="math domain error"):  # Python's math refuses an infinite angle
        build.small_rotation((math.inf, 0.0, 0.0))


def _truths() -> list:
    good = dict(q_TN=(0.5, 0.5, 0.5, 0.5), omega_TN_T=(0.001, -0.01, 0.03))
    out = [TrackerTruth(**good), TrackerTruth(q_TN=(2.0, 0, 0, 0)), TrackerTruth(q_TN=("1", "0", "0", "0")),
           TrackerTruth(**good, sigma_cross_rad=1e-5, sigma_roll_rad=np.float64(3e-5)), "not a truth", None,
           TrackerTruth(q_TN=(1.0, 0.0, 0.0)), TrackerTruth(q_TN=np.array([0.0, 0.0, 0.6, 0.8]))]
    for bad in EDGES + (10 ** 400, "x", None):
        out.append(TrackerTruth(q_TN=(bad, 0.0, 0.0, 0.9)))
        out.append(TrackerTruth(q_TN=(1.0, 0.0, 0.0, 0.0), omega_TN_T=(0.0, bad, 0.0)))
        out.append(TrackerTruth(**good, sigma_cross_rad=bad))
        out.append(TrackerTruth(**good, sigma_roll_rad=bad))
    return out


def test_checked_truth_takes_and_refuses_the_same_truths_with_the_same_sentence(compiled) -> None:
    outcomes = []
    for truth in _truths():
        got = _outcome(plain.checked_truth, truth, 1.5)
        assert got == _outcome(compiled.checked_truth, truth, 1.5), truth
        outcomes.append(got[0])
    assert outcomes[:3] == ["ok", "ok", "ok"] and "ValueError" in outcomes and "OverflowError" in outcomes
    q, rate = plain.checked_truth(TrackerTruth(q_TN=(2.0, 0.0, 0.0, 0.0), omega_TN_T=(3.0, 4.0, 0.0)), 0.0)
    assert (q, rate) == ((1.0, 0.0, 0.0, 0.0), 5.0)
    with pytest.raises(ValueError, match=r"measurement_source\(1.5\) must return a TrackerTruth with a unit quat"):
        compiled.checked_truth(TrackerTruth(q_TN=(0.1, 0.0, 0.0, 0.0)), 1.5)
