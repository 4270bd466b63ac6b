"""``drivers.can_bus.ServedBus``: what a served emulator reads through. On python-can's ``virtual`` bus (in this
process): a frame the interface cannot decode is counted once and skipped, the frames after it still arrive, a failed
line is raised as DriverError, and a second node sending with the served device's own ids is noticed."""

from __future__ import annotations

import itertools

import can
import pytest

from drivers.can_bus import ServedBus, data_frame, open_bus
from drivers.errors import DriverError
from drivers.magnetorquer.codec import DipoleCommand, MagnetorquerCodec
from drivers.magnetorquer.emulator import MagnetorquerEmulator

_channels = itertools.count()


@pytest.fixture
def buses():
    """The served board's bus and a flight computer's bus on one virtual channel of their own."""
    channel = f"served-bus-{next(_channels)}"
    board, fc = open_bus("virtual", channel), open_bus("virtual", channel)
    yield board, fc
    board.shutdown()
    fc.shutdown()


class Undecodable:
    """Raise, on the next recv, what python-can's udp_multicast raises on a datagram that does not unpack."""

    def __init__(self, bus, times: int):
        self.bus, self.times = bus, times
        self.recv_inner = bus.recv

    def recv(self, timeout=None):
        if self.times:
            self.times -= 1
            try:
                raise ValueError("unpack(b) received extra data.")
            except ValueError as exc:
                raise can.CanOperationError("could not unpack received message") from exc
        return self.recv_inner(timeout)


def test_undecodable_frames_are_counted_once_each_and_the_commands_after_them_applied(buses):
    board_bus, fc = buses
    codec = MagnetorquerCodec()
    served = ServedBus(board_bus, own_ids=codec.board_tx_ids)
    board_bus.recv = Undecodable(board_bus, 2).recv  # two truncated datagrams before the command
    emu = MagnetorquerEmulator(served, lambda _t: (2e-5, 0.0, -4e-5))
    fc.send(data_frame(*codec.encode(DipoleCommand((0.1, 0.0, 0.0), 1.0))))
    assert emu.receive(0.0) == 1
    assert served.counters["rejected_undecodable"] == 2 and "could not unpack" in served.last_rejected
    assert emu.counters["commands_accepted"] == 1 and emu.dipole_xyz_at(0.5)[0] == pytest.approx(0.1, abs=2e-4)


def test_a_failed_line_is_raised_as_a_driver_error_naming_the_bus(buses):
    board_bus, _ = buses

    def broken(timeout=None):
        try:
            raise OSError(5, "Input/output error")
        except OSError as exc:
            raise can.CanOperationError("could not read from serial") from exc

    board_bus.recv = broken
    with pytest.raises(DriverError, match="the line failed while reading"):
        ServedBus(board_bus).recv(0.0)


def test_a_second_node_sending_the_served_devices_own_ids_is_noticed_and_not_taken_in(buses):
    board_bus, other = buses
    codec = MagnetorquerCodec()
    served = ServedBus(board_bus, own_ids=codec.board_tx_ids)
    emu = MagnetorquerEmulator(served, lambda _t: (2e-5, 0.0, -4e-5))
    emu.publish(0.0)  # this board's own frames: a virtual bus does not hand them back
    twin = MagnetorquerEmulator(other, lambda _t: (2e-5, 0.0, -4e-5))  # a second stand serving the same board
    twin.publish(0.0)
    emu.receive(0.0)
    assert served.counters["foreign_own_id"] == twin.counters["sent"] > 0
    assert served.conflict is not None and "another stand or emulator serves the same device" in served.conflict
    assert emu.counters["rejected_unknown_id"] == 0  # not the flight computer's fault
