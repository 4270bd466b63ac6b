"""Reaction wheel over CAN, one node per wheel (ICD: ``fixtures/devices/reaction_wheel.dbc``;
document: ``docs/reaction_wheel_icd.md``).

- :mod:`.codec`: pure codec, payloads <-> messages in SI units (no bus, no clock);
- :mod:`.host`: :class:`ReactionWheelHost`, the stand (or flight software) driving a wheel;
- :mod:`.emulator`: :class:`ReactionWheelEmulator`, the stand being the wheel (holds the command,
  reports the speed its source gives);
- :mod:`.icd`: renders the ICD document from the DBC.

The host and emulator modules import python-can; importing this package does not.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from drivers.lazy import lazy_getattr
from drivers.reaction_wheel.codec import (
    HEARTBEAT_STATES,
    MODES,
    Heartbeat,
    ModeCommand,
    ReactionWheelCodec,
    SpeedCommand,
    Status,
    TorqueCommand,
    WheelSpeed,
)

if TYPE_CHECKING:  # pragma: no cover
    from drivers.reaction_wheel.emulator import ReactionWheelEmulator, WheelCommand, WheelEmulatorConfig
    from drivers.reaction_wheel.host import ReactionWheelHost

__all__ = [
    "HEARTBEAT_STATES",
    "MODES",
    "Heartbeat",
    "ModeCommand",
    "ReactionWheelCodec",
    "ReactionWheelEmulator",
    "ReactionWheelHost",
    "SpeedCommand",
    "Status",
    "TorqueCommand",
    "WheelCommand",
    "WheelEmulatorConfig",
    "WheelSpeed",
]

__getattr__ = lazy_getattr(__name__, {
    "ReactionWheelHost": "drivers.reaction_wheel.host",
    "ReactionWheelEmulator": "drivers.reaction_wheel.emulator",
    "WheelEmulatorConfig": "drivers.reaction_wheel.emulator",
    "WheelCommand": "drivers.reaction_wheel.emulator",
})
