"""What a sample costs on the serial half of the chain (issue 26): every SOLUTION and RATE still crosses its ICD
codec and its framing, in a bounded number of calls (counted, not timed: the count does not depend on the load),
and the SLIP unescaping that the tracker's frames go through reads every chunk as RFC 1055 says."""

from __future__ import annotations

import itertools
import sys
from dataclasses import replace

import pytest

from drivers.datagram import DEVICE_TO_HOST, DatagramDecoder
from drivers.framing import END, ESC, ESC_END, ESC_ESC, SlipDecoder, escape, unescape
from drivers.gyro.codec import GyroCodec, GyroRate
from drivers.star_tracker.codec import Solution, StarTrackerCodec

SOLUTION = Solution(time_us=123_456_789, q_TN=(0.5, 0.5, -0.5, 0.5), sigma_cross_rad=2.0 ** -16,
                    sigma_roll_rad=2.0 ** -14, stars_centroided=14, stars_matched=12, mode="TRACKING", valid=True,
                    sun_in_field=False, moon_in_field=False, earth_in_field=True, rate_too_high=False,
                    time_synced=True, stable_count=9, temperature_C=21.5, seq=77)
RATE = GyroRate(omega_rad_s=(1e-3, -2e-3, 3e-4), valid=True, saturated_x=False, saturated_y=False,
                saturated_z=True, startup=False, time_synced=False, seq=5, latency_s=5e-4, time_us=1000)


def _calls(fn) -> int:
    """Python and C function calls made inside ``fn()`` (sys.setprofile's call events)."""
    n = 0

    def hook(frame, event, arg):
        nonlocal n
        if event in ("call", "c_call"):
            n += 1

    sys.setprofile(hook)
    try:
        fn()
    finally:
        sys.setprofile(None)
    return n - 1  # the setprofile(None) call itself


def test_a_solution_and_a_rate_cross_codec_and_framing_within_a_call_budget():
    st, gyro = StarTrackerCodec(), GyroCodec()
    slip, datagrams = SlipDecoder(st.max_body), DatagramDecoder(gyro, DEVICE_TO_HOST)
    got = []

    def one_tick():  # what the emulated tracker and gyro do for one sample each: encode, frame, deframe, decode
        (body,) = slip.feed(st.encode(SOLUTION, 0x21))
        got.append(st.decode_body(body, 0x21, DEVICE_TO_HOST))
        got.extend(datagrams.feed(gyro.encode(RATE)))

    one_tick()  # first use builds the per-message structs
    got.clear()
    calls = _calls(one_tick)
    sol, rate = got
    # the sigmas travel as f32 in the ICD's unit: within its precision; every other field exactly
    assert (sol.sigma_cross_rad, sol.sigma_roll_rad) == pytest.approx((2.0 ** -16, 2.0 ** -14), rel=1e-7)
    assert replace(sol, sigma_cross_rad=2.0 ** -16, sigma_roll_rad=2.0 ** -14) == SOLUTION
    assert rate.seq == RATE.seq and rate.saturated_z and rate.omega_rad_s == pytest.approx(RATE.omega_rad_s, abs=1.1e-6)
    # Measured 155 calls (324 before issue 26's work on this layer); the margin lets a field be added to an ICD.
    assert calls <= 170, calls


def _rfc1055(chunk: bytes) -> bytes | None:
    """The reference reading of an escaped chunk, one byte at a time: ESC ESC_END is END, ESC ESC_ESC is ESC, any
    other byte after an ESC (or none) makes the chunk invalid."""
    out = bytearray()
    pending_esc = False
    for b in chunk:
        if pending_esc:
            if b not in (ESC_END, ESC_ESC):
                return None
            out.append(END if b == ESC_END else ESC)
            pending_esc = False
        elif b == ESC:
            pending_esc = True
        else:
            out.append(b)
    return None if pending_esc else bytes(out)


def test_slip_unescape_reads_every_short_chunk_as_rfc1055_says():
    alphabet = (ESC, ESC_END, ESC_ESC, 0x00, 0x41)
    checked = 0
    for length in range(7):
        for chunk in itertools.product(alphabet, repeat=length):
            data = bytes(chunk)
            assert unescape(data) == _rfc1055(data), data.hex()
            assert unescape(bytearray(data)) == _rfc1055(data)
            checked += 1
    assert checked == sum(5 ** n for n in range(7))
    for body in (b"", bytes([END, ESC, ESC_END, ESC_ESC, END]), bytes(range(256))):
        framed = escape(body)
        assert framed[0] == framed[-1] == END and END not in framed[1:-1]
        assert unescape(framed[1:-1]) == body
