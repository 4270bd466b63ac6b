"""The cage register map: the committed document equals the one generated from the TOML, the codec
round-trips every register, and a broken map is refused with a sentence naming the entry."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.cage.register_doc import render
from drivers.cage.registers import load_map
from drivers.errors import EncodeError

REPO = Path(__file__).resolve().parents[2]
MAP = load_map()


def test_committed_document_equals_the_generated_one():
    doc = REPO / "docs" / "cage_register_map.md"
    assert doc.read_text() == render(), "regenerate: python -m drivers.cage.register_doc > docs/cage_register_map.md"


def test_every_register_name_ends_in_its_unit_or_is_a_plain_count():
    for table in ("holding", "input"):
        for r in MAP.table(table).values():
            if r.scale != 1.0:
                assert r.unit, f"{r.name} is scaled but its name does not end in a unit"
            assert r.bits is None or r.enum is None


_regs = st.sampled_from([r for t in ("holding", "input") for r in MAP.table(t).values()])


@given(_regs, st.data())
def test_round_trip_of_every_register(reg, data):
    lo, hi = reg.raw_range
    raw = data.draw(st.integers(lo, hi))
    words = reg.words_from_raw(raw)
    assert len(words) == reg.words and all(0 <= w <= 0xFFFF for w in words)
    assert reg.raw_from_words(words) == raw
    value = reg.decode(words)
    if reg.bits is None and (reg.enum is None or raw >= len(reg.enum)):
        assert reg.encode(value) == words
    elif reg.bits is not None and raw < (1 << len(reg.bits)):
        assert reg.encode(value) == words


@given(st.floats(-2147.48, 2147.48, allow_nan=False))
def test_si_encoding_is_within_half_a_count(x):
    reg = MAP.input["current_x_A"]
    assert abs(reg.decode(reg.encode(x)) - x) <= reg.scale / 2 + 1e-12


def test_32_bit_values_are_high_word_first_and_twos_complement():
    reg = MAP.input["current_x_A"]
    assert reg.encode(-1e-6) == [0xFFFF, 0xFFFF]
    assert reg.encode(65536e-6) == [1, 0]


@pytest.mark.parametrize("value", [math.nan, math.inf, 7.0, -0.1, "a"])
def test_values_a_register_cannot_carry_are_refused_naming_it(value):
    with pytest.raises(EncodeError, match="current_setpoint_x_A"):
        MAP.holding["current_setpoint_x_A"].encode(value)


def test_contiguous_encoding_and_its_refusal():
    start, words = MAP.encode("holding", {"polarity_request": {"negative_y"}, "current_setpoint_x_A": 1.0,
                                          "current_setpoint_y_A": 0.5, "current_setpoint_z_A": 0.0, "heartbeat": 9})
    assert (start, words) == (1, [2, 10000, 5000, 0, 9])
    with pytest.raises(EncodeError, match="contiguous"):
        MAP.encode("holding", {"output_enable": 1, "heartbeat": 2})


@pytest.mark.parametrize("edit, message", [
    (("address = 3\nname = \"current_setpoint_y_A\"", "address = 2\nname = \"current_setpoint_y_A\""),
     "belongs to both"),
    (("type = \"i32\"\nscale = 1e-6\ndoc = \"Measured", "type = \"f64\"\nscale = 1e-6\ndoc = \"Measured"),
     "type 'f64'"),
    (("name = \"heartbeat\"", "name = \"heartbeat\"\nunits = \"none\""), "unknown key"),
])
def test_a_broken_map_is_refused_naming_the_entry(tmp_path, edit, message):
    text = (REPO / "fixtures" / "devices" / "cage.toml").read_text()
    assert edit[0] in text
    path = tmp_path / "cage.toml"
    path.write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(ValueError, match=message):
        load_map(path)


_any_value = st.one_of(
    st.none(), st.booleans(), st.integers(), st.integers(min_value=10**308, max_value=10**400),
    st.floats(), st.floats(min_value=1e300), st.complex_numbers(), st.text(max_size=12), st.binary(max_size=8),
    st.sampled_from(["none", "x", "negative_x", "output_on", "3", "1e400", "nan"]),
    st.lists(st.one_of(st.text(max_size=12), st.integers(), st.lists(st.integers(), max_size=2)), max_size=4),
    st.frozensets(st.sampled_from(["negative_x", "negative_y", "output_on", "bogus"])),
    st.dictionaries(st.text(max_size=4), st.integers(), max_size=2), st.builds(object),
)


@given(_regs, _any_value)
def test_encode_of_any_value_gives_words_or_an_encode_error(reg, value):
    """Issue 22: out-of-range or wrong-type values raised OverflowError / TypeError from the codec."""
    try:
        words = reg.encode(value)
    except EncodeError as exc:
        assert reg.name in str(exc)
        return
    assert len(words) == reg.words and all(isinstance(w, int) and 0 <= w <= 0xFFFF for w in words)


@given(_regs, st.one_of(st.integers(), st.floats(), st.text(max_size=4), st.none(), st.builds(object)))
def test_words_from_raw_of_any_value_gives_words_or_an_encode_error(reg, raw):
    try:
        words = reg.words_from_raw(raw)
    except EncodeError as exc:
        assert reg.name in str(exc)
        return
    assert isinstance(raw, int) and reg.raw_from_words(words) == raw


@given(st.dictionaries(st.sampled_from([*MAP.holding, "no_such_register"]), _any_value, max_size=6))
def test_map_encode_of_any_values_gives_words_or_an_encode_error(values):
    try:
        start, words = MAP.encode("holding", values)
    except EncodeError:
        return
    assert 0 <= start and all(0 <= w <= 0xFFFF for w in words)
