"""What the project's CAN ICDs share at the message level (no bus, no clock): an enumerated signal given by name or
number, the CANopen-like heartbeat (id 0x700 + node) that the magnetorquer board and every wheel send, the mode
command, and :class:`CanCodec`, the encode / decode machinery every device codec runs on its DBC (each kind adds
only its messages, their SI conversions and its ids)."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import compiled_paths
from drivers.errors import EncodeError, ProtocolError, frame_hex

#: The per-frame work (encode), compiled where the install could (compiled_paths), the same either way.
_frames = compiled_paths.load("drivers.can_frames")

__all__ = ["HEARTBEAT_STATES", "CanCodec", "Heartbeat", "ModeCommand", "ModeStatus", "enum_name"]

#: Heartbeat states, in the order of the DBCs' VAL_ tables (each codec checks its DBC when it loads).
HEARTBEAT_STATES: tuple[str, ...] = ("BOOT", "NOMINAL", "DEGRADED", "FAULT")


def enum_name(value: str | int, names: tuple[str, ...], field: str) -> str:
    """The name of ``value`` in ``names``, given as a name (any case) or its index; ValueError naming ``field``, the
    value and every allowed name with its number otherwise."""
    if isinstance(value, str):
        if value in names:  # as every decoded or emulated message gives it
            return value
        upper = value.upper()
        if upper in names:
            return upper
    elif isinstance(value, int) and not isinstance(value, bool) and 0 <= value < len(names):
        return names[value]
    allowed = ", ".join(f"{n!r} ({i})" for i, n in enumerate(names))
    raise ValueError(f"{field} must be one of {allowed}; got {value!r}.")


@dataclass(frozen=True, slots=True)
class Heartbeat:
    """Whole seconds since boot, state (name from :data:`HEARTBEAT_STATES`), counter."""

    uptime_s: int
    state: str | int
    counter: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "state", enum_name(self.state, HEARTBEAT_STATES, "Heartbeat.state"))


@dataclass(frozen=True, slots=True)
class ModeStatus:
    """The first field of every device's status message: its mode, a name from its ICD's ``MODES`` or its number
    (stored as the name). Each codec's ``Status`` subclasses it with its ``MODES`` and its own fields."""

    mode: str | int
    MODES: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "mode", enum_name(self.mode, self.MODES, "Status.mode"))


@dataclass(frozen=True, slots=True)
class ModeCommand:
    """Set the device's mode: a name from its ICD's ``MODES`` or its number (stored as the name); ``reset_counters``
    zeroes the device's own counters; ``seq`` is echoed back once applied. Each codec subclasses it with its
    ``MODES`` (``__slots__ = ()``)."""

    mode: str | int
    reset_counters: bool = False
    seq: int = 0
    MODES: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "mode", enum_name(self.mode, self.MODES, "ModeCommand.mode"))


