"""Reaction wheel over CAN: codec round trips, node numbering, the ICD document, and host drivers
+ emulators talking over python-can's ``virtual`` bus (several wheels on one bus). No test measures time."""

from __future__ import annotations

import math
import uuid
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.errors import DeviceTimeoutError, EncodeError, ProtocolError
from drivers.reaction_wheel import icd
from drivers.reaction_wheel.codec import (
    HEARTBEAT_STATES,
    MODES,
    Heartbeat,
    ModeCommand,
    ReactionWheelCodec,
    SpeedCommand,
    Status,
    TorqueCommand,
    WheelSpeed,
)
from drivers.reaction_wheel.emulator import ReactionWheelEmulator, WheelCommand, WheelEmulatorConfig
from drivers.reaction_wheel.host import ReactionWheelHost

REPO = Path(__file__).resolve().parents[2]
CODEC = ReactionWheelCodec(0)
TQ_LSB = CODEC.dbc.signal_scale("RW_TORQUE_CMD", "torque")  # 1e-7 N m
W_LSB = CODEC.speed_lsb_rad_s  # 1e-3 rad/s


def test_icd_document_is_the_rendering_of_the_dbc():
    doc = (REPO / "docs" / "reaction_wheel_icd.md").read_text()
    assert doc == icd.render(CODEC), "regenerate: python -m drivers.reaction_wheel.icd > docs/reaction_wheel_icd.md"
    for name in CODEC.dbc.names:
        assert f"### {name} (0x{CODEC.dbc.frame_id(name):03X})" in doc
        for sig in CODEC.dbc.signal_names(name):
            assert f"| {sig} |" in doc


def test_every_message_takes_the_fast_path_and_default_periods_are_the_dbcs():
    assert all(CODEC.dbc.is_fast(n) for n in CODEC.dbc.names)
    cfg = WheelEmulatorConfig()
    assert cfg.telemetry_period_s == CODEC.cycle_time_s["RW_SPEED_TLM"]
    assert cfg.status_period_s == CODEC.cycle_time_s["RW_STATUS"] == CODEC.cycle_time_s["RW_HEARTBEAT"]


def test_wheel_n_uses_every_id_plus_n_and_no_id_of_the_magnetorquer():
    w3 = ReactionWheelCodec(3)
    assert w3.node == 0x23
    assert {n: i - 3 for n, i in w3.ids.items()} == CODEC.ids
    assert w3.ids["RW_HEARTBEAT"] == 0x723  # CANopen-like 0x700 + node
    mtq = {0x090, 0x091, 0x0A0, 0x2A0, 0x2A1, 0x710}
    assert not mtq & CODEC.all_wheel_ids
    assert w3.wheel_of(0x1B5) == 5 and w3.wheel_of(0x090) is None
    fid, payload = CODEC.encode(WheelSpeed(1.0, 0.0, True, False, False, 1))
    with pytest.raises(ProtocolError, match="not one of wheel 3's") as ei:
        w3.decode(fid, payload)
    assert ei.value.frame_hex.startswith("1B0#")
    with pytest.raises(ValueError, match="from 0 to 15"):
        ReactionWheelCodec(16)


# -- round trips ----------------------------------------------------------------------------------


def _grid(lo: float, hi: float, lsb: float) -> st.SearchStrategy[float]:
    return st.integers(math.ceil(lo / lsb - 1e-9), math.floor(hi / lsb + 1e-9)).map(lambda k: k * lsb)


u8 = st.integers(0, 255)
messages = st.one_of(
    st.builds(TorqueCommand, _grid(-1, 1, TQ_LSB), u8, st.integers(0, 65535).map(lambda k: k * 1e-3)),
    st.builds(SpeedCommand, _grid(-2000, 2000, 1e-3), u8, st.integers(0, 65535).map(lambda k: k * 1e-3)),
    st.builds(ModeCommand, st.sampled_from(MODES), st.booleans(), u8),
    st.builds(WheelSpeed, _grid(-8388.608, 8388.607, W_LSB), _grid(-0.8388608, 0.8388607, TQ_LSB), st.booleans(),
              st.booleans(), st.booleans(), u8),
    st.builds(Status, st.sampled_from(MODES), st.integers(0, 65535), u8, u8, u8, u8,
              st.integers(0, 255).map(lambda k: k * 0.5 - 40)),
    st.builds(Heartbeat, st.integers(0, 2 ** 32 - 1), st.sampled_from(HEARTBEAT_STATES), u8),
)


