"""The wheel emulator's speed sensor failure on the wire (issue 24): RW_SPEED_TLM carries speed 0 with valid = 0 while
the fault lasts, the motor torque still reported; cleared, the frames are those of a wheel that never failed."""

from __future__ import annotations

import uuid

import can
import pytest

from drivers.reaction_wheel.emulator import ReactionWheelEmulator
from drivers.reaction_wheel.host import ReactionWheelHost


@pytest.fixture
def buses():
    channel = f"rw-fault-{uuid.uuid4().hex}"
    made: list[can.BusABC] = []

    def open_one() -> can.BusABC:
        made.append(can.Bus(interface="virtual", channel=channel))
        return made[-1]

    yield open_one
    for b in made:
        b.shutdown()


def _frames(emu: ReactionWheelEmulator, listener: can.BusABC, t_s: float) -> list[bytes]:
    emu.service(t_s)
    out = []
    for _ in range(16):  # bounded: a service sends at most three frames
        msg = listener.recv(timeout=0.0)
        if msg is None:
            break
        out.append((msg.arbitration_id, bytes(msg.data)))
    return out


def test_speed_sensor_failure_reports_zero_invalid_speed_and_clears_to_the_same_bytes(buses):
    source = lambda _t: (123.4, 2e-3)  # noqa: E731 - the stand's truth, here a fixed rotor speed and torque
    emu = ReactionWheelEmulator(buses(), source)
    twin = ReactionWheelEmulator(buses(), source, wheel=1)  # never fails: its frames, re-numbered, are the reference
    host, listen_twin = ReactionWheelHost(buses()), buses()
    assert emu.speed_sensor_failed is False
    emu.service(0.0)
    twin.service(0.0)
    good = host.take_speed()
    assert good.valid and good.speed_rad_s == pytest.approx(123.4, abs=1e-3)
    emu.speed_sensor_failed = True
    emu.service(0.1)
    bad = host.take_speed()
    assert not bad.valid and bad.speed_rad_s == 0.0
    assert bad.torque_Nm == pytest.approx(2e-3, abs=1e-7)  # the drive still reports its torque
    emu.speed_sensor_failed = False
    emu.service(0.2)
    healed = host.take_speed()
    assert healed.valid and healed.speed_rad_s == good.speed_rad_s
    # The healthy emulator's RW_SPEED_TLM after the fault is byte for byte the never-failed one's (same sequence).
    twin.service(0.1)
    twin_frames = [(fid - 1, data) for fid, data in _frames(twin, listen_twin, 0.2) if fid & 0xF == 1]
    fid, payload = emu.codec.encode(healed)
    assert (fid, payload) in twin_frames
