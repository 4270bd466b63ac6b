"""Serial ports for device drivers and emulators: URLs in, one small byte-stream interface out.

A port is given as

- a URL or path that pyserial's ``serial_for_url`` understands: ``loop://``, ``socket://host:port``,
  ``spy://...``, ``/dev/ttyUSB0``, a pty slave path such as ``/dev/pts/5`` or a socat link;
- an already open object with ``read``, ``write``, ``in_waiting`` and ``close`` (a
  ``serial.Serial``, or :class:`FdPort`), which the caller keeps owning unless told otherwise.

:class:`FdPort` wraps a raw file descriptor (the master side of ``os.openpty()``), and
:func:`pty_pair` makes an in-process pty pair: the emulator serves on the master fd, the code
under test opens the slave path like any serial device. :func:`pipe_pair` is the same line without
the kernel: two :class:`PipePort` ends in one process, bytes readable at the other end as soon as
they are written (the serial analogue of the ``stand_loopback`` CAN bus).

Nothing here can hang on a peer that stopped reading: :meth:`FdPort.write` has a monotonic
deadline (``write_timeout``) and raises :class:`~drivers.errors.DeviceTimeoutError` when the line
does not take the bytes in time; :func:`write_available` writes only what a port takes at once
(an emulator in the loop's thread uses it and counts what it had to drop). A pty takes about 4 KiB
before a writer would block. :class:`SerialEndpoint` is the serial
sibling of :class:`drivers.endpoint.BusEndpoint`: an owned port, idempotent ``close()``, context
manager.

A port named by a device path (``/dev/ttyUSB0``, a pty, a socat link) is held exclusively while open (pyserial's
``exclusive=True``, an advisory ``flock`` every stand and emulator takes): a second stand or ``stand emulate``
opening a port that one already serves is refused with a :class:`~drivers.errors.ConnectError` saying the port is
in use, instead of both reading from one line and each getting part of the bytes. URLs (``loop://``,
``socket://``) are not locked.
"""

from __future__ import annotations

import errno
import os
import select
import threading
import time
import tty
from collections.abc import Callable
from typing import Any

from drivers.endpoint import Endpoint
from drivers.errors import ConnectError, DeviceTimeoutError, DriverError

__all__ = ["FdPort", "PipePort", "SerialEndpoint", "SerialHost", "SerialServer", "check_free", "hold_exclusively",
           "is_port_error", "open_port", "pipe_pair", "port_name", "pty_pair", "wait_readable", "write_available"]

#: errno values that say another open file holds the port: flock's EWOULDBLOCK, TIOCEXCL's EBUSY.
_BUSY = (errno.EWOULDBLOCK, errno.EAGAIN, errno.EBUSY)


class FdPort:
    """A byte stream on a file descriptor, with the parts of the ``serial.Serial`` API drivers use.

    ``timeout`` (s, None = block) bounds :meth:`read` like pyserial's: it returns as soon as
    ``size`` bytes arrived or the timeout passed. ``write_timeout`` (s) bounds :meth:`write`: the
    descriptor is non-blocking and a write that the other side does not take by then raises
    :class:`~drivers.errors.DeviceTimeoutError` (``written`` says how many bytes went out). The
    descriptor is closed by :meth:`close` (twice is fine).
    """

    def __init__(self, fd: int, name: str = "", timeout: float | None = 0.0, write_timeout: float = 1.0) -> None:
        if not (isinstance(write_timeout, (int, float)) and 0 <= write_timeout < 3600):
            raise ValueError(f"FdPort write_timeout = {write_timeout!r}; allowed 0 to 3600 s (never unbounded).")
        self.fd = fd
        self.name = name or f"fd:{fd}"
        self.timeout = timeout
        self.write_timeout = float(write_timeout)
        self.port = self.name
        self.is_open = True
        os.set_blocking(fd, False)

    def fileno(self) -> int:
        return self.fd

    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            return 0
        r, _, _ = select.select([self.fd], [], [], 0)
        return 4096 if r else 0

    def read(self, size: int = 1) -> bytes:
        import time

        out = bytearray()
        deadline = None if self.timeout is None else time.monotonic() + self.timeout
        while len(out) < size:
            wait = None if deadline is None else max(deadline - time.monotonic(), 0.0)
            r, _, _ = select.select([self.fd], [], [], wait)
            if not r:
                break
            try:
                chunk = os.read(self.fd, size - len(out))
            except BlockingIOError:
                continue
            except OSError:  # EIO: the other side of a pty is closed
                break
            if not chunk:
                break
            out += chunk
        return bytes(out)

    def write(self, data: bytes) -> int:
        import time

        view = memoryview(bytes(data))
        deadline = time.monotonic() + self.write_timeout
        while view:
            try:
                n = os.write(self.fd, view)
            except BlockingIOError:
                n = 0
            view = view[n:]
            if not view:
                break
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([], [self.fd], [], left)[1]:
                written = len(data) - len(view)
                err = DeviceTimeoutError(
                    f"{self.name}: {len(view)} of {len(data)} bytes could not be written within "
                    f"{self.write_timeout:g} s; the other end is not reading.",
                    device=self.name, awaited="the line to take the bytes", timeout_s=self.write_timeout)
                err.written = written
                raise err
        return len(data)

    def flush(self) -> None:
        pass

    def reset_input_buffer(self) -> None:
        for _ in range(256):  # bounded: a peer writing without pause cannot hold the caller here
            if not self.in_waiting:
                break
            try:
                if not os.read(self.fd, 4096):
                    break
            except BlockingIOError:
                break
            except OSError:
                break

    def close(self) -> None:
        if self.is_open:
            self.is_open = False
            os.close(self.fd)

    def __repr__(self) -> str:
        return f"FdPort({self.name!r})"


