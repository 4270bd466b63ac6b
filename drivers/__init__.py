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

from pathlib import Path

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

#: ``<repo>/fixtures``, located relative to this package (works from a source checkout and an
#: editable install).
FIXTURES_DIR = Path(__file__).resolve().parents[1] / "fixtures"


def fixture_path(relative: str | Path) -> Path:
    """The path of a fixture file, e.g. ``fixture_path("devices/magnetorquer.dbc")``.

    Raises FileNotFoundError naming the full path looked at when the file does not exist.
    """
    path = FIXTURES_DIR / relative
    if not path.is_file():
        raise FileNotFoundError(
            f"Fixture {str(relative)!r} not found: looked at {path} (fixtures are located relative to "
            f"the drivers package, at {FIXTURES_DIR})."
        )
    return path
