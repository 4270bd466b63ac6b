"""Device faults in the emulators (issue 24): each attribute's effect on the wire or on what reaches the truth, and
the same bytes without the fault. Magnetorquer coils (gain: open, reversed; stuck on), the star tracker (blinded,
lost, misidentified, slow and late solutions), the cage's open coil pair, the clock faults shared by every emulator
base (a jump, a drift) and the reboot (silent while off, sequence numbers and clock reset, the boot message, commands
in flight lost). Everything runs in sim time through ``service``/``publish``/``advance``; no test measures time."""

from __future__ import annotations

import math
from collections.abc import Iterator

import can
import numpy as np
import pytest

from drivers.cage.model import CageModel
from drivers.datagram import DatagramDecoder
from drivers.gyro.codec import GyroCodec, GyroRate, SetOutputPeriod, SetTime
from drivers.gyro.emulator import GyroEmulator, GyroEmulatorConfig
from drivers.magnetorquer.codec import Heartbeat, MagnetorquerCodec, MagSample, Status
from drivers.magnetorquer.emulator import EmulatorConfig, MagnetorquerEmulator
from drivers.magnetorquer.host import MagnetorquerBoard
from drivers.star_tracker.codec import (
    Ack,
    Action,
    RequestTelemetry,
    Solution,
    StarTrackerCodec,
    Subscribe,
)
from drivers.star_tracker.emulator import EmulatorConfig as TrackerConfig
from drivers.star_tracker.emulator import StarTrackerEmulator, TrackerTruth
from drivers.star_tracker.slip import SlipDecoder
from drivers.sun_sensor.emulator import SunEmulatorConfig, SunSensorEmulator

from .star_tracker_helpers import Truth, pipe_pair

MTQ = MagnetorquerCodec()
GYRO = GyroCodec()
TRACKER = StarTrackerCodec()
ADDR = TRACKER.default_address
SOL, STATUS = TRACKER.solution_id, TRACKER.status_id
DEG = math.pi / 180


# -- magnetorquer: coils ---------------------------------------------------------------------------------------------


class Board:
    """The magnetorquer emulator, its host and a listener recording every frame the board sends, on one virtual
    channel."""

    _n = 0

    def __init__(self) -> None:
        Board._n += 1
        channel = f"faults-{id(self)}-{Board._n}"
        self.buses = [can.Bus(interface="virtual", channel=channel) for _ in range(3)]
        self.host = MagnetorquerBoard(self.buses[0], codec=MTQ, name="mtq-host")
        self.emu = MagnetorquerEmulator(self.buses[1], lambda t: (20e-6, -5e-6, 40e-6),
                                        EmulatorConfig(mag_noise_T=0.0), rng=0, codec=MTQ)
        self.spy = self.buses[2]
        self.cfg = self.emu.config

    def wire(self) -> list[tuple[int, bytes]]:
        """Every board frame since the last call (id, payload), the host's commands left out."""
        out = []
        while (msg := self.spy.recv(0.0)) is not None:
            if msg.arbitration_id not in MTQ.board_rx_ids:
                out.append((msg.arbitration_id, bytes(msg.data)))
        return out

    def decoded(self) -> list:
        return [MTQ.decode(i, d) for i, d in self.wire()]

    def close(self) -> None:
        self.host.close()
        self.emu.close()
        for b in self.buses:
            b.shutdown()


@pytest.fixture
def board() -> Iterator[Board]:
    b = Board()
    yield b
    b.close()


def _q(m: float, cfg: EmulatorConfig) -> float:
    """The board's quantisation of a dipole (the PWM step)."""
    levels = math.floor(cfg.max_dipole_A_m2 / cfg.dipole_lsb_A_m2 + 1e-9)
    return max(-levels, min(levels, round(m / cfg.dipole_lsb_A_m2))) * cfg.dipole_lsb_A_m2


def _status(board: Board, t: float) -> Status:
    board.emu.publish(t)
    (st,) = [m for m in board.decoded() if isinstance(m, Status)]
    return st


