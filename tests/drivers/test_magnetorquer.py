"""Magnetorquer board: codec round trips, and host driver + emulator talking over python-can's
``virtual`` bus (every byte goes through the real protocol path).

No test measures time: ``read_sample`` timeouts only check that the deadline is honoured.
"""

from __future__ import annotations

import math
import os
import socket
import subprocess
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.can_bus import open_bus, socketcan_available
from drivers.errors import ConnectError, DeviceTimeoutError, DriverError, EncodeError, ProtocolError
from drivers.magnetorquer import (
    HEARTBEAT_STATES,
    MODES,
    Counters,
    DipoleCommand,
    Heartbeat,
    MagnetorquerCodec,
    MagSample,
    ModeCommand,
    Status,
)
from drivers.magnetorquer.emulator import COMMAND_BLOCK, EmulatorConfig, MagnetorquerEmulator
from drivers.magnetorquer.host import MagnetorquerBoard

REPO = Path(__file__).resolve().parents[2]
CODEC = MagnetorquerCodec()  # one DBC load for the whole module
NT = 1e-9

DIPOLE_LSB = CODEC.dipole_lsb_A_m2  # 1e-5 A m^2
MAG_LSB = CODEC.mag_lsb_T  # 5 nT
CURRENT_LSB = CODEC.current_lsb_A  # 0.1 mA


def _channel() -> str:
    return f"mtq-test-{uuid.uuid4().hex}"


def _virtual(channel: str) -> can.BusABC:
    return can.Bus(interface="virtual", channel=channel)


class Field:
    """A settable true field at the magnetometer (what the stand would hand in)."""

    def __init__(self, b_T: tuple[float, float, float] = (20e-6, -5e-6, 40e-6)) -> None:
        self.b_T = np.array(b_T, dtype=float)
        self.calls: list[float] = []

    def __call__(self, t_s: float) -> np.ndarray:
        self.calls.append(t_s)
        return self.b_T


class Rig:
    """Host driver and emulator on one virtual channel, plus spare buses for rogue traffic."""

    def __init__(self, config: EmulatorConfig | None = None, rng: int = 0) -> None:
        self.channel = _channel()
        self.field = Field()
        self._buses: list[can.BusABC] = []
        self.host = MagnetorquerBoard(self.bus(), codec=CODEC, name="mtq-test")
        self.emu = MagnetorquerEmulator(
            self.bus(), self.field, config or EmulatorConfig(), rng=rng, codec=CODEC
        )

    def bus(self) -> can.BusABC:
        bus = _virtual(self.channel)
        self._buses.append(bus)
        return bus

    def close(self) -> None:
        self.host.close()
        self.emu.close()
        for bus in self._buses:
            bus.shutdown()


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = Rig()
    yield r
    r.close()


@pytest.fixture
def quiet_rig() -> Iterator[Rig]:
    """No magnetometer noise: samples are deterministic."""
    r = Rig(EmulatorConfig(mag_noise_T=0.0))
    yield r
    r.close()


# ---------------------------------------------------------------------------------------------
# ICD


def test_the_icd_has_the_documented_ids_directions_and_rates() -> None:
    assert CODEC.ids == {
        "MTQ_DIPOLE_CMD": 0x090,
        "MTQ_MODE_CMD": 0x091,
        "MAG_SAMPLE": 0x0A0,
        "MTQ_STATUS": 0x2A0,
        "MTQ_COUNTERS": 0x2A1,
        "MTQ_HEARTBEAT": 0x710,
    }
    assert CODEC.board_rx_ids == {0x090, 0x091}
    assert CODEC.board_tx_ids == {0x0A0, 0x2A0, 0x2A1, 0x710}
    # magnetometer: +-100 uT covered with an LSB of at most 5 nT
    assert MAG_LSB <= 5 * NT and CODEC.mag_range_T[0] <= -100e-6 and CODEC.mag_range_T[1] >= 100e-6
    # the emulator's default periods are the DBC's GenMsgCycleTime
    cfg = EmulatorConfig()
    assert cfg.sample_period_s == CODEC.cycle_time_s["MAG_SAMPLE"]
    assert cfg.status_period_s == CODEC.cycle_time_s["MTQ_STATUS"] == CODEC.cycle_time_s["MTQ_COUNTERS"]
    assert cfg.heartbeat_period_s == CODEC.cycle_time_s["MTQ_HEARTBEAT"]
    assert cfg.mag_lsb_T == pytest.approx(MAG_LSB)


