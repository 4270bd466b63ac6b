"""DbcCodec.packer: the positional per-tick codec. drivers.bitpack, its one source, compiled (Cython, compiled_paths)
and plain agree to the bit on any input, both agree with the dict path (and so with cantools), and both refuse a
signal table they could misread. `.ci/run` runs this file a second time with ``STAND_NATIVE=0``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import compiled_paths
import drivers.bitpack as plain
from drivers import dbc as dbc_mod
from drivers import fixture_path
from drivers.dbc import DbcCodec
from tests.drivers.test_dbc import MIXED_DBC, MTQ_DBC, _fast_messages, _physical_values
from tests.oracles import build_fixtures, require_compiled

compiled, build = build_fixtures("drivers.bitpack")


def _packers(codec: DbcCodec, name: str, order: tuple[str, ...], compiled) -> tuple:
    """The plain and the compiled packer of one message in ``order`` (the rows DbcCodec builds)."""
    rows = dbc_mod._packer(codec._message(name), order)  # any build: it is only read for its rows below
    assert rows is not None
    by_name = {sig.name: sig for sig in codec._message(name).signals}
    table = tuple((s.start, s.mask.bit_length(), bool(s.sign_bit), s.kind, s.scale, s.offset, s.lo, s.hi, s.raw_lo,
                   s.raw_hi) for s in (by_name[n] for n in order))
    length = codec.length(name)
    return plain.Packer(length, table), compiled.Packer(length, table)


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


@pytest.mark.parametrize("which", ["mtq", "rw", "mixed"])
@settings(max_examples=400, suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None)
@given(data=st.data())
def test_compiled_and_plain_packers_agree_on_any_values(which, data, codecs, compiled) -> None:
    codec = codecs[which]
    name = data.draw(st.sampled_from(_fast_messages(codec)))
    order = _order(codec, name, data.draw)
    python, native = _packers(codec, name, order, compiled)
    values = tuple(_value(codec, name, s, data.draw) for s in order)
    assert _same(native.pack(*values), python.pack(*values)), values
    payload = data.draw(st.binary(min_size=python.length, max_size=python.length))
    assert _same(native.unpack(payload), python.unpack(payload)), payload.hex()


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


def test_the_packer_checks_its_arguments(build) -> None:
    packer = build.Packer(8, ((0, 8, False, 0, 1, 0, -1e-6, 255.000001, 0, 255),
                              (8, 1, False, 0, 1, 0, -1e-6, 1.000001, 0, 1),
                              (16, 8, False, 0, 1, 0, 0.0, 255.0, 0, 255)))
    assert packer.pack(1, False, 7) == bytes([1, 0, 7, 0, 0, 0, 0, 0])
    with pytest.raises(TypeError, match="takes 3 values; got 2"):
        packer.pack(1, False)
    with pytest.raises(ValueError, match="takes 8 bytes; got 3"):
        packer.unpack(b"\x01\x02\x03")
    assert packer.unpack(bytearray(8)) == (0, 0, 0)
    assert packer.unpack(memoryview(bytes([1, 1, 7, 0, 0, 0, 0, 0]))) == (1, 1, 7)
    with pytest.raises(ValueError, match="1 to 8"):
        build.Packer(9, ())
    with pytest.raises(ValueError, match="beyond the packer"):
        build.Packer(8, ((0, 53, False, 0, 1, 0, 0.0, 1.0, 0, 1),))


class _ClearsOnBool:
    """A signal flag whose truth test empties the table it sits in (the old C read the table's rows after that)."""

    def __init__(self, victim: list) -> None:
        self.victim = victim

    def __bool__(self) -> bool:
        self.victim.clear()
        return True


def test_a_signal_table_that_could_change_while_read_raises_type_error(build) -> None:
    """The old C read a list of rows as it converted them: a flag whose __bool__ cleared the list was read after it
    was freed, and a list in place of a row's tuple went to a tuple parser. The table is a tuple of tuples now
    (immutable), the flag a bool: anything else is a TypeError before any row is read, in both builds."""
    row = (0, 8, True, 0, 1, 0, -128.0, 127.0, -128, 127)
    victim: list = []
    victim.extend([(0, 8, _ClearsOnBool(victim), 0, 1, 0, -128.0, 127.0, -128, 127), row])
    with pytest.raises(TypeError, match="takes an int and a tuple"):
        build.Packer(8, victim)
    assert len(victim) == 2  # nothing read it
    with pytest.raises(TypeError, match="signed a bool"):
        build.Packer(8, tuple(victim))
    assert len(victim) == 2
    with pytest.raises(TypeError, match="a signal is a tuple"):
        build.Packer(8, (list(row),))
    with pytest.raises(TypeError, match="a signal is a tuple"):
        build.Packer(8, (row[:9],))
    assert build.Packer(8, (row,)).pack(-3) == bytes([253, 0, 0, 0, 0, 0, 0, 0])


def test_the_codec_runs_the_build_compiled_paths_chose(codecs) -> None:
    """What summary.json and `stand bench loop` report: the compiled twin unless STAND_NATIVE=0 (or no build)."""
    chosen = compiled_paths.load("drivers.bitpack")
    assert dbc_mod._bitpack is chosen
    packer = codecs["mtq"].packer("MTQ_MODE_CMD", ("mode", "reset_counters", "seq"))
    assert type(packer.pack.__self__) is chosen.Packer
    expected = "compiled" if compiled_paths.native_allowed() else "python"
    if expected == "compiled":
        require_compiled("drivers.bitpack")
    assert compiled_paths.active()["drivers.bitpack"] == expected


def test_codecs_of_one_dbc_file_share_each_message_s_packer(tmp_path):
    """A packer holds only its message's signals: the codecs of one file version share it (each scene built its own
    for every device), one per signal order; another version of the file gets its own."""
    a, b = DbcCodec(MTQ_DBC), DbcCodec(MTQ_DBC)
    name = next(n for n in a.names if a.is_fast(n))
    order = a.signal_names(name)
    first, second = a.packer(name, order), b.packer(name, order)
    assert first is not second and first.pack is not None
    assert first.pack.__self__ is second.pack.__self__  # one packer behind both
    if len(order) > 1:
        turned = a.packer(name, order[::-1])
        assert turned.pack.__self__ is not first.pack.__self__
    copy = tmp_path / "copy.dbc"
    copy.write_bytes(Path(MTQ_DBC).read_bytes())
    assert DbcCodec(copy).packer(name, order).pack.__self__ is not first.pack.__self__