def test_a_reversed_coil_reverses_and_an_open_coil_zeroes_the_produced_dipole(board: Board) -> None:
    emu, cfg = board.emu, board.cfg
    emu.publish(0.0)
    board.wire()
    board.host.command_dipole((0.1, 0.05, -0.1), 5.0)
    emu.receive(0.5)
    nominal = (_q(0.1, cfg), _q(0.05, cfg), _q(-0.1, cfg))
    assert emu.dipole_xyz_at(0.5) == nominal
    # set while the command runs: it acts at once, on what reaches the truth (the stand's effect reads this)
    emu.coil_gain = (-1, 0, 1)
    assert emu.dipole_xyz_at(0.6) == (-nominal[0], 0.0, nominal[2])
    np.testing.assert_array_equal(emu.dipole_at(0.6), [-nominal[0], 0.0, nominal[2]])
    # a command under the fault is produced reversed / not at all, too
    board.host.command_dipole((-0.02, 0.2, 0.0), 5.0)
    emu.receive(0.7)
    assert emu.dipole_xyz_at(0.8) == (-_q(-0.02, cfg), 0.0, 0.0)
    # the board reports what its drivers measure: the commanded current through the reversed coil (it cannot tell),
    # nothing through the open one
    st = _status(board, 1.0)
    na = cfg.coil_area_turns_m2
    assert st.coil_current_A[0] == pytest.approx(_q(-0.02, cfg) / na[0], abs=MTQ.current_lsb_A)
    assert st.coil_current_A[0] < 0 and st.coil_current_A[1] == 0.0
    assert st.coil_active == (True, False, False)
    emu.coil_gain = (1, 1, 1)  # cleared: nominal again
    assert emu.dipole_xyz_at(0.9) == (_q(-0.02, cfg), _q(0.2, cfg), 0.0)


def test_a_stuck_coil_holds_the_rated_dipole_with_its_last_sign_whatever_is_commanded(board: Board) -> None:
    emu, cfg = board.emu, board.cfg
    rated = _q(1.0, cfg)  # the rated dipole on the PWM grid
    board.host.command_dipole((-0.05, 0.0, 0.01), 0.2)
    emu.receive(0.0)
    emu.stuck_on_axes = (0,)
    assert emu.dipole_xyz_at(0.1) == (-rated, 0.0, _q(0.01, cfg))
    board.host.command_dipole((0.1, 0.1, 0.0), 0.2)  # commanded the other way: still stuck
    emu.receive(0.15)
    assert emu.dipole_xyz_at(0.2) == (-rated, _q(0.1, cfg), 0.0)
    # past the watchdog, and with the board switched OFF: the stuck coil alone still produces
    emu.publish(0.5)
    assert emu.counters["watchdog_expiries"] == 1
    assert emu.dipole_xyz_at(0.5) == (-rated, 0.0, 0.0)
    board.host.set_mode("OFF")
    emu.receive(0.6)
    assert emu.mode == "OFF" and emu.dipole_xyz_at(0.7) == (-rated, 0.0, 0.0)
    assert emu.coil_active(0.7)
    np.testing.assert_array_equal(emu.dipole_at(0.7), [-rated, 0.0, 0.0])
    with pytest.raises(ValueError):
        emu.dipole_at(0.7)[0] = 0.0  # read-only, as without the fault
    st = _status(board, 1.0)
    assert st.coil_active == (True, False, False)
    assert st.coil_current_A[0] == pytest.approx(-rated / cfg.coil_area_turns_m2[0], abs=MTQ.current_lsb_A)
    emu.stuck_on_axes = ()
    assert emu.dipole_xyz_at(1.0) == (0.0, 0.0, 0.0) and not emu.coil_active(1.0)


def test_coil_fault_values_outside_what_is_allowed_are_named(board: Board) -> None:
    with pytest.raises(ValueError, match="coil_gain"):
        board.emu.coil_gain = (1, 1)
    with pytest.raises(ValueError, match="stuck_on_axes"):
        board.emu.stuck_on_axes = (3,)


def _board_session(board: Board, touch) -> list[tuple[int, bytes]]:
    """A fixed command schedule; ``touch(emu)`` before it. Every frame the board sent."""
    emu, host = board.emu, board.host
    touch(emu)
    for k in range(30):
        t = k * 0.1
        if k % 5 == 0:
            host.command_dipole((0.05 * (-1) ** k, 0.1, -0.15), 0.3)
        emu.receive(t)
        emu.publish(t)
    return board.wire()


