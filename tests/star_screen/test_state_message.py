"""The display node's state message: round trip, exact layout, and refusal of bad datagrams."""

import math
import struct
import zlib

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim.time import Epoch
from star_screen.state_message import (
    MAGIC,
    MAX_RATE_RAD_S,
    MAX_SPEED_M_S,
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
rate = st.floats(-3.0, 3.0, allow_nan=False)  # |omega| <= 3 sqrt(3) < MAX_RATE_RAD_S
KEY = b"k" * 32
unit3 = st.tuples(finite, finite, finite).filter(lambda v: np.linalg.norm(v) > 1e-3).map(
    lambda v: tuple(np.asarray(v) / np.linalg.norm(v)))


@given(
    seq=st.integers(0, 2**64 - 1),
    t_ns=st.integers(-(2**63), 2**63 - 1),
    off=st.integers(-(10**15), 10**15),
    q=st.tuples(finite, finite, finite, finite).filter(lambda v: np.linalg.norm(v) > 1e-3),
    omega=st.none() | st.tuples(rate, rate, rate),
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
    signed = encode(s, KEY)
    assert signed[: len(data)] != data and len(signed) == len(data) + 32  # flag bit 3, then the tag
    assert decode(signed, KEY) == s == decode(signed)


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


def _with(d: bytes, offset: int, fmt: str, *values) -> bytes:
    return _recrc(d[:offset] + struct.pack(fmt, *values) + d[offset + struct.calcsize(fmt):])


@pytest.mark.parametrize(
    "mutate, field, words",
    [
        (lambda d: _with(d, 28, "<dd", 1e300, 0.0), "epoch", "split date"),
        (lambda d: _with(d, 28, "<dd", 1e300, -1e300 + 2.46e6), "epoch", "split date"),
        (lambda d: _with(d, 28, "<dd", 2400000.5, 0.0), "epoch", "1900 to 2100"),
        (lambda d: _with(d, 28, "<dd", 2488434.5, 2.0), "epoch", "1900 to 2100"),
        (lambda d: _with(d, 44, "<q", 2**62), "epoch", "1900 to 2100"),  # offset_ns of 146 years
        (lambda d: _with(d, 52, "<d", 1.5), "epoch", "dut1_s"),
        (lambda d: _with(d, 92, "<3d", 3.0e8, 0.0, 0.0), "v_sc_gcrs_m_s", "speed"),
        (lambda d: _with(d, 92, "<3d", 1e300, 1e300, 0.0), "v_sc_gcrs_m_s", "speed"),
        (lambda d: _with(d, 116, "<3d", 1e300, 0.0, 0.0), "omega_SN_S", "rate"),
        (lambda d: _with(d, 116, "<3d", 0.0, 0.0, 7.0), "omega_SN_S", "rate"),
    ],
)
def test_decode_refuses_values_outside_physical_ranges(mutate, field, words):
    with pytest.raises(StateMessageError) as exc:
        decode(mutate(encode(_state(omega_SN_S=(0.0, 0.0, 0.1)))))
    assert exc.value.field == field and words in str(exc.value)


def test_limits_are_physical_and_the_edges_pass():
    assert MAX_SPEED_M_S < 299_792_458.0 / 100 and MAX_RATE_RAD_S >= math.radians(180.0)
    near = _state(v_sc_gcrs_m_s=(MAX_SPEED_M_S * 0.999, 0.0, 0.0), omega_SN_S=(0.0, 0.0, MAX_RATE_RAD_S))
    assert decode(encode(near)) == near
    for text in ("1900-01-01T00:00:00Z", "2100-12-31T23:59:59Z"):
        edge = _state(epoch=Epoch.from_iso(text))
        assert decode(encode(edge)) == edge
    with pytest.raises(StateMessageError, match="omega_SN_S"):
        encode(_state(omega_SN_S=(0.0, 0.0, 7.0)))


def test_hmac_is_required_and_checked_when_a_key_is_given():
    plain, signed = encode(_state()), encode(_state(), KEY)
    with pytest.raises(StateMessageError, match="no HMAC") as exc:
        decode(plain, KEY)
    assert exc.value.field == "hmac"
    with pytest.raises(StateMessageError, match="does not match"):
        decode(signed, b"x" * 32)
    forged = bytearray(signed)
    forged[20] ^= 1  # sequence changed and the CRC fixed up: only the key can tell
    forged = bytes(forged[:-36]) + struct.pack("<I", zlib.crc32(bytes(forged[:-36]))) + bytes(forged[-32:])
    with pytest.raises(StateMessageError, match="does not match"):
        decode(forged, KEY)
    with pytest.raises(StateMessageError, match="at least 16") as exc:
        encode(_state(), b"short")
    assert exc.value.field == "key"
