"""Shared helpers of the star tracker tests: an in-memory pipe pair, a settable truth source, and a
host + emulator rig on an in-process pty pair (the emulator served by a thread)."""

from __future__ import annotations

import os
import threading

from drivers.serial_port import pty_pair
from drivers.star_tracker.emulator import EmulatorConfig, StarTrackerEmulator, TrackerTruth
from drivers.star_tracker.host import StarTrackerHost

FAST = EmulatorConfig(boot_time_s=0.0, output_interval_s=0.05, output_delay_s=0.01, stable_count=2)


class Pipe:
    """One end of an in-memory byte pipe: reads what the peer wrote. Enough of the serial API."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.inbox = bytearray()
        self.peer: Pipe | None = None
        self.is_open = True
        self.timeout = 0.0
        self.written = 0

    @property
    def in_waiting(self) -> int:
        return len(self.inbox)

    def read(self, n: int = 1) -> bytes:
        out = bytes(self.inbox[:n])
        del self.inbox[:n]
        return out

    def write(self, data: bytes) -> int:
        assert self.peer is not None
        self.peer.inbox += data
        self.written += len(data)
        return len(data)

    def close(self) -> None:
        self.is_open = False


def pipe_pair() -> tuple[Pipe, Pipe]:
    a, b = Pipe("host-end"), Pipe("device-end")
    a.peer, b.peer = b, a
    return a, b


class Truth:
    """A settable measurement source: what the stand would hand the emulator."""

    def __init__(self, truth: TrackerTruth | None = None) -> None:
        self.truth = truth or TrackerTruth(q_TN=(1.0, 0.0, 0.0, 0.0), stars_in_field=12)
        self.calls: list[float] = []

    def __call__(self, t_s: float) -> TrackerTruth:
        self.calls.append(t_s)
        return self.truth


class PtyRig:
    """Emulator on the master side of an os.openpty() pair (served by a thread in wall-clock time),
    host driver on the slave path through pyserial. Close it (context manager) to stop everything."""

    def __init__(self, config: EmulatorConfig = FAST, timeout_s: float = 1.0, duration_s: float = 30.0) -> None:
        self.master, self.slave_path, self._slave_fd = pty_pair()
        self.truth = Truth()
        self.emu = StarTrackerEmulator(self.master, self.truth, config, rng=3)
        self._stop = threading.Event()
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._serve, args=(duration_s,), daemon=True)
        self._thread.start()
        self.host = StarTrackerHost(self.slave_path, timeout_s=timeout_s, name="tracker-under-test")

    def _serve(self, duration_s: float) -> None:
        try:
            self.emu.run(duration_s, stop=self._stop.is_set, max_wait_s=0.01)
        except BaseException as exc:  # reported by close()
            self.error = exc

    def close(self) -> None:
        self.host.close()
        self._stop.set()
        self._thread.join(5.0)
        self.emu.close()
        self.master.close()
        os.close(self._slave_fd)
        assert not self._thread.is_alive()
        if self.error is not None:
            raise self.error

    def __enter__(self) -> PtyRig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
