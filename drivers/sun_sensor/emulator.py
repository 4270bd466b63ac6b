"""Emulator: the stand *being* a serial sun sensor (fine two-axis or coarse six-head), on any port.

It serves the ICD (``fixtures/devices/sun_sensor.toml``) through the same codec as the host driver
and knows no physics: the stand hands it ``sun_source(t_s) -> (values, valid)`` or
``(values, valid, intensity)``, exactly what :meth:`sim.sensors.FineSunSensor.measure` (two angles,
rad) or :meth:`sim.sensors.CoarseSunSensors.measure` (six head currents, A; the stand supplies
``valid``, e.g. "not in umbra") give. The emulator adds only what the wire does: quantisation, the
angle and current ranges, angles sent as 0 when not valid.

Behaviour (times are sim seconds passed to :meth:`SunSensorEmulator.service`; no clock is read there):

- Power-up at the first service time ``t_on``; with ``output_period_s`` > 0 a sample is due at
  ``t_on + k * period`` (SET_OUTPUT_PERIOD restarts the grid at the command; 0 = only on request).
  A late service sends the newest due sample (measured at its slot time) and counts the missed
  slots in ``samples_skipped``.
- REQUEST_SAMPLE: a sample measured at the service time, sent at once.
- Fine: ``intensity`` is the third element of the source's answer, else 1 when valid and 0 when
  not. Coarse: a head beyond the current range is clipped and flags ``saturated`` (not valid).
- Commands with a bad CRC or a value outside its range are counted and ignored.
- Reboot (:meth:`SunSensorEmulator.reboot`, :mod:`drivers.device_faults`): silent for the boot, then a power-up
  as above: counter from 0, the clock restarted and not synchronised, the configured output period.

``counters``: ``bytes_received``, ``frames_received``, ``sent``, ``rejected_crc``,
``rejected_undecodable`` (each stretch of bytes that held no good datagram, once), ``rejected_other``,
``bytes_dropped``, ``samples``, ``samples_skipped``, ``saturations``,
``requests``, ``commands_applied``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drivers.datagram import DatagramEmulator
from drivers.sun_sensor.codec import (
    HEADS,
    CoarseSunSample,
    FineSunSample,
    RequestSample,
    SetOutputPeriod,
    SetTime,
    SunSensorCodec,
)

__all__ = ["SunEmulatorConfig", "SunSensorEmulator", "SunSource"]

SunSource = Callable[[float], Any]
_EPS_S = 1e-9
KINDS = ("fine", "coarse")


@dataclass(frozen=True)
class SunEmulatorConfig:
    """Knobs of the emulated sun sensor.

    Attributes:
        kind: ``"fine"`` (two angles) or ``"coarse"`` (six head currents).
        output_period_s: time between samples sent unasked (0.1 s); 0 = only on request.
        clock_offset_s: the device clock before SET_TIME is ``clock_offset_s + t``.
    """

    kind: str = "fine"
    output_period_s: float = 0.1
    clock_offset_s: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"SunEmulatorConfig.kind must be one of {', '.join(KINDS)}; got {self.kind!r}.")
        for name in ("output_period_s", "clock_offset_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"SunEmulatorConfig.{name} must be a finite number >= 0; got {v!r}.")


class SunSensorEmulator(DatagramEmulator):
    """A sun sensor, emulated on ``port`` (see the module docstring for the behaviour).

    Args:
        port: URL/path (opened with pyserial and closed by :meth:`close`) or an open port object
            (the caller keeps it).
        sun_source: ``sun_source(t_s) -> (values, valid)`` or ``(values, valid, intensity)``; values
            are the two angles (rad) of a fine sensor or the six head currents (A) of a coarse one.
        config: :class:`SunEmulatorConfig` (the kind, the output period).
        codec: a :class:`SunSensorCodec` (default: the ICD in ``fixtures/``).
        baudrate: for URL ports.
    """

    def __init__(
        self,
        port: Any,
        sun_source: SunSource,
        config: SunEmulatorConfig | None = None,
        codec: SunSensorCodec | None = None,
        *,
        baudrate: int = 115200,
        name: str = "sun sensor emulator",
    ) -> None:
        self.config = cfg = config if config is not None else SunEmulatorConfig()
        codec = codec if codec is not None else SunSensorCodec()
        if cfg.output_period_s > codec.period_range_s[1]:
            raise ValueError(f"SunEmulatorConfig.output_period_s = {cfg.output_period_s!r} exceeds what "
                             f"SET_OUTPUT_PERIOD carries ({codec.period_range_s[1]:g} s).")
        self.source = sun_source
        super().__init__(port, codec, baudrate=baudrate, name=name, clock_offset_s=cfg.clock_offset_s)
        self.counters.update({"samples": 0, "samples_skipped": 0, "saturations": 0, "requests": 0,
                              "commands_applied": 0})
        self.kind = cfg.kind
        self.period_s = cfg.output_period_s
        self._t_on: float | None = None
        self._grid0 = 0.0
        self._k = 0
        self._seq = 0
        self._angle_max = codec.angle_range_rad[1]
        self._i_max = codec.current_range_A[1]
        #: The newest sample sent, or None.
        self.latest_sample: FineSunSample | CoarseSunSample | None = None

    def service(self, t_s: float) -> None:
        """Apply received commands (answering requests) at ``t_s``, then publish what is due."""
        self._check_open()
        if self._t_on is None:
            if self.booting(t_s):  # rebooting (drivers.device_faults): off until the boot ends
                self._drop_input()
                return
            self._t_on = self._grid0 = t_s
            self._k = 0
        self._receive(t_s)
        self._publish(t_s)

    def _reboot_device(self, t_up: float) -> None:
        # Power-up again at the first service after the boot: counter from 0, the configured period.
        self._t_on = None
        self.period_s = self.config.output_period_s
        self._seq = 0

    def next_due_s(self) -> float | None:
        if self._t_on is None or self.period_s <= 0:
            return None
        return self._grid0 + self._k * self.period_s

    def _publish(self, t_s: float) -> None:
        period = self.period_s
        if period <= 0 or self._grid0 + self._k * period > t_s + _EPS_S:
            return
        last = math.floor((t_s + _EPS_S - self._grid0) / period)
        self.counters["samples_skipped"] += last - self._k
        self._send(self.sample(self._grid0 + last * period))
        self._k = last + 1

    def _apply(self, msg: Any, t_s: float) -> None:
        if isinstance(msg, RequestSample):
            self.counters["requests"] += 1
            self._send(self.sample(t_s))
            return
        if isinstance(msg, SetTime):
            self.set_time(t_s, msg.time_us)
        elif isinstance(msg, SetOutputPeriod):
            self.period_s = msg.period_s
            self._grid0, self._k = t_s, 1
        else:  # pragma: no cover - the decoder only lets host->device datagrams through
            return
        self.counters["commands_applied"] += 1

    def sample(self, t_k: float) -> FineSunSample | CoarseSunSample:
        """The sample the sensor reports for measurement time ``t_k`` (advances the counter)."""
        got = self.source(t_k)
        width = 2 if self.kind == "fine" else HEADS
        try:
            values, valid, *rest = got
            v = [float(x) for x in values]
            valid = bool(valid)
            intensity = float(rest[0]) if rest else (1.0 if valid else 0.0)
            if len(v) != width or len(rest) > 1 or not math.isfinite(intensity):
                raise ValueError
            if valid and not all(math.isfinite(x) for x in v):
                raise ValueError
        except (TypeError, ValueError):
            what = "2 angles (rad)" if self.kind == "fine" else f"{HEADS} head currents (A)"
            raise ValueError(f"sun_source({t_k!r}) must return (values, valid) or (values, valid, intensity) with "
                             f"{what}, finite when valid; got {got!r}.") from None
        seq = self._seq
        self._seq = (seq + 1) & 0xFFFF
        self.counters["samples"] += 1
        time_us = self.device_time_us(t_k)
        msg: FineSunSample | CoarseSunSample
        if self.kind == "fine":
            a_max = self._angle_max
            if valid and not all(abs(x) <= a_max for x in v):
                valid = False  # the Sun beyond 90 deg: no fine-sensor reading can carry it
            angles = (round(v[0] * 1e6) * 1e-6, round(v[1] * 1e6) * 1e-6) if valid else (0.0, 0.0)
            msg = FineSunSample(time_us, angles, round(min(max(intensity, 0.0), 1.0) * 100) * 0.01, valid,
                                self.time_synced, seq)
        else:
            i_max = self._i_max
            saturated = any(x > i_max for x in v)
            if saturated:
                self.counters["saturations"] += 1
            lsb = 1e-7
            currents = tuple(round(min(max(x if math.isfinite(x) else 0.0, 0.0), i_max) / lsb) * lsb for x in v)
            msg = CoarseSunSample(time_us, currents, valid and not saturated, saturated,  # type: ignore[arg-type]
                                  self.time_synced, seq)
        self.latest_sample = msg
        return msg
