"""What the project's CAN ICDs share at the message level (no bus, no clock): an enumerated signal given by name or
number, and the CANopen-like heartbeat (id 0x700 + node) that the magnetorquer board and every wheel send."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

__all__ = ["HEARTBEAT_STATES", "Heartbeat", "ModeCommand", "enum_name"]

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
