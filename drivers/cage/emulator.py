"""Emulator: the stand *being* the Helmholtz cage controller, a pymodbus server (Modbus TCP on
127.0.0.1, or Modbus RTU on a serial port) in front of :class:`~drivers.cage.model.CageModel`.

The server is pymodbus's own (``ModbusTcpServer`` / ``ModbusSerialServer`` on a ``SimDevice``), run
on an asyncio loop in a thread of its own. Every request goes through one ``action`` hook that asks
the model: reads are answered from the model's state at that instant, writes are checked against
the register map and applied atomically (or refused with a Modbus exception and not applied at all).
Requests for other unit ids get no answer (a shared RS-485 line).

Two ways time passes:

- ``clock`` given (default ``time.monotonic``): the cage runs in wall time. Before every request,
  and every ``tick_s`` on the server loop, the model is advanced to ``clock() - start``.
- ``clock=None``: sim time. Only :meth:`CageEmulator.step` moves the model (the stand calls it once
  per tick); requests see the cage as of the last step.

Only the functions the register map lists reach the model (3, 4, 6, 16); every other one is answered
with exception 1 and applies nothing. Over TCP at most ``max_connections`` clients are served (a further
one is closed at once) and, with ``max_request_rate_hz``, each connection is held to that rate by no
longer reading its socket; repeated log lines are rate-limited (see ``docs/cage.md``).

``counters``: ``received`` and ``sent`` (Modbus frames), ``rejected`` (requests answered with an
exception), ``ignored_other_id`` (requests for another unit id, not answered), ``connections`` and
``connections_refused`` (TCP clients served, and closed for being one too many), ``throttled`` (times a
connection was paused for exceeding its request rate).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException
from pymodbus.framer.rtu import FramerRTU
from pymodbus.pdu import DecodePDU, ExceptionResponse, ModbusPDU
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.simulator import DataType, SimData, SimDevice

from drivers.cage.model import EXC_ILLEGAL_FUNCTION, CageConfig, CageModel, LabField
from drivers.cage.registers import RegisterMap
from drivers.endpoint import Endpoint
from drivers.errors import ConnectError, DriverError

__all__ = ["CageEmulator"]

log = logging.getLogger(__name__)

_READ = {3: "holding", 4: "input"}
#: A Modbus TCP server on a bench serves a host or two: more connections than this are closed at once.
MAX_CONNECTIONS = 8
#: Requests per second one TCP connection may send (and how many it may send at once) where the emulator serves
#: outside clients (``stand emulate cage``; the stand's own in-process link is not limited): beyond it the
#: emulator stops reading that socket until it may again, so one flooding client cannot starve another.
MAX_REQUEST_RATE_HZ = 1000.0
REQUEST_BURST = 100
_SHORTEST_REQUEST_BYTES = 12
#: A repeated log line (refused connections, a flood, asyncio errors) is written at most this often.
LOG_EVERY_S = 10.0
_WRITE = (6, 16)
_START_TIMEOUT_S = 5.0
_STOP_TIMEOUT_S = 5.0


class _Refuse(ModbusPDU):
    """A request of a function the map does not list: decoded only to be answered with exception 1."""

    def __init__(self, function_code: int, emulator: CageEmulator, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.function_code = function_code
        self._emulator = emulator

    async def datastore_update(self, context: Any, device_id: int) -> ModbusPDU:
        return self._emulator._refuse(self.function_code, device_id)


class _MapDecoder(DecodePDU):
    """pymodbus's request decoder, but only the functions of the register map reach the cage.

    Every other function (pymodbus also serves 1, 2, 5, 7, 8, 11, 12, 15, 17, 20-24 and 43 on its own) is
    refused with exception 1 and applies nothing. Over RTU a function pymodbus does not know is still
    framed when the whole buffer is one frame with a good CRC, so it too gets its exception 1.
    """

    def __init__(self, emulator: CageEmulator, functions: tuple[int, ...]) -> None:
        super().__init__(True)
        self._emulator = emulator
        self._functions = frozenset(functions)

    def lookupPduClass(self, data: bytes) -> type[ModbusPDU] | None:  # noqa: N802 - pymodbus's name
        known = super().lookupPduClass(data)
        if known is not None or len(data) < 4 or data[1] & 0x80:
            return known
        if not FramerRTU.check_CRC(data[:-2], int.from_bytes(data[-2:], "big")):
            return None  # not a whole frame: let pymodbus hunt on
        size = len(data)

        class _Whole(ModbusPDU):
            @classmethod
            def calculateRtuFrameSize(cls, _data: bytes) -> int:  # noqa: N802 - pymodbus's name
                return size

        return _Whole

    def decode(self, frame: bytes) -> ModbusPDU | None:
        fc = int(frame[0]) if frame else 0
        if fc in self._functions:
            return super().decode(frame)
        return _Refuse(fc, self._emulator) if fc < 0x80 else None


class _RateLimitedLog(logging.Filter):
    """Lets one record per message pattern through every ``LOG_EVERY_S``: pymodbus logs each frame it
    cannot decode, which a flood would turn into megabytes a second of output."""

    def __init__(self) -> None:
        super().__init__()
        self._last: dict[str, float] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        now = time.monotonic()
        key = str(record.msg)
        if now - self._last.get(key, -LOG_EVERY_S) < LOG_EVERY_S:
            return False
        self._last[key] = now
        return True


_PYMODBUS_FILTER = _RateLimitedLog()


class _GuardedHandler(ServerRequestHandler):
    """pymodbus's per-connection handler, with the emulator's connection limit and request rate."""

    def __init__(self, server: Any, emulator: CageEmulator) -> None:
        super().__init__(server, server.trace_packet, server.trace_pdu, server.trace_connect)
        self._emu = emulator
        self._admitted = False
        self._tokens = float(emulator.request_burst)
        self._t_tokens = time.monotonic()
        self._resume_at: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        super().connection_made(transport)
        self._admitted = self._emu._admit(transport.get_extra_info("peername"))
        if not self._admitted:
            transport.abort()  # frees the descriptor now: the emulator never runs out of them

    def connection_lost(self, exc: Exception | None) -> None:
        if self._admitted:
            self._admitted = False
            self._emu._connections -= 1
        if self._resume_at is not None:
            self._resume_at.cancel()
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if not self._admitted:
            return
        rate = self._emu.max_request_rate_hz
        if rate is None:  # the stand's own in-process link at full speed: no limit
            super().data_received(data)
            return
        now = time.monotonic()
        # a chunk is charged the most requests it can hold (the shortest request, a read, is 12 bytes on TCP):
        # pipelined frames arrive many to a read
        charge = max(1, len(data) // _SHORTEST_REQUEST_BYTES)
        self._tokens = min(float(self._emu.request_burst), self._tokens + (now - self._t_tokens) * rate) - charge
        self._t_tokens = now
        if self._tokens < 0.0 and self._resume_at is None:
            # over its rate: read nothing more from this client until it has a token again (TCP flow control
            # holds the rest of its burst in its own socket buffers, not in the emulator)
            self._emu._note_throttled()
            self.transport.pause_reading()  # type: ignore[attr-defined]
            self._resume_at = self.loop.call_later(-self._tokens / rate, self._resume)
        super().data_received(data)

    def _resume(self) -> None:
        self._resume_at = None
        if self._admitted and self.transport is not None and not self.transport.is_closing():
            self.transport.resume_reading()  # type: ignore[attr-defined]


def _blocks() -> tuple[list[SimData], list[SimData], list[SimData], list[SimData]]:
    # The whole address space exists for pymodbus, so every request reaches the action hook, which
    # answers from the register map (and counts what it refuses).
    bits = [SimData(0, values=[False] * 65536, datatype=DataType.BITS)]
    regs = [SimData(0, count=65536, values=0, datatype=DataType.REGISTERS)]
    return bits, list(bits), regs, list(regs)


class CageEmulator(Endpoint):
    """The cage behind a Modbus server.

    Args:
        config: the bench (:class:`~drivers.cage.model.CageConfig`; default the nominal cage).
        rng: seed or Generator of the magnetometer noise.
        clock: a monotonic clock in seconds for wall-time running, or None for sim time (:meth:`step`).
        lab_field: optional ``lab_field(t_s) -> 3 floats`` (T, cage axes), a moving lab field.
        regmap: the register map (default: the ICD).
        tick_s: in wall time, how often the server loop advances the model with no request coming.
        name: how errors name this device.
    """

    def __init__(self, config: CageConfig | None = None, *, rng: int | np.random.Generator | None = 0,
                 clock: Callable[[], float] | None = time.monotonic, lab_field: LabField | None = None,
                 regmap: RegisterMap | None = None, tick_s: float = 0.01, name: str = "cage emulator",
                 max_connections: int = MAX_CONNECTIONS, max_request_rate_hz: float | None = None,
                 request_burst: int = REQUEST_BURST) -> None:
        if not (isinstance(max_connections, int) and max_connections >= 1):
            raise ValueError(f"max_connections = {max_connections!r} is not allowed; give a whole number >= 1.")
        if max_request_rate_hz is not None and not (isinstance(max_request_rate_hz, int | float)
                                                    and 0 < max_request_rate_hz < float("inf")):
            raise ValueError(f"max_request_rate_hz = {max_request_rate_hz!r} is not allowed; give a positive rate "
                             "in requests per second.")
        if not (isinstance(request_burst, int) and request_burst >= 1):
            raise ValueError(f"request_burst = {request_burst!r} is not allowed; give a whole number >= 1.")
        self.model = CageModel(config, rng=rng, lab_field=lab_field, regmap=regmap)
        self.config = self.model.config
        self.name = name
        self._clock = clock
        self._t0 = clock() if clock is not None else 0.0
        self._tick_s = float(tick_s)
        self._lock = threading.Lock()
        self.max_connections = max_connections
        self.max_request_rate_hz = None if max_request_rate_hz is None else float(max_request_rate_hz)
        self.request_burst = request_burst
        self._connections = 0
        self._log_last: dict[str, float] = {}
        self._log_suppressed: dict[str, int] = {}
        self.counters: dict[str, int] = {"received": 0, "sent": 0, "rejected": 0, "ignored_other_id": 0,
                                         "connections": 0, "connections_refused": 0, "throttled": 0}
        self.where: str | None = None
        self.address: tuple[str, int] | None = None
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_event: asyncio.Event | None = None
        self._closed = False

    def __repr__(self) -> str:
        state = "closed" if self._closed else (f"serving {self.where}" if self.where else "not serving")
        return f"CageEmulator({state}, t={self.model.t_s:g} s, counters={self.counters})"

    # -- time ------------------------------------------------------------------------------------

    @property
    def t_s(self) -> float:
        """The cage's time, s since power-up."""
        return self.model.t_s

    def step(self, t_s: float) -> None:
        """Advance the cage to sim time ``t_s`` (s since power-up); only for ``clock=None``."""
        if self._clock is not None:
            raise DriverError(f"{self.name}: step() drives a cage in sim time, but this one runs on its own clock; "
                              "build it with clock=None to step it.")
        with self._lock:
            self.model.advance(t_s)

    def _sync(self) -> None:
        if self._clock is not None:
            self.model.advance(self._clock() - self._t0)

    def cage_field_T(self) -> np.ndarray:
        """The noiseless field at the test position now (T, cage axes): what a magnetometer there sees."""
        with self._lock:
            self._sync()
            return self.model.cage_field_T()

    def currents_A(self) -> tuple[float, float, float]:
        """Coil currents now, signed (A)."""
        with self._lock:
            self._sync()
            return self.model.currents_A()

    # -- the Modbus side -------------------------------------------------------------------------

    async def _action(self, function_code: int, start_address: int, address: int, count: int,
                      registers: list[int], set_values: Sequence[int] | Sequence[bool] | None) -> ExcCodes | None:
        with self._lock:
            self._sync()
            if function_code in _READ:
                words = self.model.read(_READ[function_code], address, count)
                if isinstance(words, list):
                    registers[address - start_address : address - start_address + count] = words
                    return None
                code = words
            elif function_code in _WRITE and set_values is not None:
                code = self.model.write(address, [int(v) for v in set_values])
            elif function_code == 6:
                # pymodbus reads a function-6 write back to build its echo: the block holds the value just
                # written (what the standard's echo carries), so answer from it.
                return None
            else:
                code = EXC_ILLEGAL_FUNCTION
        if code:
            self.counters["rejected"] += 1
            return ExcCodes(code)
        return None

    def _refuse(self, function_code: int, device_id: int) -> ModbusPDU:
        if device_id != self.config.device_id:
            self.counters["ignored_other_id"] += 1
            raise NoSuchIdException("not this cage")  # with ignore_missing_devices: no answer at all
        self.counters["rejected"] += 1
        return ExceptionResponse(function_code, ExcCodes.ILLEGAL_FUNCTION)

    async def _other_id(self, *_args: Any) -> None:
        self.counters["ignored_other_id"] += 1
        raise NoSuchIdException("not this cage")  # with ignore_missing_devices: no answer at all

    # -- limits: connections, request rate, logging ----------------------------------------------

    def _admit(self, peer: Any) -> bool:
        if self._connections >= self.max_connections:
            self.counters["connections_refused"] += 1
            self._log("refused", f"{self.name}: refused a connection from {peer} on {self.where}: "
                      f"{self.max_connections} connections are open, the most it serves")
            return False
        self._connections += 1
        self.counters["connections"] += 1
        return True

    def _note_throttled(self) -> None:
        self.counters["throttled"] += 1
        self._log("throttled", f"{self.name}: a client on {self.where} sends more than "
                  f"{self.max_request_rate_hz:g} requests/s; its requests wait")

    def _log(self, key: str, message: str) -> None:
        """One line, at most every LOG_EVERY_S per kind; the next one says how many were left out."""
        now = time.monotonic()
        if now - self._log_last.get(key, -LOG_EVERY_S) < LOG_EVERY_S:
            self._log_suppressed[key] = self._log_suppressed.get(key, 0) + 1
            return
        more = self._log_suppressed.pop(key, 0)
        self._log_last[key] = now
        log.warning(message + (f" ({more} more like it since the last such line)" if more else ""))

    def _loop_exception(self, loop: asyncio.AbstractEventLoop, context: dict) -> None:
        # asyncio's default handler prints a traceback per failed accept(): one line now and then instead
        exc = context.get("exception")
        self._log(f"loop:{context.get('message')}", f"{self.name}: {context.get('message', 'error')}"
                  + (f": {exc}" if exc is not None else ""))

    def _trace(self, sending: bool, data: bytes) -> bytes:
        self.counters["sent" if sending else "received"] += 1
        return data

    def _devices(self) -> list[SimDevice]:
        return [SimDevice(id=self.config.device_id, simdata=_blocks(), action=self._action),
                SimDevice(id=0, simdata=_blocks(), action=self._other_id)]

    def _restrict(self, server: Any, tcp: bool = False) -> Any:
        server.decoder = _MapDecoder(self, self.model.map.function_codes)  # before listen: handlers copy it
        if tcp:
            server.callback_new_connection = lambda: _GuardedHandler(server, self)
        return server

    def serve_tcp(self, host: str = "127.0.0.1", port: int = 0) -> tuple[str, int]:
        """Serve Modbus TCP on ``host:port`` (port 0: a free one); returns the address bound."""
        devices = self._devices()

        def make():
            return self._restrict(ModbusTcpServer(devices, address=(host, port), ignore_missing_devices=True,
                                                  trace_packet=self._trace), tcp=True)

        server = self._start(make, f"tcp://{host}:{port}")
        sock = server.transport.sockets[0].getsockname()
        self.address = (sock[0], sock[1])
        self.where = f"tcp://{sock[0]}:{sock[1]}"
        return self.address

    def serve_rtu(self, port: str, *, baudrate: int = 115200, parity: str = "N", stopbits: int = 1) -> None:
        """Serve Modbus RTU on the serial ``port`` (a device path, a pty, or any pyserial URL)."""
        devices = self._devices()

        def make():
            return self._restrict(ModbusSerialServer(
                devices, port=port, baudrate=baudrate, parity=parity, stopbits=stopbits, ignore_missing_devices=True,
                trace_packet=self._trace, reconnect_delay=0.5))

        self._start(make, port)
        self.where = f"rtu:{port}@{baudrate}"

    def _start(self, make: Callable[[], Any], where: str) -> Any:
        if self._closed:
            raise DriverError(f"{self.name}: closed; create a new one.")
        if self._thread is not None:
            raise DriverError(f"{self.name}: already serving {self.where}; one emulator serves one port.")
        ready = threading.Event()
        box: dict[str, Any] = {}
        self._thread = threading.Thread(target=self._thread_main, args=(make, ready, box), daemon=True,
                                        name=f"cage-emulator {where}")
        self._thread.start()
        if not ready.wait(_START_TIMEOUT_S):
            self._release()
            raise ConnectError(f"{self.name}: the Modbus server on {where} did not start within "
                               f"{_START_TIMEOUT_S:g} s.", where=where, reason="timeout")
        if "error" in box:
            self._thread.join(_STOP_TIMEOUT_S)
            self._thread = None
            exc = box["error"]
            raise ConnectError(f"{self.name}: cannot serve Modbus on {where}: {exc}", where=where,
                               reason=str(exc)) from exc
        return box["server"]

    def _thread_main(self, make, ready: threading.Event, box: dict) -> None:
        asyncio.run(self._main(make, ready, box))

    async def _main(self, make, ready: threading.Event, box: dict) -> None:
        self._loop = asyncio.get_running_loop()
        self._loop.set_exception_handler(self._loop_exception)
        logging.getLogger("pymodbus.logging").addFilter(_PYMODBUS_FILTER)  # once: the same filter object
        self._stop_event = asyncio.Event()
        try:
            server = make()
            await server.serve_forever(background=True)
        except Exception as exc:  # noqa: BLE001 - reported to the caller of serve_*
            box["error"] = exc if str(exc) else RuntimeError("the port could not be opened")
            ready.set()
            return
        box["server"] = server
        ready.set()
        ticker = asyncio.create_task(self._tick()) if self._clock is not None else None
        try:
            await self._stop_event.wait()
        finally:
            if ticker is not None:
                ticker.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await ticker
            await server.shutdown()

    async def _tick(self) -> None:
        while True:
            await asyncio.sleep(self._tick_s)
            with self._lock:
                self._sync()

    # -- running alone ---------------------------------------------------------------------------

    def run(self, duration_s: float | None = None, stop: Callable[[], bool] | None = None) -> None:
        """Block while serving, until ``duration_s`` (wall seconds) passed or ``stop()`` is true."""
        if self._thread is None:
            raise DriverError(f"{self.name}: not serving; call serve_tcp() or serve_rtu() first.")
        end = None if duration_s is None else time.monotonic() + duration_s
        while (end is None or time.monotonic() < end) and not (stop is not None and stop()):
            if not self._thread.is_alive():
                raise DriverError(f"{self.name}: the Modbus server on {self.where} stopped.")
            time.sleep(0.05 if end is None else max(0.0, min(0.05, end - time.monotonic())))

    def _release(self) -> None:
        loop, ev, thread = self._loop, self._stop_event, self._thread
        if loop is not None and ev is not None:
            with contextlib.suppress(RuntimeError):  # the loop has already ended
                loop.call_soon_threadsafe(ev.set)
        if thread is not None:
            thread.join(_STOP_TIMEOUT_S)
        self._thread = None
