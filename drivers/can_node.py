"""What every CAN node of the project shares, host driver or emulated device: the receive loop that sorts
each frame, the counters, the rejection reasons and sending one encoded message.

A node knows three sets of standard (11-bit) ids:

- ``accept``: the ids it takes (with their lengths, from the ICD);
- ``addressed``: the ids that are its to take (``accept`` plus any id of its range the ICD leaves
  unassigned, e.g. the magnetorquer board's command block 0x090..0x09F);
- ``own``: the ids it sends itself, which a bus that loops every frame back to its sender
  (``udp_multicast``) returns to it.

Each frame read is counted in ``received`` and then in exactly one of:

- ``echoes``: one of the node's own frames coming back (only on a bus that loops back);
- ``foreign``: a frame not addressed to this node (another node's traffic on a shared bus, a 29-bit
  id): ignored, not an error, since several devices may share one bus;
- ``rejected_unknown_id``, ``rejected_length``, ``rejected_other``: a frame addressed to the node
  that it cannot accept (an id of its range the ICD does not assign, a wrong length, a value that
  does not decode, a remote frame), or an error frame, which every node on the bus sees;
- taken: handed to the node's :meth:`CanNode._take` (the device's own behaviour).

:attr:`CanNode.rejected_frames` sums the three ``rejected_*`` counters and ``last_rejected`` says why
the latest one was dropped, naming the frame in candump notation. An emulated device also counts
each rejection in its on-board ``rejected_frames`` counter (``self._board``), which its ICD reports.
"""

from __future__ import annotations

import functools
import math
import time
from typing import Any

import can

import compiled_paths
from drivers.can_bus import loops_back
from drivers.device_faults import DeviceFaults
from drivers.endpoint import BusEndpoint
from drivers.errors import DeviceTimeoutError, DriverError, ProtocolError, frame_hex

__all__ = ["CanDevice", "CanHost", "CanNode", "ServedNode"]

#: How a node names each kind of frame it drops (``last_rejected``).
_WHY = {"rejected_unknown_id": "a frame with an id of {name}'s range that it does not take",
        "rejected_length": "a frame of the wrong length for its id",
        "rejected_other": "a frame that does not decode (a value outside its table, an error or remote frame)"}

#: The counters every node keeps; a device adds its own after these.
#: The per-frame work (drain, send), compiled where the install could (compiled_paths), the same either way.
_frames = compiled_paths.load("drivers.can_frames")

NODE_COUNTERS = ("sent", "received", "rejected_unknown_id", "rejected_length", "rejected_other", "foreign", "echoes")


def _same(value: Any) -> Any:
    return value


def _routes(codec: Any, accept: frozenset[int]) -> dict[int, tuple[int, Any, Any]]:
    """For each id the node takes: (ICD payload length, unpack, build), ``build(unpack(data))`` being the codec's
    ``decode`` for a payload of that length. A codec that offers ``payload_decoders()`` (id -> (unpack, build)) is
    called without its per-frame look-up; any other is called through ``decode``."""
    offered = codec.payload_decoders() if hasattr(codec, "payload_decoders") else {}
    lengths = codec.lengths
    return {frame_id: (lengths[frame_id], *offered[frame_id]) if frame_id in offered
            else (lengths[frame_id], functools.partial(codec.decode, frame_id), _same)
            for frame_id in accept}


