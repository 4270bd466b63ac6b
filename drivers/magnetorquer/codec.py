"""Pure codec of the magnetorquer board: CAN payloads <-> messages in SI units.

No bus, no clock. The frame layout, scaling, ranges, enum names and directions all come from the
ICD ``fixtures/devices/magnetorquer.dbc`` through :class:`drivers.dbc.DbcCodec`; this module only
converts the DBC's units to SI (A m^2, s, T, A, degC for temperature) and back.

================  ======  =========  ================================================================
message           id      direction  content
================  ======  =========  ================================================================
MTQ_DIPOLE_CMD    0x090   host->MTQ  :class:`DipoleCommand`: dipole per axis, duration (0 = off)
MTQ_MODE_CMD      0x091   host->MTQ  :class:`ModeCommand`: OFF / DIPOLE / SELFTEST, reset, seq
MAG_SAMPLE        0x0A0   MTQ->host  :class:`MagSample`: B in sensor axes, coil-active, valid, seq
MTQ_STATUS        0x2A0   MTQ->host  :class:`Status`: mode, coil-active per axis, currents, temp
MTQ_COUNTERS      0x2A1   MTQ->host  :class:`Counters`: rejected, watchdog, saturations, ...
MTQ_HEARTBEAT     0x710   MTQ->host  :class:`Heartbeat`: uptime, state, counter
================  ======  =========  ================================================================

Round trip: ``codec.decode(*codec.encode(x)) == x`` up to one LSB of each field (exactly for
the integer and enum fields).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drivers import can_messages
from drivers.can_messages import HEARTBEAT_STATES, Heartbeat, enum_name
from drivers.dbc import DbcCodec
from drivers.errors import EncodeError, ProtocolError, frame_hex
from drivers.magnetometer.codec import MagSample  # the one sample type of every magnetometer

__all__ = [
    "HEARTBEAT_STATES",
    "MODES",
    "Counters",
    "DipoleCommand",
    "Heartbeat",
    "MagSample",
    "MagnetorquerCodec",
    "Message",
    "ModeCommand",
    "Status",
    "default_dbc_path",
]

#: Board modes, in the order of the DBC's VAL_ table (checked when the codec loads the DBC).
MODES: tuple[str, ...] = ("OFF", "DIPOLE", "SELFTEST")

_NT = 1e-9  # T per nT
_MA = 1e-3  # A per mA
_MS = 1e-3  # s per ms


@dataclass(frozen=True, slots=True)
class DipoleCommand:
    """Drive the coils with ``dipole_A_m2`` (per board axis) for ``duration_s``; 0 s = coils off."""

    dipole_A_m2: tuple[float, float, float]
    duration_s: float


class ModeCommand(can_messages.ModeCommand):
    """Set the board mode: a name from :data:`MODES` or its number (stored as the name)."""

    __slots__ = ()
    MODES = MODES


@dataclass(frozen=True, slots=True)
class Status:
    """Board status: mode, which coils are driven, coil currents (A), board temperature (degC)."""

    mode: str | int
    coil_active: tuple[bool, bool, bool]
    coil_current_A: tuple[float, float, float]
    temperature_C: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "mode", enum_name(self.mode, MODES, "Status.mode"))


@dataclass(frozen=True, slots=True)
class Counters:
    """Board counters (each wraps at its DBC width: 16 bits, 8 bits for the last two)."""

    rejected_frames: int = 0
    watchdog_expiries: int = 0
    saturations: int = 0
    commands_accepted: int = 0
    mode_seq_ack: int = 0


Message = DipoleCommand | ModeCommand | MagSample | Status | Counters | Heartbeat


#: The signals of each message in the order this codec passes them to the DBC's packer (names from the ICD).
_SIGNALS: dict[str, tuple[str, ...]] = {
    "MTQ_DIPOLE_CMD": ("dipole_x", "dipole_y", "dipole_z", "duration_ms"),
    "MTQ_MODE_CMD": ("mode", "reset_counters", "seq"),
    "MAG_SAMPLE": ("b_x", "b_y", "b_z", "seq", "coil_active", "valid"),
    "MTQ_STATUS": ("mode", "coil_active_x", "coil_active_y", "coil_active_z", "current_x", "current_y", "current_z",
                   "temperature"),
    "MTQ_COUNTERS": ("rejected_frames", "watchdog_expiries", "saturations", "commands_accepted", "mode_seq_ack"),
    "MTQ_HEARTBEAT": ("uptime_s", "state", "counter"),
}


def default_dbc_path() -> Path:
    """``fixtures/devices/magnetorquer.dbc``."""
    from drivers import fixture_path

    return fixture_path("devices/magnetorquer.dbc")


class MagnetorquerCodec:
    """Encode and decode magnetorquer-board messages, from the DBC at ``dbc_path`` (default: the ICD).

    ``encode(msg) -> (frame_id, payload)``; ``decode(frame_id, payload) -> message``. ``encode``
    raises :class:`~drivers.errors.EncodeError` (a ValueError), and nothing else, naming the field,
    the value and the DBC's range (or the message types it knows); ``decode`` raises
    :class:`~drivers.errors.ProtocolError` (frame in hex) for an unknown id, a wrong length or an
    enum value outside its table.
    """

    def __init__(self, dbc_path: str | Path | None = None) -> None:
        self.dbc = DbcCodec(default_dbc_path() if dbc_path is None else dbc_path)
        dbc = self.dbc
        for msg, sig, names in (
            ("MTQ_MODE_CMD", "mode", MODES),
            ("MTQ_STATUS", "mode", MODES),
            ("MTQ_HEARTBEAT", "state", HEARTBEAT_STATES),
        ):
            table = dbc.choices(msg, sig)
            if table != dict(enumerate(names)):
                raise ValueError(
                    f"{dbc.path.name}: the value table of {msg}.{sig} is {table}; this codec expects "
                    f"{dict(enumerate(names))}."
                )
        self.ids: dict[str, int] = {name: dbc.frame_id(name) for name in dbc.names}
        self.id_dipole_cmd = dbc.frame_id("MTQ_DIPOLE_CMD")
        self.id_mode_cmd = dbc.frame_id("MTQ_MODE_CMD")
        self.id_mag_sample = dbc.frame_id("MAG_SAMPLE")
        self.id_status = dbc.frame_id("MTQ_STATUS")
        self.id_counters = dbc.frame_id("MTQ_COUNTERS")
        self.id_heartbeat = dbc.frame_id("MTQ_HEARTBEAT")
        #: Frame ids the board sends (MTQ) and the ones it receives (from HOST), from the DBC.
        self.board_tx_ids = frozenset(dbc.frame_id(n) for n in dbc.names if "MTQ" in dbc.senders(n))
        self.board_rx_ids = frozenset(dbc.frame_id(n) for n in dbc.names if "HOST" in dbc.senders(n))
        self.lengths: dict[int, int] = {dbc.frame_id(n): dbc.length(n) for n in dbc.names}
        lo, hi = dbc.signal_range("MTQ_DIPOLE_CMD", "dipole_x")
        #: What MTQ_DIPOLE_CMD can carry per axis, A m^2 (the board's rating is lower).
        self.dipole_range_A_m2: tuple[float, float] = (lo, hi)
        lo, hi = dbc.signal_range("MAG_SAMPLE", "b_x")
        #: What MAG_SAMPLE can carry per axis, T (a magnetometer saturates there).
        self.mag_range_T: tuple[float, float] = (lo * _NT, hi * _NT)
        #: One LSB of MAG_SAMPLE, T.
        self.mag_lsb_T: float = dbc.signal_scale("MAG_SAMPLE", "b_x") * _NT
        #: One LSB of MTQ_DIPOLE_CMD, A m^2.
        self.dipole_lsb_A_m2: float = dbc.signal_scale("MTQ_DIPOLE_CMD", "dipole_x")
        #: One LSB of the MTQ_STATUS coil currents, A.
        self.current_lsb_A: float = dbc.signal_scale("MTQ_STATUS", "current_x") * _MA
        #: One LSB of MTQ_STATUS temperature, degC.
        self.temperature_lsb_C: float = dbc.signal_scale("MTQ_STATUS", "temperature")
        #: GenMsgCycleTime of each periodic message, s.
        self.cycle_time_s: dict[str, float | None] = {n: dbc.cycle_time_s(n) for n in dbc.names}
        self._encoders = {
            DipoleCommand: self._encode_dipole,
            ModeCommand: self._encode_mode,
            MagSample: self._encode_sample,
            Status: self._encode_status,
            Counters: self._encode_counters,
            Heartbeat: self._encode_heartbeat,
        }
        # Each message's signals in the order this codec passes them (positionally: no dict per frame).
        p = {name: dbc.packer(name, order) for name, order in _SIGNALS.items()}
        self._p_dipole, self._p_mode, self._p_sample = p["MTQ_DIPOLE_CMD"], p["MTQ_MODE_CMD"], p["MAG_SAMPLE"]
        self._p_status, self._p_counters, self._p_heartbeat = p["MTQ_STATUS"], p["MTQ_COUNTERS"], p["MTQ_HEARTBEAT"]
        builders = {
            "MTQ_DIPOLE_CMD": self._decode_dipole,
            "MTQ_MODE_CMD": self._decode_mode,
            "MAG_SAMPLE": self._decode_sample,
            "MTQ_STATUS": self._decode_status,
            "MTQ_COUNTERS": self._decode_counters,
            "MTQ_HEARTBEAT": self._decode_heartbeat,
        }
        #: frame id -> (payload length, unpack, message builder, name).
        self._decoders = {q.frame_id: (q.length, q.unpack, builders[name], name) for name, q in p.items()}
        #: True when the compiled bit packer (drivers._bitpack) runs every message, False for the generated Python.
        self.compiled = all(q.compiled for q in p.values())

    # -- encode ---------------------------------------------------------------------------------

    def encode(self, msg: Message) -> tuple[int, bytes]:
        """Encode one message: returns (frame id, 8-byte payload)."""
        try:
            encoder = self._encoders[type(msg)]
        except KeyError:
            raise EncodeError(
                f"Cannot encode {type(msg).__name__}: expected one of "
                f"{', '.join(t.__name__ for t in self._encoders)}."
            ) from None
        try:
            return encoder(msg)
        except EncodeError as exc:
            raise EncodeError(f"Cannot encode {msg!r}: {exc}") from exc
        except (TypeError, ValueError, ArithmeticError) as exc:  # a 2-vector, a string or a huge int for a number
            raise EncodeError(f"Cannot encode {msg!r}: {type(exc).__name__}: {exc}") from exc

    def _pack(self, packer, values: tuple) -> tuple[int, bytes]:
        payload = packer.pack(*values)
        if payload is None:  # the DBC codec's full checks, and their error messages
            return self.dbc.encode(packer.name, dict(zip(packer.order, values, strict=True)))
        return packer.frame_id, payload

    def _encode_dipole(self, msg: DipoleCommand) -> tuple[int, bytes]:
        mx, my, mz = msg.dipole_A_m2
        return self._pack(self._p_dipole, (mx, my, mz, msg.duration_s / _MS))

    def _encode_mode(self, msg: ModeCommand) -> tuple[int, bytes]:
        return self._pack(self._p_mode, (MODES.index(msg.mode), bool(msg.reset_counters), msg.seq))

    def _encode_sample(self, msg: MagSample) -> tuple[int, bytes]:
        bx, by, bz = msg.b_T
        return self._pack(self._p_sample, (bx / _NT, by / _NT, bz / _NT, msg.seq, bool(msg.coil_active),
                                           bool(msg.valid)))

    def _encode_status(self, msg: Status) -> tuple[int, bytes]:
        ax, ay, az = msg.coil_active
        ix, iy, iz = msg.coil_current_A
        return self._pack(self._p_status, (MODES.index(msg.mode), bool(ax), bool(ay), bool(az), ix / _MA, iy / _MA,
                                           iz / _MA, msg.temperature_C))

    def _encode_counters(self, msg: Counters) -> tuple[int, bytes]:
        return self._pack(self._p_counters, (msg.rejected_frames, msg.watchdog_expiries, msg.saturations,
                                             msg.commands_accepted, msg.mode_seq_ack))

    def _encode_heartbeat(self, msg: Heartbeat) -> tuple[int, bytes]:
        return self._pack(self._p_heartbeat, (msg.uptime_s, HEARTBEAT_STATES.index(msg.state), msg.counter))

    # -- decode ---------------------------------------------------------------------------------

    def decode(self, frame_id: int, data: bytes | bytearray) -> Message:
        """Decode one payload into its message (ProtocolError for unknown id / length / enum)."""
        entry = self._decoders.get(frame_id)
        if entry is None or len(data) != entry[0]:
            name, _ = self.dbc.decode(frame_id, data)  # raises the ProtocolError that says why
            raise ProtocolError(f"{name} is not a magnetorquer message", frame_hex=frame_hex(frame_id, data))
        _, unpack, build, name = entry
        try:
            return build(unpack(data))
        except ValueError as exc:  # an enum value outside its table
            raise ProtocolError(f"invalid {name}: {exc}", frame_hex=frame_hex(frame_id, data)) from exc

    def payload_decoders(self) -> dict[int, tuple]:
        """Frame id -> (unpack, build): ``build(unpack(data))`` is :meth:`decode` for a payload of the ICD's length,
        without its look-up (a ValueError for an enum value outside its table). For
        :class:`drivers.can_node.CanNode`."""
        return {frame_id: (unpack, build) for frame_id, (_, unpack, build, _) in self._decoders.items()}

    # The builders take the values in _SIGNALS order.
    @staticmethod
    def _decode_dipole(v: tuple) -> DipoleCommand:
        return DipoleCommand((v[0], v[1], v[2]), v[3] * _MS)

    @staticmethod
    def _decode_mode(v: tuple) -> ModeCommand:
        return ModeCommand(v[0], bool(v[1]), v[2])

    @staticmethod
    def _decode_sample(v: tuple) -> MagSample:
        return MagSample((v[0] * _NT, v[1] * _NT, v[2] * _NT), v[4] == 1, v[5] == 1, v[3])

    @staticmethod
    def _decode_status(v: tuple) -> Status:
        return Status(v[0], (v[1] == 1, v[2] == 1, v[3] == 1), (v[4] * _MA, v[5] * _MA, v[6] * _MA), v[7])

    @staticmethod
    def _decode_counters(v: tuple) -> Counters:
        return Counters(*v)

    @staticmethod
    def _decode_heartbeat(v: tuple) -> Heartbeat:
        return Heartbeat(v[0], v[1], v[2])