@settings(max_examples=300, deadline=None)
@given(msg=messages, wheel=st.integers(0, 15))
def test_every_message_round_trips_for_every_wheel(msg, wheel):
    codec = CODEC if wheel == 0 else ReactionWheelCodec(wheel, dbc=CODEC.dbc)
    fid, payload = codec.encode(msg)
    assert len(payload) == 8 and fid & 0xF == wheel
    got = codec.decode(fid, payload)
    assert type(got) is type(msg)
    for a, b in zip(got.__slots__, msg.__slots__, strict=True):
        x, y = getattr(got, a), getattr(msg, b)
        assert x == pytest.approx(y, rel=1e-12, abs=1e-12) if isinstance(y, float) else x == y
    assert codec.encode(got) == (fid, payload)


def test_encode_errors_name_the_signal_the_value_and_the_range():
    with pytest.raises(EncodeError, match=r"RW_TORQUE_CMD.torque = 1.5 N.m.*allowed -1 N.m to 1 N.m"):
        CODEC.encode(TorqueCommand(1.5))
    with pytest.raises(EncodeError, match="RW_SPEED_CMD.speed = nan"):
        CODEC.encode(SpeedCommand(math.nan))
    with pytest.raises(ValueError, match="'IDLE' \\(0\\), 'TORQUE' \\(1\\), 'SPEED' \\(2\\)"):
        ModeCommand("BRAKE")


# -- host + emulator on a virtual bus ---------------------------------------------------------------


class Speed:
    def __init__(self, value=100.0) -> None:
        self.value = value
        self.calls: list[float] = []

    def __call__(self, t: float):
        self.calls.append(t)
        return self.value


class Bus:
    """Buses on one fresh virtual channel, all shut down at the end."""

    def __init__(self) -> None:
        self.channel = f"rw-test-{uuid.uuid4().hex}"
        self.buses: list[can.BusABC] = []

    def __call__(self) -> can.BusABC:
        bus = can.Bus(interface="virtual", channel=self.channel)
        self.buses.append(bus)
        return bus

    def close(self) -> None:
        for b in self.buses:
            b.shutdown()


@pytest.fixture
def bus() -> Iterator[Bus]:
    b = Bus()
    yield b
    b.close()


def test_torque_command_is_held_clipped_and_acknowledged(bus):
    speed = Speed(150.0)
    emu = ReactionWheelEmulator(bus(), speed, WheelEmulatorConfig(max_torque_Nm=4e-3))
    host = ReactionWheelHost(bus(), name="rw-under-test")
    emu.service(0.0)
    seq = host.command_torque(1.5e-3)
    emu.service(0.05)
    assert emu.command_at(0.05) == WheelCommand("TORQUE", pytest.approx(1.5e-3, abs=TQ_LSB), 0.0)
    host.command_torque(-9e-3)  # beyond the rating: clipped, keeping the sign
    emu.service(0.1)
    assert emu.torque_command_Nm(0.1) == -4e-3 and emu.counters["saturations"] == 1
    tlm = host.take_speed()
    assert tlm is not None and host.take_speed() is None
    assert tlm.speed_rad_s == pytest.approx(150.0, abs=W_LSB) and tlm.valid and tlm.torque_limited
    assert tlm.torque_Nm == pytest.approx(-4e-3, abs=TQ_LSB)  # the held command, as the source gave a float
    emu.service(1.0)
    host.poll()
    assert host.latest_status.seq_ack == seq + 1 and host.latest_status.mode == "TORQUE"
    assert host.latest_status.saturations == 1 and host.last_heartbeat.uptime_s == 1
    assert speed.calls == pytest.approx([0.0, 0.1, 1.0])
    assert host.counters["rejected_unknown_id"] == emu.counters["rejected_unknown_id"] == 0


def test_speed_mode_idle_and_the_command_timeout(bus):
    emu = ReactionWheelEmulator(bus(), Speed((-20.0, 2e-4)))
    host = ReactionWheelHost(bus())
    host.command_speed(300.0, timeout_s=0.5)
    emu.service(0.0)
    assert emu.command_at(0.2) == WheelCommand("SPEED", 0.0, pytest.approx(300.0))
    assert emu.command_at(0.5) == WheelCommand("IDLE", 0.0, 0.0)  # timed out: motor off
    emu.service(0.6)
    assert emu.counters["watchdog_expiries"] == 1 and emu.mode == "IDLE"
    host.command_speed(1e3)  # beyond 6000 rpm: clipped to the rating
    emu.service(0.7)
    assert emu.command_at(0.7).speed_rad_s == pytest.approx(WheelEmulatorConfig().max_speed_rad_s)
    host.set_mode("IDLE", reset_counters=True)
    emu.service(1.0)
    assert emu.command_at(1.0) == WheelCommand("IDLE", 0.0, 0.0)
    host.poll()
    assert host.latest_status.mode == "IDLE" and host.latest_status.watchdog_expiries == 0
    assert host.latest_speed.torque_Nm == pytest.approx(2e-4, abs=TQ_LSB)  # from the (speed, torque) source
    assert host.latest_speed.speed_rad_s == pytest.approx(-20.0, abs=W_LSB)


