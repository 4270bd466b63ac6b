"""Pure codec of a reaction wheel: CAN payloads <-> messages in SI units (no bus, no clock).

The frame layout, scaling, ranges, enum names and directions come from the ICD
``fixtures/devices/reaction_wheel.dbc`` through :class:`drivers.dbc.DbcCodec`; this module adds the
node numbering (wheel ``n`` of 0..15, node ``0x20 + n``, uses every DBC id plus ``n``) and the
conversions to SI (N m, rad/s, s).

================  ==========  =========  ===========================================================
message           id (n = 0)  direction  content
================  ==========  =========  ===========================================================
RW_TORQUE_CMD     0x0B0 + n   host->RW   :class:`TorqueCommand`: motor torque, seq, timeout
RW_SPEED_CMD      0x0C0 + n   host->RW   :class:`SpeedCommand`: wheel speed, seq, timeout
RW_MODE_CMD       0x0D0 + n   host->RW   :class:`ModeCommand`: IDLE / TORQUE / SPEED, reset, seq
RW_SPEED_TLM      0x1B0 + n   RW->host   :class:`WheelSpeed`: speed, motor torque, flags, seq
RW_STATUS         0x2B0 + n   RW->host   :class:`Status`: mode, counters, seq ack, temperature
RW_HEARTBEAT      0x720 + n   RW->host   :class:`Heartbeat`: uptime, state, counter
================  ==========  =========  ===========================================================

Round trip: ``codec.decode(*codec.encode(x)) == x`` for values on the DBC's grid (exactly for the
integer and enum fields).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drivers import can_messages
from drivers.can_messages import HEARTBEAT_STATES, CanCodec, Heartbeat
from drivers.dbc import DbcCodec
from drivers.errors import ProtocolError, frame_hex
from drivers.frozen_build import positional_maker3

__all__ = [
    "HEARTBEAT_STATES",
    "MAX_WHEELS",
    "MODES",
    "NODE_BASE",
    "Heartbeat",
    "Message",
    "ModeCommand",
    "ReactionWheelCodec",
    "SpeedCommand",
    "Status",
    "TorqueCommand",
    "WheelSpeed",
    "default_dbc_path",
]

#: Wheel modes, in the order of the DBC's VAL_ table (checked when the codec loads the DBC).
MODES: tuple[str, ...] = ("IDLE", "TORQUE", "SPEED")
#: Node id of wheel 0; wheel n is node NODE_BASE + n.
NODE_BASE = 0x20
#: Wheels one DBC can number (the low four bits of every id).
MAX_WHEELS = 16
_MS = 1e-3

#: The signals of each message in the order this codec passes them to the DBC's packer (names from the ICD).
_SIGNALS: dict[str, tuple[str, ...]] = {
    "RW_TORQUE_CMD": ("torque", "seq", "timeout_ms"),
    "RW_SPEED_CMD": ("speed", "seq", "timeout_ms"),
    "RW_MODE_CMD": ("mode", "reset_counters", "seq"),
    "RW_SPEED_TLM": ("speed", "torque", "seq", "valid", "speed_limited", "torque_limited"),
    "RW_STATUS": ("mode", "rejected_frames", "commands_accepted", "seq_ack", "watchdog_expiries", "saturations",
                  "temperature"),
    "RW_HEARTBEAT": ("uptime_s", "state", "counter"),
}


@dataclass(frozen=True, slots=True)
class TorqueCommand:
    """Drive ``torque_Nm`` on the rotor (TORQUE mode); dropped ``timeout_s`` after it (0 = held)."""

    torque_Nm: float
    seq: int = 0
    timeout_s: float = 0.0


@dataclass(frozen=True, slots=True)
class SpeedCommand:
    """Hold the wheel at ``speed_rad_s`` (SPEED mode); dropped ``timeout_s`` after it (0 = held)."""

    speed_rad_s: float
    seq: int = 0
    timeout_s: float = 0.0


#: ``TorqueCommand(torque_Nm, seq, timeout_s)`` and ``SpeedCommand(...)`` without the dataclass ``__init__``'s Python
#: frame (a test checks they give what the constructors give): the host builds one and the wheel decodes one a tick.
new_torque_command = positional_maker3(TorqueCommand)
new_speed_command = positional_maker3(SpeedCommand)


class ModeCommand(can_messages.ModeCommand):
    """Set the mode: a name from :data:`MODES` or its number (stored as the name)."""

    __slots__ = ()
    MODES = MODES


class WheelSpeed(float):
    """Measured wheel speed: the float itself is the speed in rad/s about the spin axis (what flight code
    written against ``take_speed() -> rad/s`` expects), and the rest of the telemetry rides along as
    attributes: ``speed_rad_s`` (the same value), ``torque_Nm`` (motor torque applied), ``valid``,
    ``speed_limited``, ``torque_limited``, ``seq``. Immutable; equal when every field is."""

    __slots__ = ("torque_Nm", "valid", "speed_limited", "torque_limited", "seq")

    def __new__(cls, speed_rad_s: float, torque_Nm: float, valid: bool, speed_limited: bool,
                torque_limited: bool, seq: int) -> WheelSpeed:
        obj = _float_new(cls, speed_rad_s)
        # Past the refusing __setattr__ by each slot's own setter, without object.__setattr__'s look-up of the name
        # (a sample is built twice a tick per wheel: sent, taken).
        _set_torque(obj, torque_Nm)
        _set_valid(obj, valid)
        _set_speed_limited(obj, speed_limited)
        _set_torque_limited(obj, torque_limited)
        _set_seq(obj, seq)
        return obj

    @property
    def speed_rad_s(self) -> float:
        return float(self)

    def _fields(self) -> tuple:
        return (float(self), self.torque_Nm, self.valid, self.speed_limited, self.torque_limited, self.seq)

    def __setattr__(self, name, value):
        raise AttributeError(f"WheelSpeed is immutable; cannot set {name!r}.")

    def __eq__(self, other):
        if isinstance(other, WheelSpeed):
            return self._fields() == other._fields()
        return float(self) == other

    def __ne__(self, other):
        return not self == other

    def __hash__(self):
        return hash(self._fields())

    def __repr__(self) -> str:
        return (f"WheelSpeed(speed_rad_s={float(self)!r}, torque_Nm={self.torque_Nm!r}, valid={self.valid!r}, "
                f"speed_limited={self.speed_limited!r}, torque_limited={self.torque_limited!r}, seq={self.seq!r})")

    def __reduce__(self):
        return (WheelSpeed, self._fields())


_float_new = float.__new__
#: The setters of WheelSpeed's slots (member descriptors), in __slots__ order.
_set_torque, _set_valid, _set_speed_limited, _set_torque_limited, _set_seq = (
    getattr(WheelSpeed, name).__set__ for name in WheelSpeed.__slots__)


@dataclass(frozen=True, slots=True)
class Status(can_messages.ModeStatus):
    """Wheel status: mode, counters (each wraps at its DBC width), seq of the last command, temperature."""

    rejected_frames: int = 0
    commands_accepted: int = 0
    seq_ack: int = 0
    watchdog_expiries: int = 0
    saturations: int = 0
    temperature_C: float = 20.0
    MODES = MODES


Message = TorqueCommand | SpeedCommand | ModeCommand | WheelSpeed | Status | Heartbeat


def default_dbc_path() -> Path:
    """``fixtures/devices/reaction_wheel.dbc``."""
    from drivers import fixture_path

    return fixture_path("devices/reaction_wheel.dbc")


class ReactionWheelCodec(CanCodec):
    """Encode and decode the messages of wheel ``wheel`` (0..15, node 0x20 + wheel).

    ``encode(msg) -> (frame_id, payload)``; ``decode(frame_id, payload) -> message`` for this
    wheel's ids. ``encode`` raises :class:`~drivers.errors.EncodeError` naming the field, the value
    and the DBC's range; ``decode`` raises :class:`~drivers.errors.ProtocolError` (frame in hex) for
    an id that is not this wheel's, a wrong length or an enum value outside its table.

    Attributes: ``wheel``, ``node``, ``ids`` (name -> this wheel's id), ``wheel_tx_ids`` /
    ``wheel_rx_ids`` (ids the wheel sends / receives), ``all_wheel_ids`` (every id of every wheel:
    frames of the wheel's siblings on a shared bus), ``lengths``, ``torque_range_Nm``,
    ``speed_range_rad_s`` (what the commands carry), ``speed_lsb_rad_s``, ``torque_lsb_Nm``,
    ``cycle_time_s``.
    """

    KIND = "reaction wheel"
    UNKNOWN_TYPE_ERROR = TypeError

    def __init__(self, wheel: int = 0, dbc_path: str | Path | None = None, *, dbc: DbcCodec | None = None) -> None:
        if not (isinstance(wheel, int) and not isinstance(wheel, bool) and 0 <= wheel < MAX_WHEELS):
            raise ValueError(f"reaction wheel number = {wheel!r} is not allowed; allowed: an int from 0 to "
                             f"{MAX_WHEELS - 1} (node 0x{NODE_BASE:02X} + number).")
        self.wheel = self.id_offset = wheel
        self.where = f" for wheel {wheel}"
        self.node = NODE_BASE + wheel
        d = dbc if dbc is not None else DbcCodec(default_dbc_path() if dbc_path is None else dbc_path)
        for name in d.names:
            if d.frame_id(name) & 0xF:
                raise ValueError(f"{d.path.name}: {name} has id 0x{d.frame_id(name):03X}; wheel 0's ids must end in "
                                 "a zero hex digit (the wheel number is added to them).")
        builders = {
            "RW_TORQUE_CMD": lambda v: new_torque_command(v[0], v[1], v[2] * _MS),
            "RW_SPEED_CMD": lambda v: new_speed_command(v[0], v[1], v[2] * _MS),
            "RW_MODE_CMD": lambda v: ModeCommand(v[0], v[1] == 1, v[2]),
            "RW_SPEED_TLM": lambda v: WheelSpeed(v[0], v[1], v[3] == 1, v[4] == 1, v[5] == 1, v[2]),
            "RW_STATUS": lambda v: Status(*v),
            "RW_HEARTBEAT": lambda v: Heartbeat(v[0], v[1], v[2]),
        }
        self._load(d, _SIGNALS, builders, (("RW_MODE_CMD", "mode", MODES), ("RW_STATUS", "mode", MODES),
                                           ("RW_HEARTBEAT", "state", HEARTBEAT_STATES)))
        self.ids: dict[str, int] = {name: d.frame_id(name) + wheel for name in d.names}
        self._names = {fid: name for name, fid in self.ids.items()}
        self.wheel_tx_ids = frozenset(self.ids[n] for n in d.names if "RW" in d.senders(n))
        self.wheel_rx_ids = frozenset(self.ids[n] for n in d.names if "HOST" in d.senders(n))
        self.all_wheel_ids = frozenset(d.frame_id(n) + k for n in d.names for k in range(MAX_WHEELS))
        self.torque_range_Nm: tuple[float, float] = d.signal_range("RW_TORQUE_CMD", "torque")
        self.speed_range_rad_s: tuple[float, float] = d.signal_range("RW_SPEED_CMD", "speed")
        #: What RW_SPEED_TLM can carry.
        self.tlm_speed_range_rad_s: tuple[float, float] = d.signal_range("RW_SPEED_TLM", "speed")
        self.tlm_torque_range_Nm: tuple[float, float] = d.signal_range("RW_SPEED_TLM", "torque")
        self.speed_lsb_rad_s: float = d.signal_scale("RW_SPEED_TLM", "speed")
        self.torque_lsb_Nm: float = d.signal_scale("RW_SPEED_TLM", "torque")
        self._encoding({
            TorqueCommand: ("RW_TORQUE_CMD", self._torque_values),
            SpeedCommand: ("RW_SPEED_CMD", self._speed_values),
            ModeCommand: ("RW_MODE_CMD", self._mode_values),
            WheelSpeed: ("RW_SPEED_TLM", self._tlm_values),
            Status: ("RW_STATUS", self._status_values),
            Heartbeat: ("RW_HEARTBEAT", self._heartbeat_values),
        })

    def wheel_of(self, frame_id: int) -> int | None:
        """The wheel number a wheel id belongs to, or None for an id that is no wheel's."""
        return (frame_id & 0xF) if frame_id in self.all_wheel_ids else None

    # -- encode: the values in _SIGNALS order ---------------------------------------------------

    @staticmethod
    def _torque_values(msg: TorqueCommand) -> tuple:
        return msg.torque_Nm, msg.seq, msg.timeout_s / _MS

    @staticmethod
    def _speed_values(msg: SpeedCommand) -> tuple:
        return msg.speed_rad_s, msg.seq, msg.timeout_s / _MS

    @staticmethod
    def _tlm_values(msg: WheelSpeed) -> tuple:
        # The float itself is the speed (what .speed_rad_s returns, without the property's call).
        return (float(msg), msg.torque_Nm, msg.seq, bool(msg.valid), bool(msg.speed_limited),
                bool(msg.torque_limited))

    @staticmethod
    def _status_values(msg: Status) -> tuple:
        return (MODES.index(msg.mode), msg.rejected_frames, msg.commands_accepted, msg.seq_ack, msg.watchdog_expiries,
                msg.saturations, msg.temperature_C)

    # -- decode ---------------------------------------------------------------------------------

    def _reject(self, frame_id: int, data: bytes | bytearray) -> None:
        if frame_id not in self._decoders:
            raise ProtocolError(
                f"frame id 0x{frame_id:03X} is not one of wheel {self.wheel}'s (node 0x{self.node:02X})",
                frame_hex=frame_hex(frame_id, data, extended=frame_id > 0x7FF),
                expected="one of " + ", ".join(f"0x{i:03X}" for i in sorted(self._names)),
                computed=f"0x{frame_id:03X}",
            )
        super()._reject(frame_id, data)
