"""The codec layer shared by the serial devices: field and message specifications read from a TOML
ICD, and the encoding of one field's SI value to its wire value.

No port, no clock, no framing. The datagram devices (:mod:`drivers.datagram`: the gyro, the sun
sensor) and the star tracker (:mod:`drivers.star_tracker.codec`) build their messages from these
pieces, so one field type table, one range check and one error sentence serve every serial ICD.
"""

from __future__ import annotations

import math
import struct
import tomllib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import compiled_paths
from drivers.errors import EncodeError
from drivers.frozen_build import keyword_maker

_plan = compiled_paths.load("drivers.icd_plan")

__all__ = ["HOST_TO_DEVICE", "DEVICE_TO_HOST", "TYPES", "FieldSpec", "MessageSpec", "field_specs",
           "load_icd", "wire_value", "wire_values"]

HOST_TO_DEVICE = "host->device"
DEVICE_TO_HOST = "device->host"

#: Wire type -> (struct code or None for 24-bit, size, min, max).
TYPES: dict[str, tuple[str | None, int, float, float]] = {
    "u8": ("B", 1, 0, 0xFF),
    "i8": ("b", 1, -0x80, 0x7F),
    "u16": ("H", 2, 0, 0xFFFF),
    "i16": ("h", 2, -0x8000, 0x7FFF),
    "i24": (None, 3, -0x80_0000, 0x7F_FFFF),
    "u32": ("I", 4, 0, 0xFFFF_FFFF),
    "i32": ("i", 4, -0x8000_0000, 0x7FFF_FFFF),
    "u64": ("Q", 8, 0, 0xFFFF_FFFF_FFFF_FFFF),
    "f32": ("f", 4, -3.4028234663852886e38, 3.4028234663852886e38),
}


@dataclass(frozen=True)
class FieldSpec:
    name: str
    type: str
    attr: str
    index: int | None
    scale: float
    lo: float
    hi: float
    enum: tuple[str, ...] | None
    bits: tuple[str, ...] | None
    unit: str
    doc: str

    @cached_property  # read for every field of every decoded frame: an attribute after the first read
    def is_float(self) -> bool:
        return self.type == "f32"

    @property
    def size(self) -> int:
        return TYPES[self.type][1]

    @property
    def struct_code(self) -> str:
        """The field's ``struct`` code (a 24-bit field travels as 3 raw bytes)."""
        return TYPES[self.type][0] or "3s"


@dataclass(frozen=True)
class MessageSpec:
    id: int
    name: str
    direction: str
    doc: str
    fields: tuple[FieldSpec, ...]
    fmt: str
    payload_len: int
    cls: type
    #: Bytes of the whole frame around the payload (identifier, address, CRC), before any escaping.
    overhead: int = 0
    #: A telemetry message a host may request or subscribe to (the star tracker's ICD says which).
    telemetry: bool = False
    #: ``(attr, tolerance)`` of tuple attributes that must have unit norm (the ICD's ``unit_norm``).
    norms: tuple[tuple[str, float], ...] = ()

    @property
    def length(self) -> int:
        """The whole frame: payload and overhead, before any escaping."""
        return self.payload_len + self.overhead

    @cached_property  # built once: every frame is packed and unpacked with it
    def packer(self) -> struct.Struct:
        """The payload's ``struct.Struct`` (``fmt``)."""
        return struct.Struct(self.fmt)

    @cached_property  # built once: the per-frame loops of wire_values and decode_fields read only this
    def plan(self) -> tuple[tuple[Any, ...], ...]:
        """Per field, in payload order, what encoding and decoding a frame need (:func:`field_plan`)."""
        return tuple(field_plan(f) for f in self.fields)

    @cached_property  # built once: every decoded frame is made with it
    def make(self) -> Callable[[dict[str, Any]], Any]:
        """``make(kw)``: the message ``cls(**kw)`` from a dict holding every field (drivers.frozen_build)."""
        return keyword_maker(self.cls)

    @cached_property
    def tuple_attrs(self) -> tuple[tuple[str, int], ...]:
        """``(attr, length)`` of every tuple attribute (fields with an ``index``), in field order."""
        lengths: dict[str, int] = {}
        for f in self.fields:
            if f.index is not None:
                lengths[f.attr] = max(lengths.get(f.attr, 0), f.index + 1)
        return tuple(lengths.items())


_FLOAT_MAX = 1.7976931348623157e308


