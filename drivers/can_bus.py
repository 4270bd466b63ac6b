"""Opening CAN buses through python-can, with errors from :mod:`drivers.errors`.

A CAN endpoint is an interface name plus a channel: ``("virtual", "adcs")`` or
``("stand_loopback", "adcs")`` (:mod:`drivers.can_loopback`, the fast in-process bus) in tests,
``("socketcan", "can0")`` on a bench. python-can is imported lazily, so importing this module
costs nothing on a stand that has no CAN device.

Never use python-can's ``udp_multicast`` interface on shared machines: it sends multicast out of
the default route (see docs/architecture.md, "Cross-process tests on one machine").
"""

from __future__ import annotations

import importlib
import socket
from typing import TYPE_CHECKING, Any

from drivers.errors import ConnectError

if TYPE_CHECKING:  # pragma: no cover
    import can

__all__ = ["OWN_INTERFACES", "data_frame", "loops_back", "open_bus", "socketcan_available"]

#: Interfaces this package provides, name -> (module, class). They are registered with python-can
#: through the ``can.interface`` entry-point group when the package is installed; ``open_bus``
#: opens them from here either way, so a source checkout works too.
OWN_INTERFACES: dict[str, tuple[str, str]] = {
    "stand_loopback": ("drivers.can_loopback", "LoopbackBus"),
}


def open_bus(interface: str, channel: str, **kwargs: Any) -> can.BusABC:
    """Open a python-can bus, e.g. ``open_bus("stand_loopback", "adcs")`` or ``open_bus("socketcan", "can0")``.

    Extra keyword arguments go to :class:`can.Bus` (``bitrate``, ``receive_own_messages``...).
    Any failure (python-can missing, unknown interface, missing vendor library, no such device,
    permission denied) becomes :class:`ConnectError` naming the interface and channel, the reason,
    and the interfaces python-can knows. The caller owns the bus and must ``shutdown()`` it.
    """
    where = f"interface {interface!r}, channel {channel!r}"
    try:
        import can
        import can.interfaces
    except ImportError as exc:  # pragma: no cover - python-can is a core dependency
        raise ConnectError(
            f"Cannot open CAN bus ({where}): python-can is not installed ({exc}). "
            "It is part of the base install (pip install adcs-stand).",
            where=where,
            reason=str(exc),
        ) from exc
    valid = sorted(set(can.interfaces.VALID_INTERFACES) | set(OWN_INTERFACES))
    if interface not in valid:
        raise ConnectError(
            f"Cannot open CAN bus ({where}): unknown interface {interface!r}. "
            f"python-can knows: {', '.join(valid)}.",
            where=where,
            reason="unknown interface",
        )
    try:
        if interface in OWN_INTERFACES:
            # Straight to the class: the package need not be installed for its entry point to exist.
            module, cls = OWN_INTERFACES[interface]
            return getattr(importlib.import_module(module), cls)(channel=channel, **kwargs)
        return can.Bus(interface=interface, channel=channel, **kwargs)
    except Exception as exc:  # every backend failure is a connect failure
        reason = f"{type(exc).__name__}: {exc}"
        raise ConnectError(
            f"Cannot open CAN bus ({where}): {reason}. python-can knows: {', '.join(valid)}.",
            where=where,
            reason=reason,
        ) from exc


def socketcan_available() -> bool:
    """True when this kernel offers SocketCAN (an ``AF_CAN`` raw socket can be created).

    This says nothing about whether a given interface (``vcan0``, ``can0``) exists.
    """
    family = getattr(socket, "AF_CAN", None)
    proto = getattr(socket, "CAN_RAW", None)
    if family is None or proto is None:
        return False
    try:
        sock = socket.socket(family, socket.SOCK_RAW, proto)
    except OSError:
        return False
    sock.close()
    return True


def loops_back(bus) -> bool:
    """True for a bus that hands a node its own frames back (python-can's ``udp_multicast``: every datagram sent to
    the group reaches the sender too). A node on such a bus counts those frames as echoes, not as foreign traffic."""
    return type(bus).__name__ == "UdpMulticastBus"


_message_new: Any = None


def data_frame(frame_id: int, payload: bytes) -> can.Message:
    """A classic CAN data frame with an 11-bit id: what ``can.Message(arbitration_id=frame_id, data=payload,
    is_extended_id=False)`` makes, field for field, without the constructor's keyword handling (the host drivers
    and emulators make one per frame, several per tick)."""
    global _message_new
    if _message_new is None:
        import can

        _message_new = (object.__new__, can.Message)
    new, cls = _message_new
    m = new(cls)
    m.timestamp = 0.0
    m.arbitration_id = frame_id
    m.is_extended_id = False
    m.is_remote_frame = False
    m.is_error_frame = False
    m.channel = None
    m.data = bytearray(payload)
    m.dlc = len(m.data)
    m.is_fd = False
    m.is_rx = True
    m.bitrate_switch = False
    m.error_state_indicator = False
    return m
