"""The CAN chain's per-frame work: a node draining the stand's in-process bus, a node encoding and sending one
message, the in-process bus handing one data frame to its receivers. The one source of
:meth:`drivers.can_node.CanNode._drain`, :meth:`~drivers.can_node.CanNode._send` and
:meth:`drivers.can_loopback.LoopbackBus.send_data`, which are these functions (a class takes each as its method).

Plain Python, and compiled by Cython in pure-Python mode where the install has a C compiler (``compiled_paths``
lists it; docs/fast_paths.md): compiled, a frame crosses the node and the bus without a Python frame of theirs, and
the typed locals (the frame counter, whether a frame is a plain data frame, the route of its id) are C values. Both
builds count, sort, reject, deliver and raise the same; tests run both (``STAND_NATIVE=0``).

Nothing here is a short-cut around the wire: every message is encoded by its codec and handed to the bus as a frame,
and every frame a node reads is counted, checked against its ICD length and decoded by its codec.
"""

from __future__ import annotations

import time

import can
import cython

from drivers.can_bus import data_frame
from drivers.errors import DriverError, EncodeError, ProtocolError

__all__ = ["drain", "encode", "host_take", "send", "send_data", "take_observed"]


def _message(frame):
    """A frame popped from a loopback bus's queue as a :class:`can.Message` (a ``send_data`` tuple is a standard-id
    data frame), for the rare paths that name or sort a refused frame."""
    return data_frame(frame[0], frame[1]) if type(frame) is tuple else frame


def drain(node, t_s=None):
    """``CanNode._drain``: read every pending frame without blocking and sort each (drivers.can_node's docstring);
    returns how many.

    On the in-process bus (``rx_ready``) the node pops the bus's queue itself: the same frames in the same order as
    its ``recv(0)`` would give (it offers the queue only while it has no filters and is open), each sorted as
    ``CanNode._handle`` sorts it (a test feeds both the same frames). A frame sent with ``send_data`` is a tuple
    ``(id, payload, timestamp, is_rx)`` of a standard-id data frame (drivers.can_loopback). Any other bus: one
    ``recv(0)`` per frame (``CanNode._drain_bus``)."""
    if node._closed:
        node._check_open()
    queue = node.bus.rx_ready if node._has_rx_ready else None
    if queue is None:
        return node._drain_bus(t_s)
    if not queue:  # most drains of a tick: nothing new
        return 0
    popleft = queue.popleft
    counters: dict = node.counters
    routes: dict = node._routes
    take = node._take
    n: cython.Py_ssize_t = 0
    plain: cython.bint
    route: tuple
    while queue:
        try:
            frame = popleft()
        except IndexError:  # another reader of this bus took the last frame
            break
        n += 1
        counters["received"] += 1
        if type(frame) is tuple:
            frame_id = frame[0]
            data = frame[1]
            plain = True
        else:
            frame_id = frame.arbitration_id
            data = frame.data
            plain = not (frame.is_extended_id or frame.is_remote_frame or frame.is_error_frame)
        route = routes.get(frame_id)
        if route is None or not plain or len(data) != route[0]:
            node._refuse(_message(frame), route)
            continue
        try:
            decoded = route[2](route[1](data))
        except (ValueError, ProtocolError):  # an enum value outside its table
            node._reject("rejected_other", _message(frame))
            continue
        take(decoded, t_s)
    return n


def host_take(host, decoded, t_s):
    """``CanHost._take``: a message the device sent kept as the newest of its kind (``host._latest`` names the
    attribute); the periodic sample (most of the traffic) also counted in ``counters["samples"]``."""
    kind = type(decoded)
    if kind is host._sample_type:
        setattr(host, host._sample_attr, decoded)
        host.counters["samples"] += 1
        return
    attr = host._latest.get(kind)
    if attr is None:  # pragma: no cover - accept only holds the device's messages
        host._reject("rejected_other")
        return
    setattr(host, attr, decoded)


def take_observed(node, take, decoded, t_s):
    """A node's ``_take`` once it has observers (``CanNode.add_observer``): ``take(decoded, t_s)``, then each of
    ``node._observers`` sees the message."""
    take(decoded, t_s)
    for each in node._observers:
        each(decoded)


