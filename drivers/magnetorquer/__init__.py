"""Magnetorquer board with an on-board magnetometer, over CAN (ICD: ``fixtures/devices/magnetorquer.dbc``).

- :mod:`.codec`: pure codec, payloads <-> messages in SI units (no bus, no clock);
- :mod:`.host`: :class:`MagnetorquerBoard`, the stand driving a board;
- :mod:`.emulator`: :class:`MagnetorquerEmulator`, the stand being the board.

The host and emulator modules import python-can; importing this package does not.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from drivers.lazy import lazy_getattr
from drivers.magnetorquer.codec import (
    HEARTBEAT_STATES,
    MODES,
    Counters,
    DipoleCommand,
    Heartbeat,
    MagnetorquerCodec,
    MagSample,
    ModeCommand,
    Status,
)

if TYPE_CHECKING:  # pragma: no cover
    from drivers.magnetorquer.emulator import EmulatorConfig, MagnetorquerEmulator
    from drivers.magnetorquer.host import MagnetorquerBoard

__all__ = [
    "HEARTBEAT_STATES",
    "MODES",
    "Counters",
    "DipoleCommand",
    "EmulatorConfig",
    "Heartbeat",
    "MagSample",
    "MagnetorquerBoard",
    "MagnetorquerCodec",
    "MagnetorquerEmulator",
    "ModeCommand",
    "Status",
]

__getattr__ = lazy_getattr(__name__, {
    "MagnetorquerBoard": "drivers.magnetorquer.host",
    "MagnetorquerEmulator": "drivers.magnetorquer.emulator",
    "EmulatorConfig": "drivers.magnetorquer.emulator",
})
