"""The hardware-link fault proxy: a process between a host driver and a real device's port (serial) or bus (CAN)
that forwards every frame both ways through :class:`drivers.link_faults.LinkFaults`, in wall time.

Serial (:class:`SerialFaultProxy`): two ports, the host's side (e.g. one end of a socat pty pair whose other end the
host driver opens) and the device's side (the device's adapter, or a pty an emulator serves). Bytes read from each
are cut into frames (``framing``: ``"slip"``, a datagram codec, or None for each chunk read), each frame goes through
the faults of its direction and is written to the other side without ever waiting for the line: what a side cannot
take at once waits in a bounded queue (``max_queue_bytes``); beyond it, frames are dropped whole and counted
(``overflow_frames``).

CAN (:class:`CanFaultProxy`): two python-can buses, the host's channel and the device's. On a bus that hands its
own frames back (``udp_multicast``), the frames the proxy sent itself are recognised when they come back and not
forwarded again.

Both have ``faults`` (the engine: ``start``/``stop``/``counters``/``in_flight``), :meth:`step` (one bounded pass)
and :meth:`run` (until ``duration_s`` or ``stop()``), and :meth:`report` (a dict for JSON: the link's counters and
what was forwarded each way). Times given to the faults are seconds since the proxy started.
"""

from __future__ import annotations

import select
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

import numpy as np

from drivers.link_faults import TO_DEVICE, TO_HOST, LinkFaults, splitter_for
from drivers.serial_port import open_port, port_name, write_available

__all__ = ["CanFaultProxy", "SerialFaultProxy", "check_faults"]

#: Frames one step forwards from one side at most (a flooding side cannot hold the loop).
MAX_FRAMES_PER_STEP = 4096


def check_faults(faults: list[dict], kinds: tuple[str, ...]) -> list[tuple[str, dict, float, float | None]]:
    """Each fault table (``{"type": kind, "at_s": ..., "duration_s": ..., **params}``) as ``(kind, params, at_s,
    end_s)``, checked on a scratch link before anything is opened. ValueError naming the fault, the field, the value
    and what is allowed."""
    out = []
    scratch = LinkFaults("can" if "error_frame" in kinds else "serial")
    for i, table in enumerate(faults):
        params = dict(table)
        kind = params.pop("type", None)
        params.pop("name", None)
        when = {}
        for key in ("at_s", "duration_s"):
            v = params.pop(key, None)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v < 1e9):
                raise ValueError(f"fault {i + 1} ({kind}): {key} = {v!r} is not allowed; allowed: seconds >= 0 since "
                                 "the proxy started.")
            when[key] = v
        try:
            scratch.start(kind, params, np.random.default_rng(0), 0.0)
        except ValueError as exc:
            raise ValueError(f"fault {i + 1} ({kind}): {exc}") from None
        at_s = float(when["at_s"] or 0.0)
        out.append((kind, params, at_s, None if when["duration_s"] is None else at_s + float(when["duration_s"])))
    return out


class _Proxy:
    faults: LinkFaults
    forwarded: dict[str, int]
    t0: float | None = None
    _plan: list

    def schedule(self, faults: list[dict], seed: int = 0) -> None:
        """Faults to start and stop by themselves (wall seconds since the proxy started: ``at_s``, default 0, and
        ``duration_s``, default until the end); fault ``i`` draws from ``numpy.random.default_rng([seed, i])``."""
        kinds = ("error_frame",) if isinstance(self, CanFaultProxy) else ()
        self._plan = [[kind, params, at_s, end_s, np.random.default_rng([seed, i]), None]
                      for i, (kind, params, at_s, end_s) in enumerate(check_faults(faults, kinds))]

    def due(self, t_s: float) -> None:
        """Start and stop the scheduled faults due at ``t_s`` (:meth:`run` calls it before each step)."""
        for entry in getattr(self, "_plan", ()):
            kind, params, at_s, end_s, rng, handle = entry
            if handle is None and t_s >= at_s and (end_s is None or t_s < end_s):
                entry[5] = self.faults.start(kind, params, rng, t_s)
            elif handle and end_s is not None and t_s >= end_s:
                self.faults.stop(handle)
                entry[5] = 0  # over (handles start at 1)

    def run(self, duration_s: float | None = None, *, stop: Callable[[], bool] | None = None,
            clock: Callable[[], float] = time.monotonic, slice_s: float = 0.005) -> None:
        """Forward in wall time until ``duration_s`` has passed or ``stop()`` is true (checked every slice)."""
        if self.t0 is None:
            self.t0 = clock()
        while True:
            t = clock() - self.t0
            if (duration_s is not None and t >= duration_s) or (stop is not None and stop()):
                break
            self.due(t)
            self.step(t, slice_s)

    def step(self, t_s: float, wait_s: float) -> int:  # pragma: no cover - each proxy fills it
        raise NotImplementedError

    def report(self) -> dict[str, Any]:
        return {"counters": dict(self.faults.counters), "forwarded": dict(self.forwarded),
                "in_flight": self.faults.in_flight}


