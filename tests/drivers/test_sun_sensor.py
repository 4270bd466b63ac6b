"""Serial sun sensor (fine and coarse): codec round trips, the ICD document, and the host driver
against the emulator over an os.openpty() pair, fed by the sim models the stand uses. No test
measures time."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.datagram import DEVICE_TO_HOST, DatagramDecoder, DatagramRejected
from drivers.errors import DeviceTimeoutError, EncodeError
from drivers.sun_sensor import icd
from drivers.sun_sensor.codec import (
    CLASSES,
    CoarseSunSample,
    FineSunSample,
    RequestSample,
    SetOutputPeriod,
    SetTime,
    SunSensorCodec,
)
from drivers.sun_sensor.emulator import SunEmulatorConfig, SunSensorEmulator
from drivers.sun_sensor.host import SunSensorHost
from sim.sensors import CoarseSunSensors, FineSunSensor

from .datagram_helpers import PtyLink, datagram_strategy, wait_samples

REPO = Path(__file__).resolve().parents[2]
CODEC = SunSensorCodec()
SIX = np.vstack((np.eye(3), -np.eye(3)))


def test_icd_document_is_the_rendering_of_the_toml():
    doc = (REPO / "docs" / "sun_sensor_icd.md").read_text()
    assert doc == icd.render(CODEC), "regenerate: python -m drivers.sun_sensor.icd > docs/sun_sensor_icd.md"


def test_layout_is_little_endian_with_the_documented_lengths():
    assert {s.name: s.length for s in CODEC.messages.values()} == {
        "FINE_SAMPLE": 23, "COARSE_SAMPLE": 26, "SET_TIME": 11, "REQUEST_SAMPLE": 3, "SET_OUTPUT_PERIOD": 5}
    raw = CODEC.encode(FineSunSample(7, (0.25, -0.5), 0.9, True, False, 3))
    assert raw[0] == 0xA1 and int.from_bytes(raw[1:9], "little") == 7
    assert int.from_bytes(raw[9:13], "little", signed=True) == 250_000
    assert int.from_bytes(raw[13:17], "little", signed=True) == -500_000
    assert raw[17] == 90 and raw[18] == 1
    assert CODEC.encode(RequestSample()) == bytes([0x42]) + raw_crc(bytes([0x42]))


def raw_crc(head: bytes) -> bytes:
    from drivers.datagram import crc16

    return crc16(head).to_bytes(2, "little")


SPECS = list(CODEC.messages.values())


@pytest.mark.parametrize("spec", SPECS, ids=[s.name for s in SPECS])
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_every_datagram_round_trips_bytes_to_message_to_bytes(spec, data):
    raw = data.draw(datagram_strategy(CODEC, spec))
    msg = CODEC.decode(raw)
    assert type(msg) is CLASSES[spec.name]
    assert CODEC.encode(msg) == raw


angles = st.integers(-1_600_000, 1_600_000).map(lambda k: k * 1e-6)
currents = st.integers(0, 65535).map(lambda k: k * 1e-7)


@settings(max_examples=100, deadline=None)
@given(t=st.integers(0, 2 ** 64 - 1), a=st.tuples(angles, angles), i=st.integers(0, 100), flags=st.tuples(
    st.booleans(), st.booleans(), st.booleans()), seq=st.integers(0, 65535),
    c=st.tuples(*[currents] * 6), p=st.integers(0, 60000))
def test_messages_round_trip_message_to_bytes_to_message(t, a, i, flags, seq, c, p):
    for msg in (FineSunSample(t, a, i * 0.01, flags[0], flags[1], seq),
                CoarseSunSample(t, c, *flags, seq), SetTime(t), RequestSample(), SetOutputPeriod(p * 1e-3)):
        assert CODEC.decode(CODEC.encode(msg)) == msg


def test_encode_and_decode_errors_name_field_value_and_range():
    with pytest.raises(EncodeError, match=r"FINE_SAMPLE.alpha = .*allowed -1600000 to 1600000"):
        CODEC.encode(FineSunSample(0, (2.0, 0.0), 1.0, True, False, 0))
    with pytest.raises(EncodeError, match=r"SET_OUTPUT_PERIOD.period"):
        CODEC.encode(SetOutputPeriod(61.0))
    bad = bytearray(CODEC.encode(FineSunSample(0, (0.0, 0.0), 1.0, True, False, 0)))
    bad[17] = 101  # intensity above 100 %, with a good CRC
    bad[-2:] = raw_crc(bytes(bad[:-2]))
    with pytest.raises(DatagramRejected, match="intensity = 101 is outside its range") as ei:
        CODEC.decode(bytes(bad))
    assert ei.value.kind == "value"
    dec = DatagramDecoder(CODEC, DEVICE_TO_HOST)
    assert dec.feed(bytes(bad)) == [] and dec.counters["value_errors"] == 1


# -- emulator + host over a pty pair, fed by the sim models ------------------------------------------


class Sun:
    """The stand's source: the sim model measuring a settable Sun direction."""

    def __init__(self, model, s_B=(0.2, -0.1, 1.0), nu: float = 1.0) -> None:
        self.model = model
        self.s_B = np.array(s_B, dtype=float)
        self.nu = nu
        self.calls: list[float] = []

    def __call__(self, t: float):
        self.calls.append(t)
        s = self.s_B / np.linalg.norm(self.s_B)
        if isinstance(self.model, FineSunSensor):
            ang, ok = self.model.measure(s, self.nu)
            return ang, bool(ok), self.nu
        return self.model.measure(s, self.nu), self.nu > 0.0