# ---------------------------------------------------------------------------------------------
# Codec round trips (Hypothesis): decode(encode(x)) == x up to the LSB


def _close(got: tuple[float, ...], want: tuple[float, ...], lsb: float) -> bool:
    return all(abs(g - w) <= 0.5 * lsb * (1 + 1e-9) + 1e-15 for g, w in zip(got, want, strict=True))


def _floats(lo: float, hi: float) -> st.SearchStrategy[float]:
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


def _vec(lo: float, hi: float) -> st.SearchStrategy[tuple[float, float, float]]:
    return st.tuples(_floats(lo, hi), _floats(lo, hi), _floats(lo, hi))


@given(m=_vec(-0.32768, 0.32767), d=_floats(0.0, 65.535))
def test_dipole_command_round_trip(m: tuple[float, float, float], d: float) -> None:
    msg = DipoleCommand(m, d)
    frame_id, payload = CODEC.encode(msg)
    assert frame_id == 0x090 and len(payload) == 8
    back = CODEC.decode(frame_id, payload)
    assert isinstance(back, DipoleCommand)
    assert _close(back.dipole_A_m2, m, DIPOLE_LSB)
    assert abs(back.duration_s - d) <= 0.5e-3 + 1e-12


@given(mode=st.sampled_from([*MODES, 0, 1, 2]), reset=st.booleans(), seq=st.integers(0, 255))
def test_mode_command_round_trip(mode: str | int, reset: bool, seq: int) -> None:
    msg = ModeCommand(mode, reset, seq)
    assert msg.mode in MODES
    assert CODEC.decode(*CODEC.encode(msg)) == msg


@given(b=_vec(-163840e-9, 163835e-9), coil=st.booleans(), valid=st.booleans(), seq=st.integers(0, 255))
def test_mag_sample_round_trip(b: tuple[float, float, float], coil: bool, valid: bool, seq: int) -> None:
    back = CODEC.decode(*CODEC.encode(MagSample(b, coil, valid, seq)))
    assert isinstance(back, MagSample)
    assert _close(back.b_T, b, MAG_LSB)
    assert (back.coil_active, back.valid, back.seq) == (coil, valid, seq)


@given(
    mode=st.sampled_from(MODES),
    active=st.tuples(st.booleans(), st.booleans(), st.booleans()),
    current=_vec(-3.2768, 3.2767),
    temperature=_floats(-40.0, 87.5),
)
def test_status_round_trip(
    mode: str, active: tuple[bool, bool, bool], current: tuple[float, float, float], temperature: float
) -> None:
    back = CODEC.decode(*CODEC.encode(Status(mode, active, current, temperature)))
    assert isinstance(back, Status)
    assert (back.mode, back.coil_active) == (mode, active)
    assert _close(back.coil_current_A, current, CURRENT_LSB)
    assert abs(back.temperature_C - temperature) <= 0.25 + 1e-9


@given(
    st.integers(0, 0xFFFF),
    st.integers(0, 0xFFFF),
    st.integers(0, 0xFFFF),
    st.integers(0, 255),
    st.integers(0, 255),
)
def test_counters_round_trip(rejected: int, watchdog: int, saturations: int, accepted: int, ack: int) -> None:
    msg = Counters(rejected, watchdog, saturations, accepted, ack)
    assert CODEC.decode(*CODEC.encode(msg)) == msg


@given(uptime=st.integers(0, 2**32 - 1), state=st.sampled_from(HEARTBEAT_STATES), counter=st.integers(0, 255))
def test_heartbeat_round_trip(uptime: int, state: str, counter: int) -> None:
    msg = Heartbeat(uptime, state, counter)
    assert CODEC.decode(*CODEC.encode(msg)) == msg