class CanCodec:
    """The encode / decode machinery of a device codec on one DBC (:class:`drivers.dbc.DbcCodec`).

    A kind's codec calls :meth:`_load` from its ``__init__`` with the signal order of each message and a builder per
    message (values in that order -> message), then :meth:`_encoding` with, for each message type it encodes, the
    DBC message and a function giving the message's values in that order. ``KIND`` names the device in errors;
    ``id_offset`` is added to every DBC id (a wheel's number), ``where`` to every encode error (" for wheel 2").

    ``encode(msg) -> (frame_id, payload)`` raises :class:`~drivers.errors.EncodeError` naming the field, the value
    and the DBC's range; ``decode(frame_id, payload) -> message`` raises :class:`~drivers.errors.ProtocolError`
    (frame in hex) for an unknown id, a wrong length or an enum value outside its table.
    """

    KIND: ClassVar[str] = "device"
    #: What ``encode`` raises for a message type the codec does not know.
    UNKNOWN_TYPE_ERROR: ClassVar[type[Exception]] = EncodeError
    id_offset: int = 0
    where: str = ""

    def _load(self, dbc: Any, signals: Mapping[str, tuple[str, ...]], builders: Mapping[str, Callable],
              tables: Iterable[tuple[str, str, tuple[str, ...]]]) -> None:
        """Check the DBC's value ``tables`` ((message, signal, names) each) against the codec's names and build the
        packers (``_packers``, each message's signals in ``signals`` order: positionally, no dict per frame), the
        decode table, ``lengths`` and ``cycle_time_s`` (ids plus ``id_offset``)."""
        self.dbc = dbc
        for msg, sig, names in tables:
            table = dbc.choices(msg, sig)
            if table != dict(enumerate(names)):
                raise ValueError(f"{dbc.path.name}: the value table of {msg}.{sig} is {table}; this codec expects "
                                 f"{dict(enumerate(names))}.")
        offset = self.id_offset
        self._packers = packers = {name: dbc.packer(name, order) for name, order in signals.items()}
        #: frame id -> (payload length, unpack, message builder, name).
        self._decoders: dict[int, tuple] = {q.frame_id + offset: (q.length, q.unpack, builders[name], name)
                                            for name, q in packers.items()}
        self.lengths: dict[int, int] = {dbc.frame_id(n) + offset: dbc.length(n) for n in dbc.names}
        #: GenMsgCycleTime of each periodic message, s.
        self.cycle_time_s: dict[str, float | None] = {n: dbc.cycle_time_s(n) for n in dbc.names}

    # -- encode ---------------------------------------------------------------------------------

    def _encoding(self, encoders: Mapping[type, tuple[str, Callable[[Any], tuple]]]) -> None:
        """The encode table: message type -> (the DBC message, ``values(msg)`` in the order given to :meth:`_load`)."""
        self._encoders: dict[type, tuple] = {
            kind: (self._packers[name], values, self._packers[name].frame_id + self.id_offset)
            for kind, (name, values) in encoders.items()}

    #: ``encode(msg) -> (frame id, 8-byte payload)``: one message through its DBC packer (EncodeError naming the
    #: message, the field, the value and the DBC's range). :func:`drivers.can_frames.encode`, compiled where the
    #: install can.
    encode = _frames.encode

    # The mode command and the heartbeat are the same messages in every ICD.
    @staticmethod
    def _mode_values(msg: ModeCommand) -> tuple:
        return msg.MODES.index(msg.mode), bool(msg.reset_counters), msg.seq

    @staticmethod
    def _heartbeat_values(msg: Heartbeat) -> tuple:
        return msg.uptime_s, HEARTBEAT_STATES.index(msg.state), msg.counter

    # -- decode ---------------------------------------------------------------------------------

    def decode(self, frame_id: int, data: bytes | bytearray) -> Any:
        """Decode one payload into its message (ProtocolError for unknown id / length / enum)."""
        entry = self._decoders.get(frame_id)
        if entry is None or len(data) != entry[0]:
            self._reject(frame_id, data)
        _, unpack, build, name = entry
        try:
            return build(unpack(data))
        except ValueError as exc:  # an enum value outside its table
            raise ProtocolError(f"invalid {name}: {exc}", frame_hex=frame_hex(frame_id, data)) from exc

    def _reject(self, frame_id: int, data: bytes | bytearray) -> None:
        """Raise the ProtocolError that says why ``decode`` cannot take this frame (an id that is not the codec's,
        or a length other than the ICD's)."""
        name, _ = self.dbc.decode(frame_id - self.id_offset, data)  # raises the ProtocolError that says why
        raise ProtocolError(f"{name} is not a {self.KIND} message", frame_hex=frame_hex(frame_id, data))

    def payload_decoders(self) -> dict[int, tuple]:
        """Frame id -> (unpack, build): ``build(unpack(data))`` is :meth:`decode` for a payload of the ICD's length,
        without its look-up (a ValueError for an enum value outside its table). For
        :class:`drivers.can_node.CanNode`."""
        return {frame_id: (unpack, build) for frame_id, (_, unpack, build, _) in self._decoders.items()}
