"""Star tracker: the ICD fixture, the generated document, SLIP framing and the codec.

Round trips are Hypothesis properties over every message; the decoder is fed whole frames, frames
split at every position, byte by byte, behind garbage, with bad CRCs, wrong addresses and oversize
frames. No test measures time.
"""

from __future__ import annotations

import math
import re
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.errors import EncodeError, ProtocolError
from drivers.star_tracker import icd
from drivers.star_tracker.codec import (
    CLASSES,
    Action,
    FrameRejected,
    RequestTelemetry,
    SetParam,
    Solution,
    StarTrackerCodec,
    Subscribe,
    crc16,
)
from drivers.star_tracker.slip import END, ESC, SlipDecoder, escape, take_frame, unescape

REPO = Path(__file__).resolve().parents[2]
CODEC = StarTrackerCodec()
ADDR = CODEC.default_address

# -- the ICD and its document ---------------------------------------------------------------------


def test_crc_is_ccitt_false_and_matches_the_icd_check_value():
    assert crc16(b"123456789") == 0x29B1 == CODEC.icd["protocol"]["crc"]["check"]


def test_icd_document_is_the_rendering_of_the_toml():
    doc = (REPO / "docs" / "star_tracker_icd.md").read_text()
    assert doc == icd.render(CODEC), "regenerate: python -m drivers.star_tracker.icd > docs/star_tracker_icd.md"


def test_icd_states_the_quaternion_convention_the_code_uses():
    # A flight-software engineer reads the convention from the ICD alone: Hamilton, scalar first, frame rotation
    # of T relative to GCRS. The matrix it writes out must be sim.rotations.dcm, and composition its product.
    from sim.rotations import compose, dcm

    doc = (REPO / "docs" / "star_tracker_icd.md").read_text()
    line = next((x for x in doc.splitlines() if x.startswith("- Quaternion convention:")), None)
    assert line is not None, "the ICD does not state its quaternion convention"
    for words in ("Hamilton", "scalar first", "GCRS", "frame rotation", "`v_T = R(q_TN) v_N`",
                  "`q_TB (x) q_BN = q_TN`", "third row of `R(q_TN)`"):
        assert words in line, words
    rng = np.random.default_rng(25)
    for _ in range(20):
        q_TB, q_BN = (q / np.linalg.norm(q) for q in rng.normal(size=(2, 4)))
        w, e = q_BN[0], q_BN[1:]
        cross = np.array([[0.0, -e[2], e[1]], [e[2], 0.0, -e[0]], [-e[1], e[0], 0.0]])
        stated = (w * w - e @ e) * np.eye(3) + 2 * np.outer(e, e) - 2 * w * cross  # R(q) as the ICD writes it
        np.testing.assert_allclose(stated, dcm(q_BN), atol=1e-12)
        np.testing.assert_allclose(dcm(compose(q_TB, q_BN)), dcm(q_TB) @ dcm(q_BN), atol=1e-12)


def test_icd_document_tables_list_every_field_message_and_parameter_of_the_toml():
    doc = (REPO / "docs" / "star_tracker_icd.md").read_text()
    rows = [line for line in doc.splitlines() if line.startswith("|")]
    for m in CODEC.icd["messages"]:
        assert any(f"| 0x{m['id']:02X} | {m['name']} |" in r for r in rows), m["name"]
        section = doc.split(f"### {m['name']} (")[1].split("###")[0]
        for f in m["fields"]:
            assert re.search(rf"\| \d+ \| {re.escape(f['name'])} \| {f['type']} \|", section), (m["name"], f["name"])
    for p in CODEC.icd["parameters"]:
        assert any(f"| {p['id']} | {p['name']} | {p['unit']} |" in r for r in rows), p["name"]
    for name, values in CODEC.icd["enums"].items():
        assert any(r.startswith(f"| {name} |") and all(v in r for v in values) for r in rows), name


def test_field_offsets_in_the_document_follow_the_packed_layout():
    spec = CODEC.messages["SOLUTION"]
    assert spec.payload_len == struct.calcsize(spec.fmt) == 44
    body = CODEC.encode_body(_solution())
    # time_us at offset 0 of the payload, little-endian u64
    assert int.from_bytes(body[2:10], "little") == 123_456_789