def test_codec_refuses_values_the_icd_cannot_carry_naming_the_field() -> None:
    with pytest.raises(EncodeError) as err:
        CODEC.encode(DipoleCommand((0.5, 0.0, 0.0), 1.0))
    assert "dipole_x = 0.5" in str(err.value) and "0.32767 A.m2" in str(err.value)
    assert isinstance(err.value, ValueError)
    with pytest.raises(EncodeError, match=r"duration_ms = 100000.0 ms.*0 ms to 65535 ms"):
        CODEC.encode(DipoleCommand((0.0, 0.0, 0.0), 100.0))
    with pytest.raises(EncodeError, match="b_z"):
        CODEC.encode(MagSample((0.0, 0.0, 1e-3), False, True, 0))
    with pytest.raises(EncodeError, match="DipoleCommand"):
        CODEC.encode(DipoleCommand((0.0, 0.0), 1.0))  # type: ignore[arg-type]
    with pytest.raises(EncodeError, match="expected one of DipoleCommand"):
        CODEC.encode("MTQ_DIPOLE_CMD")  # type: ignore[arg-type]


def test_enum_fields_name_what_is_allowed() -> None:
    assert ModeCommand(1).mode == "DIPOLE"
    assert ModeCommand("selftest").mode == "SELFTEST"
    with pytest.raises(ValueError, match=r"ModeCommand.mode must be one of 'OFF' \(0\), 'DIPOLE' \(1\)"):
        ModeCommand("ON")
    with pytest.raises(ValueError, match="Heartbeat.state"):
        Heartbeat(0, 9, 0)


def test_decode_refuses_an_enum_value_outside_its_table_with_the_frame() -> None:
    payload = bytes([0x07, 0, 0, 0, 0, 0, 0, 0x78])  # MTQ_STATUS.mode = 7: fits 4 bits, not in VAL_
    with pytest.raises(ProtocolError) as err:
        CODEC.decode(0x2A0, payload)
    assert err.value.frame_hex == "2A0#0700000000000078"
    assert "MTQ_STATUS" in str(err.value) and "2A0#0700000000000078" in str(err.value)


# ---------------------------------------------------------------------------------------------
# Dipole commands: saturation, quantisation, watchdog


def _quantised(m: float, cfg: EmulatorConfig) -> float:
    levels = math.floor(cfg.max_dipole_A_m2 / cfg.dipole_lsb_A_m2 + 1e-9)
    n = max(-levels, min(levels, round(m / cfg.dipole_lsb_A_m2)))
    return n * cfg.dipole_lsb_A_m2


def test_dipole_command_is_saturated_quantised_and_switched_off_by_the_watchdog(rig: Rig) -> None:
    cfg = rig.emu.config
    host, emu = rig.host, rig.emu
    assert emu.mode == "DIPOLE"
    np.testing.assert_array_equal(emu.dipole_at(0.0), 0.0)

    host.command_dipole((0.3, -0.1234, 0.0), 0.5)
    assert emu.receive(10.0) == 1
    expected = np.array([cfg.max_dipole_A_m2, _quantised(-0.1234, cfg), 0.0])
    np.testing.assert_allclose(emu.dipole_at(10.0), expected, rtol=0, atol=1e-12)
    assert emu.dipole_at(10.0)[0] == pytest.approx(0.2)  # saturated, sign kept
    assert abs(emu.dipole_at(10.0)[1] - (-0.1234)) <= cfg.dipole_lsb_A_m2 / 2  # quantised to the PWM step
    assert emu.dipole_at(10.0)[1] != pytest.approx(-0.1234, abs=1e-9)
    assert emu.coil_active(10.0) and emu.coil_active(10.499)
    np.testing.assert_allclose(emu.dipole_at(10.499), expected, atol=1e-12)
    assert emu.counters["saturations"] == 1 and emu.counters["commands_accepted"] == 1
    with pytest.raises(ValueError):
        emu.dipole_at(10.0)[0] = 1.0  # read-only: the stand cannot corrupt the board state

    # the duration expires at 10.5 s: coils off, watchdog counted once
    np.testing.assert_array_equal(emu.dipole_at(10.5), 0.0)
    assert not emu.coil_active(10.5)
    emu.publish(10.6)
    emu.publish(10.7)
    assert emu.counters["watchdog_expiries"] == 1

    # the board reports it: status (currents, coil flags) and counters
    host.command_dipole((-0.05, 0.0, 0.25), 2.0)
    emu.receive(11.0)
    emu.publish(11.6)  # status is due every 1 s from the first publish (10.6 s)
    host.poll()
    status = host.latest_status
    assert status is not None and status.mode == "DIPOLE"
    assert status.coil_active == (True, False, True)
    na = cfg.coil_area_turns_m2
    want_i = (_quantised(-0.05, cfg) / na[0], 0.0, 0.2 / na[2])
    assert _close(status.coil_current_A, want_i, CURRENT_LSB)
    assert status.temperature_C == cfg.temperature_C
    assert host.latest_counters == Counters(
        rejected_frames=0, watchdog_expiries=1, saturations=2, commands_accepted=2, mode_seq_ack=0
    )


