"""Emulator: the stand *being* the serial gyro, on any port (URL, pty, open serial object).

It serves the ICD (``fixtures/devices/gyro.toml``) through the same codec as the host driver and
knows no physics: the stand hands it ``rate_source(t_s) -> (3,)``, the rate the gyro measures at
sim time ``t_s`` in sensor axes (rad/s). The sensor model (noise, bias, scale factor,
misalignment, delay: :class:`sim.sensors.Gyro`) is the stand's business; the emulator adds only
what the wire does: quantisation to the datagram's LSB and saturation at the configured range.

Behaviour (times are sim seconds passed to :meth:`GyroEmulator.service`; no clock is read there):

- Power-up at the first service time ``t_on``; RATE datagrams are due at ``t_on + k * period``
  (``output_period_s``, or the period last set by SET_OUTPUT_PERIOD, whose grid starts at the
  command). Every due sample is sent, oldest first, each from ``rate_source(t_k)`` at its own
  sample time ``t_k <= t_s``; when more than ``max_burst`` are due at once only the newest
  ``max_burst`` are sent and the rest are counted in ``samples_skipped`` (the sample counter
  still steps over them, so the host sees the gap).
- ``startup`` and not ``valid`` for samples within ``startup_time_s`` of power-up; an axis beyond
  ``range_rad_s`` is clipped, flagged ``saturated_*`` and clears ``valid``.
- Time stamp: ``t_k`` in the device clock (``clock_offset_s + t`` until SET_TIME sets it).
- Commands with a bad CRC or a value outside its range are counted and ignored (no replies).
- Reboot (:meth:`GyroEmulator.reboot`, :mod:`drivers.device_faults`): silent for the boot, then a power-up as
  above: counter from 0, ``startup`` for ``startup_time_s``, the clock restarted and not synchronised, the
  configured output period.

``counters``: ``bytes_received``, ``frames_received``, ``sent``, ``rejected_crc``,
``rejected_undecodable`` (each stretch of bytes that held no good datagram, once), ``rejected_other``,
``bytes_dropped``, ``samples``, ``samples_skipped``, ``saturations``,
``commands_applied``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from drivers.datagram import DatagramEmulator
from drivers.gyro.codec import GyroCodec, GyroRate, SetOutputPeriod, SetTime

__all__ = ["GyroEmulator", "GyroEmulatorConfig", "RateSource"]

RateSource = Callable[[float], Sequence[float]]
_EPS_S = 1e-9


@dataclass(frozen=True)
class GyroEmulatorConfig:
    """Knobs of the emulated gyro.

    Attributes:
        output_period_s: time between RATE datagrams (0.01 s = 100 Hz; the ICD allows 0.5 ms to 1 s).
        range_rad_s: measurement range per axis (400 deg/s, the STIM210's); None = what the field
            carries (512 deg/s).
        latency_s: the latency reported in each datagram (from sampling to sending; 0.5 ms).
        startup_time_s: samples are flagged ``startup`` and not valid this long after power-up.
        clock_offset_s: the device clock before SET_TIME is ``clock_offset_s + t``.
        max_burst: at most this many datagrams per service call.
    """

    output_period_s: float = 0.01
    range_rad_s: float | None = math.radians(400.0)
    latency_s: float = 5e-4
    startup_time_s: float = 0.0
    clock_offset_s: float = 0.0
    max_burst: int = 64

    def __post_init__(self) -> None:
        for name in ("output_period_s", "latency_s", "startup_time_s", "clock_offset_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"GyroEmulatorConfig.{name} must be a finite number >= 0; got {v!r}.")
        if self.range_rad_s is not None and not (math.isfinite(self.range_rad_s) and self.range_rad_s > 0):
            raise ValueError(f"GyroEmulatorConfig.range_rad_s must be a finite number > 0 or None; "
                             f"got {self.range_rad_s!r}.")
        if not (isinstance(self.max_burst, int) and self.max_burst >= 1):
            raise ValueError(f"GyroEmulatorConfig.max_burst must be an int >= 1; got {self.max_burst!r}.")


class GyroEmulator(DatagramEmulator):
    """The gyro, emulated on ``port`` (see the module docstring for the behaviour).

    Args:
        port: URL/path (opened with pyserial and closed by :meth:`close`) or an open port object
            (``serial.Serial``, :class:`~drivers.serial_port.FdPort`; the caller keeps it).
        rate_source: ``rate_source(t_s) -> (3,)`` measured rate in sensor axes, rad/s.
        config: :class:`GyroEmulatorConfig`.
        codec: a :class:`GyroCodec` (default: the ICD in ``fixtures/``).
        baudrate: for URL ports.
    """

    def __init__(
        self,
        port: Any,
        rate_source: RateSource,
        config: GyroEmulatorConfig | None = None,
        codec: GyroCodec | None = None,
        *,
        baudrate: int = 460800,
        name: str = "gyro emulator",
    ) -> None:
        self.config = cfg = config if config is not None else GyroEmulatorConfig()
        codec = codec if codec is not None else GyroCodec()
        lo_p, hi_p = codec.period_range_s
        if not lo_p - 1e-12 <= cfg.output_period_s <= hi_p + 1e-12:
            raise ValueError(f"GyroEmulatorConfig.output_period_s = {cfg.output_period_s!r} is outside what "
                             f"SET_OUTPUT_PERIOD allows: {lo_p:g} to {hi_p:g} s.")
        if not cfg.latency_s <= codec.si_range("RATE", "latency")[1]:
            raise ValueError(f"GyroEmulatorConfig.latency_s = {cfg.latency_s!r} exceeds what RATE carries "
                             f"({codec.si_range('RATE', 'latency')[1]:g} s).")
        wire_max = codec.rate_range_rad_s[1]
        self.range_rad_s = wire_max if cfg.range_rad_s is None else min(cfg.range_rad_s, wire_max)
        self.source = rate_source
        super().__init__(port, codec, baudrate=baudrate, name=name, clock_offset_s=cfg.clock_offset_s)
        self.counters.update({"samples": 0, "samples_skipped": 0, "saturations": 0, "commands_applied": 0})
        self.period_s = cfg.output_period_s
        self._t_on: float | None = None
        self._grid0 = 0.0  # sample k of the current period is due at _grid0 + k * period_s
        self._k = 1
        self._seq = 0
        self._latency_s = round(cfg.latency_s * 1e6) * 1e-6  # on the datagram's 1 us grid
        self._make_rate = codec.messages["RATE"].make
        #: The newest RATE sent, or None.
        self.latest_rate: GyroRate | None = None

    # -- service ----------------------------------------------------------------------------------

    def service(self, t_s: float) -> None:
        """Apply received commands at ``t_s``, then publish every sample due by ``t_s``."""
        self._check_open()
        if self._t_on is None:
            if self.booting(t_s):  # rebooting (drivers.device_faults): off until the boot ends
                self._drop_input()
                return
            self._t_on = self._grid0 = t_s
            self._k = 0  # a sample at power-up
        self._receive(t_s)
        self._publish(t_s)

    def _reboot_device(self, t_up: float) -> None:
        # Power-up again at the first service after the boot: sample counter from 0, the configured period,
        # and the startup flag for startup_time_s.
        self._t_on = None
        self.period_s = self.config.output_period_s
        self._seq = 0

    def next_due_s(self) -> float | None:
        return None if self._t_on is None else self._grid0 + self._k * self.period_s

    def _publish(self, t_s: float) -> None:
        period, grid0, k = self.period_s, self._grid0, self._k
        if grid0 + k * period > t_s + _EPS_S:
            return
        last = math.floor((t_s + _EPS_S - grid0) / period)
        first = last - self.config.max_burst + 1
        if first < k:  # max(k, ...) without its call
            first = k
        self.counters["samples_skipped"] += first - k
        self._seq = (self._seq + first - k) & 0xFF  # skipped samples were taken, only not sent
        for j in range(first, last + 1):
            self._send(self.sample(grid0 + j * period))
        self._k = last + 1

    def sample(self, t_k: float) -> GyroRate:
        """The RATE the gyro reports for sample time ``t_k`` (advances the sample counter)."""
        omega = self.source(t_k)
        try:
            wx, wy, wz = omega
            wx, wy, wz = float(wx), float(wy), float(wz)
            if not (math.isfinite(wx) and math.isfinite(wy) and math.isfinite(wz)):
                raise ValueError
        except (TypeError, ValueError):
            raise ValueError(f"rate_source({t_k!r}) must return 3 finite floats (rad/s, sensor axes); "
                             f"got {omega!r}.") from None
        r = self.range_rad_s
        sat_x, sat_y, sat_z = abs(wx) > r, abs(wy) > r, abs(wz) > r
        saturated = sat_x or sat_y or sat_z
        if saturated:
            self.counters["saturations"] += 1
            wx, wy, wz = min(max(wx, -r), r), min(max(wy, -r), r), min(max(wz, -r), r)
        startup = t_k - (self._t_on or 0.0) < self.config.startup_time_s - _EPS_S
        lsb = self.codec.rate_lsb_rad_s  # type: ignore[attr-defined]
        seq = self._seq
        self._seq = (seq + 1) & 0xFF
        self.counters["samples"] += 1
        msg = self._make_rate({  # GyroRate(**these), with fewer calls (drivers.frozen_build)
            "omega_rad_s": (round(wx / lsb) * lsb, round(wy / lsb) * lsb, round(wz / lsb) * lsb),
            "valid": not (startup or saturated),
            "saturated_x": sat_x, "saturated_y": sat_y, "saturated_z": sat_z,
            "startup": startup,
            "time_synced": self.time_synced,
            "seq": seq,
            "latency_s": self._latency_s,
            "time_us": self.device_time_us(t_k),
        })
        self.latest_rate = msg
        return msg

    def _apply(self, msg: Any, t_s: float) -> None:
        if isinstance(msg, SetTime):
            self.set_time(t_s, msg.time_us)
        elif isinstance(msg, SetOutputPeriod):
            self.period_s = msg.period_s
            self._grid0 = t_s
            self._k = 1
        else:  # pragma: no cover - the decoder only lets host->device datagrams through
            return
        self.counters["commands_applied"] += 1