def _link(kind: str, source: Sun, period: float = 0.1) -> PtyLink:
    cfg = SunEmulatorConfig(kind=kind, output_period_s=period)
    return PtyLink(lambda port: SunSensorEmulator(port, source, cfg), lambda path: SunSensorHost(path, name="sun-test"))


def _read(host: SunSensorHost):
    return host.read_sun(2.0)


def test_fine_sensor_angles_reach_the_host_quantised_to_a_microradian():
    sun = Sun(FineSunSensor(np.eye(3), fov_half_deg=60.0))
    with _link("fine", sun) as link:
        link.step(0.0)
        s = _read(link.host)
        s_B = sun.s_B / np.linalg.norm(sun.s_B)
        want = (math.atan2(s_B[0], s_B[2]), math.atan2(s_B[1], s_B[2]))
        assert isinstance(s, FineSunSample) and s.valid and s.intensity == 1.0
        assert s.angles_rad == pytest.approx(want, abs=0.5e-6)
        assert s.time_us == 0 and s.seq == 0
        sun.nu = 0.0  # umbra: not valid, angles sent as 0
        link.step(0.1)
        s = _read(link.host)
        assert not s.valid and s.angles_rad == (0.0, 0.0) and s.intensity == 0.0 and s.time_us == 100_000
        assert link.host.take_sun() is None


def test_coarse_sensor_currents_and_saturation():
    model = CoarseSunSensors(SIX, i_max_A=1e-3)
    sun = Sun(model, s_B=(1.0, 1.0, 0.0))
    with _link("coarse", sun) as link:
        link.step(0.0)
        s = _read(link.host)
        assert isinstance(s, CoarseSunSample) and s.valid and not s.saturated
        want = 1e-3 * np.maximum(SIX @ (sun.s_B / np.linalg.norm(sun.s_B)), 0.0)
        np.testing.assert_allclose(s.currents_A, want, atol=0.5e-7)
        link.emu.source = lambda t: ([7e-3, 0, 0, 0, 0, 0], True)  # beyond the 6.5535 mA field
        link.step(0.1)
        s = _read(link.host)
        assert s.saturated and not s.valid and s.currents_A[0] == pytest.approx(6.5535e-3)
        assert link.emu.counters["saturations"] == 1


def test_request_set_time_and_output_period():
    sun = Sun(FineSunSensor(np.eye(3)))
    with _link("fine", sun, period=0.0) as link:
        link.step(0.0)
        link.step(1.0)
        assert link.host.take_sun() is None  # period 0: nothing unasked
        link.host.set_time(5_000_000)
        link.host.send(RequestSample())
        link.step(1.5)
        s = _read(link.host)
        assert s.time_synced and s.time_us == 5_000_000 and link.emu.counters["requests"] == 1
        link.host.set_output_period(0.25)
        link.step(2.0)
        link.step(2.3)  # due at 2.25: measured then
        s = _read(link.host)
        assert s.time_us == 5_000_000 + 750_000 and sun.calls[-1] == pytest.approx(2.25)
        assert link.host.counters["samples_lost"] == 0 and link.host.counters["rejected_crc"] == 0


def test_a_late_service_sends_the_newest_sample_and_the_host_sees_the_gap():
    sun = Sun(FineSunSensor(np.eye(3)))
    with _link("fine", sun, period=0.1) as link:
        link.step(0.0)
        link.step(0.55)  # slots 0.1 .. 0.5 due: one sent, measured at 0.5
        assert link.emu.counters["samples_skipped"] == 4 and sun.calls[-1] == pytest.approx(0.5)
        wait_samples(link.host, 2)
        assert link.host.take_sun().seq == 1  # the newest of the two sent so far
        link.step(0.6)
        wait_samples(link.host, 3)
        assert link.host.take_sun().seq == 2
        assert link.host.counters["samples_lost"] == 0  # skipped slots never got a counter value


def test_request_sun_over_a_wall_clock_served_pty_and_a_timeout():
    sun = Sun(FineSunSensor(np.eye(3)))
    with _link("fine", sun, period=0.0) as link:
        with pytest.raises(DeviceTimeoutError, match="no sun sample within 0.05 s"):
            link.host.read_sun(0.05)
        link.serve()
        s = link.host.request_sun(2.0)
        assert s.valid and link.host.online and link.host.counters["recoveries"] == 1


def test_a_source_that_returns_nonsense_is_named():
    with _link("coarse", lambda t: ([1e-4] * 5, True)) as link, pytest.raises(ValueError, match="6 head currents"):
        link.step(0.0)
    with pytest.raises(ValueError, match="kind must be one of fine, coarse"):
        SunEmulatorConfig(kind="medium")