def field_plan(f: FieldSpec) -> Any:
    """What the per-frame loops (:mod:`drivers.icd_plan`) need of field ``f``, built once per message: a
    ``FieldPlan``. An f32 field's bounds are clipped to the finite floats, so one range test also says a value is
    finite (NaN and inf fail it, as the checks require); an enumeration's names are those a value may be given as
    exactly (the checks compare the upper-cased value with the table)."""
    index = -1 if f.index is None else f.index
    if f.bits is not None:
        return _plan.FieldPlan(_plan.BITS, f.attr, index, f.scale, f.lo, f.hi,
                               tuple((bit, 1 << i) for i, bit in enumerate(f.bits)), (), {}, f)
    if f.enum is not None:
        names: dict[str, int] = {}
        for i, n in enumerate(f.enum):
            if n.upper() == n:
                names.setdefault(n, i)
        return _plan.FieldPlan(_plan.ENUM, f.attr, index, f.scale, f.lo, f.hi, (), f.enum, names, f)
    if f.is_float:
        return _plan.FieldPlan(_plan.F32, f.attr, index, f.scale, max(f.lo, -_FLOAT_MAX), min(f.hi, _FLOAT_MAX),
                               (), (), {}, f)
    return _plan.FieldPlan(_plan.I24 if f.type == "i24" else _plan.INT, f.attr, index, f.scale, f.lo, f.hi, (), (),
                           {}, f)


def load_icd(path: str | Path) -> dict[str, Any]:
    """The ICD TOML as a dict."""
    with open(path, "rb") as f:
        return tomllib.load(f)


def field_specs(m: dict[str, Any], enums: dict[str, tuple[str, ...]], where: str) -> tuple[list[FieldSpec], set[str]]:
    """The fields of the ICD message ``m`` and the dataclass attributes they cover; ValueError (naming
    ``where``, the field and what is allowed) for a type or a range the wire cannot carry."""
    specs = []
    covered: set[str] = set()
    for f in m.get("fields", []):
        if f["type"] not in TYPES:
            raise ValueError(f"{where}: field {f['name']} has type {f['type']!r}; allowed: {', '.join(TYPES)}.")
        _, _, tlo, thi = TYPES[f["type"]]
        enum = tuple(enums[f["enum"]]) if "enum" in f else None
        bits = tuple(f["bits"]) if "bits" in f else None
        if f["type"] == "f32":
            lo, hi = float(f.get("min", tlo)), float(f.get("max", thi))
        else:
            lo, hi = int(f.get("min", tlo)), int(f.get("max", thi))
            if not tlo <= lo <= hi <= thi:
                raise ValueError(f"{where}: field {f['name']} range {lo}..{hi} does not fit {f['type']}.")
        if enum is not None:
            hi = len(enum) - 1
        if bits is not None:
            hi = (1 << len(bits)) - 1
            covered.update(bits)
        else:
            covered.add(f["attr"])
        specs.append(FieldSpec(f["name"], f["type"], f.get("attr", ""), f.get("index"), float(f.get("scale", 1.0)),
                               lo, hi, enum, bits, f.get("unit", ""), f.get("doc", "")))
    return specs, covered


# -- encoding one field ---------------------------------------------------------------------------


def wire_values(spec: MessageSpec, msg: Any, message: str, byte_order: str = "little") -> list[Any]:
    """The wire values of every field of ``msg`` (a ``spec.cls``), in payload order (:func:`wire_value`).

    Every frame of every device passes here, so the plain case (True/False flags, an enumeration name or index, a
    float or int whose wire value lies inside its field) is taken straight from the message's plan
    (:mod:`drivers.icd_plan`), field after field; the first field that is not plain goes to :func:`wire_value`,
    which converts it or says what is wrong, and the plan goes on after it: the same values and the same errors,
    field by field in payload order, with the checks' calls made only where they are needed."""
    out: list[Any] = []
    plan = spec.plan
    i = _plan.plain_wire_values(plan, msg, byte_order, out, 0)
    while i >= 0:
        out.append(wire_value(spec.fields[i], msg, message, byte_order))
        i = _plan.plain_wire_values(plan, msg, byte_order, out, i + 1)
    return out


def wire_value(f: FieldSpec, msg: Any, message: str, byte_order: str = "little") -> Any:
    """The wire value of field ``f`` of ``msg`` (an int, a float, or 3 bytes for i24); EncodeError naming
    ``message`` (the device and message) and the field, the value and what is allowed.

    A plain int or float inside its field takes the straight way; anything else goes through the checks that
    convert it or say what is wrong."""
    if f.bits is not None:
        return _flags(f, msg, f"{message}.{f.name}")
    value = getattr(msg, f.attr)
    index = f.index
    if index is not None:
        try:
            value = value[index]
        except (TypeError, IndexError):
            raise _not_a_sequence(f, value, message) from None
    if f.enum is not None:
        return _enum_index(f, value, f"{message}.{f.name}")
    kind = type(value)
    wire = value if kind is float or kind is int else _number(value, f"{message}.{f.name}")
    if f.scale != 1.0:
        wire = wire / f.scale
    if f.is_float:
        if type(wire) is float and f.lo <= wire <= f.hi and math.isfinite(wire):
            return wire
        return _float_wire(f, wire, value, f"{message}.{f.name}")
    if type(wire) is int:
        n = wire
    else:
        n = round(wire) if math.isfinite(wire) else None
    if n is None or not f.lo <= n <= f.hi:
        n = _int_wire(f, wire, value, f"{message}.{f.name}")  # says why (it does not return here)
    if f.type == "i24":
        return n.to_bytes(3, byte_order, signed=True)
    return n