def test_neutral_coil_faults_and_an_unused_clock_change_no_byte() -> None:
    def neutral(emu) -> None:
        emu.coil_gain = (1, 1, 1)
        emu.stuck_on_axes = ()
        h = emu.clock_fault(0.0, jump_s=3.0)
        emu.clear_clock_fault(0.0, h)

    a, b = Board(), Board()
    try:
        assert _board_session(a, lambda emu: None) == _board_session(b, neutral)
    finally:
        a.close()
        b.close()


# -- cage: an open coil pair --------------------------------------------------------------------------------------


def _cage(failed=()) -> CageModel:
    m = CageModel(rng=0)
    m.failed_coil_axes = failed
    assert m.write(5, [1]) == 0 and m.write(0, [1]) == 0
    assert m.write(1, [0, 10000, 8000, 6000, 2]) == 0  # 1.0, 0.8, 0.6 A
    for k in range(400):  # 0.4 s: settled well past the slew ramp; heartbeat every 0.1 s
        if k % 100 == 0:
            m.write(5, [(m.heartbeat + 1) & 0xFFFF])
        m.advance(m.t_s + m.config.regulator_period_s)
    return m


def test_a_failed_cage_coil_pair_carries_no_current_and_adds_no_field() -> None:
    nominal, failed = _cage(), _cage(failed=(1,))
    i_nom, i_fail = nominal.currents_A(), failed.currents_A()
    assert i_nom[1] == pytest.approx(0.8, abs=1e-3)
    assert i_fail == (i_nom[0], 0.0, i_nom[2])  # the other pairs are untouched
    k = np.asarray(failed.config.coil_T_per_A)
    lab = failed.lab_field_T()
    np.testing.assert_allclose(failed.cage_field_T() - lab, k[:, 0] * i_nom[0] + k[:, 2] * i_nom[2], rtol=0, atol=1e-15)
    np.testing.assert_allclose(nominal.cage_field_T() - failed.cage_field_T(), k[:, 1] * i_nom[1], rtol=0, atol=1e-15)
    assert failed.input_values()["current_y_A"] == 0.0  # the register reads what flows
    with pytest.raises(ValueError, match="failed_coil_axes"):
        failed.failed_coil_axes = ("z",)


# -- star tracker -------------------------------------------------------------------------------------------------


class Tracker:
    """The tracker emulator on one end of a pipe; the test is the host (codec + SLIP by hand)."""

    def __init__(self, **cfg) -> None:
        base = dict(boot_time_s=0.0, output_interval_s=0.1, output_delay_s=0.0, stable_count=1, track_loss_count=3,
                    match_probability=1.0, noise_cross_arcsec=0.0, noise_roll_arcsec=0.0)
        base.update(cfg)
        self.host_end, dev_end = pipe_pair()
        self.truth = Truth(TrackerTruth(q_TN=(1.0, 0.0, 0.0, 0.0), stars_in_field=12))
        self.emu = StarTrackerEmulator(dev_end, self.truth, TrackerConfig(**base), rng=0)
        self.dec = SlipDecoder(TRACKER.max_body)
        self.t = 0.0
        self.emu.service(0.0)
        self.send(Subscribe(SOL, 0.0))
        self.emu.service(0.0)
        assert self.replies() == [Ack(0x05)]

    def send(self, msg) -> None:
        self.host_end.write(TRACKER.encode(msg, ADDR))

    def raw_replies(self) -> list[bytes]:
        return self.dec.feed(self.host_end.read(self.host_end.in_waiting))

    def replies(self) -> list:
        return [TRACKER.decode_body(b, ADDR) for b in self.raw_replies()]

    def run_until(self, t_end: float, step: float = 0.01) -> list:
        out = []
        t0 = self.t
        for k in range(1, round((t_end - t0) / step) + 1):
            self.t = t0 + k * step
            self.emu.service(self.t)
            out += self.replies()
        return out


def _sols(msgs) -> list[Solution]:
    return [m for m in msgs if isinstance(m, Solution)]


def _angle(q_a, q_b) -> float:
    """The rotation angle between two unit quaternions, rad."""
    return 2.0 * math.acos(min(1.0, abs(sum(a * b for a, b in zip(q_a, q_b, strict=True)))))


