"""Pure codec of the serial sun sensor, built from ``fixtures/devices/sun_sensor.toml`` (no port, no clock).

Datagram: ``identifier u8 | payload | CRC-16/CCITT-FALSE u16``, little-endian, fixed length per
identifier (see :mod:`drivers.datagram`). Messages are frozen dataclasses in SI units:

==================  =====  ============  =========================================================
datagram            id     direction     content
==================  =====  ============  =========================================================
FINE_SAMPLE         0xA1   device->host  :class:`FineSunSample`: two sun angles (rad), intensity,
                                         valid, time stamp (us), counter
COARSE_SAMPLE       0xA2   device->host  :class:`CoarseSunSample`: six head currents (A), valid,
                                         saturated, time stamp (us), counter
SET_TIME            0x41   host->device  :class:`SetTime`
REQUEST_SAMPLE      0x42   host->device  :class:`RequestSample`: measure and send now
SET_OUTPUT_PERIOD   0x43   host->device  :class:`SetOutputPeriod`: 0 = on request only
==================  =====  ============  =========================================================

Round trip: ``codec.decode(codec.encode(x)) == x`` for values on the wire's grid (1 urad, 1 %,
0.1 uA, 1 us, 1 ms).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drivers.datagram import DatagramCodec, DatagramRejected, crc16

__all__ = ["CLASSES", "HEADS", "CoarseSunSample", "DatagramRejected", "FineSunSample", "RequestSample",
           "SetOutputPeriod", "SetTime", "SunSensorCodec", "crc16", "default_icd_path"]

#: Photodiode heads of the coarse sensor.
HEADS = 6


@dataclass(frozen=True, slots=True)
class FineSunSample:
    """Fine sensor: ``angles_rad`` = (alpha, beta) in the sensor frame, ``intensity`` (fraction of
    full sun), ``valid``, ``time_us`` (device clock), ``seq``."""

    time_us: int
    angles_rad: tuple[float, float]
    intensity: float
    valid: bool
    time_synced: bool
    seq: int


@dataclass(frozen=True, slots=True)
class CoarseSunSample:
    """Coarse sensor: ``currents_A`` of the six heads, ``valid``, ``saturated``, ``time_us``, ``seq``."""

    time_us: int
    currents_A: tuple[float, float, float, float, float, float]
    valid: bool
    saturated: bool
    time_synced: bool
    seq: int


@dataclass(frozen=True, slots=True)
class SetTime:
    time_us: int


@dataclass(frozen=True, slots=True)
class RequestSample:
    pass


@dataclass(frozen=True, slots=True)
class SetOutputPeriod:
    """Publish every ``period_s`` (0 = only on request)."""

    period_s: float


CLASSES: dict[str, type] = {
    "FINE_SAMPLE": FineSunSample,
    "COARSE_SAMPLE": CoarseSunSample,
    "SET_TIME": SetTime,
    "REQUEST_SAMPLE": RequestSample,
    "SET_OUTPUT_PERIOD": SetOutputPeriod,
}


def default_icd_path() -> Path:
    """``fixtures/devices/sun_sensor.toml``."""
    from drivers import fixture_path

    return fixture_path("devices/sun_sensor.toml")


class SunSensorCodec(DatagramCodec):
    """Encode and decode sun-sensor datagrams, from the ICD at ``icd_path`` (default: the fixture).

    Extra attributes: ``angle_range_rad``, ``current_range_A``, ``current_lsb_A``, ``period_range_s``.
    """

    def __init__(self, icd_path: str | Path | None = None) -> None:
        super().__init__(default_icd_path() if icd_path is None else icd_path, CLASSES, "sun sensor")
        heads = sum(1 for f in self.messages["COARSE_SAMPLE"].fields if f.attr == "currents_A")
        if heads != HEADS:
            raise ValueError(f"sun sensor ICD: COARSE_SAMPLE has {heads} head currents; this codec expects {HEADS}.")
        self.angle_range_rad: tuple[float, float] = self.si_range("FINE_SAMPLE", "alpha")
        self.current_range_A: tuple[float, float] = self.si_range("COARSE_SAMPLE", "current_0")
        self.current_lsb_A: float = self.lsb("COARSE_SAMPLE", "current_0")
        self.period_range_s: tuple[float, float] = self.si_range("SET_OUTPUT_PERIOD", "period")
