"""The in-process serial line (drivers.serial_port.pipe_pair): what one end writes the other reads, bounded,
never hanging a writer or a reader past its timeout."""

from __future__ import annotations

import threading
import time

import pytest

from drivers.errors import DeviceTimeoutError
from drivers.serial_port import pipe_pair, write_available


def test_bytes_cross_in_both_directions_in_order():
    a, b = pipe_pair("t")
    assert a.write(b"\xc0abc") == 4 and b.write(b"xyz") == 3
    assert b.in_waiting == 4 and a.in_waiting == 3
    assert b.read(2) == b"\xc0a" and b.read(10) == b"bc"  # timeout 0: what is there
    assert a.read(3) == b"xyz" and a.read(1) == b""
    assert b.in_waiting == 0


def test_a_full_line_refuses_the_rest_after_the_write_timeout_and_says_how_much_went_in():
    a, b = pipe_pair("t", capacity=64)
    a.write_timeout = 0.05
    with pytest.raises(DeviceTimeoutError, match="96 of 100 bytes could not be written") as err:
        a.write(b"x" * 60)
        a.write(b"y" * 100)
    assert err.value.written == 4
    assert b.in_waiting == 64
    a.write_timeout = 0.0
    assert write_available(a, b"z" * 10) == 0  # an emulator's write never waits: nothing taken
    b.read(64)
    assert write_available(a, b"z" * 10) == 10


def test_a_reader_with_a_timeout_waits_for_a_writer_in_another_thread_and_no_longer():
    a, b = pipe_pair("t")
    b.timeout = 2.0
    writer = threading.Timer(0.05, lambda: a.write(b"late"))
    writer.start()
    try:
        t0 = time.monotonic()
        assert b.read(4) == b"late"
        assert time.monotonic() - t0 < 1.5
    finally:
        writer.join()
    b.timeout = 0.05
    t0 = time.monotonic()
    assert b.read(4) == b""
    assert 0.04 <= time.monotonic() - t0 < 1.0


def test_closing_one_end_wakes_its_peer_and_refuses_writes():
    a, b = pipe_pair("t")
    b.timeout = None  # would wait for ever for 4 bytes
    got = []
    reader = threading.Thread(target=lambda: got.append(b.read(4)))
    reader.start()
    time.sleep(0.05)
    a.close()
    reader.join(timeout=2.0)
    assert not reader.is_alive() and got == [b""]
    with pytest.raises(OSError, match="closed"):
        a.write(b"x")


def test_capacity_is_bounded():
    with pytest.raises(ValueError, match="capacity"):
        pipe_pair("t", capacity=10)