def test_a_new_command_replaces_the_old_one_and_zero_duration_switches_off(rig: Rig) -> None:
    host, emu = rig.host, rig.emu
    host.command_dipole((0.1, 0.1, 0.1), 1.0)
    emu.receive(0.0)
    host.command_dipole((0.0, 0.05, 0.0), 1.0)
    emu.receive(0.5)
    assert emu.dipole_at(1.2)[1] == pytest.approx(_quantised(0.05, emu.config))  # runs until 1.5 s
    host.command_dipole((0.1, 0.1, 0.1), 0.0)  # duration 0: coils off now
    emu.receive(0.6)
    np.testing.assert_array_equal(emu.dipole_at(0.6), 0.0)
    emu.publish(5.0)
    assert emu.counters["watchdog_expiries"] == 0  # replaced or switched off, never expired
    assert emu.counters["commands_accepted"] == 3


def test_modes_gate_the_coils_and_counters_reset_on_request(rig: Rig) -> None:
    host, emu = rig.host, rig.emu
    host.command_dipole((0.1, 0.0, 0.0), 5.0)
    emu.receive(0.0)
    assert emu.coil_active(0.1)
    seq = host.set_mode("OFF")
    emu.receive(0.2)
    assert emu.mode == "OFF" and not emu.coil_active(0.3)  # a mode change switches the coils off
    host.command_dipole((0.1, 0.0, 0.0), 5.0)
    emu.receive(0.4)
    np.testing.assert_array_equal(emu.dipole_at(0.4), 0.0)
    assert emu.counters["rejected_mode"] == 1
    emu.publish(1.0)
    host.poll()
    assert host.latest_status is not None and host.latest_status.mode == "OFF"
    assert host.latest_counters is not None
    assert host.latest_counters.mode_seq_ack == seq and host.latest_counters.rejected_frames == 1

    seq2 = host.set_mode("DIPOLE", reset_counters=True)
    emu.receive(1.5)
    emu.publish(2.0)
    host.poll()
    assert seq2 == (seq + 1) % 256
    assert host.latest_counters == Counters(0, 0, 0, 0, seq2)
    host.command_dipole((0.0, 0.0, -0.1), 1.0)
    emu.receive(2.1)
    assert emu.dipole_at(2.2)[2] == pytest.approx(_quantised(-0.1, emu.config))
    assert emu.counters["rejected_mode"] == 1  # the emulator's own counters are cumulative


# ---------------------------------------------------------------------------------------------
# Magnetometer samples


