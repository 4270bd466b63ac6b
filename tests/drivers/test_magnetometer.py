"""The standalone magnetometer's driver package: its ICD and codec, its emulator and host over the shared CAN node,
and the one magnetometer model it shares with the magnetorquer board (no second copy of the sensor)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.can_bus import data_frame, open_bus
from drivers.errors import EncodeError
from drivers.magnetometer.codec import MagnetometerCodec, MagSample, ModeCommand, Status
from drivers.magnetometer.emulator import MagnetometerConfig, MagnetometerEmulator
from drivers.magnetometer.host import MagnetometerHost
from drivers.magnetometer.sensor import MagnetometerModel

FIELD_T = (21_000e-9, -3_500e-9, -41_250e-9)


@pytest.fixture
def rig(request):
    channel = f"mag-{request.node.name}"
    buses = [open_bus("stand_loopback", channel) for _ in range(2)]
    yield buses
    for b in buses:
        b.shutdown()


def test_codec_round_trips_every_message_and_uses_the_dbc_for_the_field_step():
    codec = MagnetometerCodec()
    assert codec.mag_lsb_T == pytest.approx(1e-9) and codec.mag_range_T == pytest.approx((-131072e-9, 131071e-9))
    for msg in (ModeCommand("OFF", True, 9), Status("MEASURE", 65535, 3, 255, 9)):
        assert codec.decode(*codec.encode(msg)) == msg
    sample = MagSample((-131072e-9, 131071e-9, -12345e-9), False, True, 200)
    back = codec.decode(*codec.encode(sample))
    assert back.b_T == pytest.approx(sample.b_T, abs=1e-15) and (back.valid, back.seq) == (True, 200)
    import cantools  # the reference decoder reads the same bits

    db = cantools.database.load_file(str(codec.dbc.path))
    frame_id, payload = codec.encode(MagSample(FIELD_T, False, True, 7))
    assert db.decode_message(frame_id, payload) == {"b_x": 21000, "b_y": -3500, "b_z": -41250, "seq": 7, "valid": 1}
    with pytest.raises(EncodeError, match="b_x"):
        codec.encode(MagSample((200e-6, 0.0, 0.0), False, True, 0))


def test_emulator_and_host_exchange_samples_and_mode_commands(rig):
    emu_bus, host_bus = rig
    emu = MagnetometerEmulator(emu_bus, lambda _t: FIELD_T, MagnetometerConfig(noise_T=0.0))
    host = MagnetometerHost(host_bus, name="mag")
    for k in range(11):
        emu.service(0.1 * k)
    s = host.take_sample()
    assert s.b_T == pytest.approx(FIELD_T, abs=0.5e-9) and s.valid and not s.coil_active and s.seq == 10
    assert host.take_sample() is None  # nothing new
    seq = host.set_mode("OFF")
    emu.service(1.1)
    emu.service(2.0)
    host.poll()
    assert emu.mode == "OFF" and host.latest_status.mode == "OFF" and host.latest_status.mode_seq_ack == seq
    samples = host.counters["samples"]
    emu.service(2.5)
    host.poll()
    assert host.counters["samples"] == samples  # no sample in mode OFF
    host_bus.send(data_frame(0x0E3, bytes(8)))  # an id of its command block that the ICD leaves free
    emu.service(2.6)
    assert emu.counters["rejected_unknown_id"] == 1 and emu.rejected_frames == 1


def test_bias_noise_and_quantisation_are_the_units_own():
    model = MagnetometerModel(lambda _t: FIELD_T, noise_T=20e-9, bias_T=(100e-9, -50e-9, 0.0), lsb_T=4e-9,
                              wire_lsb_T=1e-9, range_T=(-131072e-9, 131071e-9), rng=np.random.default_rng(3),
                              noise_block=64)
    b = np.array([model.measure(0.1 * k)[0] for k in range(4000)])
    counts = b / 4e-9
    assert np.allclose(counts, np.round(counts), atol=1e-6)  # on the 4 nT grid
    err = b - np.array(FIELD_T)
    assert err.mean(axis=0) == pytest.approx((100e-9, -50e-9, 0.0), abs=1.5e-9)  # 5 sigma of the mean: 1.6 nT
    # 20 nT of noise plus the 4 nT step's uniform error (4/sqrt(12) = 1.15 nT): 20.03 nT; 4000 samples give ~2 %.
    assert err.std(axis=0) == pytest.approx([math.hypot(20e-9, 4e-9 / math.sqrt(12))] * 3, rel=0.06)
    with pytest.raises(ValueError, match="lsb_T = 1.5e-09 T must be a whole multiple"):
        MagnetometerModel(lambda _t: FIELD_T, noise_T=0.0, bias_T=(0, 0, 0), lsb_T=1.5e-9, wire_lsb_T=1e-9,
                          range_T=(-1e-4, 1e-4), rng=np.random.default_rng(0), noise_block=1)


def test_a_saturated_field_is_clipped_and_flagged_not_valid(rig):
    emu_bus, host_bus = rig
    emu = MagnetometerEmulator(emu_bus, lambda _t: (500e-6, 0.0, 0.0), MagnetometerConfig(noise_T=0.0))
    host = MagnetometerHost(host_bus)
    emu.service(0.0)
    s = host.take_sample()
    assert not s.valid and s.b_T[0] == pytest.approx(131071e-9) and emu.counters["mag_saturations"] == 1


def test_the_magnetorquer_board_measures_through_the_same_model_with_the_same_random_stream(rig):
    """One sensor model: the board's magnetometer and a standalone unit on the same quantisation and seed read the
    same numbers (coils off)."""
    from drivers.magnetorquer.emulator import EmulatorConfig, MagnetorquerEmulator

    emu_bus, _ = rig
    board = MagnetorquerEmulator(emu_bus, lambda _t: FIELD_T, EmulatorConfig(mag_noise_T=30e-9, noise_block=16),
                                 rng=np.random.default_rng(11))
    unit = MagnetometerEmulator(emu_bus, lambda _t: FIELD_T,
                                MagnetometerConfig(noise_T=30e-9, bias_T=(200e-9, -150e-9, 100e-9), lsb_T=5e-9,
                                                   noise_block=16), rng=np.random.default_rng(11))
    assert type(board.magnetometer) is type(unit.sensor) is MagnetometerModel
    for k in range(40):  # across two noise blocks
        assert board.measure(0.1 * k).b_T == unit.measure(0.1 * k).b_T


def test_the_observer_sees_every_frame_beside_the_host_and_keeps_the_newest_good_sample():
    from drivers.can_observer import open_observer

    codec = MagnetometerCodec()
    emu_bus, host_bus = open_bus("stand_loopback", "mag-observer"), open_bus("stand_loopback", "mag-observer")
    observer = open_observer("stand_loopback", "mag-observer", codec, frozenset({codec.id_sample}), "observer")
    try:
        emu = MagnetometerEmulator(emu_bus, lambda _t: FIELD_T, MagnetometerConfig(noise_T=0.0))
        host = MagnetometerHost(host_bus)
        for k in range(3):
            emu.service(0.1 * k)
        observer.poll()
        assert observer.newest(codec.id_sample).seq == 2 and observer.seen[codec.id_sample] == 3
        assert host.counters["received"] == 0  # the host driver was never read
        host_bus.send(data_frame(codec.id_sample, bytes(3)))  # a cut frame on the sample's id
        observer.poll()
        assert observer.newest(codec.id_sample).seq == 2 and observer.rejected == 1
    finally:
        observer.close()
        emu_bus.shutdown()
        host_bus.shutdown()
