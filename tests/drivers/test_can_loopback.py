"""The ``stand_loopback`` CAN interface: python-can's bus contract, run side by side with python-can's
own ``virtual`` bus where both should behave alike, plus what is particular to it (bounded queue,
no aliasing between sender and receivers, registration as a python-can interface).

Timeouts are only checked to be honoured (a lower bound on a monotonic clock), never timed.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
import tomllib
import uuid
from pathlib import Path

import can
import numpy as np
import pytest

from drivers.can_bus import OWN_INTERFACES, open_bus
from drivers.can_loopback import INTERFACE_NAME, LoopbackBus
from drivers.errors import ConnectError
from drivers.magnetorquer.emulator import EmulatorConfig, MagnetorquerEmulator
from drivers.magnetorquer.host import MagnetorquerBoard

REPO = Path(__file__).resolve().parents[2]
INTERFACES = ("virtual", INTERFACE_NAME)


def _name() -> str:
    return f"loopback-test-{uuid.uuid4().hex}"


@pytest.fixture
def buses():
    """Open buses with ``open(interface, channel, **kw)``; all are shut down after the test."""
    opened: list[can.BusABC] = []

    def open_(interface: str, channel: str, **kw) -> can.BusABC:
        bus = open_bus(interface, channel, **kw)
        opened.append(bus)
        return bus

    yield open_
    for bus in opened:
        bus.shutdown()


def _drain(bus: can.BusABC) -> list[tuple[int, bool]]:
    """(id, extended) of what ``recv(0)`` returns over a few calls (python-can's ``virtual`` answers
    None for a queued frame its filters reject, so stop only after several Nones)."""
    out = []
    for _ in range(8):
        msg = bus.recv(0.0)
        if msg is not None:
            out.append((msg.arbitration_id, msg.is_extended_id))
    return out


def _frame(frame_id: int, data: bytes = b"\x01\x02", extended: bool = False) -> can.Message:
    return can.Message(arbitration_id=frame_id, data=data, is_extended_id=extended)


@pytest.mark.parametrize("interface", INTERFACES)
def test_two_buses_on_one_channel_exchange_frames_and_other_channels_do_not_hear(buses, interface):
    ch = _name()
    a, b, other = buses(interface, ch), buses(interface, ch), buses(interface, _name())
    a.send(_frame(0x101, b"\xaa\xbb\xcc"))
    a.send(_frame(0x1ABCDE, b"", extended=True))
    got = b.recv(0.0)
    assert (got.arbitration_id, bytes(got.data), got.dlc, got.is_extended_id) == (0x101, b"\xaa\xbb\xcc", 3, False)
    assert got.is_rx and got.channel == ch and got.timestamp > 0.0
    got2 = b.recv(0.0)
    assert (got2.arbitration_id, got2.is_extended_id, got2.dlc) == (0x1ABCDE, True, 0)
    assert b.recv(0.0) is None  # nothing more
    assert a.recv(0.0) is None  # no echo without receive_own_messages
    assert other.recv(0.0) is None
    b.send(_frame(0x202))
    assert a.recv(0.0).arbitration_id == 0x202


@pytest.mark.parametrize("interface", INTERFACES)
def test_receive_own_messages_echoes_as_transmitted(buses, interface):
    ch = _name()
    a, b = buses(interface, ch, receive_own_messages=True), buses(interface, ch)
    a.send(_frame(0x123))
    echo, heard = a.recv(0.0), b.recv(0.0)
    assert echo.arbitration_id == heard.arbitration_id == 0x123
    assert echo.is_rx is False and heard.is_rx is True
    assert echo is not heard


@pytest.mark.parametrize("interface", INTERFACES)
def test_filters_from_constructor_and_set_filters(buses, interface):
    ch = _name()
    tx = buses(interface, ch)
    rx = buses(interface, ch, can_filters=[{"can_id": 0x100, "can_mask": 0x7F0, "extended": False}])
    for frame_id, ext in ((0x105, False), (0x205, False), (0x105, True), (0x10F, False)):
        tx.send(_frame(frame_id, extended=ext))
    assert _drain(rx) == [(0x105, False), (0x10F, False)]
    rx.set_filters([{"can_id": 0x205, "can_mask": 0x7FF}])  # no "extended" key: both kinds match
    tx.send(_frame(0x105))
    tx.send(_frame(0x205, extended=True))
    tx.send(_frame(0x205))
    assert _drain(rx) == [(0x205, True), (0x205, False)]
    rx.set_filters(None)
    tx.send(_frame(0x7FF))
    assert rx.recv(0.0).arbitration_id == 0x7FF


def test_frames_queued_before_a_filter_change_obey_the_new_filters(buses):
    ch = _name()
    tx, rx = buses(INTERFACE_NAME, ch), buses(INTERFACE_NAME, ch)
    tx.send(_frame(0x100))
    tx.send(_frame(0x200))
    rx.set_filters([{"can_id": 0x200, "can_mask": 0x7FF}])
    assert rx.recv(0.0).arbitration_id == 0x200  # the rejected 0x100 ahead of it is skipped, not returned as None
    assert rx.recv(0.0) is None


@pytest.mark.parametrize("interface", INTERFACES)
def test_recv_timeout_is_honoured_and_returns_none(buses, interface):
    bus = buses(interface, _name())
    t0 = time.monotonic()
    assert bus.recv(0.05) is None
    assert time.monotonic() - t0 >= 0.05 - 1e-3  # never returns early


@pytest.mark.parametrize("interface", INTERFACES)
def test_recv_timeout_counts_frames_filtered_out_while_waiting(buses, interface):
    """A frame that does not pass the filters does not end the wait, nor restart its deadline."""
    ch = _name()
    tx, rx = buses(interface, ch), buses(interface, ch, can_filters=[{"can_id": 0x1, "can_mask": 0x7FF}])
    tx.send(_frame(0x2))
    t0 = time.monotonic()
    assert rx.recv(0.05) is None
    assert time.monotonic() - t0 >= 0.05 - 1e-3


@pytest.mark.parametrize("interface", INTERFACES)
def test_blocking_recv_wakes_when_another_thread_sends(buses, interface):
    ch = _name()
    tx, rx = buses(interface, ch), buses(interface, ch)
    got: list = []
    reader = threading.Thread(target=lambda: got.append(rx.recv(5.0)))
    reader.start()
    time.sleep(0.02)  # let the reader block first (it is correct either way)
    tx.send(_frame(0x321))
    reader.join(5.0)
    assert not reader.is_alive()
    assert got and got[0] is not None and got[0].arbitration_id == 0x321


def test_frames_cross_threads_in_order_without_loss(buses):
    ch = _name()
    tx, rx = buses(INTERFACE_NAME, ch), buses(INTERFACE_NAME, ch, rx_queue_size=5000)
    n = 3000

    def write():
        for i in range(n):
            tx.send(_frame(i & 0x7FF, i.to_bytes(2, "little")))

    writer = threading.Thread(target=write)
    writer.start()
    seen = []
    deadline = time.monotonic() + 20.0
    while len(seen) < n and time.monotonic() < deadline:
        msg = rx.recv(1.0)
        if msg is not None:
            seen.append(int.from_bytes(msg.data, "little"))
    writer.join(5.0)
    assert seen == list(range(n))
    assert rx.rx_overflow == 0


@pytest.mark.parametrize("interface", INTERFACES)
def test_shutdown_is_idempotent_and_a_shut_bus_refuses_work(interface):
    ch = _name()
    a, b = open_bus(interface, ch), open_bus(interface, ch)
    try:
        a.shutdown()
        a.shutdown()
        with pytest.raises(can.CanOperationError):
            a.send(_frame(0x1))
        with pytest.raises(can.CanOperationError):
            a.recv(0.0)
        b.send(_frame(0x1))  # the channel still works for the buses left on it
    finally:
        b.shutdown()


def test_shutdown_wakes_a_blocked_reader_and_leaves_the_channel():
    ch = _name()
    a = LoopbackBus(channel=ch)
    b = LoopbackBus(channel=ch)
    assert {"interface": INTERFACE_NAME, "channel": ch} in LoopbackBus._detect_available_configs()
    errors: list = []

    def read():
        try:
            a.recv(10.0)
        except can.CanOperationError as exc:
            errors.append(exc)

    reader = threading.Thread(target=read)
    reader.start()
    time.sleep(0.02)
    a.shutdown()
    reader.join(5.0)
    assert not reader.is_alive() and errors and "shut down" in str(errors[0])
    b.send(_frame(0x1))  # a shut bus receives nothing more and is no longer on the channel
    assert {"interface": INTERFACE_NAME, "channel": ch} in LoopbackBus._detect_available_configs()
    b.shutdown()
    assert {"interface": INTERFACE_NAME, "channel": ch} not in LoopbackBus._detect_available_configs()


def test_sender_and_receivers_never_share_a_mutable_frame(buses):
    ch = _name()
    tx, r1, r2 = buses(INTERFACE_NAME, ch), buses(INTERFACE_NAME, ch), buses(INTERFACE_NAME, ch)
    msg = _frame(0x10, b"\x01\x02\x03")
    tx.send(msg)
    msg.data[0] = 0xFF  # a sender reusing its message after send
    msg.arbitration_id = 0x11
    got1, got2 = r1.recv(0.0), r2.recv(0.0)
    assert bytes(got1.data) == bytes(got2.data) == b"\x01\x02\x03"
    assert got1.arbitration_id == got2.arbitration_id == 0x10
    got1.data[1] = 0xEE  # one receiver editing what it got
    assert bytes(got2.data) == b"\x01\x02\x03"
    assert got1 is not got2 and got1.data is not got2.data


def test_send_data_frames_share_nothing_mutable_and_obey_a_later_filter(buses):
    """send_data queues one immutable tuple for the receivers without filters: a sender's buffer changed after the
    send, or a receiver editing the message recv made of it, changes nothing for the others; a filter set after the
    frames were queued still applies."""
    ch = _name()
    tx, r1, r2, r3 = (buses(INTERFACE_NAME, ch) for _ in range(4))
    payload = bytearray(b"\x01\x02\x03")
    tx.send_data(0x10, payload)
    payload[0] = 0xFF  # a sender reusing its buffer after the send
    tx.send_data(0x20, b"\x04")
    assert r1.rx_ready[0] is r2.rx_ready[0] and type(r1.rx_ready[0]) is tuple
    r3.set_filters([{"can_id": 0x20, "can_mask": 0x7FF}])
    got1, got2 = r1.recv(0.0), r2.recv(0.0)
    assert bytes(got1.data) == bytes(got2.data) == b"\x01\x02\x03"
    got1.data[1] = 0xEE  # one receiver editing what it got
    assert bytes(got2.data) == b"\x01\x02\x03" and got1 is not got2
    frame_id, data, _, is_rx = r2.rx_ready.popleft()  # what a node popping the queue itself reads
    assert (frame_id, data, is_rx) == (0x20, b"\x04", True) and type(data) is bytes
    assert [(m.arbitration_id, bytes(m.data)) for m in iter(lambda: r3.recv(0.0), None)] == [(0x20, b"\x04")]


def test_fd_and_remote_flags_survive_the_trip(buses):
    ch = _name()
    tx, rx = buses(INTERFACE_NAME, ch), buses(INTERFACE_NAME, ch)
    fd = can.Message(arbitration_id=0x42, data=bytes(range(64)), is_fd=True, bitrate_switch=True,
                     error_state_indicator=True, is_extended_id=False)
    rtr = can.Message(arbitration_id=0x43, is_remote_frame=True, dlc=4, is_extended_id=False)
    tx.send(fd)
    tx.send(rtr)
    a, b = rx.recv(0.0), rx.recv(0.0)
    assert a.equals(fd, timestamp_delta=None, check_channel=False, check_direction=False)
    assert b.equals(rtr, timestamp_delta=None, check_channel=False, check_direction=False)


def test_timestamps_are_stamped_or_preserved(buses):
    ch = _name()
    tx, rx = buses(INTERFACE_NAME, ch), buses(INTERFACE_NAME, ch)
    keep = buses(INTERFACE_NAME, _name() + "p", preserve_timestamps=True)
    keep_rx = buses(INTERFACE_NAME, keep.channel_id)
    msg = can.Message(timestamp=12.5, arbitration_id=0x1, is_extended_id=False)
    before = time.time()
    tx.send(msg)
    assert rx.recv(0.0).timestamp >= before
    keep.send(msg)
    assert keep_rx.recv(0.0).timestamp == 12.5


def test_full_queue_drops_the_oldest_and_counts_it(buses):
    ch = _name()
    tx, rx = buses(INTERFACE_NAME, ch), buses(INTERFACE_NAME, ch, rx_queue_size=3)
    for i in range(5):
        tx.send(_frame(0x100 + i))
    assert rx.rx_overflow == 2
    assert [m.arbitration_id for m in iter(lambda: rx.recv(0.0), None)] == [0x102, 0x103, 0x104]
    tx.send(_frame(0x1))
    assert rx.rx_overflow == 2  # room again


@pytest.mark.parametrize("size", [0, -1, 2.5, True, "8"])
def test_bad_queue_size_is_refused_with_a_sentence(size):
    with pytest.raises(ValueError, match=r"rx_queue_size is .* 1 or more"):
        LoopbackBus(channel=_name(), rx_queue_size=size)


def test_open_bus_names_the_interface_when_the_loopback_refuses():
    with pytest.raises(ConnectError, match=r"stand_loopback.*rx_queue_size"):
        open_bus(INTERFACE_NAME, _name(), rx_queue_size=0)


def test_magnetorquer_host_and_emulator_talk_over_the_loopback(buses):
    ch = _name()
    field = (20e-6, -5e-6, 40e-6)

    emu = MagnetorquerEmulator(buses(INTERFACE_NAME, ch), lambda t: field,
                               EmulatorConfig(mag_noise_T=0.0, mag_bias_T=(0.0, 0.0, 0.0)),
                               np.random.default_rng(0))
    host = MagnetorquerBoard(buses(INTERFACE_NAME, ch))
    emu.publish(0.0)
    sample = host.take_sample()
    assert sample is not None and sample.valid
    assert np.allclose(sample.b_T, field, atol=2.5e-9)
    host.command_dipole((0.1, 0.0, -0.05), 1.0)
    assert emu.receive(0.05) == 1 and emu.counters["commands_accepted"] == 1
    assert host.counters["rejected_unknown_id"] == 0


def _pyproject_entry_points() -> dict[str, str]:
    data = tomllib.loads((REPO / "pyproject.toml").read_text())
    return data["project"]["entry-points"]["can.interface"]


def test_entry_point_matches_the_table_open_bus_uses():
    assert _pyproject_entry_points() == {k: f"{m}:{c}" for k, (m, c) in OWN_INTERFACES.items()}


def test_python_can_discovers_the_interface_through_its_entry_point(tmp_path):
    """Install only the package metadata (a dist-info with pyproject's entry points) and let a fresh
    python-can find ``stand_loopback`` the way it finds any third-party interface."""
    dist = tmp_path / "adcs_stand-0.0.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: adcs-stand\nVersion: 0.0.0\n")
    lines = ["[can.interface]"] + [f"{k} = {v}" for k, v in _pyproject_entry_points().items()]
    (dist / "entry_points.txt").write_text("\n".join(lines) + "\n")
    code = (
        "import can, can.interfaces\n"
        "assert 'stand_loopback' in can.interfaces.VALID_INTERFACES\n"
        "a = can.Bus(interface='stand_loopback', channel='ep')\n"
        "b = can.Bus(interface='stand_loopback', channel='ep')\n"
        "a.send(can.Message(arbitration_id=0x7, data=b'ok', is_extended_id=False))\n"
        "m = b.recv(1.0)\n"
        "print(type(a).__module__, type(a).__name__, bytes(m.data).decode())\n"
        "a.shutdown(); b.shutdown()\n"
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), str(REPO)]))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["drivers.can_loopback", "LoopbackBus", "ok"]


def test_data_frame_is_the_message_the_constructor_makes_field_for_field():
    """``drivers.can_bus.data_frame`` skips ``can.Message.__init__``: every slot python-can declares must still
    come out as the constructor sets it (a new slot in a python-can release fails here, not in a run)."""
    from drivers.can_bus import data_frame

    for frame_id, payload in ((0x123, b"\x01\x02\x03"), (0x7FF, bytes(8)), (0, b"")):
        fast = data_frame(frame_id, payload)
        ref = can.Message(arbitration_id=frame_id, data=payload, is_extended_id=False)
        slots = [s for s in can.Message.__slots__ if s != "__weakref__"]
        assert {s: getattr(fast, s) for s in slots} == {s: getattr(ref, s) for s in slots}
        assert fast.equals(ref) and type(fast.data) is bytearray