def test_codec_refuses_an_icd_whose_fields_do_not_match_the_dataclasses(tmp_path):
    text = (REPO / "fixtures" / "devices" / "star_tracker.toml").read_text()
    bad = text.replace('attr = "stars_matched"', 'attr = "stars_used"')
    (tmp_path / "st.toml").write_text(bad)
    with pytest.raises(ValueError, match="SOLUTION maps fields to .*stars_used"):
        StarTrackerCodec(tmp_path / "st.toml")


# -- SLIP -----------------------------------------------------------------------------------------


@given(st.binary(max_size=200))
def test_slip_escape_round_trip(body):
    frame = escape(body)
    assert frame[0] == END and frame[-1] == END and END not in frame[1:-1]
    assert unescape(frame[1:-1]) == body


def test_take_frame_reports_bytes_consumed():
    frame = escape(b"\x21\x03\xc0\xdb")
    assert take_frame(frame[:3], 128) == (1, None, None)  # the opening END alone
    assert take_frame(frame[1:4], 128) == (0, None, None)  # no END yet: need more
    consumed, body, err = take_frame(frame[1:], 128)
    assert (consumed, body, err) == (len(frame) - 1, b"\x21\x03\xc0\xdb", None)
    assert take_frame(bytes([ESC, 0x00, END]), 128) == (3, None, "bad_escape")
    assert take_frame(bytes(300), 128) == (300, None, "oversize")
    assert take_frame(bytes(10), 128) == (0, None, None)


# -- messages -------------------------------------------------------------------------------------


def _solution(**kw) -> Solution:
    base = dict(time_us=123_456_789, q_TN=(0.5, 0.5, -0.5, 0.5), sigma_cross_rad=1e-5, sigma_roll_rad=5e-5,
                stars_centroided=14, stars_matched=12, mode="TRACKING", valid=True, sun_in_field=False,
                moon_in_field=False, earth_in_field=False, rate_too_high=False, time_synced=True, stable_count=9,
                temperature_C=21.25, seq=77)
    base.update(kw)
    return Solution(**base)


def _wire_strategy(f):
    if f.bits is not None:
        return st.integers(0, (1 << len(f.bits)) - 1)
    if f.enum is not None:
        return st.integers(0, len(f.enum) - 1)
    if f.is_float:
        return st.floats(f.lo, f.hi, width=32, allow_nan=False, allow_infinity=False)
    return st.integers(int(f.lo), int(f.hi))


def _unit_quaternion():
    # A unit quaternion as a device sends it: normalised, then rounded to f32 (norm within 2e-7).
    comp = st.floats(-1.0, 1.0, allow_nan=False)
    return st.tuples(comp, comp, comp, comp).filter(lambda v: math.hypot(*v) > 0.1).map(
        lambda v: tuple(float(x) for x in np.float32(np.asarray(v) / math.hypot(*v))))


def _wire_values(spec):
    """Wire values of every field, in range, with unit-norm groups drawn as unit quaternions."""
    grouped = {attr for attr, _ in spec.norms}
    parts = [(_unit_quaternion() if f.index == 0 else st.just(None)) if f.attr in grouped else _wire_strategy(f)
             for f in spec.fields]

    def spread(values):
        out, q = [], None
        for f, v in zip(spec.fields, values, strict=True):
            if f.attr in grouped:
                q = v if f.index == 0 else q
                v = q[f.index]
            out.append(v)
        return tuple(out)

    return st.tuples(*parts).map(spread)


def _payload_strategy(spec):
    return _wire_values(spec).map(lambda v: struct.pack(spec.fmt, *v))


ALL_SPECS = list(CODEC.messages.values())


@pytest.mark.parametrize("spec", ALL_SPECS, ids=[s.name for s in ALL_SPECS])
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_every_message_round_trips_bytes_to_message_to_bytes(spec, data):
    payload = data.draw(_payload_strategy(spec))
    address = data.draw(st.integers(0, 255))
    head = bytes((address, spec.id)) + payload
    body = head + crc16(head).to_bytes(2, "little")
    msg = CODEC.decode_body(body, address)
    assert type(msg) is CLASSES[spec.name]
    assert CODEC.encode_body(msg, address) == body
    # and through SLIP
    (out,) = SlipDecoder(CODEC.max_body).feed(CODEC.encode(msg, address))
    assert out == body


