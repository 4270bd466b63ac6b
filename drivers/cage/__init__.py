"""Helmholtz cage over Modbus (register map: ``fixtures/devices/cage.toml``).

- :mod:`.registers`: the register map and a pure codec, register words <-> SI values;
- :mod:`.model`: the cage itself, pure (no port, no clock): supplies, coils, relays, interlocks,
  magnetometer, stepped in time;
- :mod:`.emulator`: :class:`CageEmulator`, the model behind a pymodbus server (TCP or RTU);
- :mod:`.host`: :class:`CageHost`, the stand driving a cage through pymodbus's client;
- :mod:`.calibration`: coil constants and the lab field by least squares, stored per bench.

The emulator and host modules import pymodbus; importing this package does not.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from drivers.cage.calibration import CageCalibration, fit_calibration
from drivers.cage.model import CageConfig, CageModel
from drivers.cage.registers import Register, RegisterMap, load_map
from drivers.lazy import lazy_getattr

if TYPE_CHECKING:  # pragma: no cover
    from drivers.cage.emulator import CageEmulator
    from drivers.cage.host import CageHost, CageStatus, FieldSample

__all__ = [
    "CageCalibration",
    "CageConfig",
    "CageEmulator",
    "CageHost",
    "CageModel",
    "CageStatus",
    "FieldSample",
    "Register",
    "RegisterMap",
    "fit_calibration",
    "load_map",
]

__getattr__ = lazy_getattr(__name__, {
    "CageEmulator": "drivers.cage.emulator",
    "CageHost": "drivers.cage.host",
    "CageStatus": "drivers.cage.host",
    "FieldSample": "drivers.cage.host",
})