def test_a_blinded_tracker_reports_the_sun_in_the_field_and_no_valid_solution() -> None:
    rig = Tracker()
    before = _sols(rig.run_until(0.5))
    assert before[-1].valid and before[-1].mode == "TRACKING" and not before[-1].sun_in_field
    rig.emu.blinded = True
    during = _sols(rig.run_until(1.0))
    assert len(during) == 5
    assert all(s.sun_in_field and not s.valid and s.stars_matched == 0 for s in during)
    rig.emu.blinded = False
    after = _sols(rig.run_until(1.5))
    assert after[-1].valid and not after[-1].sun_in_field


def test_a_lost_tracker_has_no_attitude_and_falls_to_lost_in_space_at_once() -> None:
    rig = Tracker(stable_count=3)
    rig.truth.truth = TrackerTruth(q_TN=(math.cos(0.3), math.sin(0.3), 0.0, 0.0), stars_in_field=12)
    assert _sols(rig.run_until(0.6))[-1].mode == "TRACKING"
    rig.emu.lost = True
    during = _sols(rig.run_until(1.0))
    assert during and all(not s.valid and s.mode == "LOST_IN_SPACE" and s.stars_matched == 0 for s in during)
    assert all(s.q_TN == (1.0, 0.0, 0.0, 0.0) for s in during)
    rig.emu.lost = False  # reacquires as from lost in space: stable_count good exposures
    after = _sols(rig.run_until(1.3))
    assert [s.mode for s in after] == ["LOST_IN_SPACE", "LOST_IN_SPACE", "TRACKING"]
    assert after[-1].valid


def test_misidentified_stars_give_an_attitude_off_by_the_given_angle_still_valid() -> None:
    rig = Tracker()
    q_true = (math.cos(0.2), 0.0, math.sin(0.2), 0.0)
    rig.truth.truth = TrackerTruth(q_TN=q_true, stars_in_field=12)
    ok = _sols(rig.run_until(0.3))[-1]
    assert _angle(ok.q_TN, q_true) < 1e-6
    rig.emu.misid_rad = (0.0, 3.0 * DEG, 4.0 * DEG)  # 5 deg about an axis across the boresight and along it
    bad = _sols(rig.run_until(0.6))
    assert bad and all(s.valid and s.mode == "TRACKING" for s in bad)
    for s in bad:
        assert _angle(s.q_TN, q_true) == pytest.approx(5.0 * DEG, abs=1e-6)  # f32 on the wire
    rig.emu.misid_rad = (0.0, 0.0, 0.0)
    assert _angle(_sols(rig.run_until(0.8))[-1].q_TN, q_true) < 1e-6
    with pytest.raises(ValueError, match="misid_rad"):
        rig.emu.misid_rad = (4.0, 0.0, 0.0)


def test_slow_solutions_come_late_and_at_a_lower_rate() -> None:
    rig = Tracker()
    nominal = _sols(rig.run_until(0.5))
    seen_at = {}

    def watch(t_end: float) -> list[Solution]:
        got = []
        t0 = rig.t
        for k in range(1, round((t_end - t0) / 0.01) + 1):
            rig.t = t0 + k * 0.01
            rig.emu.service(rig.t)
            for s in _sols(rig.replies()):
                seen_at[s.seq] = rig.t
                got.append(s)
        return got

    assert len(nominal) == 5
    rig.emu.solution_delay_s = 0.25
    late = watch(1.5)
    for s in late:  # each solution arrives 0.25 s after its exposure (time stamp = exposure, clock = sim time)
        assert seen_at[s.seq] == pytest.approx(s.time_us * 1e-6 + 0.25, abs=1e-9)
    rig.emu.solution_delay_s = 0.0
    watch(2.0)
    rig.emu.slow_factor = 3
    slow = watch(3.5)
    stamps = [s.time_us for s in slow]
    assert np.diff(stamps).tolist() == [300_000] * (len(stamps) - 1) and len(stamps) == 5
    with pytest.raises(ValueError, match="slow_factor"):
        rig.emu.slow_factor = 1.5