def test_four_wheels_share_one_bus_without_mixing_their_traffic(bus):
    speeds = [Speed(10.0 * (n + 1)) for n in range(4)]
    emus = [ReactionWheelEmulator(bus(), speeds[n], wheel=n) for n in range(4)]
    hosts = [ReactionWheelHost(bus(), wheel=n) for n in range(4)]
    for n, h in enumerate(hosts):
        h.command_torque(1e-4 * (n + 1))
    for e in emus:
        e.service(0.0)
    for e in emus:
        e.service(0.05)  # nothing due: drains the siblings' frames sent after this wheel's first service
    for n in range(4):
        assert emus[n].torque_command_Nm(0.0) == pytest.approx(1e-4 * (n + 1), abs=TQ_LSB)
        tlm = hosts[n].take_speed()
        assert tlm.speed_rad_s == pytest.approx(10.0 * (n + 1))
        assert hosts[n].counters["foreign"] == 3 + 3 * 3  # the other hosts' commands and the siblings' frames
        assert emus[n].counters["foreign"] == 3 + 3 * 3  # the other hosts' commands and the siblings' frames
        assert hosts[n].rejected_frames == emus[n].rejected_frames == 0


def test_late_service_sends_one_sample_and_counts_the_skipped_ones(bus):
    emu = ReactionWheelEmulator(bus(), Speed())
    host = ReactionWheelHost(bus())
    emu.service(0.0)
    emu.service(0.55)
    assert emu.counters["samples_skipped"] == 4
    host.poll()
    assert host.counters["samples"] == 2 and host.latest_speed.seq == 1


def test_bad_frames_are_counted_never_raised(bus):
    emu = ReactionWheelEmulator(bus(), Speed())
    rogue = bus()
    rogue.send(can.Message(arbitration_id=0x0B0, data=b"\x00\x01", is_extended_id=False))  # short
    rogue.send(can.Message(arbitration_id=0x0D0, data=bytes([0x0F, 0, 0, 0, 0, 0, 0, 0]), is_extended_id=False))
    rogue.send(can.Message(arbitration_id=0x123, data=bytes(8), is_extended_id=False))
    rogue.send(can.Message(arbitration_id=0x0B0, data=bytes(8), is_extended_id=True))
    emu.service(0.0)
    c = emu.counters
    # 0x123 and the 29-bit id are no frame of this wheel's: another node's traffic, not rejected.
    assert (c["rejected_length"], c["rejected_other"], c["rejected_unknown_id"], c["foreign"]) == (1, 1, 0, 2)
    assert emu.status().rejected_frames == 2 and c["commands_accepted"] == 0


def test_a_source_that_returns_nonsense_is_named(bus):
    emu = ReactionWheelEmulator(bus(), lambda t: "fast")
    with pytest.raises(ValueError, match="speed_source"):
        emu.service(0.0)


def test_read_speed_times_out_naming_the_wheel(bus):
    host = ReactionWheelHost(bus(), wheel=2, name="rw-z")
    with pytest.raises(DeviceTimeoutError) as ei:
        host.read_speed(0.05)
    e = ei.value
    assert e.device == "rw-z" and e.awaited == "RW_SPEED_TLM" and "node 0x22" in str(e)


def test_config_and_wheel_number_errors_are_named(bus):
    with pytest.raises(ValueError, match="max_torque_Nm = 5"):
        ReactionWheelEmulator(bus(), Speed(), WheelEmulatorConfig(max_torque_Nm=5.0))
    with pytest.raises(ValueError, match="telemetry_period_s"):
        WheelEmulatorConfig(telemetry_period_s=0.0)
    with pytest.raises(ValueError, match="codec is for wheel 0"):
        ReactionWheelHost(bus(), wheel=1, codec=CODEC)


# -- the wheel DBC through the fast codec equals cantools -------------------------------------------

from .test_dbc import _physical_values  # noqa: E402


@settings(max_examples=300, deadline=None)
@given(data=st.data())
def test_fast_codec_equals_cantools_on_the_wheel_dbc(data):
    dbc = CODEC.dbc
    name = data.draw(st.sampled_from(dbc.names))
    msg = dbc.database.get_message_by_name(name)
    values = data.draw(st.composite(lambda draw: _physical_values(msg, draw))())
    assert dbc.encode(name, values) == (msg.frame_id, msg.encode(values, strict=True))
    payload = data.draw(st.binary(min_size=8, max_size=8))
    assert dbc.decode(msg.frame_id, payload) == (name, msg.decode(payload, decode_choices=False))


