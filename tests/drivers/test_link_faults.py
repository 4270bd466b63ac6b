"""Protocol faults on a link (drivers.link_faults): each kind's effect on the wire between a real host driver and an
emulator of the project (the gyro's datagrams on an in-process serial line, the star tracker's SLIP frames, a
reaction wheel on the in-process CAN bus), the counters on both sides against the link's, and a clean link that is
the bare port to the byte."""

from __future__ import annotations

import re
import uuid

import numpy as np
import pytest

from drivers.can_bus import open_bus
from drivers.gyro.codec import GyroCodec, GyroRate, SetTime
from drivers.gyro.emulator import GyroEmulator, GyroEmulatorConfig
from drivers.gyro.host import GyroHost
from drivers.link_faults import COUNTERS, KINDS, FaultyBus, FaultyPort, LinkFaults, splitter_for
from drivers.reaction_wheel.emulator import ReactionWheelEmulator
from drivers.reaction_wheel.host import ReactionWheelHost
from drivers.serial_port import pipe_pair
from drivers.star_tracker.codec import Subscribe
from drivers.star_tracker.emulator import StarTrackerEmulator
from drivers.star_tracker.host import StarTrackerHost
from tests.drivers.star_tracker_helpers import FAST, Truth

CODEC = GyroCodec()
RATE_LEN = CODEC.by_id[0x93].length  # bytes of one RATE datagram
PERIOD_S = 0.1  # the gyro's output period in these tests
TICK_S = 0.05


def rng(seed: int = 7) -> np.random.Generator:
    return np.random.default_rng(seed)


class GyroRig:
    """A gyro emulator behind a FaultyPort and its host on the other end of an in-process serial line, ticked in sim
    time (the link advanced first, as a device does each tick); every RATE the host decodes is kept."""

    def __init__(self, wrap: bool = True) -> None:
        self.dev_end, self.host_end = pipe_pair("gyro-line")
        self.link = FaultyPort(self.dev_end, framing=CODEC) if wrap else None
        self.emu = GyroEmulator(self.link if wrap else self.dev_end, lambda t: (0.01, -0.02, 0.03),
                                GyroEmulatorConfig(output_period_s=PERIOD_S))
        self.host = GyroHost(self.host_end, name="fc gyro")
        self.got = []
        self.host.add_observer(self.got.append)
        self.t_s = 0.0
        self.k = 0

    def run(self, duration_s: float, between=None) -> None:
        for _ in range(round(duration_s / TICK_S)):
            self.t_s = self.k * TICK_S
            if self.link is not None:
                self.link.advance(self.t_s)
            self.emu.service(self.t_s)
            self.host.poll()
            if between is not None:
                between(self)
            self.k += 1

    def start(self, kind: str, seed: int = 7, **params) -> int:
        return self.link.start(kind, params, rng(seed), self.k * TICK_S)

    def close(self) -> None:
        self.host.close()
        self.emu.close()
        self.dev_end.close()
        self.host_end.close()


@pytest.fixture
def gyro():
    rig = GyroRig()
    yield rig
    rig.close()


def seqs(rig: GyroRig) -> list[int]:
    return [m.seq for m in rig.got]


# -- a clean link is the bare line ------------------------------------------------------------------------------------


def _raw_stream(wrap: bool, fault_window: bool) -> bytes:
    """Every byte the host end receives over 3 s, with the emulator behind a FaultyPort or on the bare line."""
    rig = GyroRig(wrap)
    raw = bytearray()
    if fault_window:  # a fault that acts on nothing (rate 0) started and stopped before the run: nothing changes
        h = rig.start("drop", rate=0.0)
        rig.link.stop(h)
    for k in range(60):
        t = k * TICK_S
        if rig.link is not None:
            rig.link.advance(t)
        rig.emu.service(t)
        raw += rig.host_end.read(rig.host_end.in_waiting)
    rig.close()
    return bytes(raw)


def test_a_link_with_no_fault_active_carries_the_bare_ports_bytes():
    bare = _raw_stream(False, False)
    assert len(bare) == 30 * RATE_LEN
    assert _raw_stream(True, False) == bare
    assert _raw_stream(True, True) == bare


