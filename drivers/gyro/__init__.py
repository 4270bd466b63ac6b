"""Three-axis rate gyro on a serial line (ICD: ``fixtures/devices/gyro.toml``; document: ``docs/gyro_icd.md``).

- :mod:`.codec`: pure codec, datagrams <-> messages in SI units;
- :mod:`.host`: :class:`GyroHost`, the stand (or flight software) reading a gyro;
- :mod:`.emulator`: :class:`GyroEmulator`, the stand being the gyro (publishes the rate its source gives);
- :mod:`.icd`: renders the ICD document from the TOML.

The host and emulator modules import pyserial lazily (only to open a URL).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from drivers.gyro.codec import GyroCodec, GyroRate, SetOutputPeriod, SetTime
from drivers.lazy import lazy_getattr

if TYPE_CHECKING:  # pragma: no cover
    from drivers.gyro.emulator import GyroEmulator, GyroEmulatorConfig
    from drivers.gyro.host import GyroHost

__all__ = ["GyroCodec", "GyroEmulator", "GyroEmulatorConfig", "GyroHost", "GyroRate", "SetOutputPeriod", "SetTime"]

__getattr__ = lazy_getattr(__name__, {
    "GyroHost": "drivers.gyro.host",
    "GyroEmulator": "drivers.gyro.emulator",
    "GyroEmulatorConfig": "drivers.gyro.emulator",
})
