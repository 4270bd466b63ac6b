"""DbcCodec.packer: the positional per-tick codec. The compiled packer (drivers/_bitpack.c) and the generated Python
agree to the bit on any input, and both agree with the dict path (and so with cantools)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers import dbc as dbc_mod
from drivers import fixture_path
from drivers.dbc import DbcCodec, _compile_message
from tests.drivers.test_dbc import MIXED_DBC, MTQ_DBC, _fast_messages, _physical_values
from tests.oracles import require_compiled


@pytest.fixture(scope="module")
def compiled() -> None:
    require_compiled(dbc_mod.NATIVE, "drivers._bitpack")



@pytest.fixture(scope="module")
def codecs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, DbcCodec]:
    path = tmp_path_factory.mktemp("dbc") / "mixed.dbc"
    path.write_text(MIXED_DBC)
    return {"mtq": DbcCodec(MTQ_DBC), "rw": DbcCodec(fixture_path("devices/reaction_wheel.dbc")),
            "mixed": DbcCodec(path)}


def _order(codec: DbcCodec, name: str, draw) -> tuple[str, ...]:
    return tuple(draw(st.permutations(codec.signal_names(name))))


def _value(codec: DbcCodec, name: str, signal: str, draw):
    """Anything a caller might pass: in range, near and past the range, ints (some huge), bools, NaN, infinities,
    numpy scalars, strings."""
    lo, hi = codec.signal_range(name, signal)
    span = (hi - lo) or 1.0
    return draw(st.one_of(
        st.floats(lo - 0.01 * span, hi + 0.01 * span),
        st.floats(allow_nan=True, allow_infinity=True),
        st.integers(math.floor(lo) - 3, math.ceil(hi) + 3),
        st.integers(-(1 << 70), 1 << 70),
        st.booleans(),
        st.sampled_from([math.nan, math.inf, -math.inf, -0.0, 0.0, np.float64(lo), "ONE"]),
    ))


def _same(a, b) -> bool:
    """Equal values of the same type (a tuple of them), or both None. A float signal's payload can hold a NaN: two
    NaNs are the same value here (CI's derandomised Hypothesis draws one)."""
    if a is None or b is None:
        return a is b
    if isinstance(a, bytes):
        return a == b
    return len(a) == len(b) and all(type(x) is type(y) and (x == y or (isinstance(x, float) and math.isnan(x)
                                                                        and math.isnan(y)))
                                    for x, y in zip(a, b, strict=True))


@pytest.mark.usefixtures("compiled")
@pytest.mark.parametrize("which", ["mtq", "rw", "mixed"])
@settings(max_examples=400, suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None)
@given(data=st.data())
def test_compiled_and_generated_packers_agree_on_any_values(which, data, codecs) -> None:
    codec = codecs[which]
    name = data.draw(st.sampled_from(_fast_messages(codec)))
    order = _order(codec, name, data.draw)
    packer = codec.packer(name, order)
    assert packer.compiled
    pack_py, unpack_py = _compile_message(codec._message(name), order)
    values = tuple(_value(codec, name, s, data.draw) for s in order)
    assert _same(packer.pack(*values), pack_py(*values)), values
    payload = data.draw(st.binary(min_size=packer.length, max_size=packer.length))
    assert _same(packer.unpack(payload), unpack_py(payload)), payload.hex()


@pytest.mark.parametrize("which", ["mtq", "rw", "mixed"])
@settings(max_examples=300, suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None)
@given(data=st.data())
def test_packer_equals_the_dict_path(which, data, codecs) -> None:
    """In-range values: the payload of encode(); any payload: the values of decode(), in the packer's order, of
    the same types. Messages off the fast path (big-endian, float, multiplexed) too, through cantools."""
    codec = codecs[which]
    name = data.draw(st.sampled_from(codec.names[:4] if which == "mixed" else codec.names))
    order = _order(codec, name, data.draw)
    packer = codec.packer(name, order)
    msg = codec.database.get_message_by_name(name)
    if codec.is_fast(name):
        values = data.draw(st.composite(lambda draw: _physical_values(msg, draw))())
        payload = packer.pack(*(values[s] for s in order))
        assert (packer.frame_id, payload) == codec.encode(name, values)
    else:
        assert packer.pack(*(0 for _ in order)) is None  # DbcCodec.encode takes every case
        assert not packer.compiled
    payload = data.draw(st.binary(min_size=packer.length, max_size=packer.length))
    if name == "MUX_MSG":
        return  # cantools decodes only the multiplexed signals present: not a fixed tuple
    _, expected = codec.decode(packer.frame_id, payload)
    assert _same(packer.unpack(payload), tuple(expected[s] for s in order))


def test_packer_refuses_an_order_that_is_not_the_signals(codecs) -> None:
    mtq = codecs["mtq"]
    with pytest.raises(ValueError, match="b_x, b_y, b_z, seq, coil_active, valid"):
        mtq.packer("MAG_SAMPLE", ("b_x", "b_y", "b_z", "seq", "valid"))
    with pytest.raises(KeyError, match="Unknown message 'NOPE'"):
        mtq.packer("NOPE", ())


@pytest.mark.usefixtures("compiled")
def test_compiled_packer_checks_its_arguments(codecs) -> None:
    packer = codecs["mtq"].packer("MTQ_MODE_CMD", ("mode", "reset_counters", "seq"))
    assert packer.pack(1, False, 7) == bytes([1, 7, 0, 0, 0, 0, 0, 0])
    with pytest.raises(TypeError, match="takes 3 values; got 2"):
        packer.pack(1, False)
    with pytest.raises(ValueError, match="takes 8 bytes; got 3"):
        packer.unpack(b"\x01\x02\x03")
    assert packer.unpack(bytearray(8)) == (0, 0, 0)
    with pytest.raises(ValueError, match="1 to 8"):
        dbc_mod._Packer(9, [])
