"""Fuzz the star tracker link: byte streams of garbage, bursts, silences and valid frames carrying
out-of-range values, into the host driver and into the emulator, over in-memory pipes and over a
real pty. The only exceptions allowed are the documented ones (EncodeError for a command the ICD
cannot carry, DeviceTimeoutError for a line that does not take a write); nothing hangs (every
example runs under a SIGALRM deadline); every good frame sent is received.

Deterministic: ``derandomize=True`` fixes the examples, so a run here is a run in CI.
"""

from __future__ import annotations

import os
import struct

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.dbc import DbcCodec
from drivers.errors import DeviceTimeoutError, EncodeError
from drivers.magnetorquer.codec import default_dbc_path
from drivers.serial_port import pty_pair
from drivers.star_tracker.codec import (
    CLASSES,
    FrameRejected,
    RequestTelemetry,
    SetParam,
    StarTrackerCodec,
    Subscribe,
    crc16,
)
from drivers.star_tracker.emulator import StarTrackerEmulator
from drivers.star_tracker.host import REJECT_REASONS, StarTrackerHost
from drivers.star_tracker.slip import escape

from ..drivers.star_tracker_helpers import FAST, Truth, pipe_pair
from .deadline import deadline

CODEC = StarTrackerCodec()
ADDR = CODEC.default_address
FUZZ = settings(derandomize=True, deadline=None, max_examples=120,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _field_value(f):
    """Any wire value the field's type can hold, in range or not (f32 from raw bits: NaN, inf too)."""
    if f.is_float:
        return st.one_of(st.integers(0, 2**32 - 1).map(lambda b: struct.unpack("<f", struct.pack("<I", b))[0]),
                         st.floats(-1.5, 1.5, width=32), st.sampled_from([0.0, -1.0, 1.0, 0.5]))
    lo, hi = {"u8": (0, 255), "u16": (0, 65535), "u32": (0, 2**32 - 1), "u64": (0, 2**64 - 1),
              "i16": (-(2**15), 2**15 - 1), "i32": (-(2**31), 2**31 - 1)}[f.type]
    return st.integers(lo, hi)


@st.composite
def raw_frame(draw, direction: str) -> bytes:
    """A SLIP frame with a valid CRC for a message of ``direction``, its fields anything their type holds."""
    spec = draw(st.sampled_from([s for s in CODEC.messages.values() if s.direction == direction]))
    values = [draw(_field_value(f)) for f in spec.fields]
    head = bytes((draw(st.sampled_from([ADDR, ADDR, ADDR, 0x22])), spec.id)) + struct.pack(spec.fmt, *values)
    return escape(head + crc16(head).to_bytes(2, "little"))


def _good_solution(seq: int) -> bytes:
    return CODEC.encode(CLASSES["SOLUTION"](
        time_us=seq, q_TN=(0.5, 0.5, -0.5, 0.5), sigma_cross_rad=1e-5, sigma_roll_rad=5e-5, stars_centroided=9,
        stars_matched=8, mode="TRACKING", valid=True, sun_in_field=False, moon_in_field=False,
        earth_in_field=False, rate_too_high=False, time_synced=False, stable_count=3, temperature_C=20.0, seq=seq),
        ADDR)


def device_stream():
    """What a misbehaving device may put on the line, as (kind, bytes) chunks."""
    return st.lists(st.one_of(
        st.tuples(st.just("garbage"), st.binary(max_size=200)),
        st.tuples(st.just("burst"), st.tuples(st.binary(min_size=1, max_size=8), st.integers(100, 5000)).map(
            lambda t: (t[0] * t[1])[:40_000])),
        st.tuples(st.just("silence"), st.just(b"")),
        st.tuples(st.just("odd"), raw_frame("device->host")),
        st.tuples(st.just("good"), st.integers(0, 65535).map(_good_solution)),
    ), max_size=25)


@FUZZ
@given(chunks=device_stream())
def test_host_takes_any_device_stream_and_receives_every_good_frame(chunks):
    a, b = pipe_pair()
    good = 0
    with deadline(30.0, "the host reading a fuzzed stream"), StarTrackerHost(a, max_read_bytes=8192) as h:
        for kind, data in chunks:
            b.write(data)
            good += kind == "good"
            h.take_solution()  # at most max_read_bytes per call; never raises on traffic
            assert h.counters["bytes_received"] <= b.written
        for _ in range(64):  # drain what a burst left behind, a bounded number of calls
            if not a.in_waiting:
                break
            h.poll()
        c = h.counters
        assert a.in_waiting == 0 and c["bytes_received"] == b.written
        assert c["solutions"] >= good  # a good frame is never lost behind garbage or a burst
        assert set(k for k in c if k.startswith("rejected_")) == {f"rejected_{r}" for r in REJECT_REASONS}
        if h.latest_solution is not None:  # whatever was accepted is physical
            assert abs(np.linalg.norm(h.latest_solution.q_TN) - 1.0) <= 5e-7
            assert h.latest_solution.sigma_cross_rad >= 0 and h.latest_solution.temperature_C >= -100


def host_stream():
    """What a host (or a line full of noise) may send to the tracker."""
    commands = st.one_of(
        st.builds(RequestTelemetry, st.sampled_from([CODEC.solution_id, CODEC.status_id, 0x55])),
        st.builds(Subscribe, st.sampled_from([CODEC.solution_id, CODEC.status_id]), st.sampled_from([0.0, 0.05])),
        st.builds(SetParam, st.integers(0, 12), st.floats(-1e3, 1e5, width=32)),
    ).map(lambda m: CODEC.encode(m, ADDR))
    return st.lists(st.one_of(
        st.tuples(st.just("garbage"), st.binary(max_size=200)),
        st.tuples(st.just("burst"), st.tuples(st.binary(min_size=1, max_size=8), st.integers(100, 5000)).map(
            lambda t: (t[0] * t[1])[:40_000])),
        st.tuples(st.just("silence"), st.just(b"")),
        st.tuples(st.just("odd"), raw_frame("host->device")),
        st.tuples(st.just("command"), commands),
        st.tuples(st.just("flood"), commands.map(lambda f: f * 400)),  # replies far beyond the tx queue
    ), max_size=20)


@FUZZ
@given(chunks=host_stream())
def test_emulator_serves_any_host_stream_without_raising_or_blocking(chunks):
    a, b = pipe_pair()
    emu = StarTrackerEmulator(b, Truth(), FAST, rng=5)
    try:
        with deadline(30.0, "the emulator serving a fuzzed stream"):
            t = 0.0
            for _, data in chunks:
                a.write(data)
                before = emu.counters["bytes_received"]
                emu.service(t)
                t += 0.013
                assert emu.counters["bytes_received"] - before <= emu.max_read_bytes  # bounded per call
                assert emu.tx_pending <= emu.max_tx_bytes
        c = emu.counters
        assert c["sent"] * 6 <= a.in_waiting  # every frame counted as sent is on the line, whole
    finally:
        emu.close()


@settings(derandomize=True, deadline=None, max_examples=25,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(chunks=host_stream(), reads=st.lists(st.booleans(), min_size=20, max_size=20))
def test_pty_link_never_hangs_whoever_stops_reading(chunks, reads):
    """Emulator on a real pty master, host through pyserial on the slave. The host side sometimes
    stops reading, so the emulator's replies pile up in the pty: it must drop, not block; the host's
    own writes must end in DeviceTimeoutError, not a hang."""
    master, slave_path, slave_fd = pty_pair()
    emu = StarTrackerEmulator(master, Truth(), FAST, rng=2)
    flood = CODEC.encode(RequestTelemetry(CODEC.status_id), ADDR) * 400
    try:
        with deadline(60.0, "the pty link"), StarTrackerHost(slave_path, write_timeout_s=0.05) as h:
            # 1. the host stops reading and floods requests: 3 x 400 STATUS replies (48 kB) cannot fit
            #    in the pty (about 20 kB), so the emulator drops whole frames instead of blocking
            for k in range(3):
                h.port.write(flood)
                for _ in range(4):
                    emu.service(0.01 * k)
            assert emu.counters["tx_dropped"] > 0
            # 2. the emulator stops reading: the host's writes end in DeviceTimeoutError, not a hang
            try:
                for _ in range(5000):
                    h.send_command(RequestTelemetry(CODEC.status_id))
            except DeviceTimeoutError:
                pass
            assert h.counters["write_timeouts"] == 1
            # 3. any mixture of the two, and of noise
            t = 0.0
            for i, (_, data) in enumerate(chunks):
                try:
                    h.port.write(data[:4096])  # raw bytes from the host side, bounded by pyserial's timeout
                except Exception as exc:  # noqa: BLE001 - only pyserial's write timeout is expected here
                    assert type(exc).__name__ == "SerialTimeoutException", exc
                try:
                    h.send_command(RequestTelemetry(CODEC.status_id))
                except DeviceTimeoutError:
                    pass  # documented: the emulator is not reading fast enough
                emu.service(t)
                t += 0.05
                if reads[i % len(reads)]:
                    h.poll()
            for _ in range(50):  # both sides read again: the link comes back
                emu.service(t)
                h.poll()
                t += 0.05
            assert emu.tx_pending <= emu.max_tx_bytes
    finally:
        emu.close()
        master.close()
        os.close(slave_fd)


@FUZZ
@given(body=st.binary(max_size=140))
def test_decoding_any_body_raises_only_frame_rejected(body):
    try:
        CODEC.decode_body(body, ADDR)
    except FrameRejected as exc:
        assert exc.kind in REJECT_REASONS


odd_values = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**70), 2**70), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=5), st.binary(max_size=3), st.lists(st.floats(-2, 2), max_size=5).map(tuple),
    st.sampled_from([10**400, complex(1, 1), np.array([1.0, 2.0]), np.float32(0.5), np.int64(3), object()]),
)


@FUZZ
@given(name=st.sampled_from(sorted(CLASSES)), data=st.data())
def test_star_tracker_encode_raises_only_encode_error(name, data):
    cls = CLASSES[name]
    kw = {f: data.draw(odd_values) for f in cls.__slots__}
    try:
        CODEC.encode(cls(**kw), ADDR)
    except EncodeError:
        pass


DBC = DbcCodec(default_dbc_path())


@FUZZ
@given(name=st.sampled_from(DBC.names), data=st.data())
def test_dbc_encode_raises_only_encode_error(name, data):
    signals = DBC.signal_names(name)
    values = {s: data.draw(st.one_of(odd_values, st.floats(-1e4, 1e4))) for s in signals}
    if data.draw(st.booleans()):
        values[data.draw(st.sampled_from(["extra", signals[0]]))] = data.draw(odd_values)
    try:
        DBC.encode(name, values)
    except EncodeError:
        pass
