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
from typing import NamedTuple

from drivers import can_messages
from drivers.can_messages import HEARTBEAT_STATES, CanCodec, Heartbeat
from drivers.dbc import DbcCodec
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


class DipoleCommand(NamedTuple):
    """Drive the coils with ``dipole_A_m2`` (per board axis) for ``duration_s``; 0 s = coils off. A named tuple
    for the reason :class:`MagSample` is one: made twice a tick (the flight code's command, the board's decode)."""

    dipole_A_m2: tuple[float, float, float]
    duration_s: float


class ModeCommand(can_messages.ModeCommand):
    """Set the board mode: a name from :data:`MODES` or its number (stored as the name)."""

    __slots__ = ()
    MODES = MODES


@dataclass(frozen=True, slots=True)
class Status(can_messages.ModeStatus):
    """Board status: mode, which coils are driven, coil currents (A), board temperature (degC)."""

    coil_active: tuple[bool, bool, bool]
    coil_current_A: tuple[float, float, float]
    temperature_C: float
    MODES = MODES


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


class MagnetorquerCodec(CanCodec):
    """Encode and decode magnetorquer-board messages, from the DBC at ``dbc_path`` (default: the ICD).

    ``encode(msg) -> (frame_id, payload)``; ``decode(frame_id, payload) -> message`` (the machinery of
    :class:`drivers.can_messages.CanCodec`). ``encode`` raises :class:`~drivers.errors.EncodeError` (a
    ValueError), and nothing else, naming the field, the value and the DBC's range (or the message types it
    knows); ``decode`` raises :class:`~drivers.errors.ProtocolError` (frame in hex) for an unknown id, a wrong
    length or an enum value outside its table.
    """

    KIND = "magnetorquer"

    def __init__(self, dbc_path: str | Path | None = None) -> None:
        dbc = DbcCodec(default_dbc_path() if dbc_path is None else dbc_path)
        builders = {
            "MTQ_DIPOLE_CMD": self._decode_dipole,
            "MTQ_MODE_CMD": self._decode_mode,
            "MAG_SAMPLE": self._decode_sample,
            "MTQ_STATUS": self._decode_status,
            "MTQ_COUNTERS": self._decode_counters,
            "MTQ_HEARTBEAT": self._decode_heartbeat,
        }
        self._load(dbc, _SIGNALS, builders, (("MTQ_MODE_CMD", "mode", MODES), ("MTQ_STATUS", "mode", MODES),
                                             ("MTQ_HEARTBEAT", "state", HEARTBEAT_STATES)))
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
        self._encoding({
            DipoleCommand: ("MTQ_DIPOLE_CMD", self._dipole_values),
            ModeCommand: ("MTQ_MODE_CMD", self._mode_values),
            MagSample: ("MAG_SAMPLE", self._sample_values),
            Status: ("MTQ_STATUS", self._status_values),
            Counters: ("MTQ_COUNTERS", self._counters_values),
            Heartbeat: ("MTQ_HEARTBEAT", self._heartbeat_values),
        })

    # -- encode: the values in _SIGNALS order ---------------------------------------------------

    @staticmethod
    def _dipole_values(msg: DipoleCommand) -> tuple:
        mx, my, mz = msg.dipole_A_m2
        return mx, my, mz, msg.duration_s / _MS

    @staticmethod
    def _sample_values(msg: MagSample) -> tuple:
        bx, by, bz = msg.b_T
        return bx / _NT, by / _NT, bz / _NT, msg.seq, bool(msg.coil_active), bool(msg.valid)

    @staticmethod
    def _status_values(msg: Status) -> tuple:
        ax, ay, az = msg.coil_active
        ix, iy, iz = msg.coil_current_A
        return MODES.index(msg.mode), bool(ax), bool(ay), bool(az), ix / _MA, iy / _MA, iz / _MA, msg.temperature_C

    @staticmethod
    def _counters_values(msg: Counters) -> tuple:
        return msg.rejected_frames, msg.watchdog_expiries, msg.saturations, msg.commands_accepted, msg.mode_seq_ack

    # -- decode: the builders take the values in _SIGNALS order ---------------------------------

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