def test_a_clean_link_hands_every_call_to_the_port_and_forwards_its_attributes(gyro):
    gyro.host.set_time(5_000_000)  # host -> device through the wrapper's read
    gyro.run(0.2)
    assert gyro.emu.counters["commands_applied"] == 1 and gyro.emu.time_synced
    assert gyro.link.wrapped is gyro.dev_end and gyro.link.name == gyro.dev_end.name
    gyro.link.timeout = 0.25  # set on the wrapped port, as a host driver sets its poll slice
    assert gyro.dev_end.timeout == 0.25
    assert not gyro.link.faults.busy and gyro.link.counters == dict.fromkeys(COUNTERS, 0)


# -- serial: one test per kind ---------------------------------------------------------------------------------------


def test_dropped_frames_are_not_received_and_the_host_sees_the_gap(gyro):
    gyro.run(1.0)
    h = gyro.start("drop", rate=0.4)
    gyro.run(4.0)
    gyro.link.stop(h)
    gyro.run(1.0)
    dropped = gyro.link.counters["dropped"]
    sent = gyro.emu.counters["sent"]
    assert 4 <= dropped <= 36  # 40 frames at 0.4
    assert gyro.host.counters["frames_received"] == sent - dropped
    assert gyro.host.counters["samples_lost"] == dropped  # the sample counter's gaps
    assert gyro.host.counters["rejected_crc"] == gyro.host.counters["bytes_dropped"] == 0
    assert len(set(seqs(gyro))) == len(seqs(gyro)) == sent - dropped


def test_a_burst_drop_loses_exactly_that_many_frames_in_a_row_then_is_over(gyro):
    gyro.run(1.0)
    gyro.start("burst_drop", frames=6, direction="to_host")
    gyro.run(3.0)
    assert gyro.link.counters["dropped"] == 6
    s = seqs(gyro)
    gaps = [(a, b) for a, b in zip(s[:-1], s[1:], strict=True) if b != (a + 1) & 0xFF]
    assert gaps == [(s[9], s[9] + 7)]  # the 10 frames before the burst, then 6 missing in one gap
    assert gyro.host.counters["samples_lost"] == 6
    assert gyro.host.counters["frames_received"] == gyro.emu.counters["sent"] - 6


def test_bit_errors_are_caught_by_the_hosts_crc_check(gyro):
    gyro.run(0.5)
    h = gyro.start("bit_error", rate=0.5, bits=1, direction="to_host")
    gyro.run(5.0)
    gyro.link.stop(h)
    gyro.run(0.5)  # clean frames after the window: the last corrupted bytes are judged
    corrupted = gyro.link.counters["corrupted"]
    c = gyro.host.counters
    assert 10 <= corrupted <= 40
    assert c["frames_received"] == gyro.emu.counters["sent"] - corrupted
    assert c["bytes_dropped"] == corrupted * RATE_LEN  # every byte of a corrupted datagram, and no other
    assert c["rejected_crc"] >= 1 and c["samples_lost"] == corrupted
    assert all(m.omega_rad_s == gyro.got[0].omega_rad_s for m in gyro.got)  # no corrupted value got through


def test_several_bits_per_frame_at_distinct_places():
    link = LinkFaults()
    link.start("bit_error", {"rate": 1.0, "bits": 5}, rng(3), 0.0)
    frame = bytes(24)
    out = link.process(frame, "to_host")
    assert len(out) == 1 and sum(bin(b).count("1") for b in out[0]) == 5


