"""Emulator: the stand *being* the GNSS receiver, on any port (URL, pty, open port object).

It serves ``icd.toml`` through the same codec as the host and knows no physics: it is handed
``fix_source(t_s) -> Measured``, what the receiver measures at sim time ``t_s`` (the stand's truth with noise, or
a fixed point when served open loop). It adds only what the wire does: the fix counter, GPS week and time of week
from the source's GPS seconds, and quantisation to the datagram's LSBs (the codec rounds).

Behaviour (times are the sim seconds passed to :meth:`GnssEmulator.service`; no clock is read there): the first
fix at the first service time, then one every output period (``output_period_s`` or the period SET_OUTPUT_PERIOD
set, from the command on). A service call that comes late sends one fix, taken at that call's time: a receiver
computes its fix when it is due, it does not replay missed ones. Commands with a bad CRC or a value outside its
range are counted and ignored.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drivers.datagram import DatagramEmulator
from stand_gnss.codec import GnssCodec, GnssFix, SetOutputPeriod

__all__ = ["SECONDS_PER_WEEK", "GnssEmulator", "Measured", "week_and_tow"]

SECONDS_PER_WEEK = 604800
_EPS_S = 1e-9


@dataclass(frozen=True)
class Measured:
    """What the receiver measures at one instant: position (m) and velocity (m/s) in frame N, GPS seconds since
    1980-01-06T00:00:00 (GPS time), satellites used, and whether it has a fix."""

    r_N_m: tuple[float, float, float]
    v_N_m_s: tuple[float, float, float]
    gps_s: float
    satellites: int = 9
    valid: bool = True


def week_and_tow(gps_s: float) -> tuple[int, float]:
    """GPS week and time of week (s) of ``gps_s`` seconds of GPS time, the time of week on the wire's 1 ms grid."""
    ms = round(gps_s * 1000.0)
    week, tow_ms = divmod(ms, SECONDS_PER_WEEK * 1000)
    return int(week), tow_ms / 1000.0


class GnssEmulator(DatagramEmulator):
    """The receiver on ``port`` (see the module docstring); ``latest_fix`` is the newest FIX sent."""

    def __init__(self, port: Any, fix_source: Callable[[float], Measured], *, output_period_s: float = 1.0,
                 codec: GnssCodec | None = None, baudrate: int = 115200, name: str = "gnss emulator") -> None:
        codec = codec if codec is not None else GnssCodec()
        lo, hi = codec.period_range_s
        if not (isinstance(output_period_s, (int, float)) and lo - 1e-12 <= output_period_s <= hi + 1e-12):
            raise ValueError(f"output_period_s = {output_period_s!r} is not allowed; allowed: {lo:g} to {hi:g} s "
                             "(what SET_OUTPUT_PERIOD carries).")
        self.source = fix_source
        self.period_s = float(output_period_s)
        super().__init__(port, codec, baudrate=baudrate, name=name)
        self.counters.update({"fixes": 0, "commands_applied": 0})
        self._next_due: float | None = None
        self._seq = 0
        self.latest_fix: GnssFix | None = None

    def service(self, t_s: float) -> None:
        """Apply the commands received by ``t_s``, then send the fix due by ``t_s``, if one is."""
        self._check_open()
        if self._next_due is None:
            self._next_due = t_s
        self._receive(t_s)
        if t_s + _EPS_S < self._next_due:
            return
        self._send(self.fix(t_s))
        # the next fix on the period's grid after t_s (a late call skips the fixes it missed)
        self._next_due += self.period_s * (math.floor((t_s + _EPS_S - self._next_due) / self.period_s) + 1)

    def next_due_s(self) -> float | None:
        return self._next_due

    def fix(self, t_s: float) -> GnssFix:
        """The FIX for sim time ``t_s`` (advances the fix counter)."""
        m = self.source(t_s)
        week, tow_s = week_and_tow(m.gps_s)
        seq, self._seq = self._seq, (self._seq + 1) & 0xFF
        msg = GnssFix(r_N_m=tuple(float(x) for x in m.r_N_m), v_N_m_s=tuple(float(x) for x in m.v_N_m_s),
                      gps_week=week, tow_s=tow_s, satellites=int(m.satellites), valid=bool(m.valid), seq=seq)
        self.counters["fixes"] += 1
        self.latest_fix = msg
        return msg

    def _apply(self, msg: Any, t_s: float) -> None:  # the hook DatagramEmulator calls for each good command
        if isinstance(msg, SetOutputPeriod):
            self.period_s = msg.period_s
            self._next_due = t_s + msg.period_s
            self.counters["commands_applied"] += 1
