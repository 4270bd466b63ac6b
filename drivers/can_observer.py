"""A listen-only CAN node beside the flight code: what the stand's telemetry records of a CAN device.

The flight code drives a device through its host driver; the stand must record what the device sent whether or
not the flight code reads it, and without touching that driver's state or counters. :class:`CanObserver` holds a
bus handle of its own on the device's channel (python-can delivers every frame to every handle on a channel, as
a second controller on a real bus sees every frame), keeps the newest frame of each id it watches and decodes it
with the device's own codec when asked. It never sends.
"""

from __future__ import annotations

from typing import Any

import can

from drivers.endpoint import BusEndpoint
from drivers.errors import DriverError, ProtocolError

__all__ = ["SHARED_INTERFACES", "CanObserver", "open_observer"]

#: python-can interfaces on which every handle of a channel sees every frame on the bus (a serial-line adapter is
#: one byte stream that one reader holds: a second handle there would take frames away from the first).
SHARED_INTERFACES = ("socketcan", "udp_multicast", "virtual", "stand_loopback")


class CanObserver(BusEndpoint):
    """Watch the data frames of ``ids`` on ``bus``: :meth:`poll` drains without blocking and keeps the newest frame
    of each id; :meth:`newest` decodes it with ``codec`` (once per new frame). ``seen[id]`` counts the frames of each
    id, ``rejected`` those of a wrong length or that do not decode (the newest good message stays)."""

    def __init__(self, bus: can.BusABC, codec: Any, ids: frozenset[int], name: str, *, owns_bus: bool = True) -> None:
        self.name = name
        self.bus = bus
        self._owns_bus = owns_bus
        self._closed = False
        self._ids = frozenset(ids)
        self._decode = codec.decode
        self._raw: dict[int, can.Message] = {}
        self._decoded: dict[int, tuple[can.Message, Any]] = {}
        self.seen: dict[int, int] = dict.fromkeys(self._ids, 0)
        self.rejected = 0

    def poll(self) -> int:
        """Drain every pending frame without blocking (frames of other ids, remote, error and 29-bit frames are
        skipped); returns how many were read. DriverError naming the bus if it fails."""
        recv, ids, raw, seen = self.bus.recv, self._ids, self._raw, self.seen
        n = 0
        try:
            while (msg := recv(0.0)) is not None:
                n += 1
                frame_id = msg.arbitration_id
                if frame_id in ids and not (msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame):
                    raw[frame_id] = msg
                    seen[frame_id] += 1
        except can.CanError as exc:
            raise DriverError(f"{self.name}: cannot read from {self.bus.channel_info}: {exc}") from exc
        return n

    def newest(self, frame_id: int) -> Any:
        """The newest message of ``frame_id`` seen so far, decoded, or None."""
        msg = self._raw.get(frame_id)
        if msg is None:
            return None
        done = self._decoded.get(frame_id)
        if done is not None and done[0] is msg:
            return done[1]
        try:
            value = self._decode(frame_id, msg.data)  # ProtocolError for a wrong length too
        except ProtocolError:
            self.rejected += 1
            self._raw[frame_id] = done[0] if done is not None else None  # keep the newest good one
            return done[1] if done is not None else None
        self._decoded[frame_id] = (msg, value)
        return value


def open_observer(interface: str, channel: str, codec: Any, ids: frozenset[int], name: str) -> CanObserver:
    """A :class:`CanObserver` on a handle of its own on ``interface``/``channel`` (ConnectError naming the interface
    and channel when it cannot be opened).

    On the stand's in-process bus the handle lets only ``ids`` through (its filters act when a frame is delivered,
    so other frames cost no copy); elsewhere the observer skips the other frames itself, as python-can's generic
    filtering in ``recv(0)`` gives up at the first frame that does not pass and would leave the newer ones queued."""
    from drivers.can_bus import OWN_INTERFACES, open_bus

    if interface in OWN_INTERFACES:
        filters = [{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in sorted(ids)]
        bus = open_bus(interface, channel, can_filters=filters)
        # The same acceptance as those filters, as one set lookup: the sender runs it for every frame on the channel
        # (python-can's generic check walks the list of filter dicts), and this is the per-tick path.
        wanted = frozenset(ids)
        bus._matches_filters = lambda msg: msg.arbitration_id in wanted and not msg.is_extended_id
        return CanObserver(bus, codec, ids, name)
    return CanObserver(open_bus(interface, channel), codec, ids, name)