def test_samples_have_the_configured_noise_bias_and_quantisation(rig: Rig) -> None:
    cfg = rig.emu.config
    truth = rig.field.b_T
    n = 3000
    samples = []
    for k in range(n):
        rig.emu.publish(k * cfg.sample_period_s)
        s = rig.host.take_sample()
        assert s is not None
        samples.append(s)
    assert rig.host.take_sample() is None  # each sample is handed out once
    b = np.array([s.b_T for s in samples])
    assert not any(s.coil_active for s in samples) and all(s.valid for s in samples)
    assert [s.seq for s in samples] == [k % 256 for k in range(n)]
    # quantised to the magnetometer LSB
    counts = b / cfg.mag_lsb_T
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    # mean = truth + bias within 5 standard errors; std = noise within 5 % (~4 sigma of its estimate)
    sigma = cfg.mag_noise_T
    mean_want = truth + np.array(cfg.mag_bias_T)
    std_want = math.sqrt(sigma**2 + cfg.mag_lsb_T**2 / 12)  # noise plus quantisation
    np.testing.assert_allclose(b.mean(axis=0), mean_want, atol=5 * sigma / math.sqrt(n))
    np.testing.assert_allclose(b.std(axis=0, ddof=1), std_want, rtol=0.05)
    # axes are independent
    corr = np.corrcoef(b.T)
    assert np.all(np.abs(corr[np.triu_indices(3, 1)]) < 0.1)
    assert rig.field.calls[:3] == [0.0, 0.1, 0.2]


def test_the_seed_makes_samples_reproducible() -> None:
    def run(seed: int) -> list[MagSample]:
        r = Rig(rng=seed)
        try:
            out = []
            for k in range(50):
                r.emu.publish(k * 0.1)
                out.append(r.host.take_sample())
            return out
        finally:
            r.close()

    assert run(7) == run(7)
    assert run(7) != run(8)


def test_driven_coils_corrupt_the_sample_and_set_the_flag(quiet_rig: Rig) -> None:
    rig = quiet_rig
    cfg = rig.emu.config
    truth = rig.field.b_T
    bias = np.array(cfg.mag_bias_T)
    coupling = np.array(cfg.coil_coupling_T_per_A_m2)

    rig.emu.publish(0.0)
    clean = rig.host.take_sample()
    assert clean is not None and not clean.coil_active
    assert _close(clean.b_T, tuple(truth + bias), cfg.mag_lsb_T)

    rig.host.command_dipole((0.15, -0.2, 0.05), 0.25)
    rig.emu.receive(0.05)
    rig.emu.publish(0.1)
    dirty = rig.host.take_sample()
    m = rig.emu.dipole_at(0.1)
    assert dirty is not None and dirty.coil_active and dirty.valid
    assert _close(dirty.b_T, tuple(truth + bias + coupling @ m), cfg.mag_lsb_T)
    assert np.linalg.norm(np.subtract(dirty.b_T, clean.b_T)) > 10e-6  # tens of uT: clearly corrupted

    rig.emu.publish(0.3)  # the command expired at 0.30 s
    after = rig.host.take_sample()
    assert after is not None and not after.coil_active
    assert after.b_T == clean.b_T


def test_the_magnetometer_saturates_at_the_icd_range(quiet_rig: Rig) -> None:
    rig = quiet_rig
    rig.field.b_T = np.array([200e-6, -200e-6, 30e-6])
    rig.emu.publish(0.0)
    s = rig.host.read_sample(1.0)
    lo, hi = CODEC.mag_range_T
    assert s.b_T[0] == pytest.approx(hi) and s.b_T[1] == pytest.approx(lo)
    assert not s.valid and rig.emu.counters["mag_saturations"] == 1


@pytest.mark.parametrize("bad", [(1e-6, 2e-6), (math.nan, 0.0, 0.0), "north"])
def test_a_bad_field_source_is_named(quiet_rig: Rig, bad: object) -> None:
    quiet_rig.emu.field_source = lambda t_s: bad
    with pytest.raises(ValueError, match=r"field_source\(0.0\) must return 3 finite floats"):
        quiet_rig.emu.publish(0.0)