def _flags(f: FieldSpec, msg: Any, where: str) -> int:
    v = 0
    for i, bit in enumerate(f.bits or ()):
        flag = getattr(msg, bit)
        if type(flag) is not bool and not isinstance(flag, int) and type(flag).__name__ != "bool_":
            raise EncodeError(f"{where}: {bit} = {flag!r} is not a flag; allowed: True or False.")
        if flag:
            v |= 1 << i
    return v


def _not_a_sequence(f: FieldSpec, value: Any, message: str) -> EncodeError:
    return EncodeError(f"{message}.{f.name}: {f.attr} must be a sequence with an element {f.index}; got {value!r}.")


def _enum_index(f: FieldSpec, value: Any, where: str) -> int:
    table = f.enum or ()
    if isinstance(value, str) and value.upper() in table:
        return table.index(value.upper())
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < len(table):
        return value
    allowed = ", ".join(f"{n!r} ({i})" for i, n in enumerate(table))
    raise EncodeError(f"{where} = {value!r} is not allowed; allowed: {allowed}.")


def _number(value: Any, where: str) -> int | float:
    t = type(value)
    if t is int or t is float:
        return value
    if isinstance(value, int) and not isinstance(value, bool):
        return int(value)
    try:
        return float(value)
    except (TypeError, ValueError):
        raise EncodeError(f"{where} = {value!r} is not a number.") from None


def _si(f: FieldSpec, value: Any) -> str:
    return f" ({f.attr} = {value!r} SI)" if f.scale != 1.0 else ""


def _float_wire(f: FieldSpec, wire: int | float, value: Any, where: str) -> float:
    try:
        x = float(wire)
    except OverflowError:  # an int too large for a float is outside any f32 field
        x = math.inf
    if not (math.isfinite(x) and f.lo <= x <= f.hi):
        raise EncodeError(f"{where} = {wire!r}{_si(f, value)} is outside the field: allowed a finite number from "
                          f"{f.lo:g} to {f.hi:g}.")
    return x


def _int_wire(f: FieldSpec, wire: int | float, value: Any, where: str) -> int:
    if isinstance(wire, float) and not math.isfinite(wire):
        raise EncodeError(f"{where} = {wire!r}{_si(f, value)} is not finite; allowed: {f.lo} to {f.hi} "
                          f"{f.unit}.".replace(" .", "."))
    n = round(wire)
    if not f.lo <= n <= f.hi:
        extra = f"; in SI {f.lo * f.scale:.6g} to {f.hi * f.scale:.6g}" if f.scale != 1.0 else ""
        raise EncodeError(f"{where} = {wire!r}{_si(f, value)} is outside the field: allowed {f.lo} to {f.hi} "
                          f"({f.type}{extra}).")
    return n


# -- the message table and the ICD document --------------------------------------------------------


def index_messages(specs: Iterable[MessageSpec], names: Iterable[str], what: str,
                   id_word: str) -> tuple[dict[str, MessageSpec], dict[int, MessageSpec]]:
    """``(by name, by id)`` of ``specs``; ValueError (naming ``what``) for an id used twice or a set of
    messages that differs from the codec's dataclasses ``names``."""
    messages: dict[str, MessageSpec] = {}
    by_id: dict[int, MessageSpec] = {}
    for spec in specs:
        if spec.id in by_id:
            raise ValueError(f"{what}: {id_word} 0x{spec.id:02X} is used twice.")
        messages[spec.name] = spec
        by_id[spec.id] = spec
    if set(messages) != set(names):
        raise ValueError(f"{what}: messages {sorted(messages)} differ from the codec's {sorted(names)}.")
    return messages, by_id


def range_text(f: FieldSpec) -> str:
    """What a field may carry, for the ICD document's tables."""
    if f.enum is not None:
        return ", ".join(f"{i} {n}" for i, n in enumerate(f.enum))
    if f.bits is not None:
        return ", ".join(f"bit {i} {n}" for i, n in enumerate(f.bits))
    if f.is_float:
        return "finite" if (f.lo, f.hi) == TYPES["f32"][2:] else f"finite, {f.lo:g}..{f.hi:g}"
    return f"{f.lo}..{f.hi}"


