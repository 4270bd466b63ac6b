"""The cage's Modbus register map, read from ``fixtures/devices/cage.toml``: a pure codec between
register words and SI values (no port, no clock). Its document, ``docs/cage_register_map.md``, is
generated from the same file by :mod:`drivers.cage.register_doc`.

Words are 16-bit unsigned integers as Modbus carries them; 32-bit values take two words, high
word first. ``Register.encode(si) -> words`` and ``Register.decode(words) -> value`` round-trip to
one count (exactly for integer, bit and enum registers). Decoded values are SI floats for scaled
registers, ``int`` for plain counters, ``frozenset`` of bit names for bit registers and the name
for enum registers.
"""

from __future__ import annotations

import math
import operator
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drivers.errors import EncodeError

__all__ = ["TABLES", "Register", "RegisterMap", "default_map_path", "load_map"]

#: Register tables of the map, as named in the TOML, and the Modbus function codes that read them.
TABLES = {"holding": 3, "input": 4}

_TYPES = {  # name -> (words, signed)
    "u16": (1, False),
    "i16": (1, True),
    "u32": (2, False),
    "i32": (2, True),
}


_UNITS = (("_A_s", "A/s"), ("_A", "A"), ("_T", "T"), ("_s", "s"), ("_C", "degC"), ("_V", "V"))


def default_map_path() -> Path:
    """``fixtures/devices/cage.toml``."""
    from drivers import fixture_path

    return fixture_path("devices/cage.toml")