def test_late_publish_sends_one_sample_and_counts_the_missed_slots(rig: Rig) -> None:
    emu = rig.emu
    assert emu.publish(0.0) == 4  # sample, status, counters, heartbeat
    assert emu.publish(0.05) == 0
    assert emu.publish(0.55) == 1
    assert emu.counters["samples_skipped"] == 4  # slots 0.1 .. 0.4
    assert emu.publish(0.6) == 1  # back on the 0.1 s grid
    assert emu.publish(1.0) == 4
    rig.host.poll()
    assert rig.host.counters["samples"] == 4
    assert rig.host.latest_sample is not None and rig.host.latest_sample.seq == 3


def test_heartbeat_reaches_the_host(rig: Rig) -> None:
    rig.emu.publish(100.0)  # the board's uptime starts at the first call
    rig.host.poll()
    assert rig.host.last_heartbeat == Heartbeat(0, "NOMINAL", 0)
    rig.emu.publish(102.5)
    rig.host.poll()
    assert rig.host.last_heartbeat == Heartbeat(2, "NOMINAL", 1)


# ---------------------------------------------------------------------------------------------
# Garbage on the bus is counted, never raised, and good frames are still served

_frames = st.builds(
    lambda ident, extended, data, remote: (ident, extended, data, remote),
    st.one_of(st.sampled_from(sorted(CODEC.lengths)), st.integers(0, 0x7FF)),
    st.booleans(),
    st.binary(min_size=0, max_size=8),
    st.sampled_from([False] * 9 + [True]),
)


def _expected_class(frame: tuple[int, bool, bytes, bool], accept: frozenset[int],
                    addressed: frozenset[int] = frozenset()) -> str:
    ident, extended, data, remote = frame
    if extended or ident not in accept | addressed:
        return "foreign"  # another node's traffic: not this node's to reject
    if remote:
        return "rejected_other"
    if ident not in accept:
        return "rejected_unknown_id"
    if len(data) != 8:
        return "rejected_length"
    try:
        CODEC.decode(ident, data)
    except ProtocolError:
        return "rejected_other"
    return "accepted"


@settings(max_examples=60, deadline=None)
@given(garbage=st.lists(_frames, min_size=1, max_size=25), good_every=st.integers(1, 6))
def test_garbage_frames_are_counted_and_the_next_good_frame_is_served(
    garbage: list[tuple[int, bool, bytes, bool]], good_every: int
) -> None:
    rig = Rig()
    try:
        rogue, sniffer = rig.bus(), rig.bus()
        t = 0.0
        good_samples = 0
        for i, (ident, extended, data, remote) in enumerate(garbage):
            msg = can.Message(
                arbitration_id=ident if not extended else ident | 0x1000_0000,
                is_extended_id=extended,
                is_remote_frame=remote,
                data=None if remote else data,
                dlc=len(data),
            )
            rogue.send(msg)
            if i % good_every == 0:
                t += 0.1
                good_samples += 1
                rig.emu.publish(t)  # a good sample (plus status/heartbeat on the first call)
        t += 0.1
        rig.emu.publish(t)  # the last frame on the bus is a good sample
        good_samples += 1
        rig.host.poll()  # must not raise
        rig.emu.receive(t)  # must not raise

        for who, accept, addressed in ((rig.host, CODEC.board_tx_ids, frozenset()),
                                       (rig.emu, CODEC.board_rx_ids, COMMAND_BLOCK)):
            classes = [_expected_class(f, accept, addressed) for f in garbage]
            for key in ("rejected_unknown_id", "rejected_length", "rejected_other", "foreign"):
                assert who.counters[key] == classes.count(key), (who, key)
        assert rig.host.counters["received"] == len(garbage) + rig.emu.counters["sent"]
        assert rig.emu.counters["received"] == len(garbage)
        garbage_samples = sum(
            1
            for f in garbage
            if f[0] == CODEC.id_mag_sample and _expected_class(f, CODEC.board_tx_ids) == "accepted"
        )
        assert rig.host.counters["samples"] == good_samples + garbage_samples

        # the host serves the emulator's last sample, exactly as sent
        last = None
        while (m := sniffer.recv(0.0)) is not None:
            if m.arbitration_id == CODEC.id_mag_sample and not m.is_extended_id:
                last = m
        assert last is not None
        assert rig.host.take_sample() == CODEC.decode(last.arbitration_id, last.data)

        # and the emulator still obeys the next good commands (garbage may have changed its mode)
        rig.host.set_mode("DIPOLE")
        rig.host.command_dipole((0.0, 0.1, 0.0), 1.0)
        rig.emu.receive(t)
        assert rig.emu.dipole_at(t)[1] == pytest.approx(_quantised(0.1, rig.emu.config))
    finally:
        rig.close()