@pytest.mark.parametrize("spec", ALL_SPECS, ids=[s.name for s in ALL_SPECS])
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_every_message_round_trips_message_to_bytes_to_message(spec, data):
    # Build the message from SI values: decode(encode(x)) == x up to one LSB (exact for ints, enums, flags).
    wire = data.draw(_wire_values(spec))
    x = CODEC.decode_payload(spec, struct.pack(spec.fmt, *wire))
    kw = {}
    for f in spec.fields:  # perturb every float below half an LSB of its field
        if f.bits is not None or f.index is not None:
            continue
        v = getattr(x, f.attr)
        if isinstance(v, float) and not f.is_float and f.scale != 1.0:
            kw[f.attr] = v + data.draw(st.floats(-0.4, 0.4)) * f.scale
    y = type(x)(**{**{k: getattr(x, k) for k in x.__slots__}, **kw})
    back = CODEC.decode_body(CODEC.encode_body(y))
    assert back == x
    for k in kw:
        assert math.isclose(getattr(back, k), getattr(y, k), abs_tol=0.5 * 1.0001 * _scale(spec, k))


def _scale(spec, attr):
    return next(f.scale for f in spec.fields if f.attr == attr)


def test_solution_round_trip_in_si_units():
    s = _solution()
    back = CODEC.decode_body(CODEC.encode_body(s), ADDR)
    assert back.q_TN == pytest.approx(s.q_TN, abs=1e-7)
    assert back.sigma_cross_rad == pytest.approx(1e-5, rel=1e-6)
    assert back.temperature_C == pytest.approx(21.25)
    assert (back.mode, back.valid, back.time_synced) == ("TRACKING", True, True)
    assert (back.seq, back.time_us) == (77, 123_456_789)


# -- decode errors --------------------------------------------------------------------------------


def test_bad_crc_names_the_frame_and_expected_vs_computed():
    body = bytearray(CODEC.encode_body(RequestTelemetry(0x90), ADDR))
    good_crc = int.from_bytes(body[-2:], "little")
    body[-1] ^= 0x5A
    with pytest.raises(FrameRejected) as ei:
        CODEC.decode_body(bytes(body), ADDR)
    e = ei.value
    assert isinstance(e, ProtocolError) and e.kind == "crc"
    assert e.frame_hex == bytes(body).hex().upper()
    assert e.computed == f"0x{good_crc:04X}" and e.expected != e.computed
    assert "CRC" in str(e) and bytes(body).hex().upper() in str(e)


def test_wrong_address_unknown_id_and_bad_length_are_rejected():
    body = CODEC.encode_body(RequestTelemetry(0x90), 0x22)
    with pytest.raises(FrameRejected, match="another address") as ei:
        CODEC.decode_body(body, ADDR)
    assert ei.value.kind == "address" and ei.value.expected == "0x21" and ei.value.computed == "0x22"
    head = bytes((ADDR, 0x7E, 0))
    with pytest.raises(FrameRejected, match="unknown star tracker message id 0x7E") as ei:
        CODEC.decode_body(head + crc16(head).to_bytes(2, "little"), ADDR)
    assert ei.value.kind == "unknown_id"
    head = bytes((ADDR, 0x03, 0x90, 0x00))
    with pytest.raises(FrameRejected, match="REQUEST_TELEMETRY payload of the wrong length") as ei:
        CODEC.decode_body(head + crc16(head).to_bytes(2, "little"), ADDR)
    assert (ei.value.kind, ei.value.expected, ei.value.computed) == ("length", "1 bytes", "2 bytes")
    with pytest.raises(FrameRejected, match="too short"):
        CODEC.decode_body(b"\x21\x03", ADDR)


def test_enum_outside_its_table_is_a_protocol_error():
    head = bytes((ADDR, 0x04, 9)) + bytes(8)
    with pytest.raises(FrameRejected, match="ACTION.action = 9 is not in its table") as ei:
        CODEC.decode_body(head + crc16(head).to_bytes(2, "little"), ADDR)
    assert ei.value.kind == "value"


