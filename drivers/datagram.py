"""Fixed-length binary datagrams on a serial line, defined by a TOML ICD: the shared part of the
gyro and the sun sensor drivers.

A datagram is ``identifier u8 | payload | CRC-16/CCITT-FALSE u16``, the CRC over identifier and
payload. There are no framing bytes: each identifier has one fixed length, and a receiver finds the
datagrams in a byte stream by their identifier and their CRC (the way inertial sensors such as the
Safran STIM series stream: a datagram starts with an identifier byte and ends with a CRC). This
module holds, for every device built on it:

- :class:`DatagramCodec`: the pure codec built from the TOML (field types, scaling, ranges, enum
  tables, flag bits), checked at load time against the device's dataclasses so the ICD and the code
  cannot drift apart; ``encode(msg) -> bytes`` and ``decode(datagram) -> msg``;
- :func:`take_datagram` and :class:`DatagramDecoder`: sans-I/O stream decoding (feed bytes, get
  messages; a false start or a corrupted datagram costs one dropped byte, never an exception);
- :class:`DatagramHost` and :class:`DatagramEmulator`: the port handling, counters and the
  wall-clock serving loop that the device hosts and emulators share; each device fills small hooks;
- :func:`render_icd`: the ICD document as Markdown, generated from the TOML.

No clock is read outside :meth:`DatagramEmulator.run` and the host's monotonic deadlines.
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable
from dataclasses import fields
from pathlib import Path
from typing import Any

from drivers.device_faults import DeviceFaults
from drivers.errors import DriverError, EncodeError, ProtocolError
from drivers.framing import check_crc16_spec, crc16, crc16_doc
from drivers.icd_codec import (
    DEVICE_TO_HOST,
    HOST_TO_DEVICE,
    FieldSpec,
    MessageSpec,
    attr_text,
    decode_fields,
    enums_doc,
    field_specs,
    index_messages,
    load_icd,
    md_head,
    message_heading,
    messages_doc,
    range_text,
    wire_values,
)
from drivers.serial_port import SerialHost, SerialServer, is_port_error, open_port, port_name, write_available

__all__ = [
    "DEVICE_TO_HOST",
    "HOST_TO_DEVICE",
    "DatagramCodec",
    "DatagramDecoder",
    "DatagramEmulator",
    "DatagramHost",
    "DatagramRejected",
    "FieldSpec",
    "MessageSpec",
    "crc16",
    "render_icd",
    "take_datagram",
]

class DatagramRejected(ProtocolError):
    """A datagram cannot be accepted; ``kind`` says why (``short``, ``crc``, ``unknown_id``,
    ``direction``, ``length``, ``value``)."""

    def __init__(self, kind: str, reason: str, **kw: Any) -> None:
        super().__init__(reason, **kw)
        self.kind = kind


class DatagramCodec:
    """Encode and decode the datagrams of one device, from its TOML ICD.

    Args:
        icd_path: the TOML file.
        classes: message name in the ICD -> dataclass (SI units).
        device: how messages name the device ("gyro", "sun sensor").

    Attributes:
        icd (the TOML as a dict), messages (name -> :class:`MessageSpec`), by_id, enums,
        byte_order ("big" or "little"), ids_to_host / ids_to_device (identifier bytes by direction),
        max_length (the longest datagram).
    """

    def __init__(self, icd_path: str | Path, classes: dict[str, type], device: str) -> None:
        self.device = device
        icd = self.icd = load_icd(icd_path)
        proto = icd["protocol"]
        order = proto.get("byte_order")
        if order not in ("big", "little"):
            raise ValueError(f"{device} ICD: byte_order must be 'big' or 'little'; got {order!r}.")
        self.byte_order: str = order
        self._prefix = ">" if order == "big" else "<"
        crc = proto["crc"]
        check_crc16_spec(crc, f"{device} ICD")
        self.enums: dict[str, tuple[str, ...]] = {k: tuple(v) for k, v in icd.get("enums", {}).items()}
        self._classes = classes
        self.messages, self.by_id = index_messages((self._message_spec(m) for m in icd["messages"]), classes,
                                                   f"{device} ICD", "identifier")
        self._by_cls = {spec.cls: spec for spec in self.messages.values()}
        self.ids_to_host = frozenset(s.id for s in self.messages.values() if s.direction == DEVICE_TO_HOST)
        self.ids_to_device = frozenset(s.id for s in self.messages.values() if s.direction == HOST_TO_DEVICE)
        self.max_length = max(s.length for s in self.messages.values())
        self._prefix_text = f"{device} "  # how a refused value's sentence starts
        self._message_text = {s.id: f"{device} {s.name}" for s in self.messages.values()}  # how encode names one
        self._i24 = {s.id: tuple(i for i, f in enumerate(s.fields) if f.type == "i24") for s in self.messages.values()}

    def _message_spec(self, m: dict[str, Any]) -> MessageSpec:
        name = m["name"]
        where = f"{self.device} ICD: message {name}"
        cls = self._classes.get(name)
        if cls is None:
            raise ValueError(f"{where} has no dataclass in the codec.")
        if m["direction"] not in (HOST_TO_DEVICE, DEVICE_TO_HOST):
            raise ValueError(f"{where}: direction must be host->device or device->host; got {m['direction']!r}.")
        if not 0 <= int(m["id"]) <= 0xFF:
            raise ValueError(f"{where}: identifier must be 0..255; got {m['id']!r}.")
        specs, covered = field_specs(m, self.enums, where)
        attrs = {x.name for x in fields(cls)}
        if covered != attrs:
            raise ValueError(f"{where} maps fields to {sorted(covered)}, but {cls.__name__} has {sorted(attrs)}.")
        fmt = self._prefix + "".join(s.struct_code for s in specs)
        return MessageSpec(int(m["id"]), name, m["direction"], m.get("doc", ""), tuple(specs), fmt,
                           struct.calcsize(fmt), cls, overhead=3)

    # -- encode ---------------------------------------------------------------------------------

    def spec_of(self, msg: Any) -> MessageSpec:
        try:
            return self._by_cls[type(msg)]
        except KeyError:
            raise TypeError(f"Cannot encode {type(msg).__name__} as a {self.device} datagram: expected one of "
                            f"{', '.join(c.__name__ for c in self._classes.values())}.") from None

    def encode(self, msg: Any) -> bytes:
        """The whole datagram of ``msg``: identifier, payload, CRC."""
        spec = self._by_cls.get(type(msg)) or self.spec_of(msg)  # spec_of says what is wrong
        values = wire_values(spec, msg, self._message_text[spec.id], self.byte_order)
        head = bytes((spec.id,)) + spec.packer.pack(*values)
        return head + crc16(head).to_bytes(2, self.byte_order)

    # -- decode ---------------------------------------------------------------------------------

    def decode(self, datagram: bytes | bytearray, direction: str | None = None) -> Any:
        """Decode one whole datagram; ``direction``: accept only messages sent that way (None = both).

        Raises :class:`DatagramRejected` with the datagram in hex, a ``kind`` and expected vs got.
        """
        data = bytes(datagram)
        hx = data.hex().upper()
        if len(data) < 3:
            raise DatagramRejected("short", f"{self.device} datagram too short", frame_hex=hx,
                                   expected=">= 3 bytes", computed=f"{len(data)} bytes")
        spec = self.by_id.get(data[0])
        if spec is None:
            raise DatagramRejected("unknown_id", f"unknown {self.device} identifier 0x{data[0]:02X}", frame_hex=hx,
                                   expected=f"one of {', '.join(f'0x{i:02X}' for i in sorted(self.by_id))}",
                                   computed=f"0x{data[0]:02X}")
        if direction is not None and spec.direction != direction:
            raise DatagramRejected("direction", f"{self.device} {spec.name} is sent {spec.direction}, not {direction}",
                                   frame_hex=hx)
        if len(data) != spec.length:
            raise DatagramRejected("length", f"{self.device} {spec.name} datagram of the wrong length", frame_hex=hx,
                                   expected=f"{spec.length} bytes", computed=f"{len(data)} bytes")
        got = int.from_bytes(data[-2:], self.byte_order)
        calc = crc16(data[:-2])
        if got != calc:
            raise DatagramRejected("crc", f"{self.device} {spec.name} datagram with a bad CRC-16", frame_hex=hx,
                                   expected=f"0x{got:04X} (received)", computed=f"0x{calc:04X}")
        return self.decode_payload(spec, data[1:-2], hx)

    def decode_payload(self, spec: MessageSpec, payload: bytes, frame: str | bytes = b"") -> Any:
        """The message of one datagram's payload; DatagramRejected for a value outside its table, naming ``frame``
        (the whole datagram, in hex or as bytes; the payload when not given)."""
        raw: Any = spec.packer.unpack(payload)
        i24 = self._i24[spec.id]
        if i24:  # the few 24-bit fields travel as 3 raw bytes; no per-field type test on the other messages
            raw = list(raw)
            for i in i24:
                raw[i] = int.from_bytes(raw[i], self.byte_order, signed=True)
        return decode_fields(spec, raw, DatagramRejected, frame or payload, self._prefix_text)

    def lsb(self, message: str, field: str) -> float:
        """One wire step of a field, in SI."""
        for f in self.messages[message].fields:
            if f.name == field:
                return f.scale
        raise KeyError(f"{self.device} ICD: message {message} has no field {field!r}.")

    def si_range(self, message: str, field: str) -> tuple[float, float]:
        """What a field can carry, in SI."""
        for f in self.messages[message].fields:
            if f.name == field:
                return f.lo * f.scale, f.hi * f.scale
        raise KeyError(f"{self.device} ICD: message {message} has no field {field!r}.")


# -- stream decoding ------------------------------------------------------------------------------


def take_datagram(buf: bytes | bytearray, lengths: dict[int, int], byte_order: str) -> tuple[int, bytes | None]:
    """Look for one datagram at the start of ``buf``; ``lengths`` maps accepted identifiers to lengths.

    Returns ``(consumed, datagram)``:

    - ``(0, None)``: ``buf`` starts with an identifier but is shorter than its datagram (or is
      empty): feed more bytes;
    - ``(n, datagram)``: a datagram whose CRC checks; ``n`` is its length;
    - ``(n, None)``: ``n`` bytes to drop: everything before the next identifier byte, or the one
      identifier byte of a datagram whose CRC fails (so a real datagram starting inside it is found).
    """
    if not buf:
        return 0, None
    n = lengths.get(buf[0])
    if n is None:
        for i in range(1, len(buf)):
            if buf[i] in lengths:
                return i, None
        return len(buf), None
    if len(buf) < n:
        return 0, None
    datagram = bytes(buf[:n])
    if int.from_bytes(datagram[-2:], byte_order) == crc16(datagram[:-2]):
        return n, datagram
    return 1, None


class DatagramDecoder:
    """Streaming decoder of one direction's datagrams: :meth:`feed` bytes, get messages; bad input
    is counted, never raised.

    ``counters``: ``datagrams`` (decoded), ``crc_errors`` (an identifier byte whose datagram failed
    its CRC: a corrupted datagram or a false start), ``value_errors`` (CRC good, a field outside its
    table), ``bytes_dropped``, ``undecodable`` (stretches of bytes between two datagrams that held
    no good one: a corrupted or cut datagram, noise; each stretch counts once however many false
    starts it held). ``last_rejected`` says why the latest bytes were dropped.
    """

    def __init__(self, codec: DatagramCodec, direction: str) -> None:
        self.codec = codec
        self.direction = direction
        ids = codec.ids_to_host if direction == DEVICE_TO_HOST else codec.ids_to_device
        self._lengths = {i: codec.by_id[i].length for i in ids}
        self._buf = bytearray()
        self._dropping = False  # inside a stretch of undecodable bytes
        self.last_rejected: str | None = None
        self.counters = {"datagrams": 0, "crc_errors": 0, "value_errors": 0, "bytes_dropped": 0, "undecodable": 0}

    def reset(self) -> None:
        """Forget any partial datagram (after a reconnect)."""
        self.counters["bytes_dropped"] += len(self._buf)
        self._buf.clear()

    @property
    def pending(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Any]:
        buf = self._buf
        buf += data
        out: list[Any] = []
        c = self.counters
        lengths, order = self._lengths, self.codec.byte_order
        while buf:
            consumed, datagram = take_datagram(buf, lengths, order)
            if consumed == 0:
                break
            if datagram is None:
                if not self._dropping:
                    self._dropping = True
                    c["undecodable"] += 1
                if buf[0] in lengths:
                    c["crc_errors"] += 1
                    head = bytes(buf[:lengths[buf[0]]]).hex().upper()
                    self.last_rejected = f"{self.codec.device} bytes {head} hold no datagram with a good CRC-16"
                c["bytes_dropped"] += consumed
            else:
                self._dropping = False
                spec = self.codec.by_id[datagram[0]]
                try:
                    out.append(self.codec.decode_payload(spec, datagram[1:-2], datagram))
                    c["datagrams"] += 1
                except DatagramRejected as exc:
                    c["value_errors"] += 1
                    c["bytes_dropped"] += consumed
                    self.last_rejected = str(exc)
            del buf[:consumed]
        return out


# -- endpoints ------------------------------------------------------------------------------------


#: How far back a sample counter may step and the sample still be taken for one arriving late (not a restart).
STALE_STEPS = 8


class DatagramHost(SerialHost):
    """Generic host side of a datagram device: the port (a URL it reopens after a failure, or an
    open object the caller keeps), sending commands, and receiving without ever raising on bad
    traffic. A device's host sets ``_kind`` (its device name) and fills :meth:`_accept_message`.

    ``counters``: ``sent``, ``bytes_received``, ``frames_received`` (good datagrams),
    ``rejected_crc``, ``rejected_other`` (a field outside its table), ``bytes_dropped``,
    ``timeouts``, ``recoveries``, ``reconnects``; a device adds its own.
    """

    _kind = "device"

    def __init__(self, port: Any, codec: DatagramCodec, *, baudrate: int, timeout_s: float, name: str,
                 poll_s: float) -> None:
        self._closed = True
        self.port = None
        self._owns_port = False
        if not (isinstance(timeout_s, (int, float)) and math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"{name}: timeout_s = {timeout_s!r} is not allowed; allowed: a number of seconds > 0.")
        self.codec = codec
        self.name = name
        self.timeout_s = float(timeout_s)
        self.baudrate = baudrate
        self.poll_s = poll_s
        self._url = port if isinstance(port, str) else None
        self.port, self._owns_port = open_port(port, baudrate=baudrate, timeout=poll_s, name=name)
        if not self._owns_port and hasattr(self.port, "timeout"):
            self.port.timeout = poll_s
        self._closed = False
        self._broken = False
        self._decoder = DatagramDecoder(codec, DEVICE_TO_HOST)
        self.online = True
        self._last_rx: float | None = None
        self.counters: dict[str, int] = {
            "sent": 0, "bytes_received": 0, "frames_received": 0, "rejected_crc": 0, "rejected_other": 0,
            "bytes_dropped": 0, "timeouts": 0, "recoveries": 0, "reconnects": 0,
        }

    def __repr__(self) -> str:
        return f"{type(self).__name__}({port_name(self.port)!r}, online={self.online}, counters={self.counters})"

    def _fresh(self, last_seq: int, seq: int, modulus: int) -> bool:
        """Whether a sample with counter ``seq`` after one with ``last_seq`` is new. A repeat of the last counter is a
        duplicate and a step back of at most :data:`STALE_STEPS` a sample arriving late (out of order): both are
        counted (``duplicates``, ``stale``) and not taken as the newest. Any other step is new, its gap counted in
        ``samples_lost`` (a larger step back is a counter restarted, a device rebooted)."""
        step = (seq - last_seq) % modulus
        if step == 0:
            self.counters["duplicates"] = self.counters.get("duplicates", 0) + 1
            return False
        if step >= modulus - STALE_STEPS:
            self.counters["stale"] = self.counters.get("stale", 0) + 1
            return False
        self.counters["samples_lost"] += step - 1
        return True

    # -- send and receive (the port's reopening is SerialHost's) ---------------------------------

    def send(self, msg: Any) -> None:
        """Encode and send one command (EncodeError naming the field before anything is sent)."""
        self._check_open()
        frame = self.codec.encode(msg)
        if self.codec.spec_of(msg).direction != HOST_TO_DEVICE:
            raise EncodeError(f"{self.name}: {type(msg).__name__} is sent by the device, not by the host.")
        try:
            self.port.write(frame)
        except Exception as exc:
            if is_port_error(exc):
                raise self._port_failed("write to", exc) from exc
            raise
        self.counters["sent"] += 1

    def _read(self, block: bool) -> int:
        data = self._read_port(block)
        if data:
            self._take_in(data)
        return len(data)

    def _take_in(self, data: bytes) -> None:
        """Decode ``data`` read from the port: count it, hand every good datagram to the device and the observers."""
        c = self.counters
        c["bytes_received"] += len(data)
        dec = self._decoder
        dc = dec.counters
        crc_errors, value_errors, dropped = dc["crc_errors"], dc["value_errors"], dc["bytes_dropped"]
        messages = dec.feed(data)
        c["rejected_crc"] += dc["crc_errors"] - crc_errors
        c["rejected_other"] += dc["value_errors"] - value_errors
        c["bytes_dropped"] += dc["bytes_dropped"] - dropped
        observers = self._observers
        for msg in messages:
            c["frames_received"] += 1
            self._last_rx = time.monotonic()
            if not self.online:
                self.online = True
                c["recoveries"] += 1
            self._accept_message(msg)
            for observer in observers:  # the stand's tap beside the driver (drivers.endpoint)
                observer(msg)

    def _accept_message(self, msg: Any) -> None:  # pragma: no cover - every device overrides it
        """Store one decoded message (the device's hook)."""

    def poll(self) -> int:
        """Decode everything that has arrived, without waiting; returns the good datagrams decoded."""
        self._check_open()
        before = self.counters["frames_received"]
        for _ in range(256):  # bounded: a babbling port cannot hold the caller here
            data = self._read_port(False)
            if not data:
                break
            self._take_in(data)
        return self.counters["frames_received"] - before

    def _wait(self, ready: Callable[[], bool], awaited: str, timeout_s: float | None) -> None:
        """Read until ``ready()`` or the monotonic deadline (DeviceTimeoutError naming what was awaited)."""
        timeout = self.timeout_s if timeout_s is None else timeout_s
        self._check_open()
        deadline = time.monotonic() + timeout
        self.poll()
        while not ready():
            if time.monotonic() >= deadline:
                raise self._timed_out(awaited, timeout, "datagram",
                                      f"Is the {self._kind} powered, on this port and at {self.baudrate} baud?")
            self._read(block=True)


class DatagramEmulator(DeviceFaults, SerialServer):
    """Generic device side of a datagram device: the port, receiving commands (bad traffic counted,
    never raised), sending, a device clock that SET_TIME sets, the wall-clock serving loop, and the
    clock faults and reboot of :mod:`drivers.device_faults`.

    A device's emulator calls :meth:`_receive` and its own publishing from ``service(t_s)``, fills
    :meth:`_apply` (one decoded command) and :meth:`next_due_s` (for :meth:`run`).

    ``counters``: ``bytes_received``, ``frames_received``, ``sent``, ``rejected_crc`` (identifier
    bytes whose datagram failed its CRC), ``rejected_undecodable`` (stretches of bytes that held no
    good datagram, each once), ``rejected_other`` (a good CRC, a value outside its table),
    ``bytes_dropped``, ``tx_dropped``; a device adds its own. :attr:`rejected_frames` counts what the
    host sent that was dropped, each bad stretch or datagram once; ``last_rejected`` says why the
    latest was.

    On a port it opened itself (a real line to a flight computer: a device path, a pty, a URL) the
    emulator never waits to write, as a device's UART does not: a datagram goes out as far as the
    line takes it at once, the rest of it before the next one, and a datagram the line has no room
    for is dropped whole and counted (``tx_dropped``), so a flight computer that stops reading
    cannot stall the stand. An open port handed in (the stand's in-process line) is written as it is.

    Reboot: a device keeps its power-up time in ``_t_on`` (None until its first service); its ``_reboot_device``
    sets it back to None and its ``service`` powers up again (sequence numbers from 0) at the first call that is
    not :meth:`booting`, calling :meth:`_drop_input` until then. The device clock restarts at the end of the
    boot, not synchronised.
    """

    def __init__(self, port: Any, codec: DatagramCodec, *, baudrate: int, name: str,
                 clock_offset_s: float = 0.0) -> None:
        self._closed = True
        self.port = None
        self._owns_port = False
        self.name = name
        self.codec = codec
        self._decoder = DatagramDecoder(codec, HOST_TO_DEVICE)
        self.counters: dict[str, int] = {
            "bytes_received": 0, "frames_received": 0, "sent": 0, "rejected_crc": 0, "rejected_undecodable": 0,
            "rejected_other": 0, "bytes_dropped": 0, "tx_dropped": 0,
        }
        self._tx_rest = b""  # the part of the last datagram the line has not taken yet (owned ports)
        self._clock_offset_s = self._clock_offset0_s = float(clock_offset_s)
        self._clock_ref: tuple[float, float] | None = None  # (sim t, device s) after SET_TIME
        #: Sends dropped silently while True (a device that went quiet; for tests and fault injection).
        self.silent = False
        self.port, self._owns_port = open_port(port, baudrate=baudrate, timeout=0.0, name=name)
        self._closed = False

    def __repr__(self) -> str:
        return f"{type(self).__name__}({port_name(self.port)!r}, counters={self.counters})"

    # -- device clock ---------------------------------------------------------------------------

    @property
    def time_synced(self) -> bool:
        return self._clock_ref is not None

    def set_time(self, t_s: float, device_time_us: int) -> None:
        """SET_TIME applied at sim time ``t_s``: the device clock reads ``device_time_us`` then."""
        self._clock_ref = (t_s, device_time_us * 1e-6)
        self._clock_set(t_s)

    def device_time_us(self, t_s: float) -> int:
        """The device clock at sim time ``t_s`` (us, never negative), with any clock fault."""
        if self._clock_ref is None:
            s = self._clock_offset_s + t_s
        else:
            t_ref, dev_ref = self._clock_ref
            s = dev_ref + (t_s - t_ref)
        if self._clock_fault is not None:
            s += self._clock_fault.offset_s(t_s)
        us = round(s * 1e6)
        return us if us > 0 else 0  # max(us, 0) without its call

    # -- reboot (drivers.device_faults) ---------------------------------------------------------

    def _reboot(self, t_s: float, t_up: float) -> None:
        self._drop_input()  # what the host sent and the device had not taken yet is lost
        self._decoder.reset()
        self._tx_rest = b""
        self._clock_ref = None  # not synchronised; the clock reads clock_offset_s at power-up
        self._clock_offset_s = self._clock_offset0_s - t_up
        self._reboot_device(t_up)

    def _drop_input(self) -> None:
        """A device that is off takes nothing from the line: what waits there is read and lost, counted in
        ``bytes_lost_in_boot`` and, whole datagrams, in ``rejected_while_off`` (so every frame the host sent is
        accounted for)."""
        data = self._read_waiting()
        self._lost_in_boot("bytes_lost_in_boot", len(data))
        self._lost_in_boot("rejected_while_off", len(self._decoder.feed(data)) if data else 0)

    # -- receive and send -----------------------------------------------------------------------

    def _check_open(self) -> None:
        if self._closed:
            raise DriverError(f"{self.name}: closed; create a new one.")

    def _read_waiting(self) -> bytes:
        """Whatever waits on the line, without waiting (DriverError naming the port if it failed)."""
        port = self.port
        try:
            n = port.in_waiting
            return port.read(n) if n else b""
        except Exception as exc:
            if is_port_error(exc):
                raise DriverError(f"{self.name}: cannot read from {port_name(port)}: {exc}") from exc
            raise

    def _receive(self, t_s: float) -> int:
        data = self._read_waiting()
        if not data:
            return 0
        c = self.counters
        c["bytes_received"] += len(data)
        dec = self._decoder
        before = dict(dec.counters)
        messages = dec.feed(data)
        c["rejected_crc"] += dec.counters["crc_errors"] - before["crc_errors"]
        c["rejected_undecodable"] += dec.counters["undecodable"] - before["undecodable"]
        c["rejected_other"] += dec.counters["value_errors"] - before["value_errors"]
        c["bytes_dropped"] += dec.counters["bytes_dropped"] - before["bytes_dropped"]
        observers = self._observers
        for msg in messages:
            c["frames_received"] += 1
            self._apply(msg, t_s)
            for observer in observers:  # what the device received, for the stand beside it (drivers.endpoint)
                observer(msg)
        return len(messages)

    @property
    def rejected_frames(self) -> int:
        """What the host sent that was dropped: stretches of undecodable bytes and datagrams with a value outside
        their table, each counted once."""
        return self.counters["rejected_undecodable"] + self.counters["rejected_other"]

    @property
    def last_rejected(self) -> str | None:
        """Why the latest bytes from the host were dropped, or None."""
        return self._decoder.last_rejected

    def _apply(self, msg: Any, t_s: float) -> None:  # pragma: no cover - every device overrides it
        """Apply one decoded command at sim time ``t_s`` (the device's hook)."""

    def _send(self, msg: Any) -> None:
        if self.silent:
            return
        frame = self.codec.encode(msg)
        try:
            if self._owns_port:
                if not self._send_available(frame):
                    return
            else:
                self.port.write(frame)
        except Exception as exc:
            raise DriverError(f"{self.name}: cannot write to {port_name(self.port)}: {exc}") from exc
        self.counters["sent"] += 1
        if self._observers:  # what went on the line, decoded as a receiver decodes it (drivers.endpoint)
            sent = self.codec.decode(frame)
            for observer in self._observers:
                observer(sent)

    def _send_available(self, frame: bytes) -> bool:
        """Write ``frame`` as far as the line takes it now, after what is left of the previous one; False (and
        ``tx_dropped`` counted) when the line has no room for it."""
        if self._tx_rest:
            self._tx_rest = self._tx_rest[write_available(self.port, self._tx_rest):]
            if self._tx_rest:
                self.counters["tx_dropped"] += 1
                return False
        n = write_available(self.port, frame)
        if n == 0:
            self.counters["tx_dropped"] += 1
            return False
        self._tx_rest = frame[n:]
        return True


# -- document ---------------------------------------------------------------------------------------


def render_icd(codec: DatagramCodec, *, title: str, source: str, generator: str, intro: str,
               exchanges: list[str]) -> str:
    """The ICD of a datagram device as Markdown (every message, field, offset, scale and range)."""
    p = codec.icd["protocol"]
    crc = p["crc"]
    out = [
        f"# {title}",
        "",
        f"<!-- Generated from {source} by `python -m {generator}`; do not edit by hand (a test compares them). -->",
        "",
        f"**{p['name']} {p['version']}.** {intro}",
        "",
        "## Link and datagram",
        "",
        f"- Physical: {p['physical']}.",
        "- Datagram: `identifier u8 | payload | CRC u16`, one fixed length per identifier; no framing bytes. A "
        "receiver finds datagrams by their identifier and their CRC: when the CRC fails it drops the identifier "
        "byte and looks again from the next byte.",
        crc16_doc(crc),
        f"- Byte order: {p['byte_order']}-endian. Field value in SI = wire value x scale.",
        "- A datagram the receiver cannot accept (bad CRC, a field outside its table) is counted and dropped; "
        "nothing is answered to it.",
        *messages_doc(codec.messages.values(), "Datagrams", ("identifier", "datagram", "length (bytes)"),
                      lambda s: s.length),
    ]
    for s in codec.messages.values():
        out += [*message_heading(s),
                *md_head("offset", "field", "type", "wire unit", "scale to SI", "SI attribute", "range / values",
                         "description"),
                f"| 0 | identifier | u8 | | | | 0x{s.id:02X} | datagram identifier |"]
        offset = 1
        for f in s.fields:
            out.append(f"| {offset} | {f.name} | {f.type} | {f.unit} | {f.scale:.10g} | {attr_text(f)} | "
                       f"{range_text(f)} | {f.doc} |")
            offset += f.size
        out.append(f"| {offset} | crc | u16 | | | | | CRC-16 of bytes 0..{offset - 1} |")
    if codec.enums:
        out += enums_doc(codec.enums)
    out += ["", "## Behaviour", ""] + [f"- {line}" for line in exchanges] + [""]
    return "\n".join(out)
