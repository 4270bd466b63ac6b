"""Pure codec of the GNSS receiver, built from ``icd.toml`` beside this module (no port, no clock).

==================  =====  ============  ===========================================================
datagram            id     direction     content
==================  =====  ============  ===========================================================
FIX                 0xA1   device->host  :class:`GnssFix`: position (m) and velocity (m/s) in frame N,
                                         GPS week and time of week (s), satellites, valid, counter
SET_OUTPUT_PERIOD   0x5A   host->device  :class:`SetOutputPeriod`: output period (s)
==================  =====  ============  ===========================================================
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drivers.datagram import DatagramCodec

__all__ = ["CLASSES", "GnssCodec", "GnssFix", "SetOutputPeriod", "icd_path"]


@dataclass(frozen=True, slots=True)
class GnssFix:
    """One fix: ``r_N_m`` and ``v_N_m_s`` in the stand's inertial frame N, at GPS time ``gps_week``,
    ``tow_s``; ``seq`` an 8-bit counter."""

    r_N_m: tuple[float, float, float]
    v_N_m_s: tuple[float, float, float]
    gps_week: int
    tow_s: float
    satellites: int
    valid: bool
    seq: int


@dataclass(frozen=True, slots=True)
class SetOutputPeriod:
    """Publish a FIX every ``period_s`` (0.1 s to 10 s)."""

    period_s: float


CLASSES: dict[str, type] = {"FIX": GnssFix, "SET_OUTPUT_PERIOD": SetOutputPeriod}


def icd_path() -> Path:
    """The ICD shipped in this package."""
    return Path(__file__).with_name("icd.toml")


class GnssCodec(DatagramCodec):
    """Encode and decode GNSS datagrams (``encode(msg) -> bytes``, ``decode(datagram) -> msg``).

    Extra attributes, read from the ICD so that nothing here repeats it: ``position_lsb_m``,
    ``velocity_lsb_m_s``, ``period_range_s``.
    """

    def __init__(self, path: str | Path | None = None) -> None:
        super().__init__(icd_path() if path is None else path, CLASSES, "gnss")
        self.position_lsb_m: float = self.lsb("FIX", "pos_x")
        self.velocity_lsb_m_s: float = self.lsb("FIX", "vel_x")
        self.period_range_s: tuple[float, float] = self.si_range("SET_OUTPUT_PERIOD", "period")