def test_truncated_frames_are_rejected_by_the_host(gyro):
    gyro.run(0.5)
    h = gyro.start("truncate", rate=0.5, keep_fraction=0.5)
    gyro.run(4.0)
    gyro.link.stop(h)
    gyro.run(0.5)
    cut = gyro.link.counters["truncated"]
    c = gyro.host.counters
    assert cut >= 5
    assert c["frames_received"] == gyro.emu.counters["sent"] - cut
    assert c["bytes_received"] == gyro.emu.counters["sent"] * RATE_LEN - cut * (RATE_LEN - RATE_LEN // 2)
    assert c["bytes_dropped"] == cut * (RATE_LEN // 2)


def test_a_delay_releases_each_frame_delay_s_later_in_sim_time(gyro):
    delay_s = 0.33
    gyro.start("delay", delay_s=delay_s)
    newest = []  # (sim time it arrived, its sample time in the device clock) of each sample

    def check(rig):
        for m in rig.got[len(newest):]:
            newest.append((rig.t_s, m.time_us))

    gyro.run(3.0, check)
    # The device clock is the sim time (no SET_TIME, no offset): each sample reaches the host at the first tick at
    # least delay_s after it was sent (samples every 0.1 s, ticks every 0.05 s: 0.35 s later), and never before.
    assert newest and all(t_s - time_us * 1e-6 == pytest.approx(0.35) for t_s, time_us in newest)
    assert newest[0][0] == pytest.approx(0.35)  # sample 0, sent at 0 s
    assert gyro.link.in_flight == 3  # the samples of 2.7, 2.8 and 2.9 s are still on the line at 2.95 s
    assert gyro.link.counters["delayed"] == gyro.emu.counters["sent"]
    assert gyro.host.counters["frames_received"] == gyro.emu.counters["sent"] - gyro.link.in_flight
    assert seqs(gyro) == list(range(len(gyro.got)))  # in order


def test_jitter_delays_every_frame_by_up_to_max_s_and_never_reorders(gyro):
    gyro.start("jitter", max_s=0.3)
    ages = []

    def check(rig):
        for m in rig.got[len(ages):]:
            ages.append(rig.t_s - m.time_us * 1e-6)

    gyro.run(5.0, check)
    assert seqs(gyro) == list(range(len(gyro.got)))
    assert all(-1e-9 <= a < 0.3 + PERIOD_S + TICK_S for a in ages)
    assert len({round(a, 6) for a in ages}) >= 3  # not one fixed delay
    assert gyro.link.counters["delayed"] == gyro.emu.counters["sent"]


def test_reordered_frames_arrive_swapped_with_the_next(gyro):
    h = gyro.start("reorder", rate=0.3)
    gyro.run(5.0)
    held = gyro.link.in_flight  # a frame held when the fault stops goes out next, in order: no swap to see
    gyro.link.stop(h)
    gyro.run(0.5)
    s = seqs(gyro)
    swaps = [i for i in range(len(s) - 1) if s[i] == s[i + 1] + 1]
    assert held in (0, 1) and len(swaps) == gyro.link.counters["reordered"] - held >= 3
    assert sorted(s) == list(range(gyro.emu.counters["sent"]))  # nothing lost, nothing added
    for i in swaps:  # each pair swapped, the rest in order
        assert s[i + 1] == s[i] - 1


def test_duplicated_frames_arrive_twice(gyro):
    h = gyro.start("duplicate", rate=0.3)
    gyro.run(4.0)
    gyro.link.stop(h)
    gyro.run(0.5)
    s = seqs(gyro)
    twice = [i for i in range(len(s) - 1) if s[i] == s[i + 1]]
    dup = gyro.link.counters["duplicated"]
    assert len(twice) == dup >= 3
    assert gyro.host.counters["frames_received"] == gyro.emu.counters["sent"] + dup
    assert gyro.host.counters["rejected_crc"] == 0


def test_a_babbling_line_floods_the_host_which_survives_and_counts_it(gyro):
    gyro.run(0.5)
    h = gyro.start("babble", frames_per_s=400.0, length=16, direction="to_host")
    gyro.run(3.0)
    gyro.link.stop(h)
    gyro.run(0.5)
    babbled = gyro.link.counters["babbled"]
    c = gyro.host.counters
    assert babbled == 1180  # 400 frames/s from its start at 0.5 s to the window's last tick at 3.45 s
    assert c["frames_received"] == gyro.emu.counters["sent"]  # every good datagram still found
    assert c["bytes_received"] == gyro.emu.counters["sent"] * RATE_LEN + babbled * 16
    assert c["bytes_dropped"] == babbled * 16


def test_babble_towards_the_device_is_counted_by_the_emulator(gyro):
    h = gyro.start("babble", frames_per_s=100.0, length=8, direction="to_device")
    gyro.run(2.0)
    gyro.link.stop(h)
    gyro.host.set_time(1_000_000)
    gyro.run(0.5)
    babbled = gyro.link.counters["babbled"]
    e = gyro.emu.counters
    assert babbled == 195  # the ticks from 0 to 1.95 s
    assert e["bytes_received"] == babbled * 8 + CODEC.by_id[0x51].length
    assert e["bytes_dropped"] == babbled * 8 and e["rejected_undecodable"] >= 1
    assert e["commands_applied"] == 1  # the command after the flood is taken
    assert gyro.host.counters["frames_received"] == e["sent"]


def test_silence_lets_nothing_through_either_way(gyro):
    gyro.run(0.5)
    received = gyro.host.counters["bytes_received"]
    sent_before = gyro.emu.counters["sent"]
    h = gyro.start("silence")
    gyro.host.set_time(9_000_000)
    gyro.run(2.0)
    assert gyro.host.counters["bytes_received"] == received
    assert gyro.emu.counters["bytes_received"] == 0 and not gyro.emu.time_synced
    silenced = gyro.emu.counters["sent"] - sent_before + 1  # the device's frames and the host's SET_TIME
    assert gyro.link.counters["silenced"] == silenced
    gyro.link.stop(h)
    gyro.run(0.5)
    assert gyro.host.counters["frames_received"] == gyro.emu.counters["sent"] - (silenced - 1)


def test_to_device_faults_act_on_commands_only(gyro):
    h = gyro.start("drop", rate=1.0, direction="to_device")
    gyro.host.set_time(1_000_000)
    gyro.run(1.0)
    assert gyro.emu.counters["commands_applied"] == 0 and gyro.link.counters["dropped"] == 1
    assert gyro.host.counters["frames_received"] == gyro.emu.counters["sent"]
    gyro.link.stop(h)
    gyro.host.set_time(2_000_000)
    gyro.run(0.2)
    assert gyro.emu.counters["commands_applied"] == 1


def test_error_frames_are_refused_on_a_serial_link(gyro):
    with pytest.raises(ValueError, match="error_frame.*not possible on a serial link"):
        gyro.start("error_frame", rate=0.1)


# -- SLIP: the star tracker ------------------------------------------------------------------------------------------


def test_star_tracker_frames_with_bit_errors_or_cut_are_rejected_and_the_rest_decode():
    dev_end, host_end = pipe_pair("tracker-line")
    link = FaultyPort(dev_end, framing="slip")
    emu = StarTrackerEmulator(link, Truth(), FAST)
    host = StarTrackerHost(host_end, poll_s=0.0)
    host.send_command(Subscribe(emu.codec.solution_id, 0.0))
    link.start("bit_error", {"rate": 0.4, "bits": 1, "direction": "to_host"}, rng(11), 0.0)
    link.start("truncate", {"rate": 0.2, "keep_fraction": 0.6, "direction": "to_host"}, rng(12), 0.0)
    for k in range(200):
        t = k * 0.02
        link.advance(t)
        emu.service(t)
        host.poll()
    for h, _kind, _p in link.faults.active:
        link.stop(h)
    for k in range(200, 220):
        emu.service(k * 0.02)
        host.poll()
    c = host.counters
    bad = link.counters["corrupted"] + link.counters["truncated"]
    rejected = sum(v for key, v in c.items() if key.startswith("rejected_"))
    assert link.counters["corrupted"] >= 10 and link.counters["truncated"] >= 5
    # A frame both corrupted and cut is one bad frame: count what was lost from what the device sent.
    lost = emu.counters["sent"] - c["frames_received"]
    assert 0 < lost <= bad and rejected >= lost and c["rejected_crc"] >= 1
    host.close()
    emu.close()


# -- CAN: a reaction wheel on the in-process bus ---------------------------------------------------------------------


class WheelRig:
    """Reaction wheel emulator behind a FaultyBus and its host, on one in-process bus channel."""

    def __init__(self, interface: str = "stand_loopback", wrap: bool = True) -> None:
        self.channel = channel = f"faults-{uuid.uuid4().hex}"
        self.dev_bus = open_bus(interface, channel)
        self.host_bus = open_bus(interface, channel)
        self.spy = open_bus(interface, channel)  # what went on the bus
        self.link = FaultyBus(self.dev_bus) if wrap else None
        self.emu = ReactionWheelEmulator(self.link if wrap else self.dev_bus, lambda t: 120.0)
        self.host = ReactionWheelHost(self.host_bus, name="fc wheel")
        self.k = 0

    def run(self, duration_s: float) -> None:
        for _ in range(round(duration_s / TICK_S)):
            t = self.k * TICK_S
            if self.link is not None:
                self.link.advance(t)
            self.emu.service(t)
            self.host.poll()
            self.k += 1

    def start(self, kind: str, seed: int = 5, **params) -> int:
        return self.link.start(kind, params, rng(seed), self.k * TICK_S)

    def wire(self) -> list[tuple]:
        out = []
        for _ in range(100000):
            m = self.spy.recv(0.0)
            if m is None:
                break
            out.append((m.arbitration_id, bytes(m.data), m.is_error_frame))
        return out

    def close(self) -> None:
        for b in (self.dev_bus, self.host_bus, self.spy):
            b.shutdown()


@pytest.fixture
def wheel():
    rig = WheelRig()
    yield rig
    rig.close()


def _wheel_wire(wrap: bool, interface: str) -> list[tuple]:
    rig = WheelRig(interface, wrap)
    rig.host.command_torque(1e-3)
    rig.run(3.0)
    out = rig.wire()
    rig.close()
    return out


@pytest.mark.parametrize("interface", ["stand_loopback", "virtual"])
def test_a_clean_can_link_carries_the_bare_bus_frames(interface):
    bare = _wheel_wire(False, interface)
    assert len(bare) >= 30
    assert _wheel_wire(True, interface) == bare


def test_a_clean_can_link_keeps_the_in_process_buses_fast_paths(wheel):
    assert wheel.link.rx_ready is wheel.dev_bus.rx_ready is not None
    h = wheel.start("drop", rate=0.5)
    assert wheel.link.rx_ready is None  # frames then come through recv, past the faults
    wheel.link.stop(h)
    assert wheel.link.rx_ready is wheel.dev_bus.rx_ready


def test_can_frames_dropped_duplicated_and_delayed(wheel):
    wheel.run(0.5)
    h = wheel.start("drop", rate=0.3)
    wheel.run(3.0)
    wheel.link.stop(h)
    dropped = wheel.link.counters["dropped"]
    assert dropped >= 5
    assert wheel.host.counters["received"] == wheel.emu.counters["sent"] - dropped
    h = wheel.start("duplicate", rate=0.3)
    wheel.run(3.0)
    wheel.link.stop(h)
    dup = wheel.link.counters["duplicated"]
    assert dup >= 5
    assert wheel.host.counters["received"] == wheel.emu.counters["sent"] - dropped + dup
    h = wheel.start("delay", delay_s=0.5)
    wheel.run(2.0)
    assert wheel.link.in_flight >= 1
    assert wheel.host.counters["received"] == wheel.emu.counters["sent"] - dropped + dup - wheel.link.in_flight
    wheel.link.stop(h)
    wheel.run(1.0)
    assert wheel.link.in_flight == 0
    assert wheel.host.counters["received"] == wheel.emu.counters["sent"] - dropped + dup
    assert wheel.host.rejected_frames == 0


def test_can_bit_errors_become_error_frames_the_host_rejects(wheel):
    h = wheel.start("bit_error", rate=0.3)
    wheel.run(3.0)
    wheel.link.stop(h)
    corrupted = wheel.link.counters["corrupted"]
    assert corrupted >= 5
    assert wheel.host.counters["rejected_other"] == corrupted
    assert wheel.host.counters["received"] == wheel.emu.counters["sent"]
    assert sum(1 for f in wheel.wire() if f[2]) == corrupted


def test_can_error_frames_are_counted_and_the_frame_still_arrives(wheel):
    h = wheel.start("error_frame", rate=0.2)
    wheel.run(3.0)
    wheel.link.stop(h)
    n = wheel.link.counters["error_frames"]
    assert n >= 3
    assert wheel.host.counters["rejected_other"] == n
    assert wheel.host.counters["received"] == wheel.emu.counters["sent"] + n
    assert wheel.host.latest_speed.speed_rad_s == pytest.approx(120.0, abs=0.01)


def test_can_truncated_frames_are_rejected_for_their_length(wheel):
    h = wheel.start("truncate", rate=0.3, keep_fraction=0.5)
    wheel.run(3.0)
    wheel.link.stop(h)
    cut = wheel.link.counters["truncated"]
    assert cut >= 5 and wheel.host.counters["rejected_length"] == cut


def test_can_reorder_and_jitter_keep_every_frame(wheel):
    h = wheel.start("reorder", rate=0.3)
    h2 = wheel.start("jitter", max_s=0.2)
    wheel.run(3.0)
    wheel.link.stop(h)
    wheel.link.stop(h2)
    wheel.run(0.5)
    assert wheel.link.counters["reordered"] >= 3 and wheel.link.in_flight == 0
    assert wheel.host.counters["received"] == wheel.emu.counters["sent"]
    assert wheel.host.rejected_frames == 0


def test_a_babbling_can_node_floods_the_bus_and_the_host_counts_it_as_foreign(wheel):
    h = wheel.start("babble", frames_per_s=500.0, frame_id=0x7F0, length=8, direction="to_host")
    wheel.run(2.0)
    wheel.link.stop(h)
    babbled = wheel.link.counters["babbled"]
    assert babbled == 975  # the ticks from 0 to 1.95 s at 500 frames/s
    assert wheel.host.counters["foreign"] == babbled
    assert wheel.host.counters["received"] == wheel.emu.counters["sent"] + babbled


def test_can_silence_and_commands_lost_on_the_way_to_the_device(wheel):
    h = wheel.start("silence")
    wheel.host.command_torque(2e-3)
    wheel.run(1.0)
    assert wheel.host.counters["received"] == 0 and wheel.emu.counters["commands_accepted"] == 0
    assert wheel.link.counters["silenced"] == wheel.emu.counters["sent"] + 1
    wheel.link.stop(h)
    wheel.host.command_torque(2e-3)
    wheel.run(0.5)
    assert wheel.emu.counters["commands_accepted"] == 1


# -- parameters ------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("kind", "params", "text"), [
    ("drop", {"rate": 1.5}, "drop rate = 1.5 is not allowed; allowed: a probability per frame from 0 to 1"),
    ("drop", {}, "drop needs the parameter rate"),
    ("delay", {"delay_s": -1}, "delay delay_s = -1 is not allowed; allowed: seconds from 0 to 3600"),
    ("burst_drop", {"frames": 2.5}, "burst_drop frames = 2.5 is not allowed"),
    ("truncate", {"rate": 0.1, "keep_fraction": 1.0}, "keep_fraction = 1.0 is not allowed"),
    ("jitter", {"max_s": float("nan")}, "jitter max_s = nan is not allowed"),
    ("drop", {"rate": 0.1, "direction": "up"}, "drop direction = 'up' is not allowed; allowed: to_host, to_device"),
    ("drop", {"rate": 0.1, "ratio": 2}, "drop has no parameter 'ratio'; allowed: rate, direction"),
    ("flood", {}, "link fault kind = 'flood' is unknown"),
    ("babble", {"frames_per_s": 1e6}, "babble frames_per_s = 1000000.0 is not allowed"),
    ("babble", {"frames_per_s": 10, "frame_hex": "zz"}, "babble frame_hex = 'zz' is not allowed"),
    ("babble", {"frames_per_s": 10, "frame_id": 5}, "babble frame_id is not allowed on a serial link"),
])
def test_bad_parameters_are_named_with_what_is_allowed(kind, params, text):
    with pytest.raises(ValueError, match=re.escape(text)):
        LinkFaults().start(kind, params, rng(), 0.0)


