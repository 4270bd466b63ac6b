"""What goes wrong with any emulated device whatever its link (serial datagrams, the SLIP star tracker, CAN): its
clock (a jump, a rate error) and a reboot. One implementation, mixed into the emulator bases
(:class:`drivers.datagram.DatagramEmulator`, :class:`drivers.star_tracker.emulator.StarTrackerEmulator`,
:class:`drivers.can_node.CanDevice`); each base fills :meth:`DeviceFaults._reboot` and each device its own RAM state
in ``_reboot_device``.

Neutral cost: without a clock fault the device clock costs one attribute test (``_clock_fault is None``) per time
tag; the reboot's power-off is tested only on a device's power-up path (the branch taken when its power-up time is
unset), never on every tick.

Clock faults (sim time ``t``, the device clock ``s(t)`` as the device would read it without the fault):

- :meth:`DeviceFaults.clock_fault` ``(t0, jump_s, drift)`` adds ``jump_s + drift * (t - t0)`` from ``t0`` on; several
  add up (a jump and a drift at once); each call returns a handle;
- :meth:`DeviceFaults.clear_clock_fault` removes one (by its handle) or all: the clock reads as without it again;
- an event that sets the device clock (SET_TIME, a reboot) makes it right at that instant: each active fault's
  offset starts again from 0 there, its drift goes on (the oscillator is still off).

Reboot (:meth:`DeviceFaults.reboot` ``(t, boot_s)``): what waits on the line at ``t`` and arrives during the next
``boot_s`` is lost (counted), the device sends nothing until ``t + boot_s``, then powers up as from cold: sequence
numbers from 0, the device clock restarted and not synchronised, modes and RAM state as configured; a device whose
ICD has a boot message sends it first.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["ClockFault", "DeviceFaults"]


def _finite(name: str, value: Any, lo: float = -math.inf, hi: float = math.inf) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not (ok and math.isfinite(value) and lo <= value <= hi):
        bounds = "" if (lo, hi) == (-math.inf, math.inf) else f" from {lo:g} to {hi:g}"
        raise ValueError(f"{name} = {value!r} is not allowed; give a finite number{bounds}.")
    return float(value)


def axis_indices(what: str, axes) -> tuple[int, ...]:
    """A set of axis indices (0 x, 1 y, 2 z) a fault names, sorted; ValueError naming ``what`` otherwise."""
    try:
        out = tuple(sorted({int(a) for a in axes}))
    except (TypeError, ValueError):
        out = (-1,)
    if not all(0 <= a <= 2 for a in out):
        raise ValueError(f"{what} = {axes!r} is not allowed; give axis indices 0 (x), 1 (y), 2 (z).")
    return out


class ClockFault:
    """The active clock faults of one device: ``offset_s(t) = sum(jump + drift * (t - t0))``."""

    __slots__ = ("_next", "_parts")

    def __init__(self) -> None:
        self._parts: dict[int, tuple[float, float, float]] = {}  # handle -> (t0, jump_s, drift)
        self._next = 1

    def __bool__(self) -> bool:
        return bool(self._parts)

    def add(self, t_s: float, jump_s: float, drift: float) -> int:
        handle = self._next
        self._next += 1
        self._parts[handle] = (t_s, jump_s, drift)
        return handle

    def remove(self, handle: int) -> None:
        self._parts.pop(handle, None)

    def offset_s(self, t_s: float) -> float:
        """What the faults add to the device clock at sim time ``t_s``, s."""
        return sum(j + d * (t_s - t0) for t0, j, d in self._parts.values())

    @property
    def jump_s(self) -> float:
        return sum(j for _, j, _ in self._parts.values())

    @property
    def drift(self) -> float:
        return sum(d for _, _, d in self._parts.values())

    def rebase(self, t_s: float) -> None:
        """The device clock was set right at ``t_s``: every fault's offset starts again from 0 there."""
        self._parts = {h: (t_s, 0.0, d) for h, (_, _, d) in self._parts.items()}


class DeviceFaults:
    """Clock faults and reboot of an emulated device (module docstring). A base fills :meth:`_reboot`; its
    ``counters`` dict gets ``reboots`` (and what was lost while off) from the first reboot on."""

    counters: dict[str, int]
    #: The active clock faults, or None (no cost but this test).
    _clock_fault: ClockFault | None = None
    #: Sim time until which a rebooting device is off: deaf and silent.
    _off_until_s = -math.inf

    # -- clock ------------------------------------------------------------------------------------

    def clock_fault(self, t_s: float, jump_s: float = 0.0, drift: float = 0.0) -> int:
        """From sim time ``t_s`` on the device clock reads ``jump_s`` (s) more, plus ``drift`` (a fractional rate
        error, e.g. 1e-4 = 100 ppm fast) times the time since ``t_s``; returns a handle for
        :meth:`clear_clock_fault`. ValueError naming the value for anything not finite (``|drift|`` < 1)."""
        t_s = _finite("clock fault t_s", t_s)
        jump_s = _finite("clock fault jump_s", jump_s, -1e9, 1e9)
        drift = _finite("clock fault drift", drift, -0.999, 0.999)
        if self._clock_fault is None:
            self._clock_fault = ClockFault()
        return self._clock_fault.add(t_s, jump_s, drift)

    def clear_clock_fault(self, t_s: float, handle: int | None = None) -> None:
        """End the clock fault ``handle`` (every one when None) at ``t_s``: the clock reads as without it again."""
        fault = self._clock_fault
        if fault is None:
            return
        if handle is not None:
            fault.remove(handle)
        if handle is None or not fault:
            self._clock_fault = None

    @property
    def clock_jump_s(self) -> float:
        """The jumps of the active clock faults, s (0 without one)."""
        return 0.0 if self._clock_fault is None else self._clock_fault.jump_s

    @property
    def clock_drift(self) -> float:
        """The fractional rate error of the active clock faults (0 without one)."""
        return 0.0 if self._clock_fault is None else self._clock_fault.drift

    def _clock_set(self, t_s: float) -> None:
        """The device clock was set right at ``t_s`` (SET_TIME, power-up)."""
        if self._clock_fault is not None:
            self._clock_fault.rebase(t_s)

    # -- reboot -----------------------------------------------------------------------------------

    def reboot(self, t_s: float, boot_s: float = 0.0) -> None:
        """Reboot at sim time ``t_s``: off (deaf and silent) for ``boot_s`` seconds, then a cold power-up (module
        docstring). ValueError naming the value for a ``boot_s`` that is not a finite number >= 0."""
        t_s = _finite("reboot t_s", t_s)
        boot_s = _finite("reboot boot_s", boot_s, 0.0, 1e6)
        t_up = t_s + boot_s
        self._off_until_s = t_up
        self._clock_set(t_up)
        self.counters["reboots"] = self.counters.get("reboots", 0) + 1
        self._reboot(t_s, t_up)

    def booting(self, t_s: float) -> bool:
        """True while a reboot keeps the device off at sim time ``t_s``."""
        return t_s < self._off_until_s - 1e-9

    def _lost_in_boot(self, key: str, n: int) -> None:
        self.counters[key] = self.counters.get(key, 0) + n

    def _reboot(self, t_s: float, t_up: float) -> None:  # pragma: no cover - every base overrides it
        raise NotImplementedError

    def _reboot_device(self, t_up: float) -> None:
        """The device's own RAM state back to power-up (its hook; a device that keeps none leaves it)."""