def test_frames_of_another_host_are_not_taken_for_the_board(rig: Rig) -> None:
    other_host = MagnetorquerBoard(rig.bus(), codec=CODEC, name="other")
    try:
        other_host.command_dipole((0.1, 0.0, 0.0), 1.0)  # reaches the emulator and our host
        rig.host.poll()
        assert rig.host.counters["foreign"] == 1 and rig.host.rejected_frames == 0
        assert rig.emu.receive(0.0) == 1 and rig.emu.coil_active(0.0)
    finally:
        other_host.close()


# ---------------------------------------------------------------------------------------------
# Timeouts, connection errors, lifecycle


def test_read_sample_times_out_naming_the_device_and_recovers(rig: Rig) -> None:
    with pytest.raises(DeviceTimeoutError) as err:
        rig.host.read_sample(0.02)
    e = err.value
    assert e.device == "mtq-test" and "MAG_SAMPLE" in e.awaited and e.timeout_s == 0.02
    assert "mtq-test" in str(e) and "0.02 s" in str(e) and "no sample has been received yet" in str(e)
    assert isinstance(e, DriverError)

    rig.emu.publish(0.0)
    first = rig.host.read_sample(1.0)
    assert first.seq == 0
    with pytest.raises(DeviceTimeoutError, match="the last one had seq 0"):
        rig.host.read_sample(0.0)  # the same sample is never returned twice
    rig.emu.publish(0.1)
    assert rig.host.read_sample(1.0).seq == 1


def test_open_bus_with_a_bogus_interface_names_it_and_lists_the_known_ones() -> None:
    with pytest.raises(ConnectError) as err:
        open_bus("warp_drive", "can7")
    text = str(err.value)
    assert "'warp_drive'" in text and "'can7'" in text and "virtual" in text and "socketcan" in text
    assert "warp_drive" in err.value.where


def test_open_bus_turns_backend_failures_into_connect_error() -> None:
    if socketcan_available():
        channel = f"nope{uuid.uuid4().hex[:6]}"  # no such interface
    else:
        channel = "can0"  # fails for want of AF_CAN
    with pytest.raises(ConnectError) as err:
        open_bus("socketcan", channel)
    assert f"'{channel}'" in str(err.value) and err.value.reason
    assert isinstance(err.value.__cause__, Exception)


def test_open_bus_virtual_and_owned_bus_lifecycle() -> None:
    channel = _channel()
    board = MagnetorquerBoard.open("virtual", channel, codec=CODEC, name="owned")
    peer = open_bus("virtual", channel)
    try:
        with board:
            board.command_dipole((0.0, 0.0, 0.0), 0.0)
            got = peer.recv(1.0)
            assert got is not None and got.arbitration_id == 0x090 and board.counters["sent"] == 1
        assert board.closed and board.bus._is_shutdown  # owned: shut down with the driver
        board.close()  # idempotent
        with pytest.raises(DriverError, match="owned: the magnetorquer driver is closed"):
            board.command_dipole((0.0, 0.0, 0.0), 0.0)
        with pytest.raises(DriverError, match="closed"):
            board.poll()
    finally:
        peer.shutdown()


