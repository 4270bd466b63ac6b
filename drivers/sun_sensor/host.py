"""Host driver: the stand (or flight software) reading a serial sun sensor, fine or coarse.

The sensor may be real or :class:`~drivers.sun_sensor.emulator.SunSensorEmulator` on a pty, socat
link or ``socket://``: the driver cannot tell. It streams at its output period; it also answers
REQUEST_SAMPLE::

    with SunSensorHost("/dev/ttyUSB1") as sun:
        s = sun.take_sun()          # once per control tick: the newest unseen sample, or None
        s.angles_rad (fine) or s.currents_A (coarse), s.valid, s.time_us

Receiving never raises on bad traffic (bad CRC, a field outside its table, stray bytes: counted and
dropped). :meth:`SunSensorHost.read_sun` and :meth:`SunSensorHost.request_sun` wait up to a
monotonic deadline and raise :class:`~drivers.errors.DeviceTimeoutError`.
"""

from __future__ import annotations

from typing import Any

from drivers.datagram import DatagramHost
from drivers.sun_sensor.codec import (
    CoarseSunSample,
    FineSunSample,
    RequestSample,
    SetOutputPeriod,
    SetTime,
    SunSensorCodec,
)

__all__ = ["SunSensorHost"]


class SunSensorHost(DatagramHost):
    """Host-side driver of one sun sensor.

    Args:
        port: URL/path (opened with pyserial, reopened after a port failure, closed by :meth:`close`)
            or an open port object the caller keeps.
        codec: a :class:`SunSensorCodec` (default: the ICD in ``fixtures/``).
        baudrate, timeout_s, name, poll_s: as for the other serial hosts.

    Attributes:
        latest_sample: the newest :class:`FineSunSample` or :class:`CoarseSunSample`, or None.
        counters: ``sent``, ``bytes_received``, ``frames_received``, ``rejected_crc``,
            ``rejected_other``, ``bytes_dropped``, ``timeouts``, ``recoveries``, ``reconnects``,
            ``samples``, ``samples_lost`` (gaps in the sample counter).
    """

    _kind = "sun sensor"

    def __init__(self, port: Any, *, codec: SunSensorCodec | None = None, baudrate: int = 115200,
                 timeout_s: float = 0.5, name: str = "sun sensor", poll_s: float = 0.05) -> None:
        super().__init__(port, codec if codec is not None else SunSensorCodec(), baudrate=baudrate,
                         timeout_s=timeout_s, name=name, poll_s=poll_s)
        self.counters.update({"samples": 0, "samples_lost": 0})
        self.latest_sample: FineSunSample | CoarseSunSample | None = None
        self._taken = True

    def _accept_message(self, msg: Any) -> None:
        if isinstance(msg, (FineSunSample, CoarseSunSample)):
            last = self.latest_sample
            if last is not None and type(last) is type(msg) and not self._fresh(last.seq, msg.seq, 0x10000):
                return  # a duplicate or a sample late out of order: not the newest
            self.latest_sample = msg
            self.counters["samples"] += 1
            self._taken = False

    def take_sun(self) -> FineSunSample | CoarseSunSample | None:
        """Poll (never blocks); the newest sample not returned before, or None."""
        self.poll()
        if self._taken:
            return None
        self._taken = True
        return self.latest_sample

    def read_sun(self, timeout_s: float | None = None) -> FineSunSample | CoarseSunSample:
        """Wait (up to ``timeout_s``, default the driver's) for a sample not returned before."""
        self._wait(lambda: not self._taken, "sun sample", timeout_s)
        self._taken = True
        return self.latest_sample  # type: ignore[return-value]

    def request_sun(self, timeout_s: float | None = None) -> FineSunSample | CoarseSunSample:
        """Send REQUEST_SAMPLE and wait for the sample it brings (or any newer one)."""
        self.poll()
        self._taken = True
        self.send(RequestSample())
        return self.read_sun(timeout_s)

    def set_time(self, time_us: int) -> None:
        """Send SET_TIME: the device clock reads ``time_us`` now (not acknowledged)."""
        self.send(SetTime(int(time_us)))

    def set_output_period(self, period_s: float) -> None:
        """Send SET_OUTPUT_PERIOD (0 = only on request; EncodeError beyond 60 s; not acknowledged)."""
        self.send(SetOutputPeriod(float(period_s)))