def attr_text(f: FieldSpec) -> str:
    """The SI attribute(s) a field maps to, for the ICD document's tables."""
    if f.bits is not None:
        return ", ".join(f.bits)
    return f.attr if f.index is None else f"{f.attr}[{f.index}]"


# -- decoding a payload ---------------------------------------------------------------------------


def decode_fields(spec: MessageSpec, raw: Sequence[Any], exc: Callable[..., Exception], frame: str | bytes,
                  prefix: str = "") -> Any:
    """The message of ``spec`` from its unpacked wire values ``raw`` (SI units; a 24-bit field already an int).

    A value outside its table or range raises ``exc("value", reason, frame_hex=..., expected=..., computed=...)``
    (the device codec's rejection), the reason naming ``prefix`` (the device), the message and the field;
    ``frame`` is the frame in hex, or its bytes (made hex only when a value is refused).
    """
    kw: dict[str, Any] = {}
    tuple_attrs = spec.tuple_attrs
    for attr, n in tuple_attrs:  # filled element by element, made tuples at the end
        kw[attr] = [None] * n
    i = _plan.decode_plain(spec.plan, raw, kw)
    if i >= 0:
        raise _value_refused(spec, spec.fields[i], raw[i], exc, frame, prefix)
    if len(raw) != len(spec.fields):  # the caller's struct gave another count: a defect, not a bad frame
        raise ValueError(f"{prefix}{spec.name}: {len(raw)} wire values for {len(spec.fields)} fields.")
    for attr, _ in tuple_attrs:
        kw[attr] = tuple(kw[attr])
    if spec.norms:
        _check_norms(spec, kw, exc, frame, prefix)
    return spec.make(kw)


def _value_refused(spec: MessageSpec, f: FieldSpec, v: Any, exc: Callable[..., Exception], frame: str | bytes,
                   prefix: str) -> Exception:
    """The rejection of a wire value ``v`` outside field ``f``'s flags, table or range."""
    where = f"{prefix}{spec.name}.{f.name}"
    if f.bits is not None:
        return _refused(exc, frame, f"{where} = 0x{v:X} has undefined bits set", f"<= 0x{f.hi:X}", f"0x{v:X}")
    if f.enum is not None:
        return _refused(exc, frame, f"{where} = {v} is not in its table", f"0..{len(f.enum) - 1}", v)
    return _refused(exc, frame, f"{where} = {v!r} is outside its range",
                    f"a finite number from {f.lo:g} to {f.hi:g}" if f.is_float else f"{f.lo}..{f.hi}", v)


def _check_norms(spec: MessageSpec, kw: dict[str, Any], exc: Callable[..., Exception], frame: str | bytes,
                 prefix: str) -> None:
    for attr, tol in spec.norms:
        norm = norm2(kw[attr])
        if not abs(norm - 1.0) <= tol:
            raise _refused(exc, frame, f"{prefix}{spec.name}.{attr} has norm {norm:.9g}, not a unit quaternion",
                           f"1 within {tol:g}", f"{norm:.9g}")


#: The Euclidean norm of a few numbers, summed in order (a unit-norm check on a decoded or encoded tuple): one
#: typed loop in :mod:`drivers.icd_plan`.
norm2 = _plan.norm2


def _refused(exc: Callable[..., Exception], frame: str | bytes, reason: str, expected: str, computed: Any) -> Exception:
    frame_hex = frame if isinstance(frame, str) else bytes(frame).hex().upper()
    return exc("value", reason, frame_hex=frame_hex, expected=expected, computed=computed)


def md_head(*columns: str) -> list[str]:
    """A Markdown table's header and rule."""
    return ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]


def enums_doc(enums: dict[str, tuple[str, ...]]) -> list[str]:
    """The ICD document's section of enumeration tables."""
    out = ["", "## Enumerations", "", *md_head("enumeration", "values")]
    for name, values in enums.items():
        out.append(f"| {name} | {', '.join(f'{i} {v}' for i, v in enumerate(values))} |")
    return out


def messages_doc(specs: Iterable[MessageSpec], title: str, columns: tuple[str, str, str],
                 size: Callable[[MessageSpec], int]) -> list[str]:
    """The ICD document's list of messages: ``columns`` names the id, the message and the size column."""
    out = ["", f"## {title}", "", *md_head(columns[0], columns[1], "direction", columns[2], "description")]
    out += [f"| 0x{s.id:02X} | {s.name} | {s.direction} | {size(s)} | {s.doc} |" for s in specs]
    return out


def message_heading(s: MessageSpec) -> list[str]:
    """The heading of one message's field table."""
    return ["", f"### {s.name} (0x{s.id:02X}, {s.direction})", ""]