def test_tracker_faults_left_neutral_change_no_byte() -> None:
    def session(touch) -> list[bytes]:
        rig = Tracker(noise_cross_arcsec=2.0, noise_roll_arcsec=10.0, match_probability=0.9)
        touch(rig.emu)
        out = []
        for k in range(1, 150):
            rig.emu.service(k * 0.01)
            out += rig.raw_replies()
        return out

    def neutral(emu) -> None:
        emu.blinded = emu.lost = False
        emu.misid_rad = (0.0, 0.0, 0.0)
        emu.solution_delay_s = 0.0
        emu.slow_factor = 1

    assert session(lambda emu: None) == session(neutral)


# -- clock faults -------------------------------------------------------------------------------------------------


class Gyro:
    def __init__(self, **cfg) -> None:
        self.host_end, dev_end = pipe_pair()
        self.emu = GyroEmulator(dev_end, lambda t: (0.01, -0.02, 0.03), GyroEmulatorConfig(**cfg))
        self.dec = DatagramDecoder(GYRO, "device->host")

    def send(self, msg) -> None:
        self.host_end.write(GYRO.encode(msg))

    def run(self, t0: float, t1: float, step: float = 0.01) -> list[tuple[float, GyroRate]]:
        """(service time, sample) of every RATE sent while servicing from t0 to t1 inclusive."""
        out = []
        for k in range(round((t1 - t0) / step) + 1):
            t = t0 + k * step
            self.emu.service(t)
            out += [(t, m) for m in self.dec.feed(self.host_end.read(self.host_end.in_waiting))]
        return out


def test_a_clock_jump_shifts_the_gyro_time_tags_by_exactly_the_jump_and_clearing_it_ends_it() -> None:
    a, b = Gyro(output_period_s=0.1), Gyro(output_period_s=0.1)
    a.run(0.0, 1.0)
    b.run(0.0, 1.0)
    h = b.emu.clock_fault(1.0, jump_s=2.5)
    assert b.emu.clock_jump_s == 2.5
    ref, jumped = a.run(1.01, 2.0), b.run(1.01, 2.0)
    assert len(ref) == len(jumped) == 10
    for (_, x), (_, y) in zip(ref, jumped, strict=True):
        assert y.time_us - x.time_us == 2_500_000 and y.seq == x.seq and y.omega_rad_s == x.omega_rad_s
    b.emu.clear_clock_fault(2.0, h)
    assert [m.time_us for _, m in a.run(2.01, 2.5)] == [m.time_us for _, m in b.run(2.01, 2.5)]


def test_a_clock_drift_grows_the_time_tag_error_linearly_from_its_start() -> None:
    a, b = Gyro(output_period_s=0.1), Gyro(output_period_s=0.1)
    a.run(0.0, 0.5)
    b.run(0.0, 0.5)
    b.emu.clock_fault(0.5, drift=1e-3)
    assert b.emu.clock_drift == 1e-3
    ref, drifting = a.run(0.51, 10.5), b.run(0.51, 10.5)
    err_us = [y.time_us - x.time_us for (_, x), (_, y) in zip(ref, drifting, strict=True)]
    t_k = [x.time_us * 1e-6 for _, x in ref]  # sample times (clock = sim time here)
    for t, e in zip(t_k, err_us, strict=True):
        assert abs(e - 1e3 * (t - 0.5)) <= 1  # 1 ms per s, within the 1 us tick
    assert err_us[-1] == 10_000
    # SET_TIME sets the clock right: the error starts again from 0 there, the drift goes on
    b.send(SetTime(5_000_000_000))
    a.send(SetTime(5_000_000_000))
    ref, drifting = a.run(10.51, 12.5), b.run(10.51, 12.5)  # both set at 10.51 s
    for (_, x), (_, y) in zip(ref, drifting, strict=True):
        since_set_s = (x.time_us - 5_000_000_000) * 1e-6
        assert abs((y.time_us - x.time_us) - 1e3 * since_set_s) <= 1
    assert drifting[-1][1].time_us - ref[-1][1].time_us == 1_990


def test_a_clock_jump_shifts_the_can_heartbeat_uptime(board: Board) -> None:
    emu = board.emu
    emu.publish(0.0)
    emu.clock_fault(0.5, jump_s=7.0)
    emu.publish(1.0)
    (hb,) = [m for m in board.decoded() if isinstance(m, Heartbeat)][-1:]
    assert hb.uptime_s == 1 + 7
    emu.clear_clock_fault(1.5)
    emu.publish(2.0)
    assert [m for m in board.decoded() if isinstance(m, Heartbeat)][-1].uptime_s == 2