# -- encode errors --------------------------------------------------------------------------------


def test_encode_errors_name_field_value_and_range():
    with pytest.raises(EncodeError, match=r"SOLUTION\.stars_matched = 300 is outside the field: allowed 0 to 255"):
        CODEC.encode(_solution(stars_matched=300))
    with pytest.raises(EncodeError, match=r"SOLUTION\.q_w = nan .*finite"):
        CODEC.encode(_solution(q_TN=(math.nan, 0, 0, 1)))
    with pytest.raises(EncodeError, match=r"ACTION\.action = 'FLY' is not allowed; allowed: 'NONE' \(0\), 'BOOT'"):
        CODEC.encode(Action("FLY"))
    with pytest.raises(EncodeError, match=r"SUBSCRIBE\.period_ms = 70000\.0 \(period_s = 70\.0 SI\) .*0 to 60000"):
        CODEC.encode(Subscribe(0x90, 70.0))
    with pytest.raises(EncodeError, match="address = 300"):
        CODEC.encode(RequestTelemetry(0x90), 300)


def test_set_param_checks_the_icd_range_in_si_and_wire_units():
    assert CODEC.set_param("rate_limit", math.radians(2.0)) == SetParam(4, pytest.approx(2.0))
    assert CODEC.set_param("stable_count", 7) == SetParam(3, 7.0)
    with pytest.raises(EncodeError, match=r"rate_limit = .* is 45 deg/s; allowed: a number from 0\.01 to 20 deg/s"):
        CODEC.set_param("rate_limit", math.radians(45.0))
    with pytest.raises(EncodeError, match="stable_count .* allowed: a whole number from 1 to 100"):
        CODEC.set_param("stable_count", 2.5)
    with pytest.raises(EncodeError, match="Unknown star tracker parameter 'gain'; known parameters: output_interval"):
        CODEC.set_param("gain", 1.0)


# -- the decoder on streams -----------------------------------------------------------------------


def _frames():
    return [CODEC.encode(m, ADDR) for m in (_solution(), RequestTelemetry(0x90), _solution(seq=78, q_TN=(1, 0, 0, 0)))]


def _decode_stream(chunks):
    dec = SlipDecoder(CODEC.max_body)
    out = []
    for c in chunks:
        out += dec.feed(c)
    return dec, out


def test_decoder_whole_split_at_every_position_and_byte_by_byte():
    frames = _frames()
    stream = b"".join(frames)
    msgs = (_solution(), RequestTelemetry(0x90), _solution(seq=78, q_TN=(1, 0, 0, 0)))
    bodies = [CODEC.encode_body(m, ADDR) for m in msgs]
    assert _decode_stream([stream])[1] == bodies
    for i in range(len(stream) + 1):
        assert _decode_stream([stream[:i], stream[i:]])[1] == bodies, i
    assert _decode_stream([bytes([b]) for b in stream])[1] == bodies


def test_decoder_behind_garbage_and_after_an_oversize_frame_serves_the_next_good_frame():
    good = CODEC.encode(RequestTelemetry(0x90), ADDR)
    dec, out = _decode_stream([b"\x01\x02garbage" + good])
    # the garbage before the opening END comes out as a frame of its own, which the codec rejects
    assert out[-1] == CODEC.encode_body(RequestTelemetry(0x90), ADDR)
    with pytest.raises(FrameRejected):
        CODEC.decode_body(out[0], ADDR)
    dec, out = _decode_stream([bytes([END]) + bytes(range(1, 190)) * 3, bytes(50), good])
    assert dec.counters["oversize"] == 1 and dec.counters["bytes_dropped"] > 500
    assert out == [CODEC.encode_body(RequestTelemetry(0x90), ADDR)]
    dec, out = _decode_stream([bytes([END, ESC, 0x01, END]) + good])
    assert dec.counters["bad_escape"] == 1 and out == [CODEC.encode_body(RequestTelemetry(0x90), ADDR)]


