"""The display node's state message: round trip, exact layout, and refusal of bad datagrams."""

import struct
import zlib

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim.time import Epoch
from star_screen.state_message import (
    MAGIC,
    DisplayState,
    StateMessageError,
    decode,
    encode,
    message_size,
)

EPOCH = Epoch.from_iso("2026-01-01T00:00:00Z").add_ns(123_456_789)


def _state(**kw):
    base = dict(sequence=7, sim_time_ns=5_000_000_000, epoch=EPOCH, q_SN=(0.5, 0.5, -0.5, 0.5),
                v_sc_gcrs_m_s=(7000.0, -120.5, 3.25), stream_id=0xDEADBEEF)
    base.update(kw)
    return DisplayState(**base)


finite = st.floats(-1e4, 1e4, allow_nan=False)
unit3 = st.tuples(finite, finite, finite).filter(lambda v: np.linalg.norm(v) > 1e-3).map(
    lambda v: tuple(np.asarray(v) / np.linalg.norm(v)))


@given(
    seq=st.integers(0, 2**64 - 1),
    t_ns=st.integers(-(2**63), 2**63 - 1),
    off=st.integers(-(10**15), 10**15),
    q=st.tuples(finite, finite, finite, finite).filter(lambda v: np.linalg.norm(v) > 1e-3),
    omega=st.none() | st.tuples(finite, finite, finite),
    sun=st.none() | unit3,
    moon=st.none() | unit3,
)
def test_round_trip_is_exact(seq, t_ns, off, q, omega, sun, moon):
    q = tuple(np.asarray(q) / np.linalg.norm(q))
    s = _state(sequence=seq, sim_time_ns=t_ns, epoch=EPOCH.add_ns(off), q_SN=q, omega_SN_S=omega, sun_N=sun,
               moon_N=moon)
    data = encode(s)
    assert len(data) == 120 + 24 * sum(x is not None for x in (omega, sun, moon))
    assert decode(data) == s  # bit-exact floats, the same Epoch fields


def test_layout_matches_the_documented_offsets():
    data = encode(_state(sun_N=(0.0, 0.0, 1.0)))
    assert data[:4] == MAGIC and struct.unpack_from("<HH", data, 4) == (1, 0b010)
    assert struct.unpack_from("<IQq", data, 8) == (0xDEADBEEF, 7, 5_000_000_000)
    assert struct.unpack_from("<ddqd", data, 28) == (EPOCH.tai1, EPOCH.tai2, 123_456_789, 0.0)
    assert struct.unpack_from("<4d", data, 60) == (0.5, 0.5, -0.5, 0.5)
    assert struct.unpack_from("<3d", data, 116) == (0.0, 0.0, 1.0)
    assert struct.unpack_from("<I", data, 140)[0] == zlib.crc32(data[:140]) and len(data) == message_size(0b010)


def _recrc(body: bytes) -> bytes:
    return body[:-4] + struct.pack("<I", zlib.crc32(body[:-4]))


@pytest.mark.parametrize(
    "mutate, field",
    [
        (lambda d: b"XXXX" + d[4:], "magic"),
        (lambda d: d[:4] + struct.pack("<H", 2) + d[6:], "version"),
        (lambda d: _recrc(d[:6] + struct.pack("<H", 0x10) + d[8:]), "flags"),
        (lambda d: d[:-1], "length"),
        (lambda d: d + b"\0", "length"),
        (lambda d: d[:10], "length"),
        (lambda d: d[:70] + bytes([d[70] ^ 1]) + d[71:], "crc32"),
        (lambda d: _recrc(d[:60] + struct.pack("<4d", 1.0, 0.1, 0.0, 0.0) + d[92:]), "q_SN"),
        (lambda d: _recrc(d[:92] + struct.pack("<3d", float("nan"), 0.0, 0.0) + d[116:]), "v_sc_gcrs_m_s"),
    ],
)
def test_decode_refuses_bad_datagrams_naming_the_field(mutate, field):
    with pytest.raises(StateMessageError) as exc:
        decode(mutate(encode(_state())))
    assert exc.value.field == field and field.split("_")[0] in str(exc.value)


def test_encode_refuses_bad_state_naming_the_field():
    with pytest.raises(StateMessageError, match="q_SN"):
        encode(_state(q_SN=(1.0, 1.0, 0.0, 0.0)))
    with pytest.raises(StateMessageError, match="sequence"):
        encode(_state(sequence=-1))
    with pytest.raises(StateMessageError, match="sun_N"):
        encode(_state(sun_N=(2.0, 0.0, 0.0)))
    with pytest.raises(StateMessageError, match="v_sc_gcrs_m_s"):
        encode(_state(v_sc_gcrs_m_s=(1.0, 2.0)))