class _LineCondition(threading.Condition):
    """The lock of one in-process line (:func:`pipe_pair`) and how many threads wait on it: an end wakes the other
    only when one waits (the stand's own loop, the usual reader and writer, never does)."""

    def __init__(self) -> None:
        lock = threading.RLock()
        super().__init__(lock)
        #: The line's lock itself: ``with line.lock`` takes it without the Condition's own ``__enter__`` and
        #: ``__exit__``, two Python-level calls for each read and write of the line.
        self.lock = lock
        self.waiting = 0

    def wait_counted(self, timeout: float | None) -> bool:
        """``wait(timeout)``, counted while it waits (the lock held, as for ``wait``)."""
        self.waiting += 1
        try:
            return self.wait(timeout)
        finally:
            self.waiting -= 1

    def wake(self) -> None:
        """``notify_all()`` when a thread waits (the lock held)."""
        if self.waiting:
            self.notify_all()


class PipePort:
    """One end of an in-process serial line (:func:`pipe_pair`), with the parts of the ``serial.Serial`` API
    drivers use and no file descriptor.

    What one end writes the other can read at once. Like a pty, the line holds at most ``capacity`` bytes
    in each direction: :meth:`write` waits up to ``write_timeout`` for the reader, then raises
    :class:`~drivers.errors.DeviceTimeoutError` (``written`` says how many bytes went in), so a writer never
    hangs on a peer that stopped reading; :meth:`read` waits up to ``timeout`` (None = until ``size``
    bytes or the other end closes). Both ends may be used from different threads.
    """

    def __init__(self, name: str, rx: bytearray, tx: bytearray, cond: _LineCondition, capacity: int,
                 timeout: float | None = 0.0, write_timeout: float = 1.0) -> None:
        self.name = self.port = name
        self._rx, self._tx, self._cond, self.capacity = rx, tx, cond, capacity
        self._lock = cond.lock  # the condition's lock, taken directly (the waits go through the condition)
        self.timeout = timeout
        self.write_timeout = float(write_timeout)
        self.is_open = True
        self.peer: PipePort | None = None

    @property
    def in_waiting(self) -> int:
        return len(self._rx) if self.is_open else 0

    def read(self, size: int = 1) -> bytes:
        rx = self._rx
        if len(rx) < size and self.timeout != 0:
            deadline = None if self.timeout is None else time.monotonic() + self.timeout
            with self._lock:
                while len(rx) < size and self.peer is not None and self.peer.is_open and self.is_open:
                    left = None if deadline is None else deadline - time.monotonic()
                    if left is not None and left <= 0:
                        break
                    self._cond.wait_counted(left)
        with self._lock:
            if size >= len(rx):  # all of it: the usual read of what in_waiting said, without a slice
                out = bytes(rx)
                rx.clear()
            else:
                out = bytes(rx[:size])
                del rx[:size]
            self._cond.wake()
        return out

    def write(self, data: bytes) -> int:
        data = bytes(data)
        tx, cond = self._tx, self._cond
        with self._lock:
            if self.is_open and self.capacity - len(tx) >= len(data):  # the usual case: room for all of it
                tx += data
                cond.wake()
                return len(data)
        view = memoryview(data)
        deadline = None  # the write timeout runs from the first wait for room
        with self._lock:
            while view:
                if not self.is_open:
                    raise OSError(f"{self.name}: the port is closed.")
                room = self.capacity - len(tx)
                if room > 0:
                    tx += view[:room]
                    view = view[room:]
                    cond.wake()
                    continue
                if deadline is None:
                    deadline = time.monotonic() + self.write_timeout
                left = deadline - time.monotonic()
                if left <= 0 or not cond.wait_counted(left) and self.capacity - len(tx) <= 0:
                    err = DeviceTimeoutError(
                        f"{self.name}: {len(view)} of {len(data)} bytes could not be written within "
                        f"{self.write_timeout:g} s; the other end is not reading.",
                        device=self.name, awaited="the line to take the bytes", timeout_s=self.write_timeout)
                    err.written = len(data) - len(view)
                    raise err
        return len(data)

    def flush(self) -> None:
        pass

    def reset_input_buffer(self) -> None:
        with self._lock:
            self._rx.clear()
            self._cond.wake()

    def close(self) -> None:
        with self._lock:
            self.is_open = False
            self._cond.wake()

    def __repr__(self) -> str:
        return f"PipePort({self.name!r})"


