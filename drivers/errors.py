"""Exceptions raised by device drivers, codecs and emulators.

Every device error derives from :class:`DriverError`, so the stand can catch one class around a
device and still tell the kinds apart::

    DriverError(Exception)            anything a driver, codec or emulator refuses or cannot do
     +-- ConnectError                 a port or bus cannot be opened (names interface/channel or
     |                                URL and the OS reason)
     +-- DeviceTimeoutError           the device stayed silent past a monotonic deadline (names
     |                                the device, what was awaited and the timeout)
     +-- ProtocolError                a frame cannot be accepted: unknown id, wrong length, bad
     |                                checksum, field out of its table (carries the frame in hex,
     |                                the reason, and what was expected vs what was computed/got)
     +-- EncodeError (also ValueError) a value cannot be put on the wire: outside the range the
                                      ICD allows, not finite, unknown enum name, missing signal
                                      (names the signal, the value and the allowed range)

Messages are full sentences that name the field, the value given and what is allowed.
"""

from __future__ import annotations

__all__ = [
    "ConnectError",
    "DeviceTimeoutError",
    "DriverError",
    "EncodeError",
    "ProtocolError",
    "frame_hex",
]


class DriverError(Exception):
    """Base class of every error raised by :mod:`drivers`."""


class ConnectError(DriverError):
    """A port or bus cannot be opened.

    ``where`` names the interface and channel (CAN) or the URL (serial, Modbus); ``reason`` is the
    underlying OS or library message.
    """

    def __init__(self, message: str, *, where: str = "", reason: str = "") -> None:
        super().__init__(message)
        self.where = where
        self.reason = reason


class DeviceTimeoutError(DriverError):
    """A device stayed silent past a monotonic deadline."""

    def __init__(self, message: str, *, device: str = "", awaited: str = "", timeout_s: float = 0.0) -> None:
        super().__init__(message)
        self.device = device
        self.awaited = awaited
        self.timeout_s = timeout_s


class ProtocolError(DriverError):
    """A received frame cannot be accepted.

    Attributes:
        frame_hex: the offending frame in hex (CAN: candump style ``"0A0#0102..."``).
        reason: what is wrong, as a sentence fragment (``"unknown frame id 0x123"``).
        expected: what the protocol requires (a checksum, a length, a set of ids), or ``None``.
        computed: what was computed or received instead, or ``None``.
    """

    def __init__(
        self,
        reason: str,
        *,
        frame_hex: str = "",
        expected: object = None,
        computed: object = None,
    ) -> None:
        self.frame_hex = frame_hex
        self.reason = reason
        self.expected = expected
        self.computed = computed
        text = reason
        if expected is not None or computed is not None:
            text += f" (expected {expected}, got {computed})"
        if frame_hex:
            text += f"; frame {frame_hex}"
        super().__init__(text if text.endswith(".") else text + ".")


class EncodeError(DriverError, ValueError):
    """A value cannot be encoded: out of the ICD's range, not finite, unknown name, missing."""


def frame_hex(frame_id: int, data: bytes | bytearray | memoryview, *, extended: bool = False) -> str:
    """A CAN frame in candump notation: ``"0A0#01FF"`` (11-bit) or ``"000000A0#01FF"`` (29-bit)."""
    ident = f"{frame_id:08X}" if extended else f"{frame_id:03X}"
    return f"{ident}#{bytes(data).hex().upper()}"