class SerialFaultProxy(_Proxy):
    """A serial line cut in two, with faults in between (module docstring).

    Args:
        host_port, device_port: URLs/paths (opened here, closed by :meth:`close`) or open port objects.
        framing: None (each chunk read is a frame), ``"slip"``, or a datagram codec (:mod:`drivers.datagram`).
        baudrate: for device paths.
    """

    def __init__(self, host_port: Any, device_port: Any, *, framing: Any = None, baudrate: int = 115200,
                 max_queue_bytes: int = 65536) -> None:
        self.faults = LinkFaults("serial", slip=framing == "slip")
        self._ports: dict[str, Any] = {}
        self._owned: list[Any] = []
        for side, port in (("host", host_port), ("device", device_port)):
            opened, owned = open_port(port, baudrate=baudrate, timeout=0.0, name=f"fault proxy {side} side")
            self._ports[side] = opened
            if owned:
                self._owned.append(opened)
        # Frames read on the device's side go to the host, and the other way round.
        self._split = {"device": splitter_for(framing, TO_HOST), "host": splitter_for(framing, TO_DEVICE)}
        self._queue: dict[str, deque[bytes]] = {"host": deque(), "device": deque()}  # waiting to be written there
        self._queued = {"host": 0, "device": 0}
        self.max_queue_bytes = int(max_queue_bytes)
        self.forwarded = {"frames_from_device": 0, "frames_from_host": 0, "bytes_from_device": 0, "bytes_from_host": 0,
                          "frames_to_host": 0, "frames_to_device": 0, "overflow_frames": 0}

    def close(self) -> None:
        for port in self._owned:
            port.close()
        self._owned = []

    def __enter__(self) -> SerialFaultProxy:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _fds(self) -> list[int]:
        out = []
        for port in self._ports.values():
            try:
                out.append(port.fileno())
            except Exception:  # noqa: BLE001 - a port without a descriptor (loop://) is polled
                pass
        return out

    def step(self, t_s: float, wait_s: float) -> int:
        """Wait up to ``wait_s`` for bytes, forward what came, release what is due at ``t_s``; returns frames
        read."""
        fds = self._fds()
        # While frames wait (a queue, a delay, babble) the loop comes back within a millisecond.
        timeout_s = min(wait_s, 0.001) if any(self._queue.values()) or self.faults.busy else wait_s
        if len(fds) == len(self._ports):
            select.select(fds, [], [], timeout_s)
        elif timeout_s > 0:
            time.sleep(min(timeout_s, 0.001))
        self.faults.now_s = max(self.faults.now_s, t_s)
        n = self._read("device", TO_HOST, "host") + self._read("host", TO_DEVICE, "device")
        for direction, frame in self.faults.advance(t_s):
            self._enqueue("host" if direction == TO_HOST else "device", frame)
        self._flush("host")
        self._flush("device")
        return n

    def _read(self, side: str, direction: str, to: str) -> int:
        port = self._ports[side]
        n = 0
        for _ in range(MAX_FRAMES_PER_STEP):
            waiting = port.in_waiting
            data = port.read(min(waiting, 65536)) if waiting else b""
            if not data:
                break
            self.forwarded[f"bytes_from_{side}"] += len(data)
            for frame in self._split[side].feed(data):
                n += 1
                self.forwarded[f"frames_from_{side}"] += 1
                for out in self.faults.process(frame, direction):
                    self._enqueue(to, out)
        return n

    def _enqueue(self, side: str, frame: bytes) -> None:
        if self._queued[side] + len(frame) > self.max_queue_bytes:
            self.forwarded["overflow_frames"] += 1
            return
        self._queue[side].append(frame)
        self._queued[side] += len(frame)
        self.forwarded[f"frames_to_{side}"] += 1

    def _flush(self, side: str) -> None:
        queue, port = self._queue[side], self._ports[side]
        while queue:
            head = queue[0]
            n = write_available(port, head)
            self._queued[side] -= n
            if n < len(head):
                queue[0] = head[n:]
                return
            queue.popleft()

    def __repr__(self) -> str:
        return f"SerialFaultProxy(host={port_name(self._ports['host'])!r}, device={port_name(self._ports['device'])!r})"


