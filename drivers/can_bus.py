"""Opening CAN buses through python-can, with errors from :mod:`drivers.errors`.

A CAN endpoint is an interface name plus a channel: ``("virtual", "adcs")`` or
``("stand_loopback", "adcs")`` (:mod:`drivers.can_loopback`, the fast in-process bus) in tests,
``("socketcan", "can0")`` on a bench. python-can is imported lazily, so importing this module
costs nothing on a stand that has no CAN device.

Never use python-can's ``udp_multicast`` interface on shared machines: it sends multicast out of
the default route (see docs/architecture.md, "Cross-process tests on one machine").

A device on a real adapter (hardware and served links) is opened with :func:`open_device_bus`: python-can's
serial-line interfaces get short timeouts and their port is held exclusively. A served emulator reads through
:class:`ServedBus`, which counts and drops what the nodes outside send that the interface cannot decode.
"""

from __future__ import annotations

import importlib
import socket
from typing import TYPE_CHECKING, Any

from drivers.errors import ConnectError, DriverError

if TYPE_CHECKING:  # pragma: no cover
    import can

__all__ = ["OWN_INTERFACES", "SERIAL_LINE_INTERFACES", "ServedBus", "data_frame", "line_port", "loops_back", "open_bus",
           "open_device_bus", "socketcan_available"]

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
    return type(getattr(bus, "wrapped", bus)).__name__ == "UdpMulticastBus"


#: python-can interfaces that carry CAN frames over a serial line (a USB adapter, a socat pty in tests).
SERIAL_LINE_INTERFACES = ("serial", "slcan")
#: python-can's serial-line interfaces ignore recv()'s timeout and block for the port's own: keep it short, so a
#: poll that finds nothing costs a millisecond, not the default 0.1 s.
SERIAL_LINE_TIMEOUT_S = 1e-3
#: A peer that stops reading must not block the loop: a write that cannot finish in time is a CAN error.
SERIAL_LINE_WRITE_TIMEOUT_S = 0.5


def line_port(bus) -> Any:
    """The pyserial port under a serial-line bus (python-can's ``serial`` or ``slcan``), else None."""
    return getattr(bus, "_ser", None) or getattr(bus, "serialPortOrig", None)


def open_device_bus(interface: str, channel: str) -> can.BusABC:
    """:func:`open_bus` for a device on a real adapter (hardware and served links). On a serial-line interface the
    reads and writes get short timeouts and the port is held exclusively: a second stand or emulator opening the
    same line is refused with :class:`ConnectError` saying it is in use (as :func:`drivers.serial_port.open_port`
    does for serial devices). Other interfaces are opened as they are (a CAN bus is shared by design)."""
    if interface not in SERIAL_LINE_INTERFACES:
        return open_bus(interface, channel)
    from drivers.serial_port import check_free, hold_exclusively

    device_path = "://" not in channel  # URLs (socket://) are not locked
    if device_path:  # before opening: slcan writes its open command to the line as it opens
        check_free(f"CAN {interface}:{channel}", channel)
    bus = open_bus(interface, channel, timeout=SERIAL_LINE_TIMEOUT_S)
    port = line_port(bus)
    if port is not None:
        port.write_timeout = SERIAL_LINE_WRITE_TIMEOUT_S
    if port is not None and device_path:
        try:
            hold_exclusively(port, f"CAN {interface}:{channel}", channel)
        except ConnectError:
            bus.shutdown()
            raise
    return bus


def _descriptor(port) -> int | None:
    try:
        fd = port.fileno()
    except Exception:  # noqa: BLE001 - loop:// and other URL ports without one
        return None
    return fd if isinstance(fd, int) and fd >= 0 else None


def _link_failed(exc: BaseException) -> bool:
    """True when ``exc`` (raised by a python-can ``recv``) says the line or socket itself failed (an OSError
    somewhere in its chain: pyserial's SerialException is one), not that a frame could not be decoded."""
    seen = 0
    e: BaseException | None = exc
    while e is not None and seen < 16:  # bounded: a chain is short, a cycle must not hold us
        if isinstance(e, OSError):
            return True
        e, seen = e.__cause__ or e.__context__, seen + 1
    return False