def test_a_can_babble_frame_holds_at_most_8_data_bytes():
    with pytest.raises(ValueError, match="babble length = 9 is not allowed on a CAN link; allowed: 0 to 8"):
        LinkFaults("can").start("babble", {"frames_per_s": 10, "length": 9}, rng(), 0.0)


def test_every_kind_is_accepted_with_its_parameters_on_can():
    link = LinkFaults("can")
    good = {"drop": {"rate": 0.1}, "burst_drop": {"frames": 2}, "bit_error": {"rate": 0.1}, "truncate": {"rate": 0.1},
            "delay": {"delay_s": 0.1}, "jitter": {"max_s": 0.1}, "reorder": {"rate": 0.1}, "duplicate": {"rate": 0.1},
            "babble": {"frames_per_s": 10}, "silence": {}, "error_frame": {"rate": 0.1}}
    assert set(good) == set(KINDS)
    handles = [link.start(k, p, rng(), 0.0) for k, p in good.items()]
    assert len(link.active) == len(KINDS)
    for h in handles:
        link.stop(h)
    assert not link.busy


def test_the_same_seed_gives_the_same_faults():
    def run(seed):
        link = LinkFaults()
        link.start("drop", {"rate": 0.5}, rng(seed), 0.0)
        return [bool(link.process(bytes([i]), "to_host")) for i in range(200)]

    assert run(1) == run(1) != run(2)


