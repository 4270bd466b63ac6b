"""Pure codec of the standalone magnetometer: CAN payloads <-> messages in SI units.

No bus, no clock. Layout, scaling, ranges, enum names and directions come from the ICD
``fixtures/devices/magnetometer.dbc`` through :class:`drivers.dbc.DbcCodec`; this module converts nT to T.

================  ======  =========  ================================================================
message           id      direction  content
================  ======  =========  ================================================================
MAG_MODE_CMD      0x0E0   host->MAG  :class:`ModeCommand`: OFF / MEASURE, reset counters, seq
MAG_FIELD         0x0A8   MAG->host  :class:`MagSample`: B in sensor axes (1 nT steps), valid, seq
MAG_STATUS        0x2A8   MAG->host  :class:`Status`: mode, rejected frames, saturations, accepted, ack
MAG_HEARTBEAT     0x718   MAG->host  :class:`Heartbeat`: uptime, state, counter (node 0x18)
================  ======  =========  ================================================================

:class:`MagSample` is the one sample type of every magnetometer of the stand: the magnetorquer board's
MAG_SAMPLE decodes to it too (there ``coil_active`` says whether the board's coils were driven; a standalone unit
knows nothing of the coils and always reports False).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

from drivers import can_messages
from drivers.can_messages import HEARTBEAT_STATES, CanCodec, Heartbeat
from drivers.dbc import DbcCodec

__all__ = ["MODES", "Heartbeat", "MagSample", "MagnetometerCodec", "ModeCommand", "Status", "default_dbc_path"]

#: Modes, in the order of the DBC's VAL_ table (checked when the codec loads the DBC).
MODES: tuple[str, ...] = ("OFF", "MEASURE")

_NT = 1e-9  # T per nT


class MagSample(NamedTuple):
    """One magnetometer sample: flux density in sensor axes (T), flags and an 8-bit counter. A named tuple, not a
    frozen dataclass: it is made three times a tick on the detumble's path (measured, decoded by the flight code's
    driver, decoded by the stand's observer), and a frozen dataclass's constructor costs 2.4 times as much."""

    b_T: tuple[float, float, float]
    coil_active: bool
    valid: bool
    seq: int


class ModeCommand(can_messages.ModeCommand):
    """Set the magnetometer's mode: a name from :data:`MODES` or its number (stored as the name)."""

    __slots__ = ()
    MODES = MODES


@dataclass(frozen=True, slots=True)
class Status(can_messages.ModeStatus):
    """Mode and counters (16 bits for rejected frames and saturations, 8 bits for the last two)."""

    rejected_frames: int = 0
    saturations: int = 0
    commands_accepted: int = 0
    mode_seq_ack: int = 0
    MODES = MODES


Message = ModeCommand | MagSample | Status | Heartbeat

#: The signals of each message in the order this codec passes them to the DBC's packer (names from the ICD).
_SIGNALS: dict[str, tuple[str, ...]] = {
    "MAG_MODE_CMD": ("mode", "reset_counters", "seq"),
    "MAG_FIELD": ("b_x", "b_y", "b_z", "seq", "valid"),
    "MAG_STATUS": ("mode", "rejected_frames", "saturations", "commands_accepted", "mode_seq_ack"),
    "MAG_HEARTBEAT": ("uptime_s", "state", "counter"),
}


def default_dbc_path() -> Path:
    """``fixtures/devices/magnetometer.dbc``."""
    from drivers import fixture_path

    return fixture_path("devices/magnetometer.dbc")


class MagnetometerCodec(CanCodec):
    """Encode and decode standalone-magnetometer messages, from the DBC at ``dbc_path`` (default: the ICD); the
    machinery and its errors are :class:`drivers.can_messages.CanCodec`'s."""

    KIND = "magnetometer"

    def __init__(self, dbc_path: str | Path | None = None) -> None:
        dbc = DbcCodec(default_dbc_path() if dbc_path is None else dbc_path)
        builders = {"MAG_MODE_CMD": lambda v: ModeCommand(v[0], bool(v[1]), v[2]),
                    "MAG_FIELD": lambda v: MagSample((v[0] * _NT, v[1] * _NT, v[2] * _NT), False, v[4] == 1, v[3]),
                    "MAG_STATUS": lambda v: Status(*v),
                    "MAG_HEARTBEAT": lambda v: Heartbeat(v[0], v[1], v[2])}
        self._load(dbc, _SIGNALS, builders, (("MAG_MODE_CMD", "mode", MODES), ("MAG_STATUS", "mode", MODES),
                                             ("MAG_HEARTBEAT", "state", HEARTBEAT_STATES)))
        self.id_mode_cmd = dbc.frame_id("MAG_MODE_CMD")
        self.id_sample = dbc.frame_id("MAG_FIELD")
        #: Frame ids the unit sends (MAG) and the ones it receives (from HOST), from the DBC.
        self.unit_tx_ids = frozenset(dbc.frame_id(n) for n in dbc.names if "MAG" in dbc.senders(n))
        self.unit_rx_ids = frozenset(dbc.frame_id(n) for n in dbc.names if "HOST" in dbc.senders(n))
        lo, hi = dbc.signal_range("MAG_FIELD", "b_x")
        #: What MAG_FIELD can carry per axis, T (the sensor saturates there).
        self.mag_range_T: tuple[float, float] = (lo * _NT, hi * _NT)
        #: One LSB of MAG_FIELD, T.
        self.mag_lsb_T: float = dbc.signal_scale("MAG_FIELD", "b_x") * _NT
        self._encoding({ModeCommand: ("MAG_MODE_CMD", self._mode_values),
                        MagSample: ("MAG_FIELD", self._sample_values),
                        Status: ("MAG_STATUS", self._status_values),
                        Heartbeat: ("MAG_HEARTBEAT", self._heartbeat_values)})

    # The values in _SIGNALS order.
    @staticmethod
    def _sample_values(msg: MagSample) -> tuple:
        bx, by, bz = msg.b_T
        return bx / _NT, by / _NT, bz / _NT, msg.seq, bool(msg.valid)

    @staticmethod
    def _status_values(msg: Status) -> tuple:
        return MODES.index(msg.mode), msg.rejected_frames, msg.saturations, msg.commands_accepted, msg.mode_seq_ack