class CanNode(BusEndpoint):
    """Base of a CAN host driver or emulated device; a subclass calls :meth:`_init_node` and fills :meth:`_take`.

    Attributes:
        counters: :data:`NODE_COUNTERS` then the device's own (see the module docstring).
        last_rejected: why the latest frame was rejected, or None.
    """

    name: str
    #: The sentence after the name when the node is used after close.
    _closed_text = "closed; create a new one."
    #: The on-board counters an emulated device reports (``rejected_frames`` among them), or None for a host.
    _board: dict[str, int] | None = None

    def _init_node(self, bus: can.BusABC, codec: Any, *, accept: frozenset[int], own: frozenset[int],
                   addressed: frozenset[int] = frozenset(), extra_counters: tuple[str, ...] = (),
                   owns_bus: bool = False) -> None:
        self.bus = bus
        self._owns_bus = owns_bus
        self._closed = False
        self._accept = frozenset(accept)
        self._addressed = self._accept | frozenset(addressed)
        # Only a bus that loops frames back returns our own; elsewhere such a frame is another node's.
        self._echo_ids = frozenset(own) if loops_back(bus) else frozenset()
        self._encode = codec.encode
        self._routes = _routes(codec, self._accept)
        # A bus that hands frames over without a can.Message per frame on the sender's side, or its queue without a
        # call per frame on the reader's (drivers.can_loopback.LoopbackBus); None for any other bus.
        self._send_data = getattr(bus, "send_data", None)
        self._has_rx_ready = hasattr(bus, "rx_ready")
        self.last_rejected: str | None = None
        self.counters: dict[str, int] = dict.fromkeys((*NODE_COUNTERS, *extra_counters), 0)

    def _rebind_bus(self, bus: can.BusABC) -> None:
        """Talk through ``bus`` from now on: the same bus wrapped (a fault-injecting proxy, ``drivers.link_faults``);
        the fast paths are taken from the wrapper, which hands them over only while it has nothing to do."""
        self.bus = bus
        self._send_data = getattr(bus, "send_data", None)
        self._has_rx_ready = hasattr(bus, "rx_ready")

    def _check_open(self) -> None:
        if self._closed:
            raise DriverError(f"{self.name}: {self._closed_text}")

    # -- receiving --------------------------------------------------------------------------------

    #: ``_drain(t_s=None) -> int``: read every pending frame without blocking and sort each (module docstring);
    #: returns how many. :func:`drivers.can_frames.drain`, compiled where the install can.
    _drain = _frames.drain

    def _drain_bus(self, t_s: float | None) -> int:
        recv = self.bus.recv
        handle = self._handle
        n = 0
        try:
            while (msg := recv(0.0)) is not None:
                handle(msg, t_s)
                n += 1
        except can.CanError as exc:
            raise DriverError(f"{self.name}: cannot read from {self.bus.channel_info}: {exc}") from exc
        return n

    def _handle(self, msg: can.Message, t_s: float | None) -> None:
        """Count and sort one frame; a data frame the node takes is decoded and handed to :meth:`_take`."""
        self.counters["received"] += 1
        # One look-up: the ids the node takes, each with its ICD length and its codec's unpack and message builder.
        route = self._routes.get(msg.arbitration_id)
        if (route is None or msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame
                or len(msg.data) != route[0]):
            self._refuse(msg, route)
            return
        try:
            decoded = route[2](route[1](msg.data))
        except (ValueError, ProtocolError):  # an enum value outside its table
            self._reject("rejected_other", msg)
            return
        self._take(decoded, t_s)

    def _refuse(self, msg: can.Message, route: tuple | None) -> None:
        """A frame the node does not take as it is: one of its ids in a data frame of the wrong length, or else
        sorted by :meth:`_sort`."""
        if route is not None and not (msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame):
            self._reject("rejected_length", msg)
        else:
            self._sort(msg, msg.arbitration_id)

    def _sort(self, msg: can.Message, frame_id: int) -> None:
        if msg.is_error_frame:
            self._reject("rejected_other", msg)
        elif msg.is_extended_id or frame_id not in self._addressed:
            self.counters["echoes" if not msg.is_extended_id and frame_id in self._echo_ids else "foreign"] += 1
        elif msg.is_remote_frame:
            self._reject("rejected_other", msg)
        else:
            self._reject("rejected_unknown_id", msg)

    def _take(self, decoded: Any, t_s: float | None) -> None:  # pragma: no cover - every node overrides it
        raise NotImplementedError

    #: Called with (frame id, payload) of every data frame this node put on the bus; see :meth:`add_sent_observer`.
    _sent_observers: tuple = ()

    def add_sent_observer(self, observer: Any) -> None:
        """Have ``observer(frame_id, payload)`` called with every data frame this node sends, after the bus took it
        (e.g. :meth:`drivers.can_observer.CanObserver.feed`: the stand's telemetry of an emulated device, beside
        the flight code's driver and without a bus handle of its own). The node's state never depends on it."""
        self._sent_observers = (*self._sent_observers, observer)

    def add_observer(self, observer: Any) -> None:
        """The listener hook (:meth:`drivers.endpoint.Endpoint.add_observer`): every frame the node takes, decoded
        once by its codec, goes to ``observer`` after :meth:`_take`. The hook wraps ``_take`` on this instance only
        when the first observer comes, so the receive loop of a node nobody observes is the same as before."""
        super().add_observer(observer)
        if "_take" in self.__dict__:
            return
        # _take(decoded, t_s) then each observer: drivers.can_frames.take_observed(self, the class's _take, ...).
        self._take = functools.partial(_frames.take_observed, self, self._take)  # type: ignore[method-assign]

    @property
    def rejected_frames(self) -> int:
        """Frames addressed to this node that it dropped as unknown, of the wrong length or undecodable, plus error
        frames, each counted once (not commands refused in the wrong mode, nor other nodes' traffic)."""
        c = self.counters
        return c["rejected_unknown_id"] + c["rejected_length"] + c["rejected_other"]

    def _reject(self, key: str, msg: can.Message | None = None) -> None:
        self.counters[key] += 1
        if msg is not None:
            frame = frame_hex(msg.arbitration_id, msg.data, extended=msg.is_extended_id)
            kind = " (an error or remote frame)" if msg.is_error_frame or msg.is_remote_frame else ""
            self.last_rejected = f"{_WHY[key].format(name=self.name)}: frame {frame}{kind}"
        if self._board is not None:
            self._board["rejected_frames"] += 1

    # -- sending ----------------------------------------------------------------------------------

    #: ``_send(msg)``: encode ``msg`` and send it as one data frame (DriverError naming the bus if that fails); the
    #: sent-frame observers see it. :func:`drivers.can_frames.send`, compiled where the install can.
    _send = _frames.send


