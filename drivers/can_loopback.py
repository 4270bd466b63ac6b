"""An in-process CAN bus for python-can: ``can.Bus(interface="stand_loopback", channel="adcs")``.

Buses opened on the same channel name in one process see each other's frames, as with python-can's
``virtual`` interface, but a frame costs about a microsecond instead of ten:

* ``virtual`` deep-copies every frame for every receiver (through ``copy.deepcopy``) and puts it
  on a ``queue.Queue``, whose ``put`` and ``get`` each take a lock and notify a condition.
* here each receiver gets one flat copy of the frame's fields (so a sender may reuse and change
  its :class:`can.Message` after ``send``, and a receiver may change what it got, without either
  seeing the other's edits) on a ``collections.deque``, whose ``append`` and ``popleft`` are
  atomic in CPython. Sending and non-blocking receiving take no lock at all; a receive with a
  timeout sleeps on an event that a sender sets only when someone is waiting.
* a data frame sent with ``send_data(frame_id, payload)`` (how the stand's CAN nodes send) is queued
  as one immutable tuple shared by the receivers without filters, and becomes a
  :class:`can.Message` only when ``recv`` returns it: a node that pops ``rx_ready`` itself reads
  the id and payload without a message object per frame.

Semantics, chosen to match a real controller rather than an unbounded queue:

* receive queues are bounded (``rx_queue_size`` frames, default 1024); when a reader falls behind,
  the oldest frame is dropped and :attr:`LoopbackBus.rx_overflow` counts it, like a controller's
  receive FIFO overrun. Sending never blocks and never fails because a reader is slow.
* acceptance filters (``can_filters`` / :meth:`~can.BusABC.set_filters`) are applied when a frame
  is delivered, as a controller's hardware filters are, so frames a reader does not want never
  take room in its queue; ``recv`` checks again (frames queued before a filter change obey the new
  filters) and skips what fails, so ``recv(0)`` returns the next wanted frame, not None.
* ``receive_own_messages=True`` echoes sent frames back (``is_rx`` false on the echo).
* frames get ``time.time()`` as their timestamp, or keep the sender's with ``preserve_timestamps``.
* after :meth:`~can.BusABC.shutdown`, ``send`` and ``recv`` raise :class:`can.CanOperationError`;
  a thread blocked in ``recv`` wakes up and raises too.

The interface is registered in ``pyproject.toml`` under python-can's ``can.interface`` entry-point
group, so any python-can code can open it once the stand is installed;
:func:`drivers.can_bus.open_bus` opens it whether or not the package is installed.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Any

import can
from can.bus import BusABC, CanProtocol

import compiled_paths
from drivers.can_bus import data_frame

__all__ = ["INTERFACE_NAME", "LoopbackBus"]

#: The python-can interface name under which this bus is registered.
INTERFACE_NAME = "stand_loopback"

_DEFAULT_QUEUE = 1024


class _Channel:
    """The buses open on one channel name. ``members`` is replaced, never mutated, so a sender
    iterates a consistent tuple without a lock while another thread opens or shuts a bus."""

    __slots__ = ("members", "name")

    def __init__(self, name: Any) -> None:
        self.name = name
        self.members: tuple[LoopbackBus, ...] = ()


_channels: dict[Any, _Channel] = {}
_channels_lock = threading.Lock()

#: The per-frame work (send_data), compiled where the install could (compiled_paths), the same either way.
_frames = compiled_paths.load("drivers.can_frames")

_new_message = object.__new__
_Message = can.Message


#: A standard-id data frame as :meth:`LoopbackBus.send_data` queues it for a receiver without filters:
#: ``(frame_id, payload, timestamp, is_rx)``, the payload ``bytes``. ``recv`` turns it into the
#: :class:`can.Message` that :meth:`LoopbackBus.send` of ``drivers.can_bus.data_frame(frame_id, payload)`` would
#: have queued (``data_frame(*frame, channel)``); a reader of ``rx_ready`` may read the tuple itself.
DataFrame = tuple


def _copy_for(msg: can.Message, timestamp: float, channel: Any, is_rx: bool) -> can.Message:
    # Field by field on a bare instance: Message.__init__ re-validates and copy.deepcopy walks
    # a memo, and neither is needed to hand over twelve plain fields and a fresh bytearray.
    m = _new_message(_Message)
    m.timestamp = timestamp
    m.arbitration_id = msg.arbitration_id
    m.is_extended_id = msg.is_extended_id
    m.is_remote_frame = msg.is_remote_frame
    m.is_error_frame = msg.is_error_frame
    m.channel = channel
    m.dlc = msg.dlc
    m.data = bytearray(msg.data)
    m.is_fd = msg.is_fd
    m.is_rx = is_rx
    m.bitrate_switch = msg.bitrate_switch
    m.error_state_indicator = msg.error_state_indicator
    return m


class LoopbackBus(BusABC):
    """A python-can bus shared by name within this process (interface ``"stand_loopback"``).

    Args:
        channel: any hashable name; buses on the same name exchange frames.
        receive_own_messages: also receive the frames this bus sends.
        rx_queue_size: frames the receive queue holds (>= 1); beyond that the oldest is dropped
            and counted in :attr:`rx_overflow`.
        preserve_timestamps: keep the sender's ``timestamp`` instead of stamping ``time.time()``.
        protocol: the :class:`can.CanProtocol` reported by :attr:`protocol` (frames of any kind
            are carried as they are).
        can_filters: python-can acceptance filters, see :meth:`can.BusABC.set_filters`.
        accept_ids: if given, only standard-id data frames of these ids are delivered to this bus, checked before
            a frame is copied for it (a listen-only observer of a few ids costs the other frames nothing).
        listen_only: this bus only reads and never changes a frame it receives (a telemetry observer): it may be
            handed the frame object another receiver got for the same send instead of a copy of its own.

    Attributes:
        rx_overflow: frames dropped because this bus's receive queue was full.
        rx_ready: the receive queue while the bus has no filters and is open, else None: a reader may pop frames
            from it itself (``popleft`` until it is empty gives what ``recv(0)`` would, frame for frame, without a
            call per frame); when None, use ``recv``. Each frame popped is a :class:`can.Message` or, for a frame
            sent with :meth:`send_data`, a :data:`DataFrame` tuple ``(frame_id, payload, timestamp, is_rx)``, which
            ``recv`` would have returned as the :class:`can.Message` of that standard-id data frame.
    """

    def __init__(
        self,
        channel: Any = "loopback-0",
        receive_own_messages: bool = False,
        rx_queue_size: int = _DEFAULT_QUEUE,
        preserve_timestamps: bool = False,
        protocol: CanProtocol = CanProtocol.CAN_20,
        can_filters: can.typechecking.CanFilters | None = None,
        accept_ids: frozenset[int] | None = None,
        listen_only: bool = False,
        **kwargs: Any,
    ) -> None:
        if isinstance(rx_queue_size, bool) or not isinstance(rx_queue_size, int) or rx_queue_size < 1:
            raise ValueError(
                f"rx_queue_size is {rx_queue_size!r}; it must be a whole number of frames, 1 or more "
                f"(default {_DEFAULT_QUEUE}), since the receive queue is bounded."
            )
        try:
            hash(channel)
        except TypeError:
            raise ValueError(f"channel is {channel!r}; it must be a hashable name such as 'adcs'.") from None
        self.channel_info = f"stand_loopback channel {channel!r}"
        self.receive_own_messages = bool(receive_own_messages)
        self.preserve_timestamps = bool(preserve_timestamps)
        self._can_protocol = protocol
        self.rx_overflow = 0
        self.accept_ids = None if accept_ids is None else frozenset(int(i) for i in accept_ids)
        self.listen_only = bool(listen_only)
        self._queue: deque[can.Message] = deque(maxlen=rx_queue_size)
        self._maxlen = rx_queue_size
        self._waiting = False
        self._wake = threading.Event()
        self._left = False  # shut down (BusABC's _is_shutdown is True until its __init__ has run)
        # set_filters (called by BusABC.__init__) needs the fields above.
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        self.channel_id = channel
        with _channels_lock:
            chan = _channels.get(channel)
            if chan is None:
                chan = _channels[channel] = _Channel(channel)
            chan.members = (*chan.members, self)
        self._channel = chan

    # -- filters --------------------------------------------------------------------------------

    def _apply_filters(self, filters: can.typechecking.CanFilters | None) -> None:
        # BusABC.set_filters keeps the list in self._filters; delivery reads it from there. Nothing
        # to compile: the deliverer calls BusABC._matches_filters, the reference semantics.
        self.rx_ready = self._queue if filters is None and not self._left else None

    # -- sending --------------------------------------------------------------------------------

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Deliver ``msg`` to every other bus on the channel (and to this one when
        ``receive_own_messages``). Never blocks: ``timeout`` is accepted for the API and unused."""
        if self._is_shutdown:
            raise can.CanOperationError(f"Cannot send on {self.channel_info}: the bus is shut down.")
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        name = self.channel_id
        for rx in self._channel.members:
            own = rx is self
            if own and not self.receive_own_messages:
                continue
            ids = rx.accept_ids
            if ids is not None and (msg.arbitration_id not in ids or msg.is_extended_id or msg.is_remote_frame
                                    or msg.is_error_frame):
                continue
            if rx._filters is not None and not rx._matches_filters(msg):
                continue
            queue = rx._queue
            if len(queue) == rx._maxlen:
                rx.rx_overflow += 1
            queue.append(_copy_for(msg, timestamp, name, not own))
            if rx._waiting:
                rx._wake.set()

    #: ``send_data(frame_id, payload)``: ``send(drivers.can_bus.data_frame(frame_id, payload))``, the same frames
    #: delivered to the same queues, without a :class:`can.Message` per frame where none is needed (a receiver without
    #: filters is given one shared :data:`DataFrame` tuple). How a CAN node sends, several frames per tick.
    #: :func:`drivers.can_frames.send_data`, compiled where the install can.
    send_data = _frames.send_data

    # -- receiving ------------------------------------------------------------------------------

    def _take(self) -> can.Message | None:
        """The next queued frame that passes this bus's filters (others are discarded), or None."""
        queue = self._queue
        while queue:
            try:
                msg = queue.popleft()
            except IndexError:  # another thread reading this bus took the last one
                return None
            if type(msg) is tuple:  # a DataFrame (send_data)
                msg = data_frame(*msg, self.channel_id)
            if self._filters is None or self._matches_filters(msg):
                return msg
        return None

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """The next wanted frame, waiting up to ``timeout`` s (None: until one arrives); None on timeout.

        ``BusABC.recv`` with its loop and its level-9 log line left out: delivery already applied the
        filters, and this runs for every frame of the stand's tick."""
        if self._queue:
            msg = self._take()
            if msg is not None:
                return msg
        if self._is_shutdown:
            raise can.CanOperationError(f"Cannot receive on {self.channel_info}: the bus is shut down.")
        if timeout is not None and timeout <= 0.0:
            return None
        return self._wait(timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._queue:
            msg = self._take()
            if msg is not None:
                return msg, True
        if self._is_shutdown:
            raise can.CanOperationError(f"Cannot receive on {self.channel_info}: the bus is shut down.")
        if timeout is not None and timeout <= 0.0:
            return None, True
        return self._wait(timeout), True

    def _wait(self, timeout: float | None) -> can.Message | None:
        deadline = None if timeout is None else time.monotonic() + timeout
        wake = self._wake
        while True:
            # Raise the flag, then look again: a sender that appended after the look sees the
            # flag and sets the event, so the wait below cannot miss its frame.
            self._waiting = True
            wake.clear()
            try:
                msg = self._take()
                if msg is not None:
                    return msg
                if self._is_shutdown:
                    raise can.CanOperationError(
                        f"Cannot receive on {self.channel_info}: the bus was shut down while waiting.")
                if deadline is None:
                    wake.wait()
                else:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0.0:
                        return None
                    wake.wait(remaining)
            finally:
                self._waiting = False

    # -- lifecycle ------------------------------------------------------------------------------

    def shutdown(self) -> None:
        """Leave the channel (idempotent); a thread blocked in ``recv`` wakes and raises."""
        if self._is_shutdown:
            return
        super().shutdown()
        self._left = True
        self.rx_ready = None
        with _channels_lock:
            chan = self._channel
            chan.members = tuple(b for b in chan.members if b is not self)
            if not chan.members and _channels.get(chan.name) is chan:
                del _channels[chan.name]
        self._wake.set()

    def flush_tx_buffer(self) -> None:
        """Nothing to flush: a frame is delivered inside ``send``."""

    @staticmethod
    def _detect_available_configs() -> list[dict[str, Any]]:
        """The channels that have at least one bus open in this process."""
        with _channels_lock:
            names = list(_channels)
        return [{"interface": INTERFACE_NAME, "channel": name} for name in names]