def test_slip_and_datagram_streams_are_cut_into_frames():
    slip = splitter_for("slip")
    assert slip.feed(b"\xc0ab\xc0\xc0cd") == [b"\xc0ab\xc0"] and slip.feed(b"\xc0") == [b"\xc0cd\xc0"]
    dg = splitter_for(CODEC, "to_host")
    frame = CODEC.encode(GyroRate((0.0, 0.0, 0.0), True, False, False, False, False, False, 1, 0.0, 5))
    assert dg.feed(b"\x01\x02" + frame + frame[:5]) == [b"\x01\x02", frame]
    assert dg.feed(frame[5:]) == [frame]


def test_a_wrapped_port_without_fileno_has_none(gyro):
    assert not hasattr(gyro.dev_end, "fileno") and not hasattr(gyro.link, "fileno")


def test_faults_reach_an_emulator_writing_straight_to_a_pty_descriptor():
    """The star tracker writes with write_available, which uses a port's descriptor when it has one: while a fault is
    active the wrapper has none, so the frames pass its faults; clean again, the descriptor is back."""
    import os
    import time

    from drivers.serial_port import open_port, pty_pair

    master, slave_path, slave_fd = pty_pair()
    host_port, _ = open_port(slave_path, timeout=0.0)
    link = FaultyPort(master, framing="slip")
    assert link.fileno() == master.fileno()
    emu = StarTrackerEmulator(link, Truth(), FAST)
    host = StarTrackerHost(host_port, poll_s=0.0)
    try:
        host.send_command(Subscribe(emu.codec.solution_id, 0.0))
        h = link.start("drop", {"rate": 1.0, "direction": "to_host"}, rng(), 0.0)
        assert not hasattr(link, "fileno")
        for k in range(40):
            link.advance(k * 0.02)
            emu.service(k * 0.02)
            host.poll()
        assert emu.counters["sent"] == link.counters["dropped"] >= 10 and host.counters["frames_received"] == 0
        link.stop(h)
        assert link.fileno() == master.fileno()
        for k in range(40, 80):
            emu.service(k * 0.02)
            host.poll()
        expected = emu.counters["sent"] - link.counters["dropped"]
        for _ in range(200):  # a pty hands bytes over asynchronously: wait (bounded) for the last ones
            if host.counters["frames_received"] >= expected:
                break
            time.sleep(0.01)
            host.poll()
        assert host.counters["frames_received"] == emu.counters["sent"] - link.counters["dropped"] >= 10
    finally:
        host_port.close()
        master.close()
        os.close(slave_fd)