def pipe_pair(name: str = "pipe", capacity: int = 65536) -> tuple[PipePort, PipePort]:
    """Two ends of one in-process serial line, ``(a, b)``: what ``a`` writes ``b`` reads and the other way
    round, each direction holding at most ``capacity`` bytes. Close both ends when done."""
    if not (isinstance(capacity, int) and 64 <= capacity <= 1 << 24):
        raise ValueError(f"pipe_pair capacity = {capacity!r}; allowed 64 to 16777216 bytes.")
    cond = _LineCondition()
    a_to_b, b_to_a = bytearray(), bytearray()
    a = PipePort(f"{name}-a", b_to_a, a_to_b, cond, capacity)
    b = PipePort(f"{name}-b", a_to_b, b_to_a, cond, capacity)
    a.peer, b.peer = b, a
    return a, b


def wait_readable(port: Any, timeout_s: float) -> None:
    """Wait up to ``timeout_s`` until ``port`` has bytes to read: ``select`` on a port with a descriptor; a
    :class:`PipePort` has them as soon as they were written, so nothing to wait for there."""
    fileno = getattr(port, "fileno", None)
    if fileno is not None:
        select.select([fileno()], [], [], timeout_s)


def pty_pair() -> tuple[FdPort, str, int]:
    """An in-process pty pair: ``(master, slave_path, slave_fd)``, both sides raw.

    Serve on ``master`` (an :class:`FdPort`); open ``slave_path`` with :func:`open_port`. Keep
    ``slave_fd`` open while the pair is in use (it keeps the pty alive between openings) and close
    it with ``os.close`` at the end.
    """
    master, slave = os.openpty()
    tty.setraw(slave)
    tty.setraw(master)
    return FdPort(master, f"pty-master:{os.ttyname(slave)}"), os.ttyname(slave), slave


def write_available(port: Any, data: bytes) -> int:
    """Write as much of ``data`` as ``port`` takes now, without blocking; return the bytes written.

    A port with a descriptor (FdPort, pyserial's tty and socket:// ports, both non-blocking) is
    written with one ``os.write``; 0 when its buffer is full. Other ports (``loop://``) get their
    own ``write``, bounded by their ``write_timeout``; a timeout there counts as nothing written.
    """
    fileno = getattr(port, "fileno", None)
    fd = None
    if fileno is not None:
        try:
            fd = fileno()
        except Exception:  # noqa: BLE001 - loop:// and others without a usable descriptor
            fd = None
    if isinstance(fd, int) and fd >= 0:
        blocking = os.get_blocking(fd)  # pyserial's ports are non-blocking already; make sure
        if blocking:
            os.set_blocking(fd, False)
        try:
            return os.write(fd, data)
        except BlockingIOError:
            return 0
        finally:
            if blocking:
                os.set_blocking(fd, True)
    try:
        n = port.write(data)
    except DeviceTimeoutError as exc:
        return getattr(exc, "written", 0)
    except Exception as exc:
        if type(exc).__name__ in ("SerialTimeoutException", "Full"):
            return 0
        raise
    return len(data) if n is None else int(n)


