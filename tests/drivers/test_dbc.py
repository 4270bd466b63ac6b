"""DbcCodec: the fast little-endian path equals cantools bit for bit; refusals name what is wrong."""

from __future__ import annotations

import math
from pathlib import Path

import cantools
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers import fixture_path
from drivers.dbc import DbcCodec
from drivers.errors import DriverError, EncodeError, ProtocolError

MTQ_DBC = fixture_path("devices/magnetorquer.dbc")

# A DBC that exercises what the magnetorquer ICD does not: signals across byte boundaries, odd
# widths, a negative scale, an integer scale with an offset, a VAL_ table with gaps, a signal
# without [min|max], a 3-byte frame, and the cantools fall-backs (big-endian, float, multiplexed).
MIXED_DBC = """\
VERSION ""

NS_ :

BS_:

BU_: A B

BO_ 256 LE_ODD: 8 A
 SG_ s12 : 3|12@1- (1,0) [-2048|2047] "" B
 SG_ flag : 15|1@1+ (1,0) [0|1] "" B
 SG_ u20 : 16|20@1+ (0.25,-100) [-100|162043.75] "m" B
 SG_ s28 : 36|28@1- (3,7) [-402653177|402653176] "" B

BO_ 257 LE_SHORT: 3 A
 SG_ enum3 : 0|3@1+ (1,0) [0|7] "" B
 SG_ neg : 3|13@1- (-0.5,10) [-2037.5|2058] "" B
 SG_ nominmax : 16|8@1+ (2,1) [0|0] "" B

BO_ 258 BE_MSG: 8 A
 SG_ be16 : 7|16@0- (0.1,0) [-3276.8|3276.7] "" B
 SG_ le8 : 16|8@1+ (1,0) [0|255] "" B

BO_ 259 FLOAT_MSG: 8 A
 SG_ f32 : 0|32@1- (1,0) [-1000|1000] "" B
 SG_ u16 : 32|16@1+ (1,0) [0|65535] "" B

BO_ 260 MUX_MSG: 8 A
 SG_ mux M : 0|8@1+ (1,0) [0|255] "" B
 SG_ a m0 : 8|16@1+ (1,0) [0|65535] "" B
 SG_ b m1 : 8|16@1- (1,0) [-32768|32767] "" B

VAL_ 257 enum3 0 "ZERO" 1 "ONE" 5 "FIVE" ;
SIG_VALTYPE_ 259 f32 : 1;
"""


