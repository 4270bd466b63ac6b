"""Sun sensor on a serial line, fine (two angles) or coarse (six head currents) (ICD:
``fixtures/devices/sun_sensor.toml``; document: ``docs/sun_sensor_icd.md``).

- :mod:`.codec`: pure codec, datagrams <-> messages in SI units;
- :mod:`.host`: :class:`SunSensorHost`, the stand (or flight software) reading a sun sensor;
- :mod:`.emulator`: :class:`SunSensorEmulator`, the stand being the sensor (reports what its source gives);
- :mod:`.icd`: renders the ICD document from the TOML.

The host and emulator modules import pyserial lazily (only to open a URL).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from drivers.lazy import lazy_getattr
from drivers.sun_sensor.codec import (
    CoarseSunSample,
    FineSunSample,
    RequestSample,
    SetOutputPeriod,
    SetTime,
    SunSensorCodec,
)

if TYPE_CHECKING:  # pragma: no cover
    from drivers.sun_sensor.emulator import SunEmulatorConfig, SunSensorEmulator
    from drivers.sun_sensor.host import SunSensorHost

__all__ = ["CoarseSunSample", "FineSunSample", "RequestSample", "SetOutputPeriod", "SetTime",
           "SunEmulatorConfig", "SunSensorCodec", "SunSensorEmulator", "SunSensorHost"]

__getattr__ = lazy_getattr(__name__, {
    "SunSensorHost": "drivers.sun_sensor.host",
    "SunSensorEmulator": "drivers.sun_sensor.emulator",
    "SunEmulatorConfig": "drivers.sun_sensor.emulator",
})