def encode(codec, msg):
    """``CanCodec.encode``: one message of ``codec`` encoded, as ``(frame id, 8-byte payload)``.

    The message's type picks its DBC packer and the function giving its values in the packer's order; a value the
    packer does not cover (out of range, not a number) takes the DBC codec's full checks, whose error names the field,
    the value and the DBC's range. Every failure is an EncodeError naming the message (and ``codec.where``); a type
    the codec does not know is ``codec.UNKNOWN_TYPE_ERROR`` listing the types it knows."""
    entry = codec._encoders.get(type(msg))
    if entry is None:
        raise codec.UNKNOWN_TYPE_ERROR(f"Cannot encode {type(msg).__name__}: expected one of "
                                       f"{', '.join(t.__name__ for t in codec._encoders)}.")
    packer, values_of, frame_id = entry
    try:
        values = values_of(msg)
        payload = packer.pack(*values)
        if payload is None:  # the DBC codec's full checks, and their error messages
            _, payload = codec.dbc.encode(packer.name, dict(zip(packer.order, values, strict=True)))
    except EncodeError as exc:
        raise EncodeError(f"Cannot encode {msg!r}{codec.where}: {exc}") from exc
    except (TypeError, ValueError, ArithmeticError) as exc:  # a 2-vector, a string or a huge int for a number
        raise EncodeError(f"Cannot encode {msg!r}{codec.where}: {type(exc).__name__}: {exc}") from exc
    return frame_id, payload


def send(node, msg):
    """``CanNode._send``: encode ``msg`` with the node's codec and send it as one data frame (DriverError naming the
    bus if that fails); then the node's sent-frame observers see it."""
    if node._closed:
        node._check_open()
    frame_id, payload = node._encode(msg)
    send_data = node._send_data
    try:
        if send_data is not None:
            send_data(frame_id, payload)
        else:
            node.bus.send(data_frame(frame_id, payload))
    except can.CanError as exc:
        raise DriverError(
            f"{node.name}: cannot send {type(msg).__name__} on {node.bus.channel_info}: {exc}"
        ) from exc
    node.counters["sent"] += 1
    observers = node._sent_observers
    if observers:
        for observer in observers:
            observer(frame_id, payload)


def send_data(bus, frame_id, payload):
    """``LoopbackBus.send_data``: what ``bus.send(drivers.can_bus.data_frame(frame_id, payload))`` delivers, to the
    same queues, without a :class:`can.Message` per frame where none is needed.

    A receiver without filters is given the frame as a tuple ``(frame_id, payload, timestamp, is_rx)``, one shared
    by every such receiver but the sender's own echo (it is immutable); its ``recv`` makes the :class:`can.Message`
    when it reads the frame (``data_frame`` with the tuple's fields), and a reader of ``rx_ready`` takes the tuple as
    it is. A receiver with filters gets its own :class:`can.Message`, which its filters are tested on, as from
    ``send``."""
    if bus._is_shutdown:
        raise can.CanOperationError(f"Cannot send on {bus.channel_info}: the bus is shut down.")
    # A data_frame's timestamp is 0.0, which preserve_timestamps keeps.
    timestamp = 0.0 if bus.preserve_timestamps else time.time()
    if type(payload) is not bytes:  # the frame keeps what was sent, whatever the sender does with its buffer
        payload = bytes(payload)
    shared = None  # the tuple every other receiver without filters is given
    own: cython.bint
    for rx in bus._channel.members:
        own = rx is bus
        if own and not bus.receive_own_messages:
            continue
        ids = rx.accept_ids
        if ids is not None and frame_id not in ids:
            continue
        if rx._filters is not None:
            frame = data_frame(frame_id, payload, timestamp, not own, bus.channel_id)
            if not rx._matches_filters(frame):
                continue
        elif own:
            frame = (frame_id, payload, timestamp, False)
        else:
            if shared is None:
                shared = (frame_id, payload, timestamp, True)
            frame = shared
        queue = rx._queue
        if len(queue) == rx._maxlen:
            rx.rx_overflow += 1
        queue.append(frame)
        if rx._waiting:
            rx._wake.set()
