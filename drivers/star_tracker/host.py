"""Host driver: the stand (or a test) talking to a serial star tracker.

The tracker may be real (``/dev/ttyUSB0``) or :class:`~drivers.star_tracker.emulator.
StarTrackerEmulator` on a pty, socat link or ``socket://``: the driver cannot tell.

Request/response (the device answers by itself: a real tracker, or an emulator served by another
thread or process)::

    with StarTrackerHost("/dev/ttyUSB0", address=0x21) as st:
        st.set_time(unix_us)                    # ACTION SET_TIME -> ACK
        sol = st.request_solution()             # REQUEST_TELEMETRY -> SOLUTION
        st.subscribe("SOLUTION", 0.0)           # then, once per control tick:
        sol = st.take_solution()                # the newest unseen solution, or None (never blocks)

In a single-threaded loop that also services the emulator, never block on a reply: send with
:meth:`StarTrackerHost.send_command` (e.g. ``Subscribe(codec.solution_id, 0.0)``) and read with
:meth:`StarTrackerHost.take_solution` after ``emulator.service(t)``.

Receiving never raises on bad traffic: frames with a bad CRC, another address, an unknown id, a
wrong length, bad escapes, oversize, or a value outside the ICD's range (a quaternion that is not
unit, a negative sigma, a temperature below absolute zero) are counted in
:attr:`StarTrackerHost.counters`, one counter per reason, and dropped; the newest reason is in
``last_rejected``. A flood is read in bounded chunks: :meth:`StarTrackerHost.poll` reads at most
``max_read_bytes`` per call and leaves the rest for the next. A write that the port cannot take by
its deadline (``write_timeout_s``) raises :class:`~drivers.errors.DeviceTimeoutError`: the driver
never hangs on a device that stopped reading.
A request that gets no reply by its monotonic deadline raises
:class:`~drivers.errors.DeviceTimeoutError` naming the device and what was awaited; the driver
marks itself offline, and the next good frame brings it back (``recoveries``). If the port itself
fails (a USB adapter unplugged, a socket closed), the driver reopens a port it opened from a URL on
the next call (``reconnects``). A NACK raises :class:`~drivers.star_tracker.codec.NackError`.
"""

from __future__ import annotations

import time
from typing import Any

from drivers.errors import DeviceTimeoutError, EncodeError
from drivers.framing import SlipDecoder
from drivers.serial_port import SerialHost, is_port_error, open_port, port_name
from drivers.star_tracker.codec import (
    DEVICE_TO_HOST,
    Ack,
    Action,
    FrameRejected,
    GetParam,
    Message,
    Nack,
    NackError,
    ParamValue,
    RequestTelemetry,
    Solution,
    StarTrackerCodec,
    Status,
    Subscribe,
    Unsubscribe,
)

__all__ = ["StarTrackerHost"]

#: Why a received frame is dropped: the codec's FrameRejected kinds, then the SLIP decoder's.
#: Bytes asked of the port per read.
_READ_CHUNK = 4096
REJECT_REASONS = ("crc", "address", "unknown_id", "length", "value", "short", "direction", "oversize", "bad_escape")