@settings(max_examples=200, deadline=None)
@given(junk=st.binary(max_size=400), cut=st.integers(0, 60))
def test_decoder_survives_arbitrary_bytes_and_serves_the_next_good_frame(junk, cut):
    dec = SlipDecoder(CODEC.max_body)
    good = CODEC.encode(_solution(), ADDR)
    out = dec.feed(junk) + dec.feed(good[:cut]) + dec.feed(good[cut:])
    assert out and out[-1] == CODEC.encode_body(_solution(), ADDR)
    for body in out[:-1]:
        try:
            CODEC.decode_body(body, ADDR)
        except ProtocolError:
            pass


# -- physical ranges from the ICD -------------------------------------------------------------------


def _raw_solution(q=(0.5, 0.5, -0.5, 0.5), sigmas_arcsec=(2.0, 10.0), temperature_cC=2125) -> bytes:
    """A SOLUTION body with a valid CRC, its values packed as given (bypassing the encoder's checks)."""
    spec = CODEC.messages["SOLUTION"]
    head = bytes((ADDR, spec.id)) + struct.pack(spec.fmt, 5, *q, *sigmas_arcsec, 12, 11, 2, 1, 9, temperature_cC, 3)
    return head + crc16(head).to_bytes(2, "little")


@pytest.mark.parametrize(
    "body, words",
    [
        (_raw_solution(q=(0.5, 0.0, 0.0, 0.0)), "norm 0.5"),  # the case: aborted the whole run
        (_raw_solution(q=(1.0, 2e-3, 0.0, 0.0)), "norm 1.000002"),
        (_raw_solution(q=(2.0, 0.0, 0.0, 0.0)), "q_w = 2.0"),
        (_raw_solution(sigmas_arcsec=(-1.0, 10.0)), "sigma_cross_arcsec = -1.0"),
        (_raw_solution(sigmas_arcsec=(2.0, 1e9)), "sigma_roll_arcsec"),
        (_raw_solution(temperature_cC=-30000), "temperature_cC = -30000"),  # -300 degC
        (_raw_solution(temperature_cC=20000), "temperature_cC = 20000"),
    ],
)
def test_decode_refuses_values_outside_the_icd_ranges(body, words):
    with pytest.raises(FrameRejected) as ei:
        CODEC.decode_body(body, ADDR)
    assert ei.value.kind == "value" and words in str(ei.value) and body.hex().upper() in str(ei.value)


def test_icd_ranges_admit_what_a_device_sends():
    q = np.array([0.1, 0.7, -0.7, 0.1])
    sol = CODEC.decode_body(_raw_solution(q=tuple(np.float32(q / np.linalg.norm(q)))), ADDR)
    assert abs(math.hypot(*sol.q_TN) - 1.0) < 5e-7
    sol = CODEC.decode_body(_raw_solution(sigmas_arcsec=(0.0, 0.0), temperature_cC=-10000), ADDR)
    assert sol.temperature_C == -100.0 and sol.sigma_cross_rad == 0.0
    with pytest.raises(EncodeError, match="norm"):
        CODEC.encode(_solution(q_TN=(0.5, 0.0, 0.0, 0.0)))
    with pytest.raises(EncodeError, match="sigma_cross"):
        CODEC.encode(_solution(sigma_cross_rad=-1e-6))
    with pytest.raises(EncodeError, match="temperature_cC"):
        CODEC.encode(_solution(temperature_C=-300.0))


class _Weird:
    def __float__(self):
        raise ArithmeticError("no float here")


@pytest.mark.parametrize(
    "msg",
    [
        "not a message",
        RequestTelemetry(2**80),
        RequestTelemetry("0x90"),
        RequestTelemetry(_Weird()),
        Subscribe(0x90, 10**400),
        Subscribe(0x90, float("inf")),
        Action("SET_TIME", -1),
        Action(None),
        SetParam(1, 10**400),
        SetParam(1, "fast"),
        _solution(q_TN=(1.0, 0.0, 0.0)),
        _solution(q_TN=None),
        _solution(q_TN={"w": 1.0}),
        _solution(valid=np.array([True, False])),
        _solution(valid="yes please"),
        _solution(time_us=-1),
        _solution(stable_count=1.5e20),
    ],
)
def test_encode_raises_only_encode_error(msg):
    # Item 12 of the hardening issue: the encoder's only exception is EncodeError (a ValueError).
    with pytest.raises(EncodeError):
        CODEC.encode(msg)
