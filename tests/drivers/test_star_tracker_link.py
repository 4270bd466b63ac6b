"""Star tracker host driver against the emulator over a real serial path (an os.openpty() pair,
the emulator served by a thread), plus the host fed arbitrary bytes on an in-memory pipe.

Timeouts here only check that a deadline is honoured and reported; latency is measured by
``stand bench tracker-link``, never in a test."""

from __future__ import annotations

import math
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.errors import ConnectError, DeviceTimeoutError, EncodeError
from drivers.star_tracker.codec import NackError, RequestTelemetry, Solution, StarTrackerCodec
from drivers.star_tracker.emulator import EmulatorConfig
from drivers.star_tracker.host import StarTrackerHost
from drivers.star_tracker.slip import escape

from .star_tracker_helpers import FAST, PtyRig, pipe_pair

CODEC = StarTrackerCodec()


def _solution(seq: int = 5) -> Solution:
    return Solution(time_us=42, q_TN=(1.0, 0.0, 0.0, 0.0), sigma_cross_rad=0.0, sigma_roll_rad=0.0,
                    stars_centroided=10, stars_matched=9, mode="TRACKING", valid=True, sun_in_field=False,
                    moon_in_field=False, earth_in_field=False, rate_too_high=False, time_synced=False,
                    stable_count=3, temperature_C=20.0, seq=seq)


def _wait_ready(host: StarTrackerHost, tries: int = 300) -> Solution:
    for _ in range(tries):  # the first solution comes one output delay after boot: wait for it
        try:
            return host.request_solution()
        except NackError as exc:
            assert exc.error == "NOT_READY"
            time.sleep(0.01)
    raise AssertionError("the emulator never produced a solution")


def test_solution_round_trip_and_commands_over_a_pty_pair():
    with PtyRig() as rig:
        h = rig.host
        sol = _wait_ready(h)
        assert sol.q_TN[0] == pytest.approx(1.0, abs=1e-6) and sol.mode in ("LOST_IN_SPACE", "TRACKING")
        h.set_time(1_790_000_000_000_000)
        assert h.request_status().time_synced
        h.set_param("rate_limit", math.radians(0.25))
        assert h.get_param("rate_limit") == pytest.approx(math.radians(0.25), rel=1e-6)
        h.subscribe("SOLUTION", 0.0)
        a = h.wait_solution(2.0)
        b = h.wait_solution(2.0)
        assert b.seq == (a.seq + 1) % 65536 and b.time_us - a.time_us == pytest.approx(50_000, abs=5)
        assert a.time_synced and a.time_us > 1_790_000_000_000_000
        h.unsubscribe("SOLUTION")
        h.reset_counters()
        c = h.counters
        assert sum(v for k, v in c.items() if k.startswith("rejected_")) == c["timeouts"] == 0
        assert c["acks"] == 5 and c["solutions"] >= 3 and c["sent"] >= 7
        assert rig.emu.counters["frames_received"] == c["sent"]


def test_host_reports_a_timeout_when_the_device_goes_silent_and_recovers_when_it_returns():
    with PtyRig(timeout_s=0.3) as rig:
        h = rig.host
        _wait_ready(h)
        rig.emu.silent = True
        with pytest.raises(DeviceTimeoutError) as ei:
            h.request_solution(timeout_s=0.2)
        e = ei.value
        assert e.device == "tracker-under-test" and e.awaited == "SOLUTION" and e.timeout_s == 0.2
        assert "tracker-under-test: no SOLUTION from address 0x21 within 0.2 s" in str(e)
        assert not h.online and h.counters["timeouts"] == 1
        rig.emu.silent = False
        sol = h.request_solution()
        assert isinstance(sol, Solution) and h.online and h.counters["recoveries"] == 1


def test_a_nack_raises_naming_the_command_and_the_error():
    with PtyRig(EmulatorConfig(boot_time_s=60.0)) as rig:
        with pytest.raises(NackError, match="refused REQUEST_TELEMETRY .*NOT_READY") as ei:
            rig.host.request_solution()
        assert (ei.value.command, ei.value.error) == ("REQUEST_TELEMETRY", "NOT_READY")
        assert rig.host.counters["nacks"] == 1