class StarTrackerHost(SerialHost):
    """Host-side driver of one star tracker.

    Args:
        port: URL/path (opened with pyserial's ``serial_for_url``, reopened after a port failure,
            closed by :meth:`close`) or an open port object the caller keeps (its ``timeout`` is set
            to ``poll_s``).
        address: device address (default: the ICD's, 0x21).
        codec: a :class:`StarTrackerCodec` (default: the ICD in ``fixtures/``).
        baudrate: for URL ports.
        timeout_s: default reply timeout of requests.
        name: how errors name this device.
        poll_s: the port's read timeout slice (a read returns as soon as a byte arrives).
        write_timeout_s: longest a command's write may take (the port's ``write_timeout``).
        max_read_bytes: most bytes one :meth:`poll` reads (a babbling device cannot hold the caller).

    Attributes:
        latest_solution, latest_status: the newest decoded message of each kind, or None.
        online: False after a timeout until the next good frame.
        counters: ``sent``, ``bytes_received``, ``frames_received`` (good, for this address),
            one ``rejected_<reason>`` per reason a frame is dropped: ``crc``, ``address``,
            ``unknown_id``, ``length``, ``value`` (a field outside the ICD's range), ``short``,
            ``direction`` (a command sent by a device), ``oversize``, ``bad_escape``;
            ``solutions``, ``status``, ``acks``, ``nacks``, ``timeouts``, ``write_timeouts``,
            ``recoveries``, ``reconnects``.
        last_rejected: why the newest dropped frame was dropped (a sentence with the frame in hex).
    """

    def __init__(
        self,
        port: Any,
        address: int | None = None,
        *,
        codec: StarTrackerCodec | None = None,
        baudrate: int = 115200,
        timeout_s: float = 0.5,
        name: str = "star tracker",
        poll_s: float = 0.05,
        write_timeout_s: float = 1.0,
        max_read_bytes: int = 16384,
    ) -> None:
        self._closed = True
        self.port = None
        self._owns_port = False
        self.codec = codec = codec if codec is not None else StarTrackerCodec()
        self.address = codec.default_address if address is None else address
        if not (isinstance(self.address, int) and 0 <= self.address <= 255):
            raise EncodeError(f"{name}: address = {address!r} is not allowed; allowed: an int from 0 to 255.")
        if not (isinstance(timeout_s, (int, float)) and timeout_s > 0):
            raise ValueError(f"{name}: timeout_s = {timeout_s!r} is not allowed; allowed: a number of seconds > 0.")
        self.name = name
        self.timeout_s = float(timeout_s)
        self.baudrate = baudrate
        self.poll_s = poll_s
        if not (isinstance(write_timeout_s, (int, float)) and 0 < write_timeout_s < 3600):
            raise ValueError(f"{name}: write_timeout_s = {write_timeout_s!r} is not allowed; allowed: 0 to 3600 s.")
        if not (isinstance(max_read_bytes, int) and max_read_bytes >= 64):
            raise ValueError(f"{name}: max_read_bytes = {max_read_bytes!r} is not allowed; allowed: an int >= 64.")
        self.write_timeout_s = float(write_timeout_s)
        self.max_read_bytes = max_read_bytes
        self._url = port if isinstance(port, str) else None
        self.port, self._owns_port = open_port(port, baudrate=baudrate, timeout=poll_s, name=name,
                                               write_timeout=self.write_timeout_s)
        if not self._owns_port and hasattr(self.port, "timeout"):
            self.port.timeout = poll_s
        if not self._owns_port and hasattr(self.port, "write_timeout"):
            self.port.write_timeout = self.write_timeout_s
        self._closed = False
        self._broken = False
        self._decoder = SlipDecoder(codec.max_body)
        self.online = True
        self.latest_solution: Solution | None = None
        self.latest_status: Status | None = None
        self._solution_taken = True
        self._last_rx: float | None = None
        self._inbox: list[Message] = []  # replies collected while a transaction waits
        self.last_rejected = ""
        self.counters: dict[str, int] = {
            "sent": 0, "bytes_received": 0, "frames_received": 0, **{f"rejected_{r}": 0 for r in REJECT_REASONS},
            "solutions": 0, "status": 0, "acks": 0, "nacks": 0, "timeouts": 0, "write_timeouts": 0,
            "recoveries": 0, "reconnects": 0,
        }

    def __repr__(self) -> str:
        return f"StarTrackerHost({port_name(self.port)!r}, address=0x{self.address:02X}, online={self.online})"

    # -- port -----------------------------------------------------------------------------------

    def _write(self, msg: Message) -> None:
        frame = self.codec.encode(msg, self.address)
        try:
            self.port.write(frame)
        except DeviceTimeoutError:
            self.counters["write_timeouts"] += 1
            raise
        except Exception as exc:
            if type(exc).__name__ == "SerialTimeoutException":  # pyserial's write_timeout ran out
                self.counters["write_timeouts"] += 1
                raise DeviceTimeoutError(
                    f"{self.name}: writing {len(frame)} bytes to {port_name(self.port)} did not finish within "
                    f"{self.write_timeout_s:g} s; the line is not being read (is the device stalled?).",
                    device=self.name, awaited="the port to take a command", timeout_s=self.write_timeout_s,
                ) from None
            if is_port_error(exc):
                raise self._port_failed("write to", exc) from exc
            raise
        self.counters["sent"] += 1

    def _read(self, block: bool, limit: int = _READ_CHUNK) -> int:
        """Read what is there, at most ``limit`` bytes (``block``: wait up to one poll slice for the
        first byte); decode it. Returns the number of bytes read."""
        data = self._read_port(block, max(1, min(limit, _READ_CHUNK)))
        if data:
            self._feed(data)
        return len(data)

    def _feed(self, data: bytes) -> int:
        """Take in ``data`` read from the port (counted in ``bytes_received``); the good frames decoded."""
        self.counters["bytes_received"] += len(data)
        dec = self._decoder
        slip = dec.counters
        oversize, bad_escape = slip["oversize"], slip["bad_escape"]
        bodies = dec.feed(data)
        if slip["oversize"] != oversize or slip["bad_escape"] != bad_escape:  # rare: only then name them
            for k, v in (("oversize", oversize), ("bad_escape", bad_escape)):
                if slip[k] != v:
                    self.counters[f"rejected_{k}"] += slip[k] - v
                    self.last_rejected = f"{slip[k] - v} SLIP chunk(s) dropped as {k.replace('_', ' ')}."
        n = 0
        for body in bodies:
            try:
                msg = self.codec.decode_body(body, self.address, DEVICE_TO_HOST)
            except FrameRejected as exc:
                self.counters[f"rejected_{exc.kind}"] += 1
                self.last_rejected = str(exc)
                continue
            n += 1
            self._accept(msg)
            for observer in self._observers:  # the stand's tap beside the driver (drivers.endpoint)
                observer(msg)
        return n

    def _accept(self, msg: Message) -> None:
        c = self.counters
        c["frames_received"] += 1
        self._last_rx = time.monotonic()
        if not self.online:
            self.online = True
            c["recoveries"] += 1
        if isinstance(msg, Solution):
            c["solutions"] += 1
            self.latest_solution = msg
            self._solution_taken = False
        elif isinstance(msg, Status):
            c["status"] += 1
            self.latest_status = msg
        elif isinstance(msg, Ack):
            c["acks"] += 1
        elif isinstance(msg, Nack):
            c["nacks"] += 1
        self._inbox.append(msg)
        if len(self._inbox) > 64:
            del self._inbox[:-64]

    # -- receiving without a request ------------------------------------------------------------

    def poll(self) -> int:
        """Decode everything that has arrived, without waiting; returns the good frames decoded."""
        self._check_open()
        before = self.counters["frames_received"]
        budget = self.max_read_bytes  # bounded: a babbling port cannot hold the caller here
        while budget > 0:
            data = self._read_port(False, budget if budget < _READ_CHUNK else _READ_CHUNK)  # as _read(block=False)
            if not data:
                break
            self._feed(data)
            budget -= len(data)
        self._inbox.clear()
        return self.counters["frames_received"] - before

    def take_solution(self) -> Solution | None:
        """Poll; the newest solution not returned before, or None."""
        self.poll()
        if self._solution_taken:
            return None
        self._solution_taken = True
        return self.latest_solution

    def wait_solution(self, timeout_s: float | None = None) -> Solution:
        """Wait for a solution not returned before (a subscription must be on); DeviceTimeoutError if none."""
        timeout = self.timeout_s if timeout_s is None else timeout_s
        self._check_open()
        deadline = time.monotonic() + timeout
        while self._solution_taken:
            if time.monotonic() >= deadline:
                raise self._timeout("an asynchronous SOLUTION", timeout)
            self._read(block=True)
        self._inbox.clear()
        self._solution_taken = True
        return self.latest_solution  # type: ignore[return-value]

    def send_command(self, msg: Message) -> None:
        """Send one command without waiting for its reply (for a single-threaded loop that services
        the emulator itself); the ACK/NACK is counted by the next :meth:`poll`."""
        self._check_open()
        self._write(msg)

    # -- requests -------------------------------------------------------------------------------

    def _transact(self, cmd: Message, match, awaited: str, timeout_s: float | None) -> Message:
        timeout = self.timeout_s if timeout_s is None else timeout_s
        self._check_open()
        self.poll()  # drop what is already there, so an old frame is never taken for the reply
        self._write(cmd)
        deadline = time.monotonic() + timeout
        cid = self.codec.spec_of(cmd).id
        while True:
            for i, msg in enumerate(self._inbox):
                if isinstance(msg, Nack) and msg.command_id == cid:
                    del self._inbox[: i + 1]
                    spec = self.codec.by_id.get(cid)
                    cname = spec.name if spec else f"0x{cid:02X}"
                    raise NackError(f"{self.name}: the tracker refused {cname} ({cmd!r}): {msg.error}.",
                                    command=cname, error=msg.error)
                if match(msg):
                    del self._inbox[: i + 1]
                    return msg
            self._inbox.clear()
            if time.monotonic() >= deadline:
                raise self._timeout(awaited, timeout)
            self._read(block=True)

    def _timeout(self, awaited: str, timeout_s: float) -> DeviceTimeoutError:
        self._decoder.reset()
        return self._timed_out(f"{awaited} from address 0x{self.address:02X}", timeout_s, "frame",
                               "Is the tracker powered, booted and on this port and address?", awaited=awaited)

    def _command(self, cmd: Message, timeout_s: float | None) -> None:
        cid = self.codec.spec_of(cmd).id
        name = self.codec.by_id[cid].name
        self._transact(cmd, lambda m: isinstance(m, Ack) and m.command_id == cid, f"ACK of {name}", timeout_s)

    def _telemetry_id(self, telemetry: str | int) -> int:
        if isinstance(telemetry, str):
            spec = self.codec.messages.get(telemetry.upper())
            if spec is not None and spec.telemetry:
                return spec.id
        elif telemetry in self.codec.telemetry_ids:
            return telemetry
        names = ", ".join(s.name for s in self.codec.messages.values() if s.telemetry)
        raise EncodeError(f"{self.name}: telemetry = {telemetry!r} is not allowed; allowed: {names}.")

    def request_solution(self, timeout_s: float | None = None) -> Solution:
        """REQUEST_TELEMETRY(SOLUTION) -> the newest solution (NackError NOT_READY while booting)."""
        sid = self.codec.solution_id
        msg = self._transact(RequestTelemetry(sid), lambda m: isinstance(m, Solution), "SOLUTION", timeout_s)
        self._solution_taken = True
        return msg  # type: ignore[return-value]

    def request_status(self, timeout_s: float | None = None) -> Status:
        """REQUEST_TELEMETRY(STATUS) -> STATUS."""
        sid = self.codec.status_id
        return self._transact(RequestTelemetry(sid), lambda m: isinstance(m, Status), "STATUS", timeout_s)  # type: ignore[return-value]

    def set_param(self, name: str | int, value_si: float, timeout_s: float | None = None) -> None:
        """SET_PARAM with ``value_si`` in SI units; EncodeError (field, value, range) before sending."""
        self._command(self.codec.set_param(name, value_si), timeout_s)

    def get_param(self, name: str | int, timeout_s: float | None = None) -> float:
        """GET_PARAM -> the value in SI units."""
        spec = self.codec.param(name)
        msg = self._transact(GetParam(spec.id), lambda m: isinstance(m, ParamValue) and m.param_id == spec.id,
                             f"PARAM_VALUE of {spec.name}", timeout_s)
        return msg.value * spec.scale  # type: ignore[union-attr]

    def boot(self, timeout_s: float | None = None) -> None:
        self._command(Action("BOOT", 0), timeout_s)

    def set_time(self, time_us: int, timeout_s: float | None = None) -> None:
        """Set the device clock to ``time_us`` (e.g. Unix time in us)."""
        self._command(Action("SET_TIME", time_us), timeout_s)

    def reset_counters(self, timeout_s: float | None = None) -> None:
        self._command(Action("RESET_COUNTERS", 0), timeout_s)

    def subscribe(
        self, telemetry: str | int = "SOLUTION", period_s: float = 0.0, timeout_s: float | None = None
    ) -> None:
        """Ask for ``telemetry`` every ``period_s`` (0 = every new solution)."""
        self._command(Subscribe(self._telemetry_id(telemetry), period_s), timeout_s)

    def request_solutions(self, period_s: float = 0.0) -> None:
        """Subscribe to SOLUTION without waiting for the answer (for flight code in a single-threaded loop, where the
        wait would block the tick): a tracker that rebooted has lost its subscriptions; the ACK or NACK is counted by
        the next :meth:`poll`."""
        self.send_command(Subscribe(self.codec.solution_id, period_s))

    def unsubscribe(self, telemetry: str | int = "SOLUTION", timeout_s: float | None = None) -> None:
        self._command(Unsubscribe(self._telemetry_id(telemetry)), timeout_s)
