"""Pure codec of the serial gyro, built from ``fixtures/devices/gyro.toml`` (no port, no clock).

Datagram: ``identifier u8 | payload | CRC-16/CCITT-FALSE u16``, big-endian, fixed length per
identifier (see :mod:`drivers.datagram`). Messages are frozen dataclasses in SI units:

==================  =====  ============  =========================================================
datagram            id     direction     content
==================  =====  ============  =========================================================
RATE                0x93   device->host  :class:`GyroRate`: rates (rad/s, sensor axes), flags,
                                         sample counter, latency, device time stamp (us)
SET_TIME            0x51   host->device  :class:`SetTime`: set the device clock (us)
SET_OUTPUT_PERIOD   0x52   host->device  :class:`SetOutputPeriod`: output period (s)
==================  =====  ============  =========================================================

Round trip: ``codec.decode(codec.encode(x)) == x`` for every message whose values lie on the
wire's grid (2^-14 deg/s for rates, 1 us for times).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drivers.datagram import DatagramCodec, DatagramRejected, crc16

__all__ = ["CLASSES", "DatagramRejected", "GyroCodec", "GyroRate", "SetOutputPeriod", "SetTime", "crc16",
           "default_icd_path"]


@dataclass(frozen=True, slots=True)
class GyroRate:
    """One rate sample: ``omega_rad_s`` in sensor axes, ``time_us`` the sample time in the device
    clock, ``latency_s`` from the sample to the datagram, ``seq`` an 8-bit counter."""

    omega_rad_s: tuple[float, float, float]
    valid: bool
    saturated_x: bool
    saturated_y: bool
    saturated_z: bool
    startup: bool
    time_synced: bool
    seq: int
    latency_s: float
    time_us: int


@dataclass(frozen=True, slots=True)
class SetTime:
    """Set the device clock to ``time_us``."""

    time_us: int


@dataclass(frozen=True, slots=True)
class SetOutputPeriod:
    """Publish a RATE datagram every ``period_s`` (0.5 ms to 1 s)."""

    period_s: float


CLASSES: dict[str, type] = {"RATE": GyroRate, "SET_TIME": SetTime, "SET_OUTPUT_PERIOD": SetOutputPeriod}


def default_icd_path() -> Path:
    """``fixtures/devices/gyro.toml``."""
    from drivers import fixture_path

    return fixture_path("devices/gyro.toml")


class GyroCodec(DatagramCodec):
    """Encode and decode gyro datagrams, from the ICD at ``icd_path`` (default: the fixture).

    ``encode(msg) -> bytes`` (a whole datagram); ``decode(datagram) -> msg`` raises
    :class:`~drivers.datagram.DatagramRejected` (a ProtocolError: datagram in hex, kind, expected vs
    got). Extra attributes: ``rate_lsb_rad_s``, ``rate_range_rad_s`` (what RATE can carry per axis),
    ``period_range_s``.
    """

    def __init__(self, icd_path: str | Path | None = None) -> None:
        super().__init__(default_icd_path() if icd_path is None else icd_path, CLASSES, "gyro")
        self.rate_lsb_rad_s: float = self.lsb("RATE", "rate_x")
        self.rate_range_rad_s: tuple[float, float] = self.si_range("RATE", "rate_x")
        self.period_range_s: tuple[float, float] = self.si_range("SET_OUTPUT_PERIOD", "period")
