"""A listen-only CAN node beside the flight code: what the stand's telemetry records of a CAN device.

The flight code drives a device through its host driver; the stand must record what the device sent whether or
not the flight code reads it, and without touching that driver's state or counters. :class:`CanObserver` holds a
bus handle of its own on the device's channel (python-can delivers every frame to every handle on a channel, as
a second controller on a real bus sees every frame), with acceptance filters for the device's frames, decodes
them with the device's own codec and keeps the newest message of each type. It never sends.
"""

from __future__ import annotations

from typing import Any

import can

from drivers.can_node import CanNode

__all__ = ["SHARED_INTERFACES", "CanObserver", "open_observer"]

#: python-can interfaces on which every handle of a channel sees every frame on the bus (a serial-line adapter is
#: one byte stream that one reader holds: a second handle there would take frames away from the first).
SHARED_INTERFACES = ("socketcan", "udp_multicast", "virtual", "stand_loopback")


class CanObserver(CanNode):
    """Decode every frame of ``ids`` seen on ``bus`` with ``codec``; ``latest[type]`` is the newest message of each
    type and ``seen[type]`` how many were taken. :meth:`poll` drains without blocking."""

    def __init__(self, bus: can.BusABC, codec: Any, ids: frozenset[int], name: str, *, owns_bus: bool = True) -> None:
        self.name = name
        self._init_node(bus, codec, accept=frozenset(ids), own=frozenset(), owns_bus=owns_bus)
        self.latest: dict[type, Any] = {}
        self.seen: dict[type, int] = {}

    def _take(self, decoded: Any, t_s: float | None) -> None:
        kind = type(decoded)
        self.latest[kind] = decoded
        self.seen[kind] = self.seen.get(kind, 0) + 1

    #: Drain every pending frame without blocking; returns how many were read.
    poll = CanNode._drain


def open_observer(interface: str, channel: str, codec: Any, ids: frozenset[int], name: str) -> CanObserver:
    """A :class:`CanObserver` on a handle of its own on ``interface``/``channel`` (ConnectError naming the interface
    and channel when it cannot be opened).

    On the stand's in-process bus the handle lets only ``ids`` through (its filters act when a frame is delivered,
    so other frames cost no copy); elsewhere the observer sorts every frame itself, as python-can's generic filtering
    in ``recv(0)`` gives up at the first frame that does not pass and would leave the newer ones queued."""
    from drivers.can_bus import OWN_INTERFACES, open_bus

    if interface in OWN_INTERFACES:
        filters = [{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in sorted(ids)]
        return CanObserver(open_bus(interface, channel, can_filters=filters), codec, ids, name)
    return CanObserver(open_bus(interface, channel), codec, ids, name)