def test_close_is_idempotent_and_leaves_a_borrowed_bus_open(rig: Rig) -> None:
    host_bus = rig.host.bus
    rig.host.close()
    rig.host.close()
    rig.emu.close()
    rig.emu.close()
    assert rig.host.closed and rig.emu.closed
    assert not host_bus._is_shutdown  # the rig owns the buses
    with pytest.raises(DriverError):
        rig.emu.publish(0.0)
    with MagnetorquerEmulator(rig.bus(), rig.field, codec=CODEC) as emu:
        assert emu.publish(0.0) == 4
    assert emu.closed


def _af_can_socket_or_skip() -> None:
    try:
        sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except (OSError, AttributeError) as exc:
        pytest.skip(f"SocketCAN is not available on this machine ({exc})")
    sock.close()


def test_host_and_emulator_over_socketcan() -> None:
    """The same exchange over a kernel CAN interface (vcan on a dev box, can0 on a bench)."""
    _af_can_socket_or_skip()
    channel = os.environ.get("STAND_MTQ_CAN_CHANNEL", "vcan0")
    try:
        host_bus = open_bus("socketcan", channel)
    except ConnectError as exc:
        pytest.skip(f"SocketCAN channel {channel!r} cannot be opened: {exc}")
    emu_bus = open_bus("socketcan", channel)
    host = MagnetorquerBoard(host_bus, codec=CODEC, owns_bus=True)
    emu = MagnetorquerEmulator(emu_bus, Field(), codec=CODEC, owns_bus=True)
    try:
        emu.publish(0.0)
        assert host.read_sample(1.0).seq == 0
        host.command_dipole((0.1, 0.0, 0.0), 1.0)
        deadline_frames = 0
        while emu.receive(0.1) == 0 and deadline_frames < 1000:
            deadline_frames += 1
        assert emu.coil_active(0.2)
    finally:
        host.close()
        emu.close()


# ---------------------------------------------------------------------------------------------
# Configuration errors and the import rule


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"max_dipole_A_m2": -0.1}, "max_dipole_A_m2 must be a finite number > 0; got -0.1"),
        ({"mag_noise_T": math.nan}, "mag_noise_T"),
        ({"mag_bias_T": (1e-6, 2e-6)}, r"mag_bias_T must be finite numbers of shape \(3,\)"),
        ({"coil_coupling_T_per_A_m2": ((1.0, 0.0, 0.0),)}, "coil_coupling_T_per_A_m2"),
        ({"initial_mode": "ON"}, "initial_mode must be one of OFF, DIPOLE, SELFTEST"),
        ({"dipole_lsb_A_m2": 1.0}, "dipole_lsb_A_m2"),
    ],
)
def test_emulator_config_names_the_bad_field(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        EmulatorConfig(**kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"mag_lsb_T": 1e-9}, "mag_lsb_T = 1e-09 T must be a whole multiple of the DBC's"),
        ({"mag_lsb_T": 7e-9}, "mag_lsb_T"),
        ({"max_dipole_A_m2": 0.5}, "max_dipole_A_m2 = 0.5 exceeds what MTQ_DIPOLE_CMD can carry"),
    ],
)
def test_emulator_refuses_a_config_the_icd_cannot_carry(kwargs: dict[str, object], match: str) -> None:
    bus = _virtual(_channel())
    try:
        with pytest.raises(ValueError, match=match):
            MagnetorquerEmulator(bus, Field(), EmulatorConfig(**kwargs), codec=CODEC)  # type: ignore[arg-type]
    finally:
        bus.shutdown()


def test_a_coarser_magnetometer_lsb_is_honoured() -> None:
    r = Rig(EmulatorConfig(mag_lsb_T=20e-9))
    try:
        for k in range(20):
            r.emu.publish(k * 0.1)
            s = r.host.take_sample()
            assert s is not None
            counts = np.array(s.b_T) / 20e-9
            np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    finally:
        r.close()


def test_drivers_never_import_sim_star_screen_or_stand() -> None:
    code = (
        "import sys\n"
        "import drivers, drivers.can_bus, drivers.dbc\n"
        "import drivers.magnetorquer.codec, drivers.magnetorquer.host, drivers.magnetorquer.emulator\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in {'sim', 'star_screen', 'stand'})\n"
        "assert not bad, bad\n"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
