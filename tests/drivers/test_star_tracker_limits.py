"""The star tracker link cannot be hung or crashed by its peer: bad values are counted per reason,
writes have deadlines or drop whole frames, and a flood is read in bounded chunks."""

from __future__ import annotations

import os
import struct
import threading

import pytest

from drivers.errors import DeviceTimeoutError
from drivers.serial_port import FdPort, pty_pair, write_available
from drivers.star_tracker.codec import RequestTelemetry, StarTrackerCodec, crc16
from drivers.star_tracker.emulator import StarTrackerEmulator
from drivers.star_tracker.host import StarTrackerHost
from drivers.star_tracker.slip import escape

from .star_tracker_helpers import FAST, Truth, pipe_pair

CODEC = StarTrackerCodec()
ADDR = CODEC.default_address


def _solution_frame(q=(1.0, 0.0, 0.0, 0.0), sigmas=(2.0, 10.0), temperature_cC=2000, seq=1) -> bytes:
    spec = CODEC.messages["SOLUTION"]
    head = bytes((ADDR, spec.id)) + struct.pack(spec.fmt, 5, *q, *sigmas, 12, 11, 2, 1, 9, temperature_cC, seq)
    return escape(head + crc16(head).to_bytes(2, "little"))


def test_host_counts_out_of_range_solutions_and_takes_the_next_good_one():
    a, b = pipe_pair()
    with StarTrackerHost(a) as h:
        b.write(_solution_frame(q=(0.5, 0.0, 0.0, 0.0)))  # aborted a whole run before
        b.write(_solution_frame(sigmas=(-3.0, 10.0)))
        b.write(_solution_frame(temperature_cC=-30000))  # -300 degC
        b.write(_solution_frame(seq=42))
        sol = h.take_solution()
        assert sol.seq == 42 and h.counters["rejected_value"] == 3 and h.counters["frames_received"] == 1
        assert "temperature_cC = -30000" in h.last_rejected


def _hung(target, timeout_s: float) -> bool:
    """Run ``target`` in a thread; True when it is still running after ``timeout_s`` (a hang)."""
    box = {}

    def run():
        try:
            target()
        except BaseException as exc:  # reported below
            box["error"] = exc

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(timeout_s)
    if "error" in box:
        raise box["error"]
    return t.is_alive()


def test_emulator_never_blocks_on_a_line_nobody_reads():
    master, slave_path, slave_fd = pty_pair()
    os.set_blocking(slave_fd, False)
    emu = StarTrackerEmulator(master, Truth(), FAST, rng=1)
    request = CODEC.encode(RequestTelemetry(CODEC.status_id))
    burst = request * (16_000 // len(request) + 1)  # each request draws a ~40-byte STATUS reply

    def serve():
        sent = 0
        for k in range(400):
            if sent < len(burst):
                try:
                    sent += os.write(slave_fd, burst[sent: sent + 512])
                except BlockingIOError:
                    pass
            emu.service(k * 0.01)

    try:
        assert not _hung(serve, 20.0), "the emulator blocked on a full pty"
        c = emu.counters
        assert c["frames_received"] > 300 and c["tx_dropped"] > 0  # the replies did not fit: dropped whole
        assert emu.tx_pending <= emu.max_tx_bytes
        # what reached the line is whole frames: the host decodes every one it reads, no CRC errors
        with StarTrackerHost(FdPort(os.dup(slave_fd), "slave")) as h:
            for _ in range(50):
                h.poll()
                emu.service(5.0)
            assert h.counters["status"] > 50 and h.counters["rejected_crc"] == 0
    finally:
        emu.close()
        master.close()
        os.close(slave_fd)


def test_fd_port_write_has_a_deadline():
    master, _, slave_fd = pty_pair()
    try:
        port = FdPort(os.dup(master.fd), "master", write_timeout=0.05)
        with pytest.raises(DeviceTimeoutError, match="could not be written within 0.05 s") as ei:
            port.write(bytes(200_000))
        assert 0 < ei.value.written < 200_000
        assert write_available(port, bytes(4096)) == 0  # full: nothing taken, nothing blocked
        port.close()
    finally:
        master.close()
        os.close(slave_fd)


def test_host_write_times_out_instead_of_hanging():
    master, slave_path, slave_fd = pty_pair()
    try:
        with StarTrackerHost(slave_path, write_timeout_s=0.05) as h:  # nobody reads the master side
            def fill():
                with pytest.raises(DeviceTimeoutError, match="did not finish within 0.05 s"):
                    for _ in range(10_000):
                        h.send_command(RequestTelemetry(CODEC.status_id))

            assert not _hung(fill, 20.0)
            assert h.counters["write_timeouts"] == 1
    finally:
        master.close()
        os.close(slave_fd)


def test_a_flood_is_read_in_bounded_chunks():
    a, b = pipe_pair()
    with StarTrackerHost(a, max_read_bytes=16_384) as h:
        b.write(bytes(1_000_000))
        h.poll()
        assert h.counters["bytes_received"] == 16_384 and a.in_waiting == 1_000_000 - 16_384
    c, d = pipe_pair()
    emu = StarTrackerEmulator(d, Truth(), FAST)
    c.write(bytes(100_000))
    emu.service(0.0)
    assert emu.counters["bytes_received"] == emu.max_read_bytes == 4096
    emu.close()


def test_emulator_refuses_a_configuration_the_icd_cannot_carry():
    from drivers.star_tracker.emulator import EmulatorConfig

    a, b = pipe_pair()
    with pytest.raises(ValueError, match="temperature_cC"):
        StarTrackerEmulator(a, Truth(), EmulatorConfig(temperature_C=-300.0))


def test_write_available_never_blocks_even_on_a_blocking_descriptor():
    r, w = os.pipe()  # a blocking pipe, as a port opened by someone else might be
    try:
        class Port:
            def fileno(self):
                return w

        total = sum(write_available(Port(), bytes(65536)) for _ in range(8))
        assert 0 < total < 8 * 65536 and os.get_blocking(w)  # took what fit, then 0; left as it was
    finally:
        os.close(r)
        os.close(w)
