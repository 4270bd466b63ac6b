"""Device protocols for the stand: for each device a pure codec, a host driver and an emulator.

A codec turns bytes into messages and counts into SI units and never touches a port or a clock.
A host driver is the stand talking to a real device; an emulator is the stand *being* the device
(for CI and for a real flight computer wired to the stand). Both are built on the same ICD file
in ``fixtures/devices/``, so they cannot drift apart.

Nothing here imports :mod:`sim`, :mod:`star_screen` or :mod:`stand`: an emulator is handed its
measurement source (a callable) by the stand. Transports (python-can, pyserial, pymodbus) are
imported lazily by the modules that need them.

Errors come from one tree, documented in :mod:`drivers.errors`.
"""

from __future__ import annotations

import fixtures
from drivers.errors import ConnectError, DeviceTimeoutError, DriverError, EncodeError, ProtocolError

__all__ = [
    "FIXTURES_DIR",
    "ConnectError",
    "DeviceTimeoutError",
    "DriverError",
    "EncodeError",
    "ProtocolError",
    "fixture_path",
]

#: Where the ICDs live (the ``fixtures`` data package: a source checkout or site-packages).
FIXTURES_DIR = fixtures.ROOT
#: ``fixture_path("devices/magnetorquer.dbc")``: the one data locator, shared with every layer.
fixture_path = fixtures.path