def test_host_refuses_bad_arguments_before_sending():
    a, _ = pipe_pair()
    with StarTrackerHost(a, name="st") as h:
        with pytest.raises(EncodeError, match="rate_limit .* allowed: a number from 0.01 to 20 deg/s"):
            h.set_param("rate_limit", 1.0)  # 57 deg/s
        with pytest.raises(EncodeError, match="telemetry = 'IMAGE' is not allowed; allowed: SOLUTION, STATUS"):
            h.subscribe("IMAGE")
        assert h.counters["sent"] == 0 and a.written == 0
    with pytest.raises(EncodeError, match="address = 256"):
        StarTrackerHost(pipe_pair()[0], address=256)
    with pytest.raises(ConnectError, match="cannot open serial port '/nonexistent/tty'"):
        StarTrackerHost("/nonexistent/tty")


def test_close_is_idempotent_and_a_closed_host_refuses():
    a, _ = pipe_pair()
    h = StarTrackerHost(a)
    h.close()
    h.close()
    assert h.closed and a.is_open  # the caller's port is the caller's
    with pytest.raises(Exception, match="closed; create a new one"):
        h.poll()


@settings(max_examples=150, deadline=None)
@given(junk=st.binary(max_size=300), cut=st.integers(0, 60))
def test_host_survives_arbitrary_bytes_and_takes_the_next_good_frame(junk, cut):
    a, b = pipe_pair()
    with StarTrackerHost(a) as h:
        good = CODEC.encode(_solution(seq=1234))
        b.write(junk + good[:cut])
        h.poll()
        b.write(good[cut:])
        got = h.take_solution()
        assert got == _solution(seq=1234)
        assert h.take_solution() is None  # taken once
        assert h.counters["bytes_received"] == len(junk) + len(good)


def test_host_counts_each_kind_of_bad_frame():
    a, b = pipe_pair()
    with StarTrackerHost(a) as h:
        body = bytearray(CODEC.encode_body(_solution()))
        body[5] ^= 0xFF
        b.write(escape(bytes(body)))  # bad CRC
        b.write(CODEC.encode(_solution(), 0x22))  # another tracker
        b.write(b"\xc0" + bytes(300) + b"\xc0")  # oversize
        b.write(b"\xc0\x21\xdb\x00\xc0")  # bad escape
        b.write(CODEC.encode(RequestTelemetry(0x90)))  # a command: wrong direction for the host
        b.write(escape(b"\x21\x90"))  # short
        b.write(CODEC.encode(_solution(seq=9)))
        h.poll()
        c = h.counters
        got = {k[len("rejected_"):]: v for k, v in c.items() if k.startswith("rejected_") and v}
        assert got == {"crc": 1, "address": 1, "oversize": 1, "bad_escape": 1, "direction": 1, "short": 1}
        assert h.take_solution().seq == 9 and c["frames_received"] == 1


def test_fast_config_is_within_the_icd_parameter_ranges():
    assert FAST.output_interval_s >= CODEC.param("output_interval").lo * 1e-3


def test_host_reopens_a_url_port_after_it_failed():
    import serial

    with StarTrackerHost("loop://", timeout_s=0.05) as h:
        broken = h.port

        def fail(*_a):
            raise serial.SerialException("device disconnected")

        broken.read = fail
        broken.in_waiting  # noqa: B018 - still answers; the read fails
        with pytest.raises(ConnectError, match="cannot read from .*device disconnected; the port will be reopened"):
            h.request_status()
        assert not h.online
        # loop:// echoes the host's own request: a command is the wrong direction for a host, so it is
        # counted, and the request times out, but on a fresh port object
        with pytest.raises(DeviceTimeoutError):
            h.request_status()
        assert h.port is not broken and h.counters["reconnects"] == 1 and h.counters["rejected_direction"] == 1


def test_single_threaded_loop_send_command_then_service_then_take_solution():
    from drivers.star_tracker.codec import Subscribe
    from drivers.star_tracker.emulator import StarTrackerEmulator, TrackerTruth

    a, b = pipe_pair()
    cfg = EmulatorConfig(boot_time_s=0.0, output_interval_s=0.2, output_delay_s=0.1)
    with StarTrackerHost(a) as h, StarTrackerEmulator(b, lambda t: TrackerTruth(q_TN=(1, 0, 0, 0)), cfg) as emu:
        h.send_command(Subscribe(CODEC.solution_id, 0.0))
        got = []
        for k in range(11):  # a 0.1 s tick: service the device, then read what it published
            emu.service(0.1 * k)
            s = h.take_solution()
            if s is not None:
                got.append((k, s.time_us))
        assert got == [(1, 0), (3, 200_000), (5, 400_000), (7, 600_000), (9, 800_000)]
        assert h.counters["acks"] == 1 and h.counters["timeouts"] == 0
