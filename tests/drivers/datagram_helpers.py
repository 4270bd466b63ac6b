"""Shared helpers of the datagram-device tests (gyro, sun sensor): Hypothesis strategies for
payloads and messages on the wire grid, and a host + emulator pair on an in-process pty pair where
the test services the emulator itself (sim time, no thread) or a thread serves it in wall-clock time."""

from __future__ import annotations

import array
import fcntl
import os
import select
import struct
import termios
import threading
import time
from typing import Any

from hypothesis import strategies as st

from drivers.datagram import DatagramCodec, MessageSpec, crc16
from drivers.serial_port import pty_pair


def _wire_strategy(f) -> st.SearchStrategy:
    if f.bits is not None:
        return st.integers(0, (1 << len(f.bits)) - 1)
    if f.enum is not None:
        return st.integers(0, len(f.enum) - 1)
    if f.is_float:
        return st.floats(width=32, allow_nan=False, allow_infinity=False)
    return st.integers(int(f.lo), int(f.hi))


def datagram_strategy(codec: DatagramCodec, spec: MessageSpec) -> st.SearchStrategy[bytes]:
    """Whole datagrams of ``spec`` with every field anywhere in its range, and a good CRC."""
    prefix = ">" if codec.byte_order == "big" else "<"

    def build(values: tuple) -> bytes:
        packed = b""
        for f, v in zip(spec.fields, values, strict=True):
            if f.type == "i24":
                packed += v.to_bytes(3, codec.byte_order, signed=True)
            else:
                packed += struct.pack(prefix + _code(f.type), v)
        head = bytes((spec.id,)) + packed
        return head + crc16(head).to_bytes(2, codec.byte_order)

    return st.tuples(*[_wire_strategy(f) for f in spec.fields]).map(build)


def _code(t: str) -> str:
    return {"u8": "B", "i8": "b", "u16": "H", "i16": "h", "u32": "I", "i32": "i", "u64": "Q", "f32": "f"}[t]


class PtyLink:
    """Emulator on the master side of an os.openpty() pair, host on the slave path through pyserial.

    ``step(t)`` services the emulator at sim time ``t`` in the test's own thread; ``serve()`` starts
    a thread running ``emu.run`` in wall-clock time instead. Close it to stop everything.
    """

    def __init__(self, make_emulator, make_host) -> None:
        self.master, self.slave_path, self._slave_fd = pty_pair()
        self.emu = make_emulator(self.master)
        self.host = make_host(self.slave_path)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._written = self._consumed = 0
        self._count_writes()
        self.error: BaseException | None = None

    def serve(self, duration_s: float = 20.0) -> None:
        def run() -> None:
            try:
                self.emu.run(duration_s, stop=self._stop.is_set, max_wait_s=0.01)
            except BaseException as exc:  # reported by close()
                self.error = exc

        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()

    def _count_writes(self) -> None:
        port = self.host.port
        write = port.write

        def counted(data: bytes) -> int:
            self._written += len(data)
            return write(data)

        port.write = counted

    def wait_input(self, timeout_s: float = 2.0) -> None:
        """Wait (bounded) until every byte the host wrote has crossed the pty: the kernel moves it
        asynchronously, so a sim-time step right after a write could miss it."""
        deadline = time.monotonic() + timeout_s
        buf = array.array("i", [0])
        while self._written > self._consumed:
            fcntl.ioctl(self.master.fd, termios.FIONREAD, buf)
            if buf[0] >= self._written - self._consumed or time.monotonic() >= deadline:
                break
            select.select([self.master.fd], [], [], 0.01)
        self._consumed = self._written

    def step(self, t: float) -> Any:
        """Service the emulator at sim time ``t`` once what the host wrote has arrived."""
        self.wait_input()
        self.emu.service(t)

    def close(self) -> None:
        self.host.close()
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
            assert not self._thread.is_alive()
        self.emu.close()
        self.master.close()
        os.close(self._slave_fd)
        if self.error is not None:
            raise self.error

    def __enter__(self) -> PtyLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def wait_samples(host: Any, n: int, timeout_s: float = 2.0) -> None:
    """Read (bounded) until the host has received ``n`` samples in all."""
    deadline = time.monotonic() + timeout_s
    while host.counters["samples"] < n and time.monotonic() < deadline:
        host.poll()
        if host.counters["samples"] < n:
            host._read(block=True)