class ServedBus:
    """The bus of an emulator served to nodes outside the stand (``link = "served"``), wrapping a python-can bus.

    A real device counts and drops what it cannot decode; python-can's interfaces instead raise from ``recv`` on a
    malformed frame from the line (``serial``: a DLC above 8, a bad end delimiter, a frame cut short; ``slcan``: a
    line that is not a frame; ``udp_multicast``: a datagram that does not unpack). Here :meth:`recv` counts each
    such frame once in ``counters["rejected_undecodable"]``, keeps the reason in ``last_rejected`` and goes on to
    the next frame; only a failure of the line itself (an ``OSError`` in the chain: the adapter unplugged) is raised,
    as :class:`DriverError`. A serial-line interface hands over one stray byte per ``recv``: the drain goes on while
    the port holds bytes, at most ``max_per_drain`` frames and skips per drain, so a flood waits for the next tick.

    On a serial line the frames go out without waiting, as a device's transmit buffer does: as far as the line takes
    them at once, the rest of a frame before the next one, and a frame the line has no room for is dropped whole and
    counted in ``counters["tx_dropped"]`` (a flight computer that stopped reading cannot stall the stand; the
    emulator's ``sent`` still counts the frame: it left the device).

    ``own_ids`` are the frame ids the served node transmits. A frame with one of them that this node did not send
    (on a bus that loops frames back, more than the echoes of what it sent) comes from another node serving the same
    device on this bus (a second stand or emulator): it is counted in ``counters["foreign_own_id"]``, described in
    ``conflict`` and not handed to the emulator.
    """

    def __init__(self, bus: can.BusABC, own_ids=frozenset(), max_per_drain: int = 4096) -> None:
        self.wrapped = bus
        self.counters = {"rejected_undecodable": 0, "foreign_own_id": 0, "tx_dropped": 0}
        self.last_rejected: str | None = None
        self.conflict: str | None = None
        self.max_per_drain = max_per_drain
        self._port = line_port(bus)
        self._echoes_due = 0 if loops_back(bus) else None  # frames of ours still to come back on a looping bus
        self._own_ids = frozenset(own_ids)
        self._taken = 0
        self._tx_rest = b""  # the part of the last frame the line has not taken yet
        if self._port is not None and _descriptor(self._port) is not None:
            # python-can's serial-line interfaces write each frame with the port's write(), which waits for a full
            # line: its writes go through _write_available instead (one os.write on the port's descriptor).
            self._port.write = self._write_available

    def _write_available(self, data) -> int:
        from drivers.serial_port import write_available

        port = self._port
        if self._tx_rest:
            self._tx_rest = self._tx_rest[write_available(port, self._tx_rest):]
            if self._tx_rest:
                self.counters["tx_dropped"] += 1
                return len(data)
        data = bytes(data)
        n = write_available(port, data)
        if n == 0:
            self.counters["tx_dropped"] += 1
        else:
            self._tx_rest = data[n:]
        return len(data)

    @property
    def channel_info(self) -> str:
        return self.wrapped.channel_info

    def send(self, msg, timeout: float | None = None) -> None:
        self.wrapped.send(msg, timeout)
        if self._echoes_due is not None and not msg.is_extended_id and msg.arbitration_id in self._own_ids:
            self._echoes_due += 1

    def shutdown(self) -> None:
        self.wrapped.shutdown()

    def _waiting(self) -> bool:
        try:
            return bool(self._port.in_waiting)
        except Exception:  # noqa: BLE001 - a port that cannot say: the next recv reports a failed line
            return False

    def recv(self, timeout: float | None = None):
        """The next frame (None when there is none now, or when this drain took ``max_per_drain`` already)."""
        bus = self.wrapped
        for _ in range(self.max_per_drain):
            if self._taken >= self.max_per_drain:
                break
            self._taken += 1
            try:
                msg = bus.recv(timeout)
            except Exception as exc:
                if _link_failed(exc):
                    raise DriverError(f"CAN {bus.channel_info}: the line failed while reading: {exc}") from exc
                self.counters["rejected_undecodable"] += 1
                self.last_rejected = f"a frame CAN {bus.channel_info} could not decode ({type(exc).__name__}: {exc})"
                timeout = 0.0
                continue
            if msg is None:
                if self._port is not None and self._waiting():
                    timeout = 0.0
                    continue  # a stray byte was skipped; frames may follow it
                break
            if self._own_ids and not msg.is_extended_id and msg.arbitration_id in self._own_ids:
                if self._echoes_due:
                    self._echoes_due -= 1
                else:
                    self._foreign(msg)
                    continue
            return msg
        self._taken = 0
        return None

    def _foreign(self, msg) -> None:
        self.counters["foreign_own_id"] += 1
        if self.conflict is None:
            self.conflict = (f"a frame with this device's own id 0x{msg.arbitration_id:03X} came from another node on "
                             f"CAN {self.wrapped.channel_info}: another stand or emulator serves the same device "
                             "on this bus, and the flight computer hears both")


_message_new: Any = None


def data_frame(frame_id: int, payload: bytes, timestamp: float = 0.0, is_rx: bool = True,
               channel: Any = None) -> can.Message:
    """A classic CAN data frame with an 11-bit id: what ``can.Message(arbitration_id=frame_id, data=payload,
    is_extended_id=False)`` makes, field for field, without the constructor's keyword handling (the host drivers
    and emulators make one per frame, several per tick). The in-process bus gives a frame it queued as a tuple
    its ``timestamp``, ``is_rx`` and ``channel`` (:data:`drivers.can_loopback.DataFrame`); ``dlc`` is the payload's
    length and ``data`` its own ``bytearray``."""
    global _message_new
    if _message_new is None:
        import can

        _message_new = (object.__new__, can.Message)
    new, cls = _message_new
    m = new(cls)
    m.timestamp = timestamp
    m.arbitration_id = frame_id
    m.is_extended_id = False
    m.is_remote_frame = False
    m.is_error_frame = False
    m.channel = channel
    m.data = bytearray(payload)
    m.dlc = len(m.data)
    m.is_fd = False
    m.is_rx = is_rx
    m.bitrate_switch = False
    m.error_state_indicator = False
    return m