@pytest.fixture(scope="module")
def mixed_dbc(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("dbc") / "mixed.dbc"
    path.write_text(MIXED_DBC)
    return path


@pytest.fixture(scope="module")
def mtq() -> DbcCodec:
    return DbcCodec(MTQ_DBC)


@pytest.fixture(scope="module")
def mixed(mixed_dbc: Path) -> DbcCodec:
    return DbcCodec(mixed_dbc)


def _raw_bounds(sig: cantools.database.can.Signal) -> tuple[int, int]:
    """Raw values that the DBC's [min|max] (or the bits) allow."""
    if sig.is_signed:
        lo, hi = -(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1
    else:
        lo, hi = 0, (1 << sig.length) - 1
    if sig.minimum is not None and sig.maximum is not None:
        scale, offset = sig.conversion.scale, sig.conversion.offset
        a, b = (sig.minimum - offset) / scale, (sig.maximum - offset) / scale
        lo, hi = max(lo, math.ceil(min(a, b) - 1e-9)), min(hi, math.floor(max(a, b) + 1e-9))
    return lo, hi


def _fast_messages(codec: DbcCodec) -> list[str]:
    return [n for n in codec.names if codec.is_fast(n)]


def _physical_values(msg: cantools.database.can.Message, draw: st.DrawFn) -> dict[str, int | float]:
    values = {}
    for sig in msg.signals:
        lo, hi = _raw_bounds(sig)
        raw = draw(st.integers(lo, hi))
        values[sig.name] = sig.conversion.raw_to_scaled(raw, decode_choices=False)
    return values


def test_the_icd_is_entirely_on_the_fast_path(mtq: DbcCodec) -> None:
    assert mtq.names == (
        "MTQ_DIPOLE_CMD",
        "MTQ_MODE_CMD",
        "MAG_SAMPLE",
        "MTQ_STATUS",
        "MTQ_COUNTERS",
        "MTQ_HEARTBEAT",
    )
    assert all(mtq.is_fast(n) for n in mtq.names)
    for name in mtq.names:
        assert mtq.length(name) == 8
        assert mtq.frame_id(name) <= 0x7FF


def test_unsupported_layouts_fall_back_to_cantools(mixed: DbcCodec) -> None:
    assert [mixed.is_fast(n) for n in mixed.names] == [True, True, False, False, False]


@pytest.mark.parametrize("which", ["mtq", "mixed"])
@settings(max_examples=300, suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None)
@given(data=st.data())
def test_fast_encode_equals_cantools_for_in_range_values(
    which: str, data: st.DataObject, request: pytest.FixtureRequest
) -> None:
    codec: DbcCodec = request.getfixturevalue(which)
    name = data.draw(st.sampled_from(_fast_messages(codec)))
    msg = codec.database.get_message_by_name(name)
    values = data.draw(st.composite(lambda draw: _physical_values(msg, draw))())
    frame_id, payload = codec.encode(name, values)
    assert frame_id == msg.frame_id
    assert payload == msg.encode(values, strict=True)
    # and back, values and types (int stays int, float stays float)
    decoded_name, decoded = codec.decode(frame_id, payload)
    expected = msg.decode(payload, decode_choices=False)
    assert decoded_name == name
    assert decoded == expected
    assert [type(v) for v in decoded.values()] == [type(v) for v in expected.values()]


@pytest.mark.parametrize("which", ["mtq", "mixed"])
@settings(max_examples=300, suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None)
@given(data=st.data())
def test_fast_encode_matches_cantools_for_any_float(
    which: str, data: st.DataObject, request: pytest.FixtureRequest
) -> None:
    """Arbitrary floats near and past the DBC range: same bytes, or both refuse.

    One deliberate difference: for a signal without [min|max] in the DBC, cantools encodes a value
    past what the bits hold (rounding or wrapping it); we refuse it.
    """
    codec: DbcCodec = request.getfixturevalue(which)
    name = data.draw(st.sampled_from(_fast_messages(codec)))
    msg = codec.database.get_message_by_name(name)
    values: dict[str, float] = {}
    for sig in msg.signals:
        lo, hi = codec.signal_range(name, sig.name)
        span = (hi - lo) or 1.0
        values[sig.name] = data.draw(st.floats(lo - 0.01 * span, hi + 0.01 * span, allow_nan=False))
    try:
        expected = msg.encode(values, strict=True)
    except Exception:  # cantools refuses: so must we, with our error
        with pytest.raises(EncodeError):
            codec.encode(name, values)
        return
    try:
        got = codec.encode(name, values)
    except EncodeError:
        ranges = {s.name: codec.signal_range(name, s.name) for s in msg.signals}
        outside = [n for n, (lo, hi) in ranges.items() if not lo <= values[n] <= hi]
        assert any(msg.get_signal_by_name(n).minimum is None for n in outside)
        return
    assert got == (msg.frame_id, expected)


@pytest.mark.parametrize("which", ["mtq", "mixed"])
@settings(max_examples=300, suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None)
@given(data=st.data())
def test_fast_decode_equals_cantools_for_any_payload(
    which: str, data: st.DataObject, request: pytest.FixtureRequest
) -> None:
    codec: DbcCodec = request.getfixturevalue(which)
    name = data.draw(st.sampled_from(_fast_messages(codec)))
    msg = codec.database.get_message_by_name(name)
    payload = data.draw(st.binary(min_size=msg.length, max_size=msg.length))
    got_name, got = codec.decode(msg.frame_id, payload)
    expected = msg.decode(payload, decode_choices=False)
    assert got_name == name
    assert got == expected
    assert [type(v) for v in got.values()] == [type(v) for v in expected.values()]


def test_fallback_messages_round_trip_through_cantools(mixed: DbcCodec) -> None:
    frame_id, payload = mixed.encode("BE_MSG", {"be16": -12.3, "le8": 5})
    reference = mixed.database.get_message_by_name("BE_MSG").encode({"be16": -12.3, "le8": 5})
    assert (frame_id, payload) == (258, reference)
    assert mixed.decode(frame_id, payload) == ("BE_MSG", {"be16": -12.3, "le8": 5})
    float_values = {"f32": 1.5, "u16": 9}
    assert mixed.decode(*mixed.encode("FLOAT_MSG", float_values)) == ("FLOAT_MSG", float_values)
    assert mixed.decode(*mixed.encode("MUX_MSG", {"mux": 1, "b": -5})) == ("MUX_MSG", {"mux": 1, "b": -5})
    with pytest.raises(EncodeError, match="be16"):
        mixed.encode("BE_MSG", {"be16": -9999.0, "le8": 5})
    with pytest.raises(ProtocolError, match="MUX_MSG"):
        mixed.decode(260, bytes([7, 0, 0, 0, 0, 0, 0, 0]))  # multiplexer value 7 is not defined


def test_enum_names_are_accepted_and_unknown_names_listed(mixed: DbcCodec, mtq: DbcCodec) -> None:
    _, payload = mixed.encode("LE_SHORT", {"enum3": "FIVE", "neg": -3, "nominmax": 511})
    assert mixed.decode(257, payload)[1]["enum3"] == 5
    with pytest.raises(EncodeError) as err:
        mtq.encode("MTQ_MODE_CMD", {"mode": "ON", "reset_counters": 0, "seq": 0})
    text = str(err.value)
    assert "MTQ_MODE_CMD.mode" in text and "'ON'" in text and "DIPOLE (1)" in text


@pytest.mark.parametrize(
    ("message", "signal", "value", "allowed"),
    [
        ("MTQ_DIPOLE_CMD", "dipole_x", 0.4, "-0.32768 A.m2 to 0.32767 A.m2"),
        ("MTQ_DIPOLE_CMD", "dipole_z", -0.33, "-0.32768 A.m2 to 0.32767 A.m2"),
        ("MTQ_DIPOLE_CMD", "duration_ms", 70000, "0 ms to 65535 ms"),
        ("MTQ_DIPOLE_CMD", "duration_ms", -1, "0 ms to 65535 ms"),
        ("MTQ_MODE_CMD", "mode", 3, "0 to 2"),  # fits the 4 bits, outside the DBC's [0|2]
        ("MTQ_MODE_CMD", "seq", 256, "0 to 255"),
        ("MAG_SAMPLE", "b_y", 163840, "-163840 nT to 163835 nT"),
        ("MTQ_STATUS", "temperature", 90.0, "-40 degC to 87.5 degC"),
        ("MTQ_HEARTBEAT", "uptime_s", 2**32, "0 s to 4294967295 s"),
    ],
)
def test_encode_refuses_out_of_range_naming_signal_value_and_range(
    mtq: DbcCodec, message: str, signal: str, value: float, allowed: str
) -> None:
    values = {s: 0 for s in mtq.signal_names(message)}
    if message == "MTQ_STATUS":
        values["temperature"] = 20.0
    mtq.encode(message, values)  # the baseline is fine
    values[signal] = value
    with pytest.raises(EncodeError) as err:
        mtq.encode(message, values)
    text = str(err.value)
    assert f"{message}.{signal}" in text
    assert repr(value) in text
    assert allowed in text
    assert isinstance(err.value, ValueError) and isinstance(err.value, DriverError)


@settings(max_examples=200, deadline=None)
@given(data=st.data())
def test_out_of_range_never_wraps(mtq: DbcCodec, data: st.DataObject) -> None:
    codec = mtq
    name = data.draw(st.sampled_from(codec.names))
    signal = data.draw(st.sampled_from(codec.signal_names(name)))
    lo, hi = codec.signal_range(name, signal)
    scale = abs(codec.signal_scale(name, signal))
    bad = data.draw(
        st.one_of(
            st.floats(hi + scale, hi + 1e12 * scale),
            st.floats(lo - 1e12 * scale, lo - scale),
            st.sampled_from([math.nan, math.inf, -math.inf]),
        )
    )
    values = {s: codec.signal_range(name, s)[0] for s in codec.signal_names(name)}
    values[signal] = bad
    with pytest.raises(EncodeError, match=f"{name}.{signal}"):
        codec.encode(name, values)


def test_encode_refuses_missing_unknown_and_non_numeric(mtq: DbcCodec) -> None:
    with pytest.raises(EncodeError, match="missing signal.*duration_ms"):
        mtq.encode("MTQ_DIPOLE_CMD", {"dipole_x": 0, "dipole_y": 0, "dipole_z": 0})
    with pytest.raises(EncodeError, match="unknown signal.*dipole_w"):
        mtq.encode(
            "MTQ_DIPOLE_CMD", {"dipole_x": 0, "dipole_y": 0, "dipole_z": 0, "duration_ms": 0, "dipole_w": 1}
        )
    with pytest.raises(EncodeError, match="Unknown message 'MTQ_NOPE'.*MAG_SAMPLE"):
        mtq.encode("MTQ_NOPE", {})
    with pytest.raises(EncodeError, match="expected a number"):
        mtq.encode("MTQ_DIPOLE_CMD", {"dipole_x": [1], "dipole_y": 0, "dipole_z": 0, "duration_ms": 0})
    with pytest.raises(EncodeError, match="not a finite number"):
        mtq.encode("MTQ_DIPOLE_CMD", {"dipole_x": math.nan, "dipole_y": 0, "dipole_z": 0, "duration_ms": 0})


def test_numpy_scalars_are_accepted(mtq: DbcCodec) -> None:
    import numpy as np

    values = {
        "dipole_x": np.float64(0.1),
        "dipole_y": np.float32(-0.05),
        "dipole_z": np.int64(0),
        "duration_ms": np.uint16(5),
    }
    plain = {k: v.item() for k, v in values.items()}
    assert mtq.encode("MTQ_DIPOLE_CMD", values) == mtq.encode("MTQ_DIPOLE_CMD", plain)


def test_decode_refuses_unknown_id_and_wrong_length_with_frame_hex(mtq: DbcCodec) -> None:
    with pytest.raises(ProtocolError) as err:
        mtq.decode(0x123, b"\xde\xad")
    e = err.value
    assert e.frame_hex == "123#DEAD"
    assert e.computed == "0x123" and "0x0A0" in e.expected
    assert "123#DEAD" in str(e) and "unknown frame id 0x123" in str(e)
    with pytest.raises(ProtocolError) as err:
        mtq.decode(0x0A0, b"\x01\x02\x03")
    e = err.value
    assert e.frame_hex == "0A0#010203"
    assert (e.expected, e.computed) == ("8 bytes", "3 bytes")
    assert "MAG_SAMPLE" in str(e) and "0A0#010203" in str(e)
    with pytest.raises(ProtocolError, match="9 bytes"):
        mtq.decode(0x0A0, bytes(9))  # cantools would silently trim excess bytes; we refuse


def test_look_ups(mtq: DbcCodec) -> None:
    assert mtq.frame_id("MAG_SAMPLE") == 0x0A0
    assert mtq.name_of(0x0A0) == "MAG_SAMPLE" and mtq.name_of(0x7FF) is None
    assert mtq.senders("MAG_SAMPLE") == ("MTQ",) and mtq.senders("MTQ_DIPOLE_CMD") == ("HOST",)
    assert mtq.cycle_time_s("MAG_SAMPLE") == 0.1 and mtq.cycle_time_s("MTQ_DIPOLE_CMD") is None
    assert mtq.choices("MTQ_MODE_CMD", "mode") == {0: "OFF", 1: "DIPOLE", 2: "SELFTEST"}
    with pytest.raises(KeyError, match="Unknown message 'X'.*MAG_SAMPLE"):
        mtq.frame_id("X")


def test_bad_dbc_file_is_reported(tmp_path: Path) -> None:
    bad = tmp_path / "bad.dbc"
    bad.write_text("BO_ this is not a dbc\n")
    with pytest.raises(ValueError, match="Cannot load DBC file .*bad.dbc"):
        DbcCodec(bad)
    with pytest.raises(FileNotFoundError):
        DbcCodec(tmp_path / "missing.dbc")


def test_fixture_path_resolves_inside_the_repo_and_names_missing_files() -> None:
    path = fixture_path("devices/magnetorquer.dbc")
    assert path.is_file() and path.parent.parent.name == "fixtures"
    with pytest.raises(FileNotFoundError, match="devices/nope.dbc.*looked at"):
        fixture_path("devices/nope.dbc")