def test_a_frame_cut_in_two_by_a_faults_end_is_still_read_whole(gyro):
    frame = CODEC.encode(SetTime(3_000_000))
    h = gyro.start("duplicate", rate=0.0, direction="to_device")
    gyro.host_end.write(frame[:4])
    gyro.run(0.1)  # the first 4 bytes wait in the link for the rest of their datagram
    gyro.link.stop(h)
    gyro.host_end.write(frame[4:])
    gyro.run(0.1)
    assert gyro.emu.counters["commands_applied"] == 1 and gyro.emu.counters["bytes_dropped"] == 0


def test_a_host_side_bus_loses_the_commands_it_sends(wheel):
    own_bus = open_bus("stand_loopback", wheel.channel)
    host_link = FaultyBus(own_bus, side="host")
    host = ReactionWheelHost(host_link, name="fc wheel behind faults")
    h = host_link.start("drop", {"rate": 1.0, "direction": "to_device"}, rng(), 0.0)
    host.command_torque(1e-3)
    wheel.run(0.5)
    assert wheel.emu.counters["commands_accepted"] == 0 and host_link.counters["dropped"] == 1
    host_link.stop(h)
    host.command_torque(1e-3)
    wheel.run(0.5)
    host.poll()
    assert wheel.emu.counters["commands_accepted"] == 1 and host.counters["samples"] >= 5
    own_bus.shutdown()
