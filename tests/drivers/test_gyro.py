"""Serial gyro: codec round trips and stream decoding, the ICD document, and the host driver
against the emulator over an os.openpty() pair (the test services the emulator in sim time, or a
thread serves it in wall-clock time). No test measures time."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.datagram import DEVICE_TO_HOST, DatagramDecoder, DatagramRejected, crc16, take_datagram
from drivers.errors import DeviceTimeoutError, EncodeError
from drivers.gyro import icd
from drivers.gyro.codec import CLASSES, GyroCodec, GyroRate, SetOutputPeriod, SetTime
from drivers.gyro.emulator import GyroEmulator, GyroEmulatorConfig
from drivers.gyro.host import GyroHost
from tests.oracles import require_tool

from .datagram_helpers import PtyLink, datagram_strategy

REPO = Path(__file__).resolve().parents[2]
CODEC = GyroCodec()
LSB = CODEC.rate_lsb_rad_s


def _rate(**kw) -> GyroRate:
    base = dict(omega_rad_s=(1000 * LSB, -2 * LSB, 0.0), valid=True, saturated_x=False, saturated_y=False,
                saturated_z=False, startup=False, time_synced=True, seq=7, latency_s=500e-6, time_us=123_456_789)
    base.update(kw)
    return GyroRate(**base)


# -- ICD ------------------------------------------------------------------------------------------


def test_icd_document_is_the_rendering_of_the_toml():
    doc = (REPO / "docs" / "gyro_icd.md").read_text()
    assert doc == icd.render(CODEC), "regenerate: python -m drivers.gyro.icd > docs/gyro_icd.md"


def test_rate_lsb_is_2_to_the_minus_14_deg_s_and_the_layout_is_the_documented_one():
    assert LSB == math.radians(2.0 ** -14)
    assert CODEC.messages["RATE"].length == 24
    raw = CODEC.encode(_rate())
    assert raw[0] == 0x93
    assert int.from_bytes(raw[1:4], "big", signed=True) == 1000  # rate_x, 24-bit big-endian
    assert int.from_bytes(raw[4:7], "big", signed=True) == -2
    assert raw[10] == 0b100001  # valid, time_synced
    assert int.from_bytes(raw[12:14], "big") == 500
    assert int.from_bytes(raw[14:22], "big") == 123_456_789
    assert int.from_bytes(raw[22:24], "big") == crc16(raw[:22])


def test_codec_refuses_an_icd_whose_fields_do_not_match_the_dataclasses(tmp_path):
    text = (REPO / "fixtures" / "devices" / "gyro.toml").read_text()
    (tmp_path / "g.toml").write_text(text.replace('attr = "latency_s"', 'attr = "delay_s"'))
    with pytest.raises(ValueError, match="RATE maps fields to .*delay_s"):
        GyroCodec(tmp_path / "g.toml")


# -- round trips ----------------------------------------------------------------------------------

SPECS = list(CODEC.messages.values())


@pytest.mark.parametrize("spec", SPECS, ids=[s.name for s in SPECS])
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_every_datagram_round_trips_bytes_to_message_to_bytes(spec, data):
    raw = data.draw(datagram_strategy(CODEC, spec))
    try:
        msg = CODEC.decode(raw)
    except DatagramRejected as exc:  # only the ICD's narrower ranges may refuse a well-formed datagram
        assert exc.kind == "value" and spec.name == "SET_OUTPUT_PERIOD"
        return
    assert type(msg) is CLASSES[spec.name]
    assert CODEC.encode(msg) == raw


rates = st.integers(-(2 ** 23), 2 ** 23 - 1).map(lambda k: k * LSB)


@settings(max_examples=100, deadline=None)
@given(w=st.tuples(rates, rates, rates), flags=st.lists(st.booleans(), min_size=6, max_size=6),
       seq=st.integers(0, 255), lat=st.integers(0, 65535), t=st.integers(0, 2 ** 64 - 1))
def test_rate_round_trips_message_to_bytes_to_message(w, flags, seq, lat, t):
    msg = GyroRate(w, *flags, seq=seq, latency_s=lat * 1e-6, time_us=t)
    assert CODEC.decode(CODEC.encode(msg)) == msg


@given(t=st.integers(0, 2 ** 64 - 1), p=st.integers(500, 1_000_000))
def test_commands_round_trip(t, p):
    assert CODEC.decode(CODEC.encode(SetTime(t))) == SetTime(t)
    assert CODEC.decode(CODEC.encode(SetOutputPeriod(p * 1e-6))) == SetOutputPeriod(p * 1e-6)


def test_encode_errors_name_the_field_the_value_and_the_range():
    with pytest.raises(EncodeError, match=r"gyro RATE.rate_y = .* outside the field: allowed -8388608 to 8388607"):
        CODEC.encode(_rate(omega_rad_s=(0.0, 10.0, 0.0)))
    with pytest.raises(EncodeError, match=r"SET_OUTPUT_PERIOD.period = 100.* allowed 500 to 1000000"):
        CODEC.encode(SetOutputPeriod(1e-4))
    with pytest.raises(EncodeError, match="not a number"):
        CODEC.encode(SetTime("soon"))  # type: ignore[arg-type]


def test_bad_crc_length_and_identifier_are_rejected_with_the_datagram_in_hex():
    raw = bytearray(CODEC.encode(_rate()))
    raw[5] ^= 0x01
    with pytest.raises(DatagramRejected) as ei:
        CODEC.decode(bytes(raw))
    e = ei.value
    assert e.kind == "crc" and e.frame_hex == bytes(raw).hex().upper()
    assert "0x" in str(e.expected) and "expected" in str(e) and "got" in str(e)
    with pytest.raises(DatagramRejected, match="wrong length") as ei:
        CODEC.decode(CODEC.encode(_rate())[:-1])
    assert ei.value.kind == "length"
    with pytest.raises(DatagramRejected, match="unknown gyro identifier 0x77"):
        CODEC.decode(b"\x77\x00\x00")
    with pytest.raises(DatagramRejected, match="sent host->device, not device->host"):
        CODEC.decode(CODEC.encode(SetTime(1)), DEVICE_TO_HOST)


# -- stream decoding ------------------------------------------------------------------------------


def _stream(n: int = 5) -> tuple[bytes, list[GyroRate]]:
    msgs = [_rate(seq=i, time_us=1000 * i, omega_rad_s=(i * LSB, 0x93 * LSB, -i * LSB)) for i in range(n)]
    return b"".join(CODEC.encode(m) for m in msgs), msgs


def test_take_datagram_reports_bytes_consumed():
    lengths = {0x93: 24}
    raw = CODEC.encode(_rate())
    assert take_datagram(raw[:10], lengths, "big") == (0, None)  # need more
    assert take_datagram(b"\x00\x01" + raw, lengths, "big") == (2, None)  # drop up to the identifier
    assert take_datagram(raw, lengths, "big") == (24, raw)
    bad = bytes([raw[0], raw[1] ^ 0xFF]) + raw[2:]
    assert take_datagram(bad, lengths, "big") == (1, None)  # a bad CRC costs one byte


def test_decoder_whole_split_at_every_position_and_byte_by_byte():
    raw, msgs = _stream()
    assert DatagramDecoder(CODEC, DEVICE_TO_HOST).feed(raw) == msgs
    for cut in range(len(raw) + 1):
        dec = DatagramDecoder(CODEC, DEVICE_TO_HOST)
        assert dec.feed(raw[:cut]) + dec.feed(raw[cut:]) == msgs
    dec = DatagramDecoder(CODEC, DEVICE_TO_HOST)
    assert [m for b in raw for m in dec.feed(bytes([b]))] == msgs
    assert dec.counters == {"datagrams": 5, "crc_errors": 0, "value_errors": 0, "bytes_dropped": 0, "undecodable": 0}


def test_decoder_resynchronises_after_a_corrupted_datagram_and_garbage():
    raw, msgs = _stream(4)
    corrupted = bytearray(raw)
    corrupted[24 + 3] ^= 0x40  # the second datagram
    dec = DatagramDecoder(CODEC, DEVICE_TO_HOST)
    out = dec.feed(b"\x93\x93garbage" + bytes(corrupted))
    assert out == [msgs[0], msgs[2], msgs[3]]
    assert dec.counters["crc_errors"] >= 3 and dec.counters["datagrams"] == 3
    # Two bad stretches (the garbage, the corrupted datagram), however many false starts they held.
    assert dec.counters["undecodable"] == 2


@settings(max_examples=80, deadline=None)
@given(junk=st.binary(max_size=80), cut=st.integers(0, 48))
def test_decoder_survives_arbitrary_bytes_and_serves_the_next_good_datagrams(junk, cut):
    raw, msgs = _stream(3)
    dec = DatagramDecoder(CODEC, DEVICE_TO_HOST)
    out = dec.feed(junk + raw[:cut]) + dec.feed(raw[cut:])
    # Junk may hide (at most) the datagram it runs into, never the ones after it.
    assert out[-2:] == msgs[-2:]


# -- emulator + host over a pty pair, serviced in sim time ------------------------------------------


class Rate:
    """A settable rate source: what the stand would hand the emulator."""

    def __init__(self, w=(0.01, -0.02, 0.003)) -> None:
        self.w = w
        self.calls: list[float] = []

    def __call__(self, t: float):
        self.calls.append(t)
        return self.w


def _link(config: GyroEmulatorConfig | None = None, source=None) -> PtyLink:
    src = source or Rate()
    link = PtyLink(lambda port: GyroEmulator(port, src, config), lambda path: GyroHost(path, name="gyro-under-test"))
    link.source = src  # type: ignore[attr-defined]
    return link


def _drain(host: GyroHost, want: int) -> list[GyroRate]:
    """Read until ``want`` RATE datagrams arrived in all; the newest of each batch read."""
    out: list[GyroRate] = []
    for _ in range(200):
        if host.counters["samples"] >= want:
            break
        before = host.counters["samples"]
        host.poll()
        if host.counters["samples"] == before:
            host._read(block=True)
        if host.counters["samples"] > before:
            out.append(host.latest_rate)  # type: ignore[arg-type]
    return out


def test_samples_at_the_output_rate_carry_the_source_rate_quantised_and_time_stamped():
    with _link(GyroEmulatorConfig(output_period_s=0.01)) as link:
        for k in range(11):
            link.step(0.1 * k / 10)
        host = link.host
        _drain(host, 11)
        assert host.counters["samples"] == 11 and host.counters["samples_lost"] == 0
        r = host.take_rate()
        assert host.take_rate() is None  # each sample handed out once
        assert r.seq == 10 and r.valid and not r.startup and not r.time_synced
        assert r.time_us == 100_000  # sample time 0.1 s in the device clock
        for got, want in zip(r.omega_rad_s, (0.01, -0.02, 0.003), strict=True):
            assert abs(got - want) <= LSB / 2
        assert link.source.calls == pytest.approx([0.01 * k for k in range(11)])
        assert host.counters["rejected_crc"] == host.counters["bytes_dropped"] == 0


def test_a_late_service_sends_every_missed_sample_at_its_own_time_up_to_max_burst():
    src = Rate()
    with _link(GyroEmulatorConfig(output_period_s=0.01, max_burst=5), src) as link:
        link.step(0.0)
        link.step(0.035)  # samples at 0.01, 0.02, 0.03
        assert src.calls == pytest.approx([0.0, 0.01, 0.02, 0.03])
        link.step(0.2)  # 17 due, the newest 5 sent
        assert link.emu.counters["samples_skipped"] == 12
        assert src.calls[-5:] == pytest.approx([0.16, 0.17, 0.18, 0.19, 0.2])
        _drain(link.host, 9)
        assert link.host.counters["samples_lost"] == 12


def test_saturation_startup_and_set_time_show_in_the_flags():
    src = Rate((0.0, 8.0, -0.1))
    cfg = GyroEmulatorConfig(output_period_s=0.05, startup_time_s=0.1, range_rad_s=math.radians(300))
    with _link(cfg, src) as link:
        link.step(0.0)
        (r0,) = _drain(link.host, 1)
        assert r0.startup and not r0.valid and r0.saturated_y and not r0.saturated_x
        assert r0.omega_rad_s[1] == pytest.approx(math.radians(300), abs=LSB)
        src.w = (0.0, 0.1, 0.0)
        link.host.set_time(1_790_000_000_000_000)
        link.step(0.1)
        link.step(0.15)
        rates = _drain(link.host, 4)
        last = rates[-1]
        assert last.valid and not last.startup and last.time_synced
        assert last.time_us == 1_790_000_000_000_000 + 50_000  # set at 0.1 s, sample at 0.15 s
        assert link.emu.counters["saturations"] == 1 and link.emu.counters["commands_applied"] == 1


def test_set_output_period_moves_the_sample_grid():
    with _link(GyroEmulatorConfig(output_period_s=0.1)) as link:
        link.step(0.0)
        link.host.set_output_period(0.02)
        link.step(0.05)  # command applied at 0.05: samples now at 0.07, 0.09, ...
        link.step(0.1)
        assert link.source.calls == pytest.approx([0.0, 0.07, 0.09])
        assert link.emu.period_s == pytest.approx(0.02)
    with pytest.raises(EncodeError, match="period"):
        GyroHost("loop://").set_output_period(2.0)


def test_a_source_that_returns_nonsense_is_named():
    with _link(source=lambda t: (1.0, float("nan"), 0.0)) as link, pytest.raises(ValueError, match="rate_source"):
        link.step(0.0)


def test_bad_commands_are_counted_by_the_emulator_and_never_raise():
    with _link() as link:
        link.step(0.0)
        bad = bytearray(CODEC.encode(SetTime(5)))
        bad[-1] ^= 1
        out_of_range = bytes([0x52]) + (100).to_bytes(4, "big")
        out_of_range += crc16(out_of_range).to_bytes(2, "big")
        link.host.port.write(bytes(bad) + b"\x00junk" + out_of_range + CODEC.encode(SetTime(5)))
        link.step(0.01)
        c = link.emu.counters
        assert c["rejected_crc"] >= 1 and c["rejected_other"] == 1 and c["commands_applied"] == 1
        assert link.emu.time_synced


def test_read_rate_times_out_naming_the_device_and_what_was_awaited():
    with _link() as link:
        with pytest.raises(DeviceTimeoutError) as ei:
            link.host.read_rate(timeout_s=0.05)
        e = ei.value
        assert e.device == "gyro-under-test" and e.awaited == "RATE datagram" and e.timeout_s == 0.05
        assert "nothing has been received yet" in str(e)
        assert not link.host.online


def test_wall_clock_serving_thread_streams_to_the_host():
    with _link(GyroEmulatorConfig(output_period_s=0.005)) as link:
        link.serve()
        a = link.host.read_rate(2.0)
        b = link.host.read_rate(2.0)
        assert b.time_us > a.time_us and b.valid
        assert link.host.online and link.host.counters["rejected_crc"] == 0


def test_emulator_config_errors_are_named():
    with pytest.raises(ValueError, match="output_period_s = 2"):
        GyroEmulator("loop://", Rate(), GyroEmulatorConfig(output_period_s=2.0))
    with pytest.raises(ValueError, match="max_burst"):
        GyroEmulatorConfig(max_burst=0)


# -- two processes over a socat pty pair: pyserial at both ends ------------------------------------

_EMULATOR_SCRIPT = """
import sys
from drivers.gyro.emulator import GyroEmulator, GyroEmulatorConfig
emu = GyroEmulator(sys.argv[1], lambda t: (0.01, 0.02, -0.03), GyroEmulatorConfig(output_period_s=0.01))
emu.run(float(sys.argv[2]))
emu.close()
"""


def test_gyro_emulator_in_another_process_over_a_socat_pty_pair(tmp_path):
    require_tool("socat", "socat")
    a, b = tmp_path / "ttyGY_A", tmp_path / "ttyGY_B"
    socat = subprocess.Popen(["socat", f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    proc = None
    try:
        for _ in range(500):
            if a.exists() and b.exists():
                break
            time.sleep(0.01)
        assert a.exists() and b.exists(), "socat did not create its pty pair"
        proc = subprocess.Popen([sys.executable, "-c", _EMULATOR_SCRIPT, str(b), "20"], cwd=REPO,
                                env={**os.environ, "PYTHONPATH": str(REPO)},
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        with GyroHost(str(a), timeout_s=10.0) as host:
            rates = [host.read_rate()]  # the emulator is up: a command sent now is read
            host.set_time(1_000_000_000)
            for _ in range(200):  # SET_TIME reaches the other process within a few samples
                if rates[-1].time_synced:
                    break
                rates.append(host.read_rate())
            assert rates[-1].time_synced
            last = host.read_rate()  # measured after the clock was set
            # A sample is stamped with its measurement instant, which may precede the SET_TIME by up to an
            # output period plus the latency (more under load): the stamp is on the new time base, not the old.
            assert last.time_synced and last.time_us >= 1_000_000_000 - 100_000
            assert last.omega_rad_s == pytest.approx((0.01, 0.02, -0.03), abs=LSB)
            assert host.counters["rejected_crc"] == 0
    finally:
        if proc is not None:
            proc.kill()
            proc.communicate(timeout=10)
        socat.send_signal(signal.SIGTERM)
        socat.wait(5)


def test_a_failed_port_raises_connect_error_and_is_reopened_on_the_next_call():
    from drivers.errors import ConnectError

    with GyroHost("loop://", name="gyro-loop") as host:
        def broken(*_a, **_k):
            raise OSError(5, "Input/output error")

        host.port.read = broken
        host.port.write(CODEC.encode(_rate()))  # something to read, so read() is called
        with pytest.raises(ConnectError, match="gyro-loop: cannot read from .*reopened on the next call"):
            host.poll()
        assert not host.online
        host.poll()  # reopens a fresh loop:// port
        assert host.counters["reconnects"] == 1
        host.port.write(CODEC.encode(_rate(seq=9)))  # loop:// reads back what is written
        assert host.take_rate().seq == 9 and host.online and host.counters["recoveries"] == 1
