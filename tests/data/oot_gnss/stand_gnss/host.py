"""Host driver: flight software (or the stand) reading a GNSS receiver on a serial port.

The receiver may be real or :class:`~stand_gnss.emulator.GnssEmulator` on a pty, a socat link or the stand's
in-process line: the driver cannot tell. The receiver streams; the driver never asks::

    with GnssHost("/dev/ttyUSB1") as gnss:
        fix = gnss.take_fix()     # once per control tick: the newest unseen fix, or None
        fix.r_N_m, fix.gps_week, fix.tow_s

Bad traffic (a bad CRC, a field outside its range, bytes between datagrams) is counted in ``counters`` and
dropped, never raised (the stand's ``DatagramHost`` does that part).
"""

from __future__ import annotations

from typing import Any

from drivers.datagram import DatagramHost
from stand_gnss.codec import GnssCodec, GnssFix, SetOutputPeriod

__all__ = ["GnssHost"]


class GnssHost(DatagramHost):
    """Host side of one receiver. ``port``: a URL or path (opened, reopened after a failure and closed here) or an
    open port object the caller keeps. ``latest_fix``: the newest :class:`GnssFix`, or None. ``counters`` add
    ``fixes`` and ``fixes_lost`` (gaps in the fix counter) to the datagram host's."""

    _kind = "GNSS receiver"

    def __init__(self, port: Any, *, codec: GnssCodec | None = None, baudrate: int = 115200,
                 timeout_s: float = 2.0, name: str = "gnss", poll_s: float = 0.05) -> None:
        super().__init__(port, codec if codec is not None else GnssCodec(), baudrate=baudrate, timeout_s=timeout_s,
                         name=name, poll_s=poll_s)
        self.counters.update({"fixes": 0, "fixes_lost": 0})
        self.latest_fix: GnssFix | None = None
        self._taken = True

    def _accept_message(self, msg: Any) -> None:  # the hook DatagramHost calls for each good datagram
        if type(msg) is GnssFix:
            if self.latest_fix is not None:
                self.counters["fixes_lost"] += (msg.seq - self.latest_fix.seq - 1) & 0xFF
            self.latest_fix = msg
            self.counters["fixes"] += 1
            self._taken = False

    def take_fix(self) -> GnssFix | None:
        """Poll (never blocks); the newest fix not returned before, or None."""
        self.poll()
        if self._taken:
            return None
        self._taken = True
        return self.latest_fix

    def read_fix(self, timeout_s: float | None = None) -> GnssFix:
        """Wait (up to ``timeout_s``, default the driver's) for a fix not returned before; DeviceTimeoutError after."""
        self._wait(lambda: not self._taken, "FIX datagram", timeout_s)
        self._taken = True
        return self.latest_fix  # type: ignore[return-value]

    def set_output_period(self, period_s: float) -> None:
        """Send SET_OUTPUT_PERIOD (EncodeError outside 0.1 s .. 10 s; not acknowledged)."""
        self.send(SetOutputPeriod(float(period_s)))