def open_port(
    port: Any, *, baudrate: int = 115200, timeout: float | None = 0.0, name: str = "serial",
    write_timeout: float = 2.0,
) -> tuple[Any, bool]:
    """Open ``port`` (URL/path) with pyserial, or pass an open port object through.

    Returns ``(port_object, owned)``; raises :class:`ConnectError` naming the URL and the OS reason.
    """
    if not isinstance(port, (str, os.PathLike)):
        for attr in ("read", "write", "close"):
            if not hasattr(port, attr):
                raise ConnectError(
                    f"{name}: port must be a URL (loop://, socket://host:port, /dev/tty...) or an open serial "
                    f"object with read/write/close; got {port!r}.",
                    where=repr(port),
                )
        return port, False
    url = os.fspath(port)
    try:
        import serial
    except ImportError:
        raise ConnectError(f"{name}: opening serial port {url!r} needs pyserial, which is part of "
                           "the base install (pip install adcs-stand).", where=url, reason="pyserial missing") from None

    # A device path is held exclusively (flock): two stands or emulators on one line would each get part of the bytes.
    extra = {"exclusive": True} if "://" not in url else {}
    try:
        ser = serial.serial_for_url(url, baudrate=baudrate, timeout=timeout, write_timeout=write_timeout, **extra)
    except (serial.SerialException, ValueError, OSError) as exc:
        if getattr(exc, "errno", None) in _BUSY:
            raise _in_use(name, url) from exc
        raise ConnectError(f"{name}: cannot open serial port {url!r}: {exc}", where=url, reason=str(exc)) from exc
    return ser, True


def _in_use(name: str, url: str) -> ConnectError:
    return ConnectError(f"{name}: serial port {url!r} is in use: another program (a stand run or a stand emulate?) "
                        "has it open; stop that one or name another port.", where=url, reason="in use")


def check_free(name: str, path: str) -> None:
    """:class:`ConnectError` "in use" when another open file holds the exclusive lock on the device ``path``; nothing
    is held after the check. For openers that write to the line as they open it (python-can's ``slcan`` sends its
    open command), so they never write into a line another stand serves; :func:`hold_exclusively` takes the lock
    once open. A path that cannot be opened here is left to the opener to report."""
    import fcntl

    try:
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError as exc:
        if exc.errno == errno.EBUSY:
            raise _in_use(name, path) from exc
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno in _BUSY:
            raise _in_use(name, path) from exc
    finally:
        os.close(fd)  # closing the descriptor releases its lock


def hold_exclusively(port: Any, name: str, url: str) -> None:
    """Take the exclusive lock on an open port that pyserial opened without it (python-can's serial-line CAN
    interfaces), as :func:`open_port` does for device paths; :class:`ConnectError` "in use" when another open file
    holds it. A port without a file descriptor (``loop://``, ``socket://``) is left as it is."""
    import fcntl

    try:
        fd = port.fileno()
    except Exception:  # noqa: BLE001 - URL ports without a usable descriptor
        return
    if not isinstance(fd, int) or fd < 0:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno in _BUSY:
            raise _in_use(name, url) from exc
        raise ConnectError(f"{name}: cannot lock serial port {url!r}: {exc}", where=url, reason=str(exc)) from exc


def port_name(port: Any) -> str:
    """How messages name a port object."""
    for attr in ("portstr", "port", "name"):
        v = getattr(port, attr, None)
        if isinstance(v, str) and v:
            return v
    return repr(port)


class SerialEndpoint(Endpoint):
    """A serial endpoint (host driver or emulator): ``self.port``, closed on close when
    ``self._owns_port``."""

    port: Any
    _owns_port: bool

    def _release(self) -> None:
        if self._owns_port and self.port is not None:
            self.port.close()


def is_port_error(exc: BaseException) -> bool:
    """True for what a failing port raises (an OS error, a closed port, pyserial's SerialException)."""
    return isinstance(exc, (OSError, ValueError)) or type(exc).__name__.endswith("SerialException")


