"""Star tracker emulator (truth plus noise), driven by sim time through ``service(t)`` on an
in-memory pipe: boot, the lost-in-space -> tracking state machine, every valid-flag case, clock
offset and drift, noise statistics, parameters, subscriptions and robustness to bad traffic.
No test measures time."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.star_tracker.codec import (
    Ack,
    Action,
    GetParam,
    Nack,
    ParamValue,
    RequestTelemetry,
    SetParam,
    Solution,
    StarTrackerCodec,
    Status,
    Subscribe,
    Unsubscribe,
    crc16,
)
from drivers.star_tracker.emulator import EmulatorConfig, StarTrackerEmulator, TrackerTruth
from drivers.star_tracker.slip import SlipDecoder
from sim.rotations import dcm, quat_from_axis_angle

from .star_tracker_helpers import Truth, pipe_pair

CODEC = StarTrackerCodec()
ADDR = CODEC.default_address
SOL, STATUS = CODEC.solution_id, CODEC.status_id
ARCSEC = math.pi / 180 / 3600
DEG = math.pi / 180


class Rig:
    """The emulator on one end of a pipe; the test is the host on the other (codec + SLIP by hand)."""

    def __init__(self, config: EmulatorConfig | None = None, truth: Truth | None = None, rng: int = 0) -> None:
        self.host_end, self.dev_end = pipe_pair()
        self.truth = truth or Truth()
        self.emu = StarTrackerEmulator(self.dev_end, self.truth, config or EmulatorConfig(), rng=rng)
        self.dec = SlipDecoder(CODEC.max_body)
        self.t = 0.0

    def send(self, msg, address: int = ADDR) -> None:
        self.host_end.write(CODEC.encode(msg, address))

    def raw(self, data: bytes) -> None:
        self.host_end.write(data)

    def replies(self) -> list:
        return [CODEC.decode_body(b, ADDR) for b in self.dec.feed(self.host_end.read(self.host_end.in_waiting))]

    def ask(self, msg, t: float | None = None):
        self.send(msg)
        self.emu.service(self.t if t is None else t)
        (reply,) = self.replies()
        return reply

    def run_until(self, t_end: float, step: float = 0.01) -> list:
        """Service every ``step`` up to ``t_end``; return what the emulator sent."""
        out = []
        n = round((t_end - self.t) / step)
        t0 = self.t
        for k in range(1, n + 1):
            self.t = t0 + k * step
            self.emu.service(self.t)
            out += self.replies()
        return out


def _solutions(msgs):
    return [m for m in msgs if isinstance(m, Solution)]


def _tracking_rig(**cfg) -> Rig:
    """Booted and subscribed to every solution from t = 0.1 s on (one exposure every 0.1 s, published at
    once); stable_count 1 (tracking after one good exposure)."""
    base = dict(boot_time_s=0.0, output_interval_s=0.1, output_delay_s=0.0, stable_count=1, track_loss_count=3,
                match_probability=1.0)
    base.update(cfg)
    rig = Rig(EmulatorConfig(**base))
    rig.emu.service(0.0)  # power-up, boot and the first exposure (t = 0) before the subscription
    assert rig.ask(Subscribe(SOL, 0.0), 0.0) == Ack(0x05)
    return rig


# -- boot and the state machine -------------------------------------------------------------------


def test_boot_time_then_lost_in_space_then_tracking_after_the_stable_count():
    rig = Rig(EmulatorConfig(boot_time_s=1.0, output_interval_s=0.2, output_delay_s=0.1, stable_count=3,
                             match_probability=1.0))
    assert rig.ask(RequestTelemetry(SOL), 0.0) == Nack(0x03, "NOT_READY")
    assert rig.ask(RequestTelemetry(STATUS), 0.5).mode == "BOOT"
    rig.t = 0.5
    assert rig.ask(Subscribe(SOL, 0.0)) == Ack(0x05)
    sols = _solutions(rig.run_until(2.0))
    # exposures at 1.0, 1.2, ... published 0.1 s later, time stamped at mid-exposure
    assert [s.time_us for s in sols[:3]] == [1_000_000, 1_200_000, 1_400_000]
    assert [s.mode for s in sols[:4]] == ["LOST_IN_SPACE", "LOST_IN_SPACE", "TRACKING", "TRACKING"]
    assert [s.stable_count for s in sols[:4]] == [1, 2, 3, 4]
    assert [s.valid for s in sols[:4]] == [False, False, True, True]
    assert [s.seq for s in sols] == list(range(len(sols)))
    assert rig.truth.calls[:3] == pytest.approx([1.0, 1.2, 1.4])


def test_without_auto_boot_the_device_waits_for_the_boot_action():
    rig = Rig(EmulatorConfig(auto_boot=False, boot_time_s=0.3))
    rig.run_until(1.0, 0.1)
    assert rig.emu.mode == "BOOT" and rig.truth.calls == []
    assert rig.ask(Action("BOOT")) == Ack(0x04)
    rig.run_until(1.2, 0.1)
    assert rig.emu.mode == "BOOT"
    rig.run_until(1.4, 0.1)
    assert rig.emu.mode == "LOST_IN_SPACE"


def test_tracking_falls_back_to_lost_in_space_after_the_track_loss_count_and_reacquires():
    rig = _tracking_rig(stable_count=2, track_loss_count=3)
    sols = _solutions(rig.run_until(0.5))
    assert sols[-1].mode == "TRACKING" and sols[-1].valid
    rig.truth.truth = TrackerTruth(q_TN=(1, 0, 0, 0), stars_in_field=2)  # too few stars
    lost = _solutions(rig.run_until(0.8))
    assert [s.mode for s in lost] == ["TRACKING", "TRACKING", "LOST_IN_SPACE"]
    assert not any(s.valid for s in lost) and all(s.stable_count == 0 for s in lost)
    rig.truth.truth = TrackerTruth(q_TN=(1, 0, 0, 0), stars_in_field=12)
    back = _solutions(rig.run_until(1.0))
    assert [(s.mode, s.valid) for s in back] == [("LOST_IN_SPACE", False), ("TRACKING", True)]


def test_boot_action_while_tracking_reboots():
    rig = _tracking_rig(boot_time_s=0.5)
    rig.run_until(0.8)
    assert rig.emu.mode == "TRACKING"
    rig.send(Action("BOOT"))
    out = rig.run_until(0.81)
    assert out == [Ack(0x04)] and rig.emu.mode == "BOOT" and rig.emu.stable_count == 0
    assert rig.ask(RequestTelemetry(SOL)) == Nack(0x03, "NOT_READY")
    first = _solutions(rig.run_until(1.4))[0]
    assert first.time_us == 1_310_000 and first.mode == "TRACKING" and first.stable_count == 1


# -- every valid-flag case ------------------------------------------------------------------------


def _direction(angle_deg: float) -> tuple[float, float, float]:
    a = math.radians(angle_deg)
    return (math.sin(a), 0.0, math.cos(a))


GOOD = dict(q_TN=(1, 0, 0, 0), stars_in_field=12)


@pytest.mark.parametrize(
    "case, truth, flag",
    [
        ("sun centre in the exclusion cone", dict(sun_T=_direction(30.0)), "sun_in_field"),
        ("sun disk plus margin touches", dict(sun_T=_direction(40.2), sun_radius_rad=0.3 * DEG), "sun_in_field"),
        ("moon in the field", dict(moon_T=_direction(35.0)), "moon_in_field"),
        ("earth limb within its half-angle", dict(earth_T=_direction(60.0), earth_radius_rad=35 * DEG),
         "earth_in_field"),
        ("rate above the limit", dict(omega_TN_T=(0.0, 1.2 * DEG, 0.5 * DEG)), "rate_too_high"),
        ("fewer stars than configured", dict(stars_in_field=5), None),
    ],
)
def test_valid_flag_is_false_for_each_exclusion_case(case, truth, flag):
    rig = _tracking_rig(min_stars_matched=6)
    good = _solutions(rig.run_until(0.2))
    assert good[-1].valid and good[-1].mode == "TRACKING"
    assert not any((good[-1].sun_in_field, good[-1].moon_in_field, good[-1].earth_in_field, good[-1].rate_too_high))
    rig.truth.truth = TrackerTruth(**{**GOOD, **truth})
    (bad,) = _solutions(rig.run_until(0.3))
    assert not bad.valid, case
    flags = {k: getattr(bad, k) for k in ("sun_in_field", "moon_in_field", "earth_in_field", "rate_too_high")}
    assert flags == {k: k == flag for k in flags}, case
    if flag == "sun_in_field":
        assert bad.stars_matched == 0  # blinded
    if flag is None:
        assert bad.stars_matched == 5 < 6


@pytest.mark.parametrize(
    "truth",
    [
        dict(sun_T=_direction(40.5), sun_radius_rad=0.3 * DEG),  # disk just outside the 40 deg cone
        dict(moon_T=_direction(170.0)),
        dict(earth_T=_direction(100.0), earth_radius_rad=65 * DEG),  # limb 35 deg away, limit 30
        dict(omega_TN_T=(0.0, 0.0, 0.99 * DEG)),
        dict(stars_in_field=6),
    ],
)
def test_valid_flag_stays_true_just_outside_each_limit(truth):
    rig = _tracking_rig(min_stars_matched=6)
    rig.run_until(0.2)
    rig.truth.truth = TrackerTruth(**{**GOOD, **truth})
    (sol,) = _solutions(rig.run_until(0.3))
    assert sol.valid and sol.mode == "TRACKING"


# -- time stamps ----------------------------------------------------------------------------------


def test_time_stamps_follow_the_device_clock_offset_drift_and_set_time():
    rig = _tracking_rig(clock_offset_s=100.0, clock_drift_ppm=50.0, output_delay_s=0.05)
    sols = _solutions(rig.run_until(0.5))
    rate = 1 + 50e-6
    for k, s in enumerate(sols):
        t_e = 0.1 * k  # mid-exposure in sim time
        assert s.time_us == round((100.0 + t_e * rate) * 1e6)
        assert not s.time_synced
    t_set, unix_us = rig.t, 1_790_000_000_000_000
    assert rig.ask(Action("SET_TIME", unix_us)) == Ack(0x04)
    in_flight, *later = _solutions(rig.run_until(1.0))
    # exposed before SET_TIME, published after it: old clock, not synced
    assert in_flight.time_us == round((100.0 + 0.5 * rate) * 1e6) and not in_flight.time_synced
    assert len(later) == 4 and all(s.time_synced for s in later)
    for s in later:
        t_e = round((s.time_us - unix_us) / 1e6 / rate + t_set, 6)
        assert t_e == pytest.approx(round(t_e * 10) / 10, abs=1e-6)  # an exposure time on the 0.1 s grid
        assert s.time_us == round(unix_us + (t_e - t_set) * rate * 1e6)
    st_now = rig.ask(RequestTelemetry(STATUS))
    assert st_now.time_synced and st_now.time_us == round(unix_us + (rig.t - t_set) * rate * 1e6)


# -- noise ----------------------------------------------------------------------------------------


def test_noise_across_and_about_the_boresight_has_the_configured_sigmas_and_bias():
    cfg = EmulatorConfig(noise_cross_arcsec=5.0, noise_roll_arcsec=20.0, bias_arcsec=(3.0, -2.0, 10.0))
    truth = Truth()
    emu = StarTrackerEmulator(pipe_pair()[1], truth, cfg, rng=42)
    rng = np.random.default_rng(7)
    n = 3000
    errs = np.empty((n, 3))
    for i in range(n):
        q = quat_from_axis_angle(rng.normal(size=3), rng.uniform(0, math.pi))
        truth.truth = TrackerTruth(q_TN=tuple(q))
        s = emu.expose(0.0)
        assert s.q_TN[0] >= 0
        e = dcm(np.array(s.q_TN)) @ dcm(q).T  # ~ I - [theta x], theta in tracker axes
        errs[i] = [(e[1, 2] - e[2, 1]) / 2, (e[2, 0] - e[0, 2]) / 2, (e[0, 1] - e[1, 0]) / 2]
    errs /= ARCSEC
    assert errs.mean(axis=0) == pytest.approx([3.0, -2.0, 10.0], abs=1.5)
    assert errs.std(axis=0) == pytest.approx([5.0, 5.0, 20.0], rel=0.08)


def test_reported_sigmas_are_the_configured_noise():
    rig = _tracking_rig(noise_cross_arcsec=4.0, noise_roll_arcsec=12.0)
    (s,) = _solutions(rig.run_until(0.1))
    assert s.sigma_cross_rad == pytest.approx(4 * ARCSEC, rel=1e-6)
    assert s.sigma_roll_rad == pytest.approx(12 * ARCSEC, rel=1e-6)


# -- parameters, subscriptions, counters ----------------------------------------------------------


def test_parameters_set_get_and_take_effect():
    rig = _tracking_rig()
    assert rig.ask(GetParam(4)) == ParamValue(4, pytest.approx(1.0))
    assert rig.ask(CODEC.set_param("rate_limit", 0.5 * DEG)) == Ack(0x01)
    assert rig.ask(GetParam(4)).value == pytest.approx(0.5)
    rig.truth.truth = TrackerTruth(q_TN=(1, 0, 0, 0), omega_TN_T=(0, 0, 0.7 * DEG), stars_in_field=12)
    assert all(s.rate_too_high for s in _solutions(rig.run_until(0.3)))
    assert rig.ask(SetParam(4, 45.0)) == Nack(0x01, "VALUE_OUT_OF_RANGE")
    assert rig.ask(SetParam(3, 2.5)) == Nack(0x01, "VALUE_OUT_OF_RANGE")
    assert rig.ask(SetParam(99, 1.0)) == Nack(0x01, "UNKNOWN_PARAMETER")
    assert rig.ask(GetParam(99)) == Nack(0x02, "UNKNOWN_PARAMETER")
    assert rig.ask(CODEC.set_param("output_interval", 0.2)) == Ack(0x01)
    assert len(_solutions(rig.run_until(1.3))) == 5


def test_subscription_periods_and_unsubscribe():
    rig = Rig(EmulatorConfig(boot_time_s=0.0, output_interval_s=0.1, output_delay_s=0.0))
    assert rig.ask(Subscribe(STATUS, 0.5)) == Ack(0x05)
    status = [m for m in rig.run_until(2.0) if isinstance(m, Status)]
    assert len(status) == 4 and status[-1].subscribed_status
    assert rig.ask(Unsubscribe(STATUS)) == Ack(0x06)
    assert rig.run_until(3.0) == []
    assert rig.ask(Subscribe(0x42, 1.0)) == Nack(0x05, "UNKNOWN_TELEMETRY")
    assert rig.ask(RequestTelemetry(0x42)) == Nack(0x03, "UNKNOWN_TELEMETRY")


def test_status_counters_and_reset():
    rig = _tracking_rig()
    rig.run_until(0.3)
    rig.raw(b"\xc0\x21\x03\x90\x00\x00\xc0")  # bad CRC
    s = rig.ask(RequestTelemetry(STATUS))
    assert (s.rejected_crc, s.frames_received, s.solutions) == (1, 2, 4)
    assert s.frames_sent == 1 + 3  # the ACK and the solutions of 0.1, 0.2 and 0.3 s
    assert rig.ask(Action("RESET_COUNTERS")) == Ack(0x04)
    s = rig.ask(RequestTelemetry(STATUS))
    assert (s.rejected_crc, s.frames_received, s.solutions) == (0, 1, 0)


# -- bad traffic ----------------------------------------------------------------------------------


def _body(address: int, msg_id: int, payload: bytes) -> bytes:
    head = bytes((address, msg_id)) + payload
    return head + crc16(head).to_bytes(2, "little")


def test_each_kind_of_bad_frame_is_counted_and_the_next_good_frame_served():
    from drivers.star_tracker.slip import escape

    rig = _tracking_rig()
    rig.run_until(0.1)
    emu = rig.emu
    body = bytearray(_body(ADDR, 0x03, bytes([SOL])))
    body[-1] ^= 1
    cases = [
        (escape(bytes(body)), "rejected_crc", None),
        (CODEC.encode(RequestTelemetry(SOL), 0x22), "rejected_address", None),
        (escape(_body(ADDR, 0x7E, b"")), "rejected_unknown_id", Nack(0x7E, "UNKNOWN_MESSAGE")),
        (escape(_body(ADDR, 0x90, bytes(44))), "rejected_unknown_id", Nack(0x90, "UNKNOWN_MESSAGE")),
        (escape(_body(ADDR, 0x03, b"\x90\x00")), "rejected_length", Nack(0x03, "BAD_LENGTH")),
        (escape(_body(ADDR, 0x04, bytes([7]) + bytes(8))), "rejected_other", Nack(0x04, "UNKNOWN_ACTION")),
        (escape(_body(ADDR, 0x05, bytes([SOL]) + (60001).to_bytes(2, "little"))), "rejected_other",
         Nack(0x05, "VALUE_OUT_OF_RANGE")),
        (b"\xc0" + bytes(range(1, 180)) * 2 + b"\xc0", "rejected_other", None),
        (b"\xc0\x21\xdb\x01\xc0", "rejected_other", None),
        (b"\xc0\x21\xc0", "rejected_other", None),
    ]
    for frame, counter, reply in cases:
        before = dict(emu.counters)
        rig.raw(frame)
        rig.send(RequestTelemetry(SOL))
        emu.service(rig.t)
        out = rig.replies()
        assert emu.counters[counter] == before[counter] + 1, (frame.hex(), counter)
        assert isinstance(out[-1], Solution), frame.hex()
        assert out[:-1] == ([reply] if reply else []), frame.hex()


@pytest.mark.parametrize("action", [0, 4, 7, 255])
def test_an_action_outside_the_icd_table_is_nacked_unknown_action(action):
    # The ICD's action table is NONE, BOOT, SET_TIME, RESET_COUNTERS: anything else (NONE included) is
    # UNKNOWN_ACTION, not VALUE_OUT_OF_RANGE (that one is for a parameter or field value out of its range).
    from drivers.star_tracker.slip import escape

    rig = _tracking_rig()
    rig.run_until(0.1)
    rig.raw(escape(_body(ADDR, 0x04, bytes([action]) + bytes(8))))
    rig.emu.service(rig.t)
    assert rig.replies() == [Nack(0x04, "UNKNOWN_ACTION")]


@settings(max_examples=150, deadline=None)
@given(junk=st.binary(max_size=300), split=st.integers(0, 8))
def test_emulator_survives_arbitrary_bytes_and_serves_the_next_good_frame(junk, split):
    rig = Rig(EmulatorConfig(boot_time_s=0.0))
    rig.emu.service(0.0)
    good = CODEC.encode(RequestTelemetry(STATUS))
    rig.raw(junk + good[:split])
    rig.emu.service(0.01)  # never raises, whatever came in
    rig.raw(good[split:])
    rig.emu.service(0.02)
    out = [CODEC.decode_body(b) for b in rig.dec.feed(rig.host_end.read(10_000))]
    assert isinstance(out[-1], Status)
    c = rig.emu.counters
    assert c["frames_received"] >= 1 and c["bytes_received"] == len(junk) + len(good)