class CanHost(CanNode):
    """A host driver: sends commands, drains what the device sends, hands out its newest periodic sample.

    A subclass maps each message type its device sends to the attribute keeping the newest one (``_latest``), names
    the periodic sample's type and attribute (``_sample_type``, ``_sample_attr``) and its ICD's mode command
    (``_mode_command``), counts each sample it takes in ``counters["samples"]`` and sets ``self._returned_samples = 0``
    and ``self._seq = 0`` in its constructor.
    """

    _latest: dict[type, str]
    _sample_type: type
    _sample_attr: str
    _returned_samples: int
    _mode_command: Any
    _seq: int

    def _init_host(self, bus: can.BusABC, codec: Any, name: str, accept: frozenset[int], own: frozenset[int],
                   owns_bus: bool) -> None:
        """The constructor's common part: the node on ``bus`` taking ``accept`` (what the device sends; ``own`` =
        the commands, recognised as our echoes), ``counters["samples"]``, every ``_latest`` attribute None."""
        self.codec = codec
        self.name = name
        self._init_node(bus, codec, accept=accept, own=own, extra_counters=("samples",), owns_bus=owns_bus)
        for attr in self._latest.values():
            setattr(self, attr, None)
        self._returned_samples = 0  # value of counters["samples"] when a sample was last handed out
        self._seq = 0  # of the last mode command (set_mode), echoed back by the device once applied

    def _next_seq(self) -> int:
        self._seq = (self._seq + 1) & 0xFF
        return self._seq

    def set_mode(self, mode: str | int, reset_counters: bool = False) -> int:
        """Send the ICD's mode command (a name from its ``MODES`` or the number); returns the sequence number used,
        which the device echoes back once applied (the sequence advances only when the command went out)."""
        seq = (self._seq + 1) & 0xFF
        self.send(self._mode_command(mode, bool(reset_counters), seq))  # ValueError lists the modes
        self._seq = seq
        return seq

    #: Encode and send any command message (DriverError naming the bus if that fails).
    send = CanNode._send
    #: Drain every pending frame without blocking; returns how many frames were read. Bad frames are counted, never
    #: raised.
    poll = CanNode._drain

    #: ``_take(decoded, t_s)``: keep a message the device sent as the newest of its kind (the periodic sample counted
    #: in ``counters["samples"]``). :func:`drivers.can_frames.host_take`, compiled where the install can.
    _take = _frames.host_take

    def _newest_unseen(self) -> Any:
        """Poll, then the newest sample if it has not been returned yet, else None (when several arrived since the
        last call only the newest is returned: its ``seq`` tells how many were skipped)."""
        self._drain()
        n = self.counters["samples"]
        if n == self._returned_samples:
            return None
        self._returned_samples = n
        return getattr(self, self._sample_attr)

    def _wait_newest(self, timeout_s: float, timeout_error: Any) -> Any:
        """A sample newer than the last one returned, waiting up to ``timeout_s`` (monotonic); raises
        ``timeout_error()`` (a DeviceTimeoutError naming the device) when none came."""
        deadline = time.monotonic() + timeout_s
        self.poll()
        counters = self.counters
        try:
            while counters["samples"] == self._returned_samples:
                remaining = deadline - time.monotonic()
                if remaining <= 0.0:
                    error: DeviceTimeoutError = timeout_error()
                    raise error
                msg = self.bus.recv(remaining)
                if msg is not None:
                    self._handle(msg, None)
        except can.CanError as exc:
            raise DriverError(f"{self.name}: cannot read from {self.bus.channel_info}: {exc}") from exc
        self._returned_samples = counters["samples"]
        return getattr(self, self._sample_attr)