def test_take_speed_is_a_number_in_rad_s_with_the_telemetry_as_attributes():
    """Flight code written against ``take_speed() -> rad/s`` does arithmetic on it; code that wants the flags
    reads them from the same object."""
    s = WheelSpeed(12.5, 1e-3, True, False, True, 7)
    assert s + 0.5 == 13.0 and abs(s) == 12.5 and isinstance(s, float)
    assert (s.speed_rad_s, s.torque_Nm, s.valid, s.speed_limited, s.torque_limited, s.seq) == (12.5, 1e-3, True,
                                                                                              False, True, 7)
    assert s != WheelSpeed(12.5, 1e-3, True, False, True, 8)
    with pytest.raises(AttributeError):
        s.valid = False


@pytest.mark.parametrize("values", [(1.5e-3, 7, 0.25), (-0.0, 0, 0.0), (math.nan, 255, 1e300), ("x", None, [1])])
def test_the_per_frame_command_builders_give_what_the_constructors_give(values):
    from drivers.can_messages import Heartbeat
    from drivers.frozen_build import positional_maker3
    from drivers.reaction_wheel.codec import new_speed_command, new_torque_command

    for build, cls in ((new_torque_command, TorqueCommand), (new_speed_command, SpeedCommand)):
        got, want = build(*values), cls(*values)
        assert type(got) is cls and repr(got) == repr(want)
        assert all(getattr(got, f) is getattr(want, f) for f in cls.__slots__)
        with pytest.raises(AttributeError):  # still frozen
            got.seq = 1
    with pytest.raises(TypeError, match="Heartbeat: positional_maker3 takes"):
        positional_maker3(Heartbeat)  # its __post_init__ checks the state: not a class to build around it


def test_telemetry_edges_refuse_non_finite_and_clip_keeping_the_sign(bus):
    # The telemetry's checks and clips written as comparisons (docs/fast_paths.md) keep abs/min/max's results: a
    # non-finite value is named, a speed the wire cannot carry is clipped with valid = 0, the torque is clipped to
    # what the wire carries, a -0.0 stays -0.0, and speed_limited holds at the rated speed of either sign.
    cfg = WheelEmulatorConfig()
    w_top, tq_top = CODEC.tlm_speed_range_rad_s[1], CODEC.tlm_torque_range_Nm[1]
    got = [None]
    emu = ReactionWheelEmulator(bus(), lambda t: got[0], cfg)
    for bad in ((math.nan, 0.0), (math.inf, 0.0), (0.0, -math.inf), (-math.inf, math.nan)):
        got[0] = bad
        with pytest.raises(ValueError, match=r"speed_source\(0\.0\) must return a finite speed"):
            emu.telemetry(0.0)
    cases = {
        (2.0 * w_top, 0.0): (w_top, 0.0, False, True),
        (-2.0 * w_top, 0.0): (-w_top, 0.0, False, True),
        (1.0, 10.0 * tq_top): (1.0, tq_top, True, False),
        (1.0, -10.0 * tq_top): (1.0, -tq_top, True, False),
        (-0.0, -0.0): (-0.0, -0.0, True, False),
        (cfg.max_speed_rad_s, tq_top): (cfg.max_speed_rad_s, tq_top, True, True),
        (-cfg.max_speed_rad_s, -tq_top): (-cfg.max_speed_rad_s, -tq_top, True, True),
        (0.5 * cfg.max_speed_rad_s, 0.0): (0.5 * cfg.max_speed_rad_s, 0.0, True, False),
    }
    for pair, (speed, torque, valid, limited) in cases.items():
        got[0] = pair
        s = emu.telemetry(0.0)
        assert (float(s), s.torque_Nm, s.valid, s.speed_limited) == (speed, torque, valid, limited), pair
        assert math.copysign(1.0, float(s)) == math.copysign(1.0, speed), pair
        assert math.copysign(1.0, s.torque_Nm) == math.copysign(1.0, torque), pair
    emu.speed_sensor_failed = True
    got[0] = (-2.0 * w_top, -0.0)
    s = emu.telemetry(0.0)
    assert (float(s), s.valid, s.speed_limited, math.copysign(1.0, s.torque_Nm)) == (0.0, False, False, -1.0)


def test_a_torque_command_is_limited_beyond_the_rating_of_either_sign(bus):
    cfg = WheelEmulatorConfig()
    emu = ReactionWheelEmulator(bus(), lambda t: 0.0, cfg)
    top = cfg.max_torque_Nm
    for u, held, limited in ((top, top, False), (-top, -top, False), (1.5 * top, top, True), (-1.5 * top, -top, True),
                             (-0.0, -0.0, False)):
        emu._take(TorqueCommand(u), 0.0)
        assert (emu.command_at(0.0).torque_Nm, emu._torque_limited) == (held, limited), u
        assert math.copysign(1.0, emu.command_at(0.0).torque_Nm) == math.copysign(1.0, held), u
    assert emu.counters["saturations"] == 2
