"""The serial ICD codec's per-frame loops (drivers.icd_plan, compiled by Cython where a compiler exists, and plain):
both builds give the same wire values, the same decoded messages and the same refusals, field by field, for the
gyro, the sun sensor and the star tracker; Python's rounding (half to even) holds in both. `.ci/run` runs this file a
second time with ``STAND_NATIVE=0``."""

from __future__ import annotations

import dataclasses
import math
import random

import numpy as np
import pytest

import drivers.icd_codec as icd_codec
from drivers.errors import EncodeError
from drivers.gyro.codec import GyroCodec, GyroRate
from drivers.star_tracker.codec import FrameRejected, StarTrackerCodec
from drivers.sun_sensor.codec import SunSensorCodec
from tests.oracles import build_fixtures

compiled, build = build_fixtures("drivers.icd_plan")

#: Values a caller might pass: halves (rounding), the edges of the fields, out of range, non-finite, huge ints,
#: bools, numpy scalars, names, wrong types.
ODD = [0.0, -0.0, 0.5, 1.5, 2.5, -0.5, -1.5, 254.5, 255.5, 255, 256, -1, 1e300, -1e300, math.inf, -math.inf,
       math.nan, True, False, 10**30, 2**63, 2**64, -2**23, 2**23 - 1, 2**23, 8388607.5, -8388608.5, 3, 3.0,
       3.4028234663852886e38, 3.5e38, np.float64(2.5), np.int64(4), "TRACKING", "tracking", "NOPE", None, [1, 2]]


def _codecs(module, monkeypatch):
    """Fresh codecs whose plans are built by ``module`` (the plain or the compiled build)."""
    monkeypatch.setattr(icd_codec, "_plan", module)
    return GyroCodec(), SunSensorCodec(), StarTrackerCodec()


def _outcome(fn):
    try:
        return "ok", repr(fn())
    except Exception as exc:  # noqa: BLE001 - the refusal itself is compared
        return type(exc).__name__, str(exc)


def _message(spec, rng: random.Random):
    """A ``spec.cls`` built without its checks, every field a plain value, an odd one or a value near its range."""
    msg = object.__new__(spec.cls)
    values: dict = {x.name: None for x in dataclasses.fields(spec.cls)}
    for f in spec.fields:
        if f.bits is not None:
            for bit in f.bits:
                values[bit] = rng.choice([True, False, True, False, 1, np.bool_(True), 2, None])
            continue
        r = rng.random()
        lo, hi = max(f.lo, -1e12), min(f.hi, 1e12)
        v = (rng.choice(ODD) if r < 0.4 else rng.uniform(lo, hi) * f.scale if r < 0.7
             else (rng.randint(int(lo), int(hi)) + rng.choice([0, 0.5, -0.5])) * f.scale)
        if f.index is None:
            values[f.attr] = v
        else:
            seq = values[f.attr] if isinstance(values[f.attr], list) else [0.0] * (f.index + 1)
            seq += [0.0] * (f.index + 1 - len(seq))
            seq[f.index] = v
            values[f.attr] = seq
    for k, v in values.items():
        if isinstance(v, list) and rng.random() < 0.9:
            values[k] = tuple(v[:rng.choice([len(v), len(v), len(v) - 1])])
        object.__setattr__(msg, k, values[k])
    return msg


def _raw(spec, rng: random.Random) -> list:
    out = []
    for f in spec.fields:
        if f.is_float:
            out.append(rng.choice([rng.uniform(-1e5, 1e5), math.inf, -math.inf, math.nan, f.lo, f.hi, 0.0, -1.0]))
        else:
            out.append(rng.choice([rng.randint(int(f.lo) - 2, int(f.hi) + 2), int(f.lo), int(f.hi), 0, 1, -1]))
    return out


def _run(module, monkeypatch) -> list:
    """Every outcome of encoding and decoding a few hundred odd messages per ICD message with ``module``."""
    rng = random.Random(26)
    out = []
    for codec in _codecs(module, monkeypatch):
        for spec in codec.messages.values():
            for _ in range(150):
                msg = _message(spec, rng)
                order = rng.choice(["big", "little"])
                out.append(_outcome(lambda s=spec, m=msg, o=order: icd_codec.wire_values(s, m, "m", o)))
                raw = _raw(spec, rng)
                out.append(_outcome(lambda s=spec, r=raw: icd_codec.decode_fields(s, r, FrameRejected, b"\x01", "p ")))
    return out


def test_compiled_and_plain_agree_on_every_value_and_refusal(compiled, monkeypatch):
    import drivers.icd_plan as plain

    assert compiled is not plain
    got_plain = _run(plain, monkeypatch)
    got_compiled = _run(compiled, monkeypatch)
    assert got_compiled == got_plain
    kinds = {kind for kind, _ in got_plain}
    assert {"ok", "EncodeError", "FrameRejected"} <= kinds  # both ways of every path were compared


@pytest.mark.parametrize(("seq", "wire"), [(0.5, 0), (1.5, 2), (2.5, 2), (3.5, 4), (-0.5, 0), (254.5, 254)])
def test_a_half_rounds_to_even_in_both_builds(build, monkeypatch, seq, wire):
    gyro = _codecs(build, monkeypatch)[0]
    spec = gyro.messages["RATE"]
    msg = GyroRate((0.0, 0.0, 0.0), True, False, False, False, False, False, seq, 0.0, 0)
    assert icd_codec.wire_values(spec, msg, "gyro RATE", "big")[4] == wire  # field 4: the u8 counter


def test_a_half_past_the_field_is_refused_in_both_builds(build, monkeypatch):
    gyro = _codecs(build, monkeypatch)[0]
    msg = GyroRate((0.0, 0.0, 0.0), True, False, False, False, False, False, 255.5, 0.0, 0)
    with pytest.raises(EncodeError, match=r"gyro RATE.counter = 255.5 is outside the field: allowed 0 to 255 \(u8\)"):
        gyro.encode(msg)


def test_norm2_is_the_same_in_both_builds(compiled):
    """The unit-norm check's norm: the same bits, and the same refusal, in both builds, for quaternions near unit
    norm, huge, tiny and non-finite values, and values float() converts (ints, bools, numpy scalars, strings)."""
    import drivers.icd_plan as plain

    rng = random.Random(26)
    cases = [tuple(rng.uniform(-1.0, 1.0) for _ in range(rng.randint(0, 6))) for _ in range(2000)]
    cases += [(1e200, 1e200), (1e-200, 3e-200), (math.nan, 1.0), (math.inf, 0.0), (-0.0,), (1, True, 2),
              (np.float64(0.5), np.float32(0.25), np.int64(3)), ("0.5", "-1e3"), [0.5, 0.5, 0.5, 0.5],
              ("x",), (None,), 5, (1.0, [1.0])]
    for values in cases:
        got, want = _outcome(lambda v=values: compiled.norm2(v)), _outcome(lambda v=values: plain.norm2(v))
        assert got == want, values
    assert icd_codec.norm2 in (compiled.norm2, plain.norm2)