def check_positive(config: Any, names: tuple[str, ...]) -> None:
    """An emulator configuration's check: ValueError naming the class, the field and the value for any of ``names``
    that is not a finite number > 0."""
    for name in names:
        value = getattr(config, name)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f"{type(config).__name__}.{name} must be a finite number > 0; got {value!r}.")


#: A period boundary reached within 1 us counts as reached (float sums of steps drift).
EPS_S = 1e-6
_floor = math.floor


class CanDevice(DeviceFaults, CanNode):
    """An emulated device: its periodic publication schedule, its heartbeat, and the clock faults and reboot of
    :mod:`drivers.device_faults`.

    Periodic messages are due at ``t0 + k * period`` (``t0`` = the first publication time); a subclass sets
    ``self._t0 = None``, ``self._k_sample = self._k_status = self._k_heartbeat = 0`` and
    ``self._heartbeat_counter = 0`` in its constructor, with ``self._sample`` (``t_s -> message``: its periodic
    message, e.g. its bound ``measure``) and ``self._sample_period_s``; names its ICD's heartbeat message
    (``_heartbeat_type``) and keeps ``counters["samples_skipped"]``.

    The device clock is the heartbeat's ``uptime_s`` (the DBCs carry no other time tag), from the first
    publication (power-up); a clock fault shifts it. Reboot (:meth:`reboot`): frames waiting on the bus and
    arriving while the device is off are lost (``frames_lost_in_boot``); at the first :meth:`publish` after the
    boot the device powers up and sends first its heartbeat in state BOOT (the ICD's boot message) with uptime 0
    and counter 0, then its periodic message one period later and its status one status period later; the
    device's ``_reboot_device`` puts its own state back (mode, sequence numbers, on-board counters).
    """

    _heartbeat_type: Any
    _t0: float | None
    _k_sample: int
    _sample: Any
    _sample_period_s: float
    mode: str
    #: The modes in which the periodic message is sent (None: every mode).
    _sampling_modes: frozenset[str] | None = None
    #: A command with a duration is running: :meth:`publish` first runs the device's ``_watchdog(t_s)``.
    _driven = False
    _heartbeat_counter: int
    _k_status: int
    _k_heartbeat: int
    config: Any
    #: ``since`` from which :meth:`_housekeeping` has something to send (0 until it first ran).
    _housekeeping_due = 0.0

    def service(self, t_s: float) -> None:
        """``receive(t_s)`` then ``publish(t_s)``."""
        self.receive(t_s)
        self.publish(t_s)

    def receive(self, t_s: float) -> int:  # pragma: no cover - every device overrides it
        raise NotImplementedError

    def publish(self, t_s: float) -> int:
        """Send whatever is due at ``t_s`` (the periodic message, the status messages, the heartbeat); returns the
        number of frames sent. The periodic message sent is kept as ``last_sample``, for a stand that serves the
        device."""
        if self._closed:
            self._check_open()
        if self._t0 is None:
            if self.booting(t_s):  # rebooting: off until the boot ends
                return 0
            self._t0 = t_s
        if self._driven:
            self._watchdog(t_s)
        since = t_s - self._t0 + EPS_S
        sent = 0
        period = self._sample_period_s
        if since >= self._k_sample * period:
            self._k_sample = self._next_slot(since, period, self._k_sample, True)  # counting skipped slots
            modes = self._sampling_modes
            if modes is None or self.mode in modes:
                self.last_sample = msg = self._sample(t_s)
                self._send(msg)
                sent += 1
        if since >= self._housekeeping_due:
            sent += self._housekeeping(since, t_s)
        return sent

    def _watchdog(self, t_s: float) -> None:  # pragma: no cover - a device that sets _driven overrides it
        raise NotImplementedError

    def _housekeeping(self, since: float, t_s: float) -> int:
        """Send the status messages and the heartbeat when due (``since`` = seconds since ``t0``); returns frames
        sent. A subclass keeps ``_k_status`` and ``_k_heartbeat`` and lists its status messages in
        :meth:`_status_messages`; ``self.config`` has ``status_period_s`` and ``heartbeat_period_s``."""
        cfg = self.config
        sent = 0
        if since >= self._k_status * cfg.status_period_s:
            self._k_status = self._next_slot(since, cfg.status_period_s, self._k_status)
            for msg in self._status_messages(t_s):
                self._send(msg)
                sent += 1
        if since >= self._k_heartbeat * cfg.heartbeat_period_s:
            self._k_heartbeat = self._next_slot(since, cfg.heartbeat_period_s, self._k_heartbeat)
            self._send(self.heartbeat(t_s))
            sent += 1
        # The publish of every tick calls this only from here on (most ticks have nothing of it due).
        self._housekeeping_due = min(self._k_status * cfg.status_period_s, self._k_heartbeat * cfg.heartbeat_period_s)
        return sent

    def _status_messages(self, t_s: float) -> tuple:  # pragma: no cover - every device overrides it
        raise NotImplementedError

    def _next_slot(self, since: float, period: float, k: int, count_skips: bool = False) -> int:
        """The next slot after ``since`` seconds (at least ``k + 1``); with ``count_skips`` the slots passed over by
        a late call are counted in ``samples_skipped``."""
        nxt = _floor(since / period) + 1
        if nxt <= k:  # rounding at a boundary
            nxt = k + 1
        if count_skips and nxt > k + 1:
            self.counters["samples_skipped"] += nxt - k - 1
        return nxt

    #: The next heartbeat is the first after a reboot: state BOOT.
    _boot_heartbeat = False

    def heartbeat(self, t_s: float) -> Any:
        """The heartbeat the device sends at ``t_s``: whole seconds since the first publication (with any clock
        fault), NOMINAL (BOOT the first after a reboot), and a counter (advanced here)."""
        up_s = t_s - (self._t0 if self._t0 is not None else t_s)
        if self._clock_fault is not None:
            up_s += self._clock_fault.offset_s(t_s)
        uptime = int(max(up_s, 0.0)) & 0xFFFFFFFF
        counter = self._heartbeat_counter
        self._heartbeat_counter = (counter + 1) & 0xFF
        state = "NOMINAL"
        if self._boot_heartbeat:
            self._boot_heartbeat = False
            state = "BOOT"
        return self._heartbeat_type(uptime, state, counter)

    # -- reboot (drivers.device_faults) -------------------------------------------------------------

    def _reboot(self, t_s: float, t_up: float) -> None:
        self._t0 = None  # powers up at the first publish after the boot
        # At power-up only the boot heartbeat; the periodic message and the status follow a period later.
        self._k_sample = self._k_status = 1
        self._k_heartbeat = 0
        self._housekeeping_due = 0.0
        self._heartbeat_counter = 0
        self._boot_heartbeat = True
        self._reboot_device(t_up)
        self._deaf_until_up(t_s)
        self._drain(t_s)  # what waits on the bus now is lost

    def _deaf_until_up(self, t_reboot: float) -> None:
        """Frames taken at the reboot or while the device is off are lost (counted): ``_take`` is wrapped on this
        instance until the first frame after the boot, as :meth:`add_observer` wraps it, so a device never rebooted
        pays nothing."""
        self._t_reboot = t_reboot
        if "_take_up" in self.__dict__:  # rebooted again while off: the wrapper is in place
            return
        own = self.__dict__.get("_take")  # an observer's wrapper, or None
        self._take_up = take = self._take

        def take_booting(decoded: Any, t_s: float | None) -> None:
            if t_s is not None and (t_s <= self._t_reboot or self.booting(t_s)):
                self._lost_in_boot("frames_lost_in_boot", 1)
                return
            if own is None:
                del self._take
            else:
                self._take = own  # type: ignore[method-assign]
            del self._take_up
            take(decoded, t_s)

        self._take = take_booting  # type: ignore[method-assign]
        self._lost_in_boot("frames_lost_in_boot", 0)


class ServedNode:
    """An emulated node served on a link to a flight computer outside (:class:`drivers.can_bus.ServedBus`): what
    the stand counts as rejected is what the node rejected plus what the link could not decode."""

    def __init__(self, node: CanNode, link: Any) -> None:
        self.node = node
        self.link = link

    def rejected_frames(self) -> int:
        return self.node.rejected_frames + self.link.counters["rejected_undecodable"]

    def last_rejected(self) -> str | None:
        return self.link.last_rejected if self.link.last_rejected is not None else self.node.last_rejected

    def conflict(self) -> Any:
        return self.link.conflict
