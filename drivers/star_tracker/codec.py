"""Pure codec of the serial star tracker, built from ``fixtures/devices/star_tracker.toml``.

No port, no clock. The frame layout, message ids, field types, scaling, ranges, enum tables,
flag bits and parameters all come from the TOML; this module holds the dataclasses (SI units) and
checks at load time that their attributes are exactly the ones the TOML maps fields to, so the ICD
and the code cannot drift apart.

Frame (before SLIP escaping): ``address u8 | message id u8 | payload | CRC-16/CCITT-FALSE u16 LE``,
the CRC over address..payload; on the wire ``END body-escaped END``.

``encode(msg, address) -> bytes`` (a whole SLIP frame); ``decode_body(body, address) -> msg``
raises :class:`FrameRejected` (a :class:`~drivers.errors.ProtocolError`) with the frame in hex, a
``kind`` (``short``, ``crc``, ``address``, ``unknown_id``, ``direction``, ``length``, ``value``) and
expected vs computed (the CRC, the address, the length). Encoding a value outside its field raises
:class:`~drivers.errors.EncodeError` naming the message, the field, the value and the range.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from drivers.errors import DriverError, EncodeError, ProtocolError
from drivers.framing import check_crc16_spec, crc16, escape
from drivers.icd_codec import (
    DEVICE_TO_HOST,
    HOST_TO_DEVICE,
    FieldSpec,
    MessageSpec,
    decode_fields,
    field_specs,
    index_messages,
    norm2,
    wire_value,
    wire_values,
)
from drivers.icd_codec import load_icd as _load_icd

__all__ = [
    "Ack",
    "Action",
    "FieldSpec",
    "FrameRejected",
    "GetParam",
    "Message",
    "MessageSpec",
    "Nack",
    "NackError",
    "ParamSpec",
    "ParamValue",
    "RequestTelemetry",
    "SetParam",
    "Solution",
    "StarTrackerCodec",
    "Status",
    "Subscribe",
    "Unsubscribe",
    "crc16",
    "default_icd_path",
]

# -- messages (SI units) ------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SetParam:
    """Set parameter ``param_id`` to ``value`` (the parameter's wire unit; see :meth:`StarTrackerCodec.set_param`)."""

    param_id: int
    value: float


@dataclass(frozen=True, slots=True)
class GetParam:
    param_id: int


@dataclass(frozen=True, slots=True)
class RequestTelemetry:
    """Ask for telemetry message ``telemetry_id`` (the message id of SOLUTION or STATUS)."""

    telemetry_id: int


@dataclass(frozen=True, slots=True)
class Action:
    """``"BOOT"``, ``"SET_TIME"`` (``argument`` = device time, us) or ``"RESET_COUNTERS"``."""

    action: str
    argument: int = 0


@dataclass(frozen=True, slots=True)
class Subscribe:
    """Publish ``telemetry_id`` every ``period_s`` (0 = every new solution)."""

    telemetry_id: int
    period_s: float


@dataclass(frozen=True, slots=True)
class Unsubscribe:
    telemetry_id: int


@dataclass(frozen=True, slots=True)
class Ack:
    command_id: int


@dataclass(frozen=True, slots=True)
class Nack:
    command_id: int
    error: str


@dataclass(frozen=True, slots=True)
class ParamValue:
    param_id: int
    value: float


@dataclass(frozen=True, slots=True)
class Solution:
    """Attitude solution: ``q_TN`` of the tracker frame relative to GCRS, scalar first; mid-exposure
    ``time_us`` in the device clock; 1-sigma errors across and about the boresight (rad)."""

    time_us: int
    q_TN: tuple[float, float, float, float]
    sigma_cross_rad: float
    sigma_roll_rad: float
    stars_centroided: int
    stars_matched: int
    mode: str
    valid: bool
    sun_in_field: bool
    moon_in_field: bool
    earth_in_field: bool
    rate_too_high: bool
    time_synced: bool
    stable_count: int
    temperature_C: float
    seq: int


@dataclass(frozen=True, slots=True)
class Status:
    """Device status and counters (each wraps at its field width)."""

    time_us: int
    uptime_s: float
    mode: str
    time_synced: bool
    subscribed_solution: bool
    subscribed_status: bool
    frames_received: int
    frames_sent: int
    rejected_crc: int
    rejected_other: int
    commands_nacked: int
    solutions: int
    temperature_C: float


Message = (
    SetParam | GetParam | RequestTelemetry | Action | Subscribe | Unsubscribe | Ack | Nack | ParamValue | Solution
    | Status
)

#: Message name in the ICD -> dataclass.
CLASSES: dict[str, type] = {
    "SET_PARAM": SetParam,
    "GET_PARAM": GetParam,
    "REQUEST_TELEMETRY": RequestTelemetry,
    "ACTION": Action,
    "SUBSCRIBE": Subscribe,
    "UNSUBSCRIBE": Unsubscribe,
    "ACK": Ack,
    "NACK": Nack,
    "PARAM_VALUE": ParamValue,
    "SOLUTION": Solution,
    "STATUS": Status,
}


# -- errors -------------------------------------------------------------------------------------


class FrameRejected(ProtocolError):
    """A frame body cannot be accepted; ``kind`` says why (short, crc, address, unknown_id,
    direction, length, value)."""

    def __init__(self, kind: str, reason: str, **kw: Any) -> None:
        super().__init__(reason, **kw)
        self.kind = kind


def _hex(frame: bytes) -> str:
    """A frame as an error names it (made only when a frame is refused)."""
    return frame.hex().upper()


def _field_error(spec: MessageSpec, msg: Any, exc: Exception) -> EncodeError:
    """The field of ``msg`` whose value cannot be encoded at all (``exc``, not an EncodeError), named."""
    for f in spec.fields:
        try:
            wire_value(f, msg, spec.name)
        except EncodeError:
            continue
        except Exception as field_exc:  # noqa: BLE001 - this field's value is the odd object
            return EncodeError(f"{spec.name}.{f.name}: {f.attr} = {getattr(msg, f.attr, None)!r} cannot be "
                               f"encoded ({type(field_exc).__name__}: {field_exc}).")
    return EncodeError(f"{spec.name}: cannot be encoded ({type(exc).__name__}: {exc}).")


class NackError(DriverError):
    """The device refused a command with a NACK: ``command`` (name), ``error`` (name from the ICD)."""

    def __init__(self, message: str, *, command: str, error: str) -> None:
        super().__init__(message)
        self.command = command
        self.error = error


# -- the ICD ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ParamSpec:
    id: int
    name: str
    unit: str
    scale: float
    attr: str
    lo: float
    hi: float
    default: float
    integer: bool
    doc: str

    def check_wire(self, value: float) -> str | None:
        """None when ``value`` (wire unit) is allowed, else what is allowed."""
        ok = isinstance(value, (int, float)) and math.isfinite(value) and self.lo <= value <= self.hi
        if ok and self.integer and value != round(value):
            ok = False
        if ok:
            return None
        kind = "a whole number" if self.integer else "a number"
        return f"{kind} from {self.lo:g} to {self.hi:g} {self.unit}"


def default_icd_path() -> Path:
    """``fixtures/devices/star_tracker.toml``."""
    from drivers import fixture_path

    return fixture_path("devices/star_tracker.toml")


def load_icd(path: str | Path | None = None) -> dict[str, Any]:
    """The ICD TOML as a dict (default: the fixture)."""
    return _load_icd(default_icd_path() if path is None else path)


class StarTrackerCodec:
    """Encode and decode star-tracker frames, from the ICD at ``icd_path`` (default: the fixture).

    Attributes:
        icd: the TOML as a dict; messages: name -> :class:`MessageSpec`; by_id: id -> spec;
        params: name -> :class:`ParamSpec`; params_by_id; enums: name -> tuple of names;
        default_address, max_body; solution_id, status_id (the telemetry ids).
    """

    def __init__(self, icd_path: str | Path | None = None) -> None:
        icd = self.icd = load_icd(icd_path)
        proto = icd["protocol"]
        if proto.get("byte_order") != "little":
            raise ValueError(f"star tracker ICD: byte_order must be 'little'; got {proto.get('byte_order')!r}.")
        crc = proto["crc"]
        check_crc16_spec(crc, "star tracker ICD")
        fr = proto["framing"]
        if (fr["end"], fr["esc"], fr["esc_end"], fr["esc_esc"]) != (0xC0, 0xDB, 0xDC, 0xDD):
            raise ValueError(f"star tracker ICD: the SLIP bytes {fr} differ from drivers.star_tracker.slip.")
        self.default_address: int = int(proto["default_address"])
        self.max_body: int = int(proto["max_body_bytes"])
        self.enums: dict[str, tuple[str, ...]] = {k: tuple(v) for k, v in icd["enums"].items()}
        self.messages, self.by_id = index_messages((self._message_spec(m) for m in icd["messages"]), CLASSES,
                                                   "star tracker ICD", "message id")
        self._by_cls = {spec.cls: spec for spec in self.messages.values()}
        self.params: dict[str, ParamSpec] = {}
        self.params_by_id: dict[int, ParamSpec] = {}
        for p in icd["parameters"]:
            ps = ParamSpec(
                int(p["id"]), p["name"], p["unit"], float(p["scale"]), p["attr"], float(p["min"]), float(p["max"]),
                float(p["default"]), bool(p.get("integer", False)), p.get("doc", ""),
            )
            if ps.check_wire(ps.default) is not None:
                raise ValueError(f"star tracker ICD: default of parameter {ps.name} is outside its range.")
            self.params[ps.name] = ps
            self.params_by_id[ps.id] = ps
        self.solution_id = self.messages["SOLUTION"].id
        self.status_id = self.messages["STATUS"].id
        self.telemetry_ids = frozenset(s.id for s in self.messages.values() if s.telemetry)
        self.command_ids = frozenset(s.id for s in self.messages.values() if s.direction == HOST_TO_DEVICE)
        self.reply_ids = frozenset(s.id for s in self.messages.values() if s.direction == DEVICE_TO_HOST)

    def _message_spec(self, m: dict[str, Any]) -> MessageSpec:
        name = m["name"]
        cls = CLASSES.get(name)
        if cls is None:
            raise ValueError(f"star tracker ICD: message {name!r} has no dataclass in the codec.")
        if m["direction"] not in (HOST_TO_DEVICE, DEVICE_TO_HOST):
            raise ValueError(f"star tracker ICD: message {name} direction must be host->device or device->host.")
        specs, covered = field_specs(m, self.enums, f"star tracker ICD: message {name}")
        attrs = {x.name for x in fields(cls)}
        if covered != attrs:
            raise ValueError(
                f"star tracker ICD: message {name} maps fields to {sorted(covered)}, but {cls.__name__} has "
                f"{sorted(attrs)}."
            )
        fmt = "<" + "".join(s.struct_code for s in specs)
        norms = []
        for un in ([m["unit_norm"]] if isinstance(m.get("unit_norm"), dict) else m.get("unit_norm", [])):
            tol = float(un["tolerance"])
            if un["attr"] not in {x.attr for x in specs if x.index is not None} or not 0 < tol < 1:
                raise ValueError(f"star tracker ICD: message {name} unit_norm {un} must name a tuple attribute and a "
                                 "tolerance in (0, 1).")
            norms.append((un["attr"], tol))
        return MessageSpec(int(m["id"]), name, m["direction"], m.get("doc", ""), tuple(specs), fmt,
                           struct.calcsize(fmt), cls, overhead=4, telemetry=bool(m.get("telemetry", False)),
                           norms=tuple(norms))

    # -- parameters ---------------------------------------------------------------------------

    def param(self, key: str | int) -> ParamSpec:
        """The parameter named ``key`` (or with id ``key``); ValueError listing the known ones."""
        spec = self.params_by_id.get(key) if isinstance(key, int) else self.params.get(key)
        if spec is None:
            known = ", ".join(f"{p.name} ({p.id})" for p in self.params.values())
            raise EncodeError(f"Unknown star tracker parameter {key!r}; known parameters: {known}.")
        return spec

    def set_param(self, key: str | int, value_si: float) -> SetParam:
        """A SET_PARAM for parameter ``key`` with ``value_si`` in SI units (checked against the ICD range)."""
        spec = self.param(key)
        wire = value_si / spec.scale if isinstance(value_si, (int, float)) else value_si
        if isinstance(wire, float) and spec.integer and abs(wire - round(wire)) < 1e-9:
            wire = float(round(wire))
        allowed = spec.check_wire(wire)
        if allowed is not None:
            raise EncodeError(
                f"Star tracker parameter {spec.name} = {value_si!r} (SI) is "
                f"{f'{wire:.6g}' if isinstance(wire, float) else repr(wire)} {spec.unit}; allowed: {allowed}."
            )
        return SetParam(spec.id, float(wire))

    # -- encode -------------------------------------------------------------------------------

    def spec_of(self, msg: Message) -> MessageSpec:
        try:
            return self._by_cls[type(msg)]
        except KeyError:
            raise EncodeError(
                f"Cannot encode {type(msg).__name__}: expected one of "
                f"{', '.join(c.__name__ for c in CLASSES.values())}."
            ) from None

    def payload(self, msg: Message) -> bytes:
        """The payload bytes of ``msg`` (no address, id or CRC); EncodeError for anything the ICD refuses."""
        return self._payload(self.spec_of(msg), msg)

    def _payload(self, spec: MessageSpec, msg: Message) -> bytes:
        try:
            values = wire_values(spec, msg, spec.name)
        except EncodeError:
            raise
        except Exception as exc:  # noqa: BLE001 - any odd object (an array as a flag, a huge int) names its field
            raise _field_error(spec, msg, exc) from None
        for attr, tol in spec.norms:
            norm = norm2(getattr(msg, attr))
            if not abs(norm - 1.0) <= tol:
                raise EncodeError(f"{spec.name}.{attr} = {getattr(msg, attr)!r} has norm {norm!r}; it must be a unit "
                                  f"quaternion within {tol:g}.")
        return spec.packer.pack(*values)

    def encode_body(self, msg: Message, address: int | None = None) -> bytes:
        """``address | id | payload | CRC``, unescaped."""
        address = self.default_address if address is None else address
        if not (isinstance(address, int) and 0 <= address <= 0xFF):
            raise EncodeError(f"Star tracker address = {address!r} is not allowed; allowed: 0 to 255.")
        spec = self._by_cls.get(type(msg)) or self.spec_of(msg)  # spec_of says what is wrong
        head = bytes((address, spec.id)) + self._payload(spec, msg)
        return head + crc16(head).to_bytes(2, "little")

    def encode(self, msg: Message, address: int | None = None) -> bytes:
        """One whole SLIP frame of ``msg`` for ``address`` (default: the ICD's)."""
        return escape(self.encode_body(msg, address))

    # -- decode -------------------------------------------------------------------------------

    def decode_body(self, body: bytes, address: int | None = None, direction: str | None = None) -> Message:
        """Decode one unescaped body. ``address``: the only address accepted (None = any);
        ``direction``: only messages of this direction are accepted (None = both)."""
        if len(body) < 4:
            raise FrameRejected("short", "star tracker frame too short", frame_hex=_hex(body),
                                expected=">= 4 bytes", computed=f"{len(body)} bytes")
        got = int.from_bytes(body[-2:], "little")
        calc = crc16(body[:-2])
        if got != calc:
            raise FrameRejected("crc", "star tracker frame with a bad CRC-16", frame_hex=_hex(body),
                                expected=f"0x{got:04X} (received)", computed=f"0x{calc:04X}")
        if address is not None and body[0] != address:
            raise FrameRejected("address", "star tracker frame for another address", frame_hex=_hex(body),
                                expected=f"0x{address:02X}", computed=f"0x{body[0]:02X}")
        spec = self.by_id.get(body[1])
        if spec is None:
            raise FrameRejected("unknown_id", f"unknown star tracker message id 0x{body[1]:02X}", frame_hex=_hex(body),
                                expected=f"one of {sorted(hex(i) for i in self.by_id)}", computed=f"0x{body[1]:02X}")
        if direction is not None and spec.direction != direction:
            raise FrameRejected("direction", f"message {spec.name} is sent {spec.direction}, not {direction}",
                                frame_hex=_hex(body))
        payload = body[2:-2]
        if len(payload) != spec.payload_len:
            raise FrameRejected("length", f"{spec.name} payload of the wrong length", frame_hex=_hex(body),
                                expected=f"{spec.payload_len} bytes", computed=f"{len(payload)} bytes")
        return self.decode_payload(spec, payload, body)

    def decode_payload(self, spec: MessageSpec, payload: bytes, frame: str | bytes = b"") -> Message:
        """The message of one frame's payload; FrameRejected for a value outside its table or range, naming
        ``frame`` (the whole frame, in hex or as bytes; the payload when not given)."""
        return decode_fields(spec, spec.packer.unpack(payload), FrameRejected, frame or payload)
