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

    def __init__(self, bus: can.BusABC | None, codec: Any, ids: frozenset[int], name: str, *,
                 owns_bus: bool = True) -> None:
        self.name = name
        self.bus = bus
        self._owns_bus = owns_bus
        self._closed = False
        self._ids = frozenset(ids)
        self._decode = codec.decode
        self._raw: dict[int, bytes | bytearray] = {}  # id -> the newest payload of that id
        self._decoded: dict[int, tuple[bytes | bytearray, Any]] = {}
        self.seen: dict[int, int] = dict.fromkeys(self._ids, 0)
        #: The stand's in-process bus hands its receive queue over (``LoopbackBus.rx_ready``): drained directly.
        self._ready = None if bus is None else getattr(bus, "rx_ready", None)
        #: Fed by a device's transmit tap (no bus): what it sent was made by the same codec, so its payloads have
        #: their ICD length and decode through the codec's table without its look-up (``payload_decoders``).
        self._fed = bus is None
        self._routes = codec.payload_decoders() if self._fed and hasattr(codec, "payload_decoders") else None
        self.rejected = 0

    def poll(self) -> int:
        """Drain every pending frame without blocking (frames of other ids, remote, error and 29-bit frames are
        skipped); returns how many were read. DriverError naming the bus if it fails."""
        ids, raw, seen = self._ids, self._raw, self.seen
        ready = self._ready
        if ready is not None:  # the stand's in-process bus: pop its queue, no recv call per frame
            n = len(ready)
            while ready:
                msg = ready.popleft()
                if type(msg) is tuple:  # a send_data frame (drivers.can_loopback): a standard-id data frame
                    frame_id = msg[0]
                    if frame_id in ids:
                        raw[frame_id] = msg[1]
                        seen[frame_id] += 1
                    continue
                frame_id = msg.arbitration_id
                if frame_id in ids and not (msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame):
                    raw[frame_id] = msg.data
                    seen[frame_id] += 1
            return n
        if self.bus is None:  # fed by a device's transmit tap (feed): nothing to drain
            return 0
        recv = self.bus.recv
        n = 0
        try:
            while (msg := recv(0.0)) is not None:
                n += 1
                frame_id = msg.arbitration_id
                if frame_id in ids and not (msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame):
                    raw[frame_id] = msg.data
                    seen[frame_id] += 1
        except can.CanError as exc:
            raise DriverError(f"{self.name}: cannot read from {self.bus.channel_info}: {exc}") from exc
        return n

    def feed(self, frame_id: int, payload: bytes | bytearray) -> None:
        """Take one data frame a device put on the bus (:meth:`drivers.can_node.CanNode.add_sent_observer`): on an
        in-process link the stand watches the emulator's transmissions instead of holding a bus handle of its own,
        which would cost every frame a copy. The payload is kept as sent and decoded when asked for."""
        if frame_id in self._ids:
            self._raw[frame_id] = payload
            self.seen[frame_id] += 1

    def poll_newest(self, frame_id: int, poll: bool = True) -> Any:
        """:meth:`poll` (unless ``poll`` is false), then :meth:`newest` of ``frame_id``: what a telemetry row asks
        every tick, in one call."""
        ready = self._ready
        if poll and not self._fed and (ready is None or ready):  # nothing pending: not even the call
            self.poll()
        msg = self._raw.get(frame_id)
        if msg is None:
            return None
        done = self._decoded.get(frame_id)
        if done is not None and done[0] is msg:  # decoded already: most ticks
            return done[1]
        if self._routes is not None:  # this node's own transmissions: one new payload a row
            unpack, build = self._routes[frame_id]
            value = build(unpack(msg))
            self._decoded[frame_id] = (msg, value)
            return value
        try:
            value = self._decode(frame_id, msg)  # ProtocolError for a wrong length too
        except ProtocolError:
            self.rejected += 1
            self._raw[frame_id] = done[0] if done is not None else None  # keep the newest good one
            return done[1] if done is not None else None
        self._decoded[frame_id] = (msg, value)
        return value

    def newest(self, frame_id: int) -> Any:
        """The newest message of ``frame_id`` seen so far, decoded, or None."""
        return self.poll_newest(frame_id, False)


def open_observer(interface: str, channel: str, codec: Any, ids: frozenset[int], name: str) -> CanObserver:
    """A :class:`CanObserver` on a handle of its own on ``interface``/``channel`` (ConnectError naming the interface
    and channel when it cannot be opened).

    On the stand's in-process bus the handle lets only ``ids`` through (``accept_ids``, checked when a frame is
    delivered, so other frames cost no copy) and shares the frame another receiver got (``listen_only``);
    elsewhere the observer skips the other frames itself, as python-can's generic filtering in ``recv(0)`` gives up
    at the first frame that does not pass and would leave the newer ones queued."""
    from drivers.can_bus import OWN_INTERFACES, open_bus

    if interface in OWN_INTERFACES:
        # Only the watched ids are delivered, checked by the sender before it copies a frame (this is the per-tick
        # path): the observer then drains its queue without a recv call per frame.
        bus = open_bus(interface, channel, accept_ids=frozenset(ids), listen_only=True)
        return CanObserver(bus, codec, ids, name)
    return CanObserver(open_bus(interface, channel), codec, ids, name)