class SerialHost(SerialEndpoint):
    """The port handling every serial host driver shares: a port the driver opened from a URL is
    reopened on the next call after it failed; an open port handed in is never reopened.

    A host sets ``name``, ``baudrate``, ``poll_s``, ``_url``, ``_decoder`` (with ``reset()``),
    ``counters`` (with ``reconnects``), ``online``, ``_closed`` and ``_broken``.
    """

    #: The reopened port's ``write_timeout`` (s).
    write_timeout_s: float = 2.0
    name: str
    baudrate: int
    poll_s: float
    online: bool
    counters: dict[str, int]
    _url: str | None
    _decoder: Any
    _broken: bool
    _last_rx: float | None

    def _check_open(self) -> None:
        if self._closed:
            raise DriverError(f"{self.name}: closed; create a new one.")
        if self._broken:
            self._reopen()

    def _reopen(self) -> None:
        if self._url is None or not self._owns_port:
            raise DriverError(f"{self.name}: the port {port_name(self.port)} failed and was not opened by the "
                              "driver, so it cannot be reopened; open it again and create a new driver.")
        try:
            self.port.close()
        except Exception:  # noqa: BLE001 - the port is already broken
            pass
        self.port, _ = open_port(self._url, baudrate=self.baudrate, timeout=self.poll_s, name=self.name,
                                 write_timeout=self.write_timeout_s)
        self._broken = False
        self._decoder.reset()
        self.counters["reconnects"] += 1

    def _read_port(self, block: bool, limit: int | None = None) -> bytes:
        """What the port holds now, at most ``limit`` bytes (None: all of it); with ``block``, wait up to one
        poll slice (the port's timeout) for the first byte. A port failure marks the port for reopening."""
        port = self.port
        try:
            n = port.in_waiting
            if n:
                return port.read(n if limit is None or n < limit else limit)  # min(n, limit), without its call
            if not block:
                return b""
            data = port.read(1)
            if data:
                more = port.in_waiting
                if more:
                    data += port.read(more if limit is None else min(more, limit))
            return data
        except Exception as exc:
            if is_port_error(exc):
                raise self._port_failed("read from", exc) from exc
            raise

    def _timed_out(self, what: str, timeout_s: float, unit: str, hint: str,
                   awaited: str | None = None) -> DeviceTimeoutError:
        """The device went quiet: counted, marked offline, and a sentence naming ``what`` was awaited, the port,
        when the last good ``unit`` came and the device's ``hint``."""
        self.counters["timeouts"] += 1
        self.online = False
        last = ("nothing has been received yet" if self._last_rx is None
                else f"the last good {unit} came {time.monotonic() - self._last_rx:.3g} s ago")
        return DeviceTimeoutError(f"{self.name}: no {what} within {timeout_s:g} s on {port_name(self.port)}; {last}. "
                                  f"{hint}", device=self.name, awaited=what if awaited is None else awaited,
                                  timeout_s=timeout_s)

    def _port_failed(self, what: str, exc: BaseException) -> DriverError:
        self._broken = True
        self.online = False
        return ConnectError(f"{self.name}: cannot {what} {port_name(self.port)}: {exc}; the port will be reopened on "
                            "the next call.", where=port_name(self.port), reason=str(exc))


class SerialServer(SerialEndpoint):
    """The wall-clock serving loop every serial device emulator shares (``stand emulate``): the device
    fills :meth:`service`, :meth:`next_due_s` and, when it queues output, :meth:`_wants_write`."""

    def service(self, t_s: float) -> None:  # pragma: no cover - every device overrides it
        raise NotImplementedError

    def next_due_s(self) -> float | None:
        """Sim time of the next frame the device will publish unasked, or None."""
        return None

    def _wants_write(self) -> bool:
        """True while output waits for room on the line (the loop then also wakes when it can write)."""
        return False

    def run(self, duration_s: float | None = None, *, stop: Callable[[], bool] | None = None,
            clock: Callable[[], float] = time.monotonic, max_wait_s: float = 0.02) -> None:
        """Serve in wall-clock time (sim time = seconds since the call) until ``duration_s`` has passed
        or ``stop()`` returns true. Wakes on incoming bytes when the port has a file descriptor."""
        fileno = getattr(self.port, "fileno", None)
        try:
            fd = fileno() if fileno is not None else None
        except Exception:  # loop:// and socket:// objects without a usable descriptor
            fd = None
        t0 = clock()
        while True:
            t = clock() - t0
            if duration_s is not None and t >= duration_s:
                break
            if stop is not None and stop():
                break
            self.service(t)
            wait = max_wait_s
            due = self.next_due_s()
            now = clock() - t0
            if due is not None:
                wait = min(wait, max(due - now, 0.0))
            if duration_s is not None:
                wait = min(wait, max(duration_s - now, 0.0))
            if fd is not None:
                select.select([fd], [fd] if self._wants_write() else [], [], wait)
            elif wait > 0:
                time.sleep(min(wait, 0.001))
