"""Host driver: the stand (or flight software) reading a serial gyro.

The gyro may be real (``/dev/ttyUSB0``) or :class:`~drivers.gyro.emulator.GyroEmulator` on a pty,
socat link or ``socket://``: the driver cannot tell. The gyro streams; the driver never asks::

    with GyroHost("/dev/ttyUSB0") as gyro:
        gyro.set_time(unix_us)          # optional: time stamps in the host's time base
        rate = gyro.take_rate()         # once per control tick: the newest unseen sample, or None
        rate.omega_rad_s, rate.valid, rate.time_us

Receiving never raises on bad traffic: datagrams with a bad CRC or a field outside its table, and
bytes between datagrams, are counted in :attr:`GyroHost.counters` and dropped. A gap in the sample
counter is counted in ``samples_lost``; a repeated or late sample is counted (``duplicates``,
``stale``) and not taken. :meth:`GyroHost.read_rate` waits up to a monotonic deadline
and raises :class:`~drivers.errors.DeviceTimeoutError`; a port that fails (a USB adapter unplugged)
is reopened on the next call when the driver opened it from a URL.
"""

from __future__ import annotations

from typing import Any

from drivers.datagram import DatagramHost
from drivers.gyro.codec import GyroCodec, GyroRate, SetOutputPeriod, SetTime

__all__ = ["GyroHost"]


class GyroHost(DatagramHost):
    """Host-side driver of one gyro.

    Args:
        port: URL/path (opened with pyserial's ``serial_for_url``, reopened after a port failure,
            closed by :meth:`close`) or an open port object the caller keeps.
        codec: a :class:`GyroCodec` (default: the ICD in ``fixtures/``).
        baudrate: for URL ports (460800, the ICD's).
        timeout_s: default timeout of :meth:`read_rate`.
        name: how errors name this device.
        poll_s: the port's read timeout slice.

    Attributes:
        latest_rate: the newest :class:`GyroRate` received, or None.
        counters: ``sent``, ``bytes_received``, ``frames_received``, ``rejected_crc``,
            ``rejected_other``, ``bytes_dropped``, ``timeouts``, ``recoveries``, ``reconnects``,
            ``samples`` (RATE datagrams), ``samples_lost`` (gaps in the sample counter).
    """

    _kind = "gyro"

    def __init__(self, port: Any, *, codec: GyroCodec | None = None, baudrate: int = 460800,
                 timeout_s: float = 0.5, name: str = "gyro", poll_s: float = 0.05) -> None:
        super().__init__(port, codec if codec is not None else GyroCodec(), baudrate=baudrate,
                         timeout_s=timeout_s, name=name, poll_s=poll_s)
        self.counters.update({"samples": 0, "samples_lost": 0})
        self.latest_rate: GyroRate | None = None
        self._taken = True

    def _accept_message(self, msg: Any) -> None:
        if type(msg) is GyroRate:
            last = self.latest_rate
            if last is not None and not self._fresh(last.seq, msg.seq, 0x100):
                return  # a duplicate or a sample late out of order: not the newest
            self.latest_rate = msg
            self.counters["samples"] += 1
            self._taken = False

    def take_rate(self) -> GyroRate | None:
        """Poll (never blocks); the newest RATE not returned before, or None."""
        self.poll()
        if self._taken:
            return None
        self._taken = True
        return self.latest_rate

    def read_rate(self, timeout_s: float | None = None) -> GyroRate:
        """Wait (up to ``timeout_s``, default the driver's) for a RATE not returned before."""
        self._wait(lambda: not self._taken, "RATE datagram", timeout_s)
        self._taken = True
        return self.latest_rate  # type: ignore[return-value]

    def set_time(self, time_us: int) -> None:
        """Send SET_TIME: the device clock reads ``time_us`` now (not acknowledged)."""
        self.send(SetTime(int(time_us)))

    def set_output_period(self, period_s: float) -> None:
        """Send SET_OUTPUT_PERIOD (EncodeError outside 0.5 ms .. 1 s; not acknowledged)."""
        self.send(SetOutputPeriod(float(period_s)))