@dataclass(frozen=True)
class Register:
    """One register (or pair of registers) of the map."""

    table: str
    address: int
    name: str
    type: str
    scale: float = 1.0
    doc: str = ""
    bits: tuple[str, ...] | None = None
    enum: tuple[str, ...] | None = None
    values: tuple[int, ...] | None = None
    values_max: int | None = None

    @property
    def words(self) -> int:
        return _TYPES[self.type][0]

    @property
    def signed(self) -> bool:
        return _TYPES[self.type][1]

    @property
    def raw_range(self) -> tuple[int, int]:
        bits = 16 * self.words
        return (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if self.signed else (0, (1 << bits) - 1)

    @property
    def si_range(self) -> tuple[float, float]:
        lo, hi = self.raw_range
        return lo * self.scale, hi * self.scale

    @property
    def unit(self) -> str:
        """The SI unit the name ends in (``"A"`` for ``current_x_A``), or ``""``."""
        for suffix, unit in _UNITS:
            if self.name.endswith(suffix):
                return unit
        return ""

    def accepts(self, raw: int) -> bool:
        """Whether a write of the raw value ``raw`` is allowed (exception 3 otherwise)."""
        if self.values is not None and raw not in self.values:
            return False
        return self.values_max is None or raw <= self.values_max

    def allowed(self) -> str:
        """What a write may carry, as a phrase."""
        if self.values is not None:
            return "one of " + ", ".join(str(v) for v in self.values)
        if self.values_max is not None:
            return f"0..{self.values_max}"
        lo, hi = self.raw_range
        return f"{lo}..{hi}"

    # -- raw integer <-> words -------------------------------------------------------------------

    def raw_from_words(self, words: Sequence[int]) -> int:
        if len(words) != self.words:
            raise ValueError(f"{self.name} takes {self.words} register(s); got {len(words)}.")
        v = 0
        for w in words:
            v = (v << 16) | (int(w) & 0xFFFF)
        if self.signed and v >= 1 << (16 * self.words - 1):
            v -= 1 << (16 * self.words)
        return v

    def words_from_raw(self, raw: int) -> list[int]:
        lo, hi = self.raw_range
        try:
            raw = operator.index(raw)  # a whole number only: a float or a string has no counts
        except TypeError:
            raise EncodeError(f"{self.name} = {raw!r} is not a whole number of counts; give an integer in "
                              f"{lo}..{hi}.") from None
        if not lo <= raw <= hi:
            raise EncodeError(f"{self.name} = {raw!r} counts is outside its {self.type} range {lo}..{hi}.")
        v = raw & ((1 << (16 * self.words)) - 1)
        return [(v >> (16 * (self.words - 1 - i))) & 0xFFFF for i in range(self.words)]

    # -- SI <-> words ----------------------------------------------------------------------------

    def encode(self, value: Any) -> list[int]:
        """Words for ``value``: SI float (scaled), int, bit names (bits) or a name (enum).

        Raises EncodeError (a ValueError) naming the register, the value and the allowed range.
        """
        if self.bits is not None and not isinstance(value, int | float):
            return self._encode_bits(value)
        if self.enum is not None and isinstance(value, str):
            if value not in self.enum:
                raise EncodeError(f"{self.name} = {value!r} is not one of {', '.join(self.enum)}.")
            return self.words_from_raw(self.enum.index(value))
        try:
            x = float(value)
        except (TypeError, ValueError, OverflowError):  # OverflowError: an int beyond a float's range
            raise EncodeError(f"{self.name} = {value!r:.80} is not a number in {self._si_phrase()}.") from None
        if not math.isfinite(x):
            raise EncodeError(f"{self.name} = {value!r} is not finite; give a number in {self._si_phrase()}.")
        counts = x / self.scale
        lo, hi = self.raw_range
        # compare before rounding: a huge x over a tiny scale is inf here, and round(inf) overflows
        if not lo - 0.5 <= counts <= hi + 0.5 or not lo <= (raw := round(counts)) <= hi:
            raise EncodeError(f"{self.name} = {value!r} is outside what the register carries, {self._si_phrase()}.")
        return self.words_from_raw(raw)

    def _encode_bits(self, value: Any) -> list[int]:
        assert self.bits is not None
        try:
            names = set(value)
        except TypeError:  # not iterable, or an unhashable member
            raise EncodeError(f"{self.name} = {value!r:.80} is not a set of bit names; known: "
                              f"{', '.join(self.bits)}.") from None
        unknown = names - set(self.bits)
        if unknown:
            shown = sorted(repr(n) for n in unknown)[:8]
            raise EncodeError(f"{self.name}: unknown bit(s) {', '.join(shown)}; known: {', '.join(self.bits)}.")
        return self.words_from_raw(sum(1 << i for i, b in enumerate(self.bits) if b in names))

    def _si_phrase(self) -> str:
        lo, hi = self.si_range
        return f"{lo:g}..{hi:g} {self.unit}".rstrip()

    def decode(self, words: Sequence[int]) -> Any:
        raw = self.raw_from_words(words)
        if self.bits is not None:
            return frozenset(b for i, b in enumerate(self.bits) if raw >> i & 1)
        if self.enum is not None:
            return self.enum[raw] if raw < len(self.enum) else raw
        if self.scale == 1.0:
            return raw
        return raw * self.scale


@dataclass(frozen=True)
class RegisterMap:
    """The map: ``holding`` and ``input`` tables, each ``name -> Register``, plus the header."""

    path: Path
    device: Mapping[str, Any]
    axes: tuple[str, ...]
    frame: str
    holding: Mapping[str, Register]
    input: Mapping[str, Register]
    _by_address: Mapping[str, Mapping[int, Register]] = field(repr=False)

    @property
    def version(self) -> str:
        return str(self.device["version"])

    @property
    def function_codes(self) -> tuple[int, ...]:
        """The Modbus function codes the map supports (the leading number of each item of
        ``device.function_codes``); every other function gets exception 1 and applies nothing."""
        return tuple(int(item.split()[0]) for item in str(self.device["function_codes"]).split(","))

    @property
    def version_word(self) -> int:
        major, _, minor = self.version.partition(".")
        return int(major) * 256 + int(minor or 0)

    def table(self, table: str) -> Mapping[str, Register]:
        if table not in TABLES:
            raise ValueError(f"table {table!r} is not one of {', '.join(TABLES)}.")
        return self.holding if table == "holding" else self.input

    def size(self, table: str) -> int:
        """Number of registers from address 0 to the end of the last one."""
        return max(r.address + r.words for r in self.table(table).values())

    def at(self, table: str, address: int) -> Register | None:
        """The register starting at ``address``, or None."""
        return self._by_address[table].get(address)

    def covering(self, table: str, address: int) -> Register | None:
        """The register that word ``address`` belongs to, or None (a gap)."""
        for back in (0, 1):
            r = self._by_address[table].get(address - back)
            if r is not None and address < r.address + r.words:
                return r
        return None

    def decode(self, table: str, start: int, words: Sequence[int]) -> dict[str, Any]:
        """Every register lying wholly inside ``words`` (read from ``start``), by name."""
        out: dict[str, Any] = {}
        end = start + len(words)
        for r in self.table(table).values():
            if r.address >= start and r.address + r.words <= end:
                out[r.name] = r.decode(words[r.address - start : r.address - start + r.words])
        return out

    def encode(self, table: str, values: Mapping[str, Any]) -> tuple[int, list[int]]:
        """``(start, words)`` for registers given by name, which must be contiguous."""
        tab = self.table(table)
        unknown = [n for n in values if n not in tab]
        if unknown:
            raise EncodeError(f"{unknown[0]!r:.80} is not a {table} register; known: {', '.join(tab)}.")
        regs = sorted((tab[n] for n in values), key=lambda r: r.address)
        if not regs:
            raise EncodeError("nothing to encode: give at least one register.")
        words: list[int] = []
        start = regs[0].address
        for r in regs:
            if r.address != start + len(words):
                raise EncodeError(f"{r.name} (address {r.address}) does not follow on from the previous register "
                                  f"(next free address {start + len(words)}); write contiguous registers only.")
            words += r.encode(values[r.name])
        return start, words


def _register(table: str, entry: Mapping[str, Any], where: str) -> Register:
    known = {"address", "name", "type", "scale", "doc", "bits", "enum", "values", "values_max"}
    extra = set(entry) - known
    if extra:
        raise ValueError(f"{where}: unknown key(s) {sorted(extra)}; allowed: {', '.join(sorted(known))}.")
    if entry.get("type") not in _TYPES:
        raise ValueError(f"{where}: type {entry.get('type')!r} is not one of {', '.join(_TYPES)}.")
    reg = Register(
        table=table,
        address=int(entry["address"]),
        name=str(entry["name"]),
        type=entry["type"],
        scale=float(entry.get("scale", 1.0)),
        doc=" ".join(str(entry.get("doc", "")).split()),
        bits=tuple(entry["bits"]) if "bits" in entry else None,
        enum=tuple(entry["enum"]) if "enum" in entry else None,
        values=tuple(int(v) for v in entry["values"]) if "values" in entry else None,
        values_max=int(entry["values_max"]) if "values_max" in entry else None,
    )
    if not 0 <= reg.address <= 0xFFFF - reg.words + 1:
        raise ValueError(f"{where}: address {reg.address} is outside 0..65535.")
    if (reg.bits or reg.enum) and reg.type != "u16":
        raise ValueError(f"{where}: bits and enum registers must be u16; {reg.name} is {reg.type}.")
    if reg.bits is not None and len(reg.bits) > 16:
        raise ValueError(f"{where}: {reg.name} names {len(reg.bits)} bits; a u16 has 16.")
    if not (math.isfinite(reg.scale) and reg.scale > 0):
        raise ValueError(f"{where}: scale {reg.scale!r} must be a positive number.")
    return reg


def load_map(path: str | Path | None = None) -> RegisterMap:
    """Read and check a register map (default: the ICD in ``fixtures/devices/cage.toml``).

    Raises ValueError naming the entry for unknown keys, types, overlapping or duplicate registers.
    """
    p = Path(path) if path is not None else default_map_path()
    data = tomllib.loads(p.read_text())
    tables: dict[str, dict[str, Register]] = {}
    by_address: dict[str, dict[int, Register]] = {}
    names: set[str] = set()
    for table in TABLES:
        regs = [_register(table, e, f"{p.name} [[{table}]] #{i}") for i, e in enumerate(data.get(table, []))]
        if not regs:
            raise ValueError(f"{p.name}: the map has no [[{table}]] registers.")
        used: dict[int, str] = {}
        for r in regs:
            if r.name in names:
                raise ValueError(f"{p.name}: register name {r.name!r} is used twice.")
            names.add(r.name)
            for a in range(r.address, r.address + r.words):
                if a in used:
                    raise ValueError(f"{p.name}: {table} address {a} belongs to both {used[a]} and {r.name}.")
                used[a] = r.name
        tables[table] = {r.name: r for r in sorted(regs, key=lambda r: r.address)}
        by_address[table] = {r.address: r for r in regs}
    axes = data["axes"]
    return RegisterMap(p, dict(data["device"]), tuple(axes["names"]), str(axes["frame"]), tables["holding"],
                       tables["input"], by_address)