class CanFaultProxy(_Proxy):
    """Two CAN buses joined through faults (module docstring). ``host_bus`` and ``device_bus`` are open python-can
    buses (shut down by :meth:`close`)."""

    def __init__(self, host_bus: Any, device_bus: Any) -> None:
        from drivers.can_bus import loops_back

        self.faults = LinkFaults("can")
        self._buses = {"host": host_bus, "device": device_bus}
        # Frames this proxy sent on a bus that hands them back, still to come back: (id, data, error frame) -> count.
        self._echoes: dict[str, Counter | None] = {side: Counter() if loops_back(bus) else None
                                                    for side, bus in self._buses.items()}
        self.forwarded = {"frames_from_device": 0, "frames_from_host": 0, "frames_to_host": 0, "frames_to_device": 0,
                          "echoes_skipped": 0, "send_errors": 0}

    def close(self) -> None:
        for bus in self._buses.values():
            bus.shutdown()

    def __enter__(self) -> CanFaultProxy:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @staticmethod
    def _key(msg: Any) -> tuple:
        return (msg.arbitration_id, bytes(msg.data), bool(msg.is_error_frame))

    def step(self, t_s: float, wait_s: float) -> int:
        """Forward every frame waiting on either bus, release what is due at ``t_s``; waits up to ``wait_s`` (on the
        device's bus) when nothing came. Returns frames read."""
        self.faults.now_s = max(self.faults.now_s, t_s)
        n = self._read("device", TO_HOST, "host", 0.0) + self._read("host", TO_DEVICE, "device", 0.0)
        for direction, frame in self.faults.advance(t_s):
            self._send("host" if direction == TO_HOST else "device", frame)
        if n == 0 and wait_s > 0:
            n = self._read("device", TO_HOST, "host", min(wait_s, 0.002))
        return n

    def _read(self, side: str, direction: str, to: str, timeout: float) -> int:
        bus, echoes = self._buses[side], self._echoes[side]
        n = 0
        for _ in range(MAX_FRAMES_PER_STEP):
            msg = bus.recv(timeout)
            timeout = 0.0
            if msg is None:
                break
            if echoes is not None and echoes[self._key(msg)] > 0:
                echoes[self._key(msg)] -= 1
                self.forwarded["echoes_skipped"] += 1
                continue
            n += 1
            self.forwarded[f"frames_from_{side}"] += 1
            for out in self.faults.process(msg, direction):
                self._send(to, out)
        return n

    def _send(self, side: str, msg: Any) -> None:
        import can

        try:
            self._buses[side].send(msg)
        except can.CanError:
            self.forwarded["send_errors"] += 1
            return
        self.forwarded[f"frames_to_{side}"] += 1
        echoes = self._echoes[side]
        if echoes is not None:
            echoes[self._key(msg)] += 1