def test_a_clock_jump_shifts_the_tracker_time_stamps_and_the_stand_still_inverts_them() -> None:
    rig = Tracker()
    rig.run_until(0.5)
    rig.emu.clock_fault(0.5, jump_s=-0.2, drift=1e-4)
    sols = _sols(rig.run_until(1.0))
    for s in sols:
        t_e = round(rig.emu.sim_time_s(s.time_us), 6)
        assert t_e == pytest.approx(round(t_e, 1), abs=1e-9)  # back on the exposure grid
        assert s.time_us == round((t_e - 0.2 + 1e-4 * (t_e - 0.5)) * 1e6)
    with pytest.raises(ValueError, match="drift"):
        rig.emu.clock_fault(1.0, drift=2.0)


# -- reboot -------------------------------------------------------------------------------------------------------


def test_a_rebooting_gyro_is_silent_then_restarts_its_counter_and_clock_unsynced() -> None:
    g = Gyro(output_period_s=0.1, clock_offset_s=0.0)
    g.send(SetTime(9_000_000))
    before = g.run(0.0, 1.0)
    assert before[-1][1].time_synced and before[-1][1].seq == 10
    g.send(SetOutputPeriod(0.05))  # in flight at the reboot: lost
    g.emu.reboot(1.0, boot_s=0.5)
    g.send(SetOutputPeriod(0.2))  # sent while it is off: lost
    during = g.run(1.01, 1.49)
    assert during == [] and g.emu.counters["reboots"] == 1
    after = g.run(1.5, 2.0)
    first = after[0][1]
    assert after[0][0] == 1.5 and first.seq == 0 and not first.time_synced
    assert first.time_us == 0  # the clock restarted at power-up (clock_offset_s 0)
    assert [round(t, 2) for t, _ in after] == [1.5, 1.6, 1.7, 1.8, 1.9, 2.0]  # the configured period
    assert g.emu.counters["bytes_lost_in_boot"] == 2 * GYRO.messages["SET_OUTPUT_PERIOD"].length
    assert g.emu.counters["rejected_while_off"] == 2
    assert g.emu.counters["commands_applied"] == 1  # the SET_TIME before the reboot only


def test_a_rebooting_sun_sensor_restarts_its_counter() -> None:
    host_end, dev_end = pipe_pair()
    emu = SunSensorEmulator(dev_end, lambda t: ((0.1, 0.2), True), SunEmulatorConfig(output_period_s=0.1))
    dec = DatagramDecoder(emu.codec, "device->host")
    for k in range(11):
        emu.service(k * 0.1)
    assert dec.feed(host_end.read(host_end.in_waiting))[-1].seq == 10
    emu.reboot(1.05, boot_s=0.0)
    emu.service(1.1)
    (first,) = dec.feed(host_end.read(host_end.in_waiting))
    assert first.seq == 0 and first.time_us == 50_000  # the clock restarted at the end of the boot, 1.05 s


def test_a_rebooting_can_board_is_silent_then_sends_its_boot_heartbeat_first(board: Board) -> None:
    emu, host = board.emu, board.host
    for k in range(12):
        emu.publish(k * 0.1)
    host.command_dipole((0.1, 0.0, 0.0), 10.0)
    emu.receive(1.1)
    assert emu.dipole_xyz_at(1.15)[0] > 0
    board.wire()
    host.command_dipole((0.0, 0.1, 0.0), 10.0)  # waiting on the bus at the reboot: lost
    emu.reboot(1.2, boot_s=0.5)
    assert emu.dipole_xyz_at(1.2) == (0.0, 0.0, 0.0)  # coils off
    host.command_dipole((0.0, 0.0, 0.1), 10.0)  # sent while it is off: lost
    for k in range(13, 17):
        emu.receive(k * 0.1)
        emu.publish(k * 0.1)
    assert board.wire() == []
    assert emu.counters["frames_lost_in_boot"] == 2 and emu.dipole_xyz_at(1.6) == (0.0, 0.0, 0.0)
    emu.publish(1.7)
    first = board.decoded()
    assert first == [Heartbeat(0, "BOOT", 0)]  # the ICD's boot message, alone, first
    emu.publish(1.8)
    (sample,) = board.decoded()
    assert isinstance(sample, MagSample) and sample.seq == 0
    emu.publish(2.8)
    later = board.decoded()
    assert Heartbeat(1, "NOMINAL", 1) in later
    host.command_dipole((0.0, 0.1, 0.0), 1.0)  # after the boot: taken
    emu.receive(2.9)
    assert emu.dipole_xyz_at(2.9)[1] > 0 and emu.counters["frames_lost_in_boot"] == 2


def test_a_rebooting_tracker_is_silent_then_boots_unsynced_with_its_subscriptions_gone() -> None:
    rig = Tracker(boot_time_s=0.3)
    rig.send(Action("SET_TIME", 5_000_000))
    sols = _sols(rig.run_until(1.0))
    assert sols[-1].time_synced and sols[-1].seq > 3
    rig.emu.reboot(1.0, boot_s=0.5)
    rig.send(RequestTelemetry(STATUS))  # sent while it is off: lost, unanswered
    assert rig.run_until(1.49) == []
    assert rig.emu.counters["bytes_lost_in_boot"] > 0
    assert rig.emu.counters["rejected_while_off"] == 1  # every frame the host sent is accounted for
    assert rig.run_until(1.59) == []  # powered up at 1.5 s, in BOOT: nothing unasked
    rig.send(RequestTelemetry(STATUS))
    rig.emu.service(1.6)
    (st,) = rig.replies()
    assert st.mode == "BOOT" and not st.time_synced and st.solutions == 0 and not st.subscribed_solution
    assert st.time_us == 100_000 and st.uptime_s == pytest.approx(0.1)  # the clock restarted at power-up, 1.5 s
    assert rig.run_until(2.5) == []  # booted at 1.8 s; the subscription is gone (the ICD): nothing unasked
    rig.send(RequestTelemetry(SOL))
    rig.emu.service(2.5)
    (sol,) = rig.replies()
    assert sol.seq == 7 and not sol.time_synced  # exposures 1.8 .. 2.5 s: counter from 0
    assert sol.time_us == 1_000_000


def test_reboot_and_clock_fault_values_outside_what_is_allowed_are_named(board: Board) -> None:
    with pytest.raises(ValueError, match="boot_s"):
        board.emu.reboot(1.0, boot_s=-1.0)
    with pytest.raises(ValueError, match="jump_s"):
        board.emu.clock_fault(1.0, jump_s=math.nan)


def test_a_rebooting_wheel_drops_its_command_and_restarts_its_counters() -> None:
    from drivers.reaction_wheel.codec import Heartbeat as WheelHeartbeat
    from drivers.reaction_wheel.codec import ReactionWheelCodec, TorqueCommand, WheelSpeed
    from drivers.reaction_wheel.emulator import ReactionWheelEmulator

    codec = ReactionWheelCodec(0)
    buses = [can.Bus(interface="virtual", channel=f"faults-rw-{id(codec)}") for _ in range(2)]
    try:
        emu = ReactionWheelEmulator(buses[0], lambda t: 10.0, codec=codec)
        send = buses[1]

        def command(torque: float) -> None:
            frame_id, payload = codec.encode(TorqueCommand(torque, seq=7))
            send.send(can.Message(arbitration_id=frame_id, data=payload, is_extended_id=False))

        def sent() -> list:
            out = []
            while (msg := send.recv(0.0)) is not None:
                out.append(codec.decode(msg.arbitration_id, bytes(msg.data)))
            return out

        for k in range(10):
            emu.publish(k * 0.1)
        command(0.002)
        emu.receive(1.0)
        assert emu.torque_command_Nm(1.0) == 0.002
        sent()
        emu.reboot(1.0, boot_s=0.2)
        assert emu.torque_command_Nm(1.0) == 0.0 and emu.mode == "TORQUE"
        emu.publish(1.1)
        emu.publish(1.19)
        assert sent() == []
        emu.publish(1.2)
        assert sent() == [WheelHeartbeat(0, "BOOT", 0)]
        emu.publish(1.2 + emu.config.telemetry_period_s)
        (tlm,) = [m for m in sent() if isinstance(m, WheelSpeed)]
        assert tlm.seq == 0
    finally:
        for b in buses:
            b.shutdown()
