"""A served device fed garbage by the flight computer outside: it counts and drops each bad frame once, answers with a
NACK where its ICD says so, applies the valid commands sent in between, and the run goes on to its end.

Each served kind runs in a ``stand run`` process on one end of a socat pty pair; this process is the flight computer
on the other end and writes, once it hears the device, a script of bad frames and valid commands, one step every
0.15 s of wall time (three ticks), so each bad frame is taken in on its own. The CAN kinds use python-can's
CAN-over-serial line (``interface = "serial"``), whose framing a malformed frame breaks (a DLC above 8, a bad end
delimiter, a frame cut short): python-can raises on those, and before the fix the run aborted with exit 3.
"""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from stand import telemetry
from tests.stand.processes import run_stand_polling

from .conftest import to_toml
from .test_gyro_wheel_links import HEAVY, small_scenario

#: Polls (10 ms each) between two steps of the flight computer's script: 0.15 s, three ticks at x2.
GAP_POLLS = 15


class ScriptedPeer:
    """The flight computer's end of the pty: reads everything the device sends; once it has heard the device (or,
    for a device that speaks only when asked, after ``hello`` was answered) writes one step of ``steps`` every
    ``GAP_POLLS`` polls. Used as ``run_stand_polling``'s ``on_poll``."""

    def __init__(self, path: str, steps: list[bytes], hello: bytes | None = None):
        import serial

        self.port = serial.Serial(path, timeout=0)
        self.steps, self.hello = steps, hello
        self.rx = bytearray()
        self.sent = 0
        self._polls = 0

    def __call__(self) -> None:
        self.rx += self.port.read(65536)
        self._polls += 1
        if not self.rx:
            if self.hello is not None and self._polls % 10 == 0:
                self.port.write(self.hello)
            return
        if self.sent < len(self.steps) and self._polls % GAP_POLLS == 0:
            self.port.write(self.steps[self.sent])
            self.sent += 1

    def close(self) -> None:
        self.rx += self.port.read(65536)
        self.port.close()


def _run(tmp_path, pty_pair, device: dict, steps: list[bytes], duration_s: float = 8.0, hello: bytes | None = None,
         spacecraft: dict | None = None):
    """``stand run`` at x2 with ``device`` served on the stand's end of the pty pair, the script on the other end.
    Returns (exit code, log, the device's summary counters, the peer)."""
    stand_end, peer_end = pty_pair
    path = tmp_path / "served.toml"
    data = small_scenario([{**device, "link": "served", **_port(device, stand_end)}], duration_s)
    data["spacecraft"].update(spacecraft or {})
    path.write_text(to_toml(data))
    out = tmp_path / "out"
    peer = ScriptedPeer(peer_end, steps, hello)
    try:
        code, log = run_stand_polling(["run", str(path), "--speed", "2", "--out", str(out), "--no-progress",
                                       "--no-plots"], tmp_path, peer, timeout_s=120)
    finally:
        peer.close()
    assert peer.sent == len(steps), f"the run ended before the script did ({peer.sent} of {len(steps)} steps)\n{log}"
    summary = json.loads((out / "summary.json").read_text())
    events = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
    return code, log, summary, events, out, peer


def _port(device: dict, stand_end: str) -> dict:
    return {"channel": stand_end} if device.get("interface") == "serial" else {"port": stand_end}


def _completed(code: int, log: str, summary: dict, events: list, name: str, rejected: int) -> None:
    assert code == 0 and summary["status"] == "completed", log
    assert not any(e["kind"] == "controller_exception" for e in events)
    assert summary["device_counters"][name]["rejected_frames"] == rejected
    logged = [e for e in events if e["kind"] == "frames_rejected"]
    assert logged and logged[0]["count"] == 1 and logged[0]["device"] == name  # the first one is logged, with why


# -- CAN over a serial line: python-can's framing (0xAA, time u32, DLC, id u32, data, 0xBB) --------------------


def serial_can(frame_id: int, data: bytes, *, dlc: int | None = None, end: int = 0xBB) -> bytes:
    """One frame of python-can's ``serial`` interface, as a flight computer's adapter writes it."""
    return (b"\xaa" + struct.pack("<I", 0) + bytes([len(data) if dlc is None else dlc]) + struct.pack("<I", frame_id)
            + data + bytes([end]))


#: Frames python-can's serial interface cannot decode (it raised on each before the fix): cut short after three
#: bytes, a DLC of 9, an end delimiter that is not 0xBB.
UNDECODABLE = [b"\xaa\x01\x02", b"\xaa" + bytes(4) + b"\x09" + bytes(4 + 9) + b"\xbb",
               serial_can(0x123, b"\x00", end=0x55)]


def test_served_magnetorquer_drops_malformed_can_frames_and_applies_the_commands_between(pty_pair, tmp_path):
    from drivers.magnetorquer.codec import DipoleCommand, MagnetorquerCodec

    codec = MagnetorquerCodec()
    dipoles = [0.05, 0.10, 0.15, 0.12, 0.08]
    good = [serial_can(*codec.encode(DipoleCommand((m, 0.0, 0.0), 1.0))) for m in dipoles]
    fid, payload = codec.encode(DipoleCommand((0.01, 0.0, 0.0), 1.0))
    # + an id of the board's command block the ICD leaves free, a short one
    bad = [*UNDECODABLE, serial_can(0x092, bytes(8)), serial_can(fid, payload[:3])]
    steps = [x for pair in zip(bad, good, strict=True) for x in pair]
    device = {"name": "mtq", "kind": "magnetorquer", "interface": "serial"}
    code, log, summary, events, out, _ = _run(tmp_path, pty_pair, device, steps)
    _completed(code, log, summary, events, "mtq", rejected=5)
    emu = summary["device_counters"]["mtq"]["emulator"]
    assert emu["rejected_undecodable"] == 3 and emu["rejected_unknown_id"] == 1 and emu["rejected_length"] == 1
    assert emu["commands_accepted"] == len(good)
    # Every commanded dipole was driven (quantised to the board's 0.2/1023 A m^2 PWM step).
    held = telemetry.load(out)["mtq.dipole_B"][:, 0]
    for m in dipoles:
        assert np.min(np.abs(held - m)) <= 0.2 / 1023, m


def test_served_reaction_wheel_drops_malformed_can_frames_and_applies_the_commands_between(pty_pair, tmp_path):
    from drivers.reaction_wheel.codec import ReactionWheelCodec, TorqueCommand

    codec = ReactionWheelCodec(0)
    good = [serial_can(*codec.encode(TorqueCommand(tau, seq=k))) for k, tau in enumerate((1e-3, -1e-3, 2e-3))]
    steps = [x for pair in zip(UNDECODABLE, good, strict=True) for x in pair]
    device = {"name": "rw0", "kind": "reaction_wheel", "interface": "serial", "wheel": 0, "spin_axis_B": [0, 0, 1],
              "inertia_kg_m2": 2e-3, "max_torque_Nm": 4e-3, "ideal": True}
    code, log, summary, events, out, _ = _run(tmp_path, pty_pair, device, steps, spacecraft=HEAVY)
    _completed(code, log, summary, events, "rw0", rejected=3)
    emu = summary["device_counters"]["rw0"]["emulator_counters"]
    assert emu["rejected_undecodable"] == 3 and emu["commands_accepted"] == len(good)
    cmd = telemetry.load(out)["rw0.torque_cmd_Nm"]
    assert {1e-3, -1e-3, 2e-3} <= {round(float(c), 6) for c in cmd}


# -- serial devices --------------------------------------------------------------------------------------------


def test_served_star_tracker_counts_each_bad_frame_once_nacks_per_its_icd_and_answers_the_rest(pty_pair, tmp_path):
    from drivers.star_tracker.codec import Nack, RequestTelemetry, StarTrackerCodec, Status, crc16
    from drivers.star_tracker.slip import SlipDecoder, escape

    codec = StarTrackerCodec()
    a = codec.default_address
    request = codec.encode(RequestTelemetry(codec.status_id), a)

    def with_crc(body: bytes) -> bytes:
        return escape(body + crc16(body).to_bytes(2, "little"))

    body = codec.encode_body(RequestTelemetry(codec.status_id), a)
    bad = [escape(bytes([a, 0x03, 0x00])),  # 3 bytes: too short to hold a CRC (dropped, no NACK)
           bytes([0xC0, a, 0xDB, 0x01, 0xC0]),  # a bad SLIP escape (dropped, no NACK)
           escape(body[:-2] + bytes([body[-2] ^ 0xFF, body[-1]])),  # a bad CRC (dropped, no NACK)
           with_crc(bytes([a, 0x7F])),  # an unknown id: NACK UNKNOWN_MESSAGE
           with_crc(bytes([a, codec.messages["REQUEST_TELEMETRY"].id, codec.status_id, 0x00]))]  # NACK BAD_LENGTH
    steps = [x for frame in bad for x in (frame, request)]
    device = {"name": "st1", "kind": "star_tracker", "boot_time_s": 0.5}
    code, log, summary, events, _, peer = _run(tmp_path, pty_pair, device, steps, hello=request)
    _completed(code, log, summary, events, "st1", rejected=5)
    emu = summary["device_counters"]["st1"]["emulator_counters"]
    assert emu["rejected_other"] == 2 and emu["rejected_crc"] == 1
    assert emu["rejected_unknown_id"] == 1 and emu["rejected_length"] == 1 and emu["commands_nacked"] == 2
    replies = [codec.decode_body(b) for b in SlipDecoder(codec.max_body).feed(bytes(peer.rx))]
    nacks = [r for r in replies if isinstance(r, Nack)]
    assert [(n.command_id, n.error) for n in nacks] == [(0x7F, "UNKNOWN_MESSAGE"),
                                                       (codec.messages["REQUEST_TELEMETRY"].id, "BAD_LENGTH")]
    status = [r for r in replies if isinstance(r, Status)]
    assert len(status) >= 5  # every valid request between the bad frames was answered
    # The device's own STATUS counters saw them too: the last one, after all five.
    assert status[-1].rejected_crc == 1 and status[-1].rejected_other == 4 and status[-1].commands_nacked == 2


def _datagram_steps(codec, good: bytes, command_id: int) -> tuple[list[bytes], bytes]:
    """Bad datagrams for a datagram device, each followed by ``good``: cut after 3 bytes, a bad CRC, noise without
    an identifier, and (returned apart) a datagram with a good CRC and a value outside its table."""
    spec = codec.by_id[command_id]
    order = codec.byte_order
    out_of_range = None
    for fill in (b"\xff", b"\x00"):
        head = bytes([command_id]) + fill * (spec.length - 3)
        candidate = head + codec_crc(head).to_bytes(2, order)
        try:
            codec.decode(candidate)
        except Exception:  # noqa: BLE001 - a DatagramRejected "value": what we want
            out_of_range = candidate
            break
    assert out_of_range is not None
    bad = [bytes([command_id, 0x00, 0x01]), good[:-2] + bytes([good[-2] ^ 0xFF, good[-1]]), b"\x00\x01\x02\x03"]
    return [x for frame in [*bad, out_of_range] for x in (frame, good)], out_of_range


def codec_crc(data: bytes) -> int:
    from drivers.datagram import crc16

    return crc16(data)


def test_served_gyro_counts_each_bad_datagram_once_and_applies_the_commands_between(pty_pair, tmp_path):
    from drivers.gyro.codec import GyroCodec, SetOutputPeriod

    codec = GyroCodec()
    good = codec.encode(SetOutputPeriod(0.1))
    steps, _ = _datagram_steps(codec, good, good[0])
    device = {"name": "imu", "kind": "gyro", "output_rate_hz": 10.0, "ideal": True}
    code, log, summary, events, _, _ = _run(tmp_path, pty_pair, device, steps)
    _completed(code, log, summary, events, "imu", rejected=4)
    emu = summary["device_counters"]["imu"]["emulator_counters"]
    assert emu["rejected_undecodable"] == 3 and emu["rejected_other"] == 1 and emu["commands_applied"] == 4


@pytest.mark.slow
def test_served_sun_sensor_counts_each_bad_datagram_once_and_answers_the_requests_between(pty_pair, tmp_path):
    from drivers.sun_sensor.codec import RequestSample, SunSensorCodec

    codec = SunSensorCodec()
    good = codec.encode(RequestSample())
    period = codec.messages["SET_OUTPUT_PERIOD"].id
    steps, out_of_range = _datagram_steps(codec, good, period)
    device = {"name": "css", "kind": "sun_sensor", "type": "fine"}
    code, log, summary, events, _, _ = _run(tmp_path, pty_pair, device, steps)
    _completed(code, log, summary, events, "css", rejected=4)
    emu = summary["device_counters"]["css"]["emulator_counters"]
    assert emu["rejected_undecodable"] == 3 and emu["rejected_other"] == 1 and emu["requests"] == 4


@pytest.mark.parametrize("fill", [b"\xaa", b"\x00"])
def test_bad_frame_bytes_never_hide_the_valid_frames_after_them_on_a_serial_can_line(fill):
    """python-can's serial interface hands over one stray byte per recv: the served bus drains on while the port
    holds bytes, so frames behind a run of stray bytes arrive in the same tick (a cut frame swallows what follows
    it in the same write only up to its length)."""
    from drivers.can_bus import ServedBus

    class Port:
        def __init__(self, data):
            self.data = bytearray(data)

        @property
        def in_waiting(self):
            return len(self.data)

    class SerialLikeBus:
        """What python-can's SerialBus does with a line, one frame or one stray byte per recv."""

        channel_info = "serial test"

        def __init__(self, data):
            self._ser = Port(data)

        def recv(self, timeout=None):
            d = self._ser.data
            if not d:
                return None
            if d[0] != 0xAA:
                del d[0]
                return None
            if len(d) < 6 or d[5] > 8:
                del d[: min(len(d), 6)]
                raise ValueError("received DLC may not exceed 8 bytes")
            n = 10 + d[5] + 1
            frame, d[:] = bytes(d[:n]), d[n:]
            if frame[-1] != 0xBB:
                raise RuntimeError(f"invalid delimiter byte while reading message: {frame[-1]}")
            from drivers.can_bus import data_frame

            return data_frame(struct.unpack("<I", frame[6:10])[0], frame[10:-1])

    good = [serial_can(0x100 + k, bytes([k])) for k in range(3)]
    line = fill * 40 if fill != b"\xaa" else b"\xaa" + bytes(4) + b"\x09" + bytes(13) + b"\xbb"
    bus = ServedBus(SerialLikeBus(line + good[0] + line + good[1] + good[2]))
    got = []
    while (msg := bus.recv(0.0)) is not None:
        got.append(msg.arbitration_id)
    assert got == [0x100, 0x101, 0x102]
    assert bus.counters["rejected_undecodable"] == (2 if fill == b"\xaa" else 0)


def _run_unread(device: dict, tmp_path) -> dict:
    """30 s of a served device at 100 Hz, paced at 8x, whose flight computer never reads: the run must complete
    and pass; its summary."""
    data = small_scenario([device], 30.0)
    data["dynamics"]["step_s"] = 0.01  # a sample every tick at 100 Hz
    path = tmp_path / "served.toml"
    path.write_text(to_toml(data))
    out = tmp_path / "out"
    code, log = run_stand_polling(["run", str(path), "--speed", "8", "--out", str(out), "--no-progress",
                                   "--no-plots"], tmp_path, lambda: None, timeout_s=120)
    assert code == 0, log
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed", log
    return summary


def test_served_gyro_whose_flight_computer_stops_reading_drops_datagrams_and_the_run_goes_on(pty_pair, tmp_path):
    """Nobody reads the other end of the line: a real gyro streams on into the void. The line fills (about 36 kB
    through socat) and from then on the emulator drops each datagram it has no room for, counted, and never waits
    (before, its write blocked 2 s and the run aborted)."""
    stand_end, _ = pty_pair
    gyro = {"name": "imu", "kind": "gyro", "link": "served", "port": stand_end, "output_rate_hz": 100.0,
            "ideal": True}
    summary = _run_unread(gyro, tmp_path)
    emu = summary["device_counters"]["imu"]["emulator_counters"]
    # 30 s at 100 Hz is 72 kB of RATE datagrams, twice what the line holds.
    assert emu["tx_dropped"] > 0 and emu["sent"] + emu["tx_dropped"] == emu["samples"] >= 2900


def test_served_magnetorquer_whose_flight_computer_stops_reading_drops_frames_and_the_run_goes_on(pty_pair, tmp_path):
    """The same on python-can's CAN-over-serial line: before, each send waited for the full line (0.5 s) and then
    the run aborted on the CAN write timeout."""
    stand_end, _ = pty_pair
    mtq = {"name": "mtq", "kind": "magnetorquer", "link": "served", "interface": "serial", "channel": stand_end,
           "sample_rate_hz": 100.0}
    summary = _run_unread(mtq, tmp_path)
    # 30 s of 100 Hz samples (plus status and heartbeat) is about 55 kB on the line, more than it holds.
    emu = summary["device_counters"]["mtq"]["emulator"]
    assert 0 < emu["tx_dropped"] < emu["sent"] and emu["sent"] >= 3000


def test_a_served_star_tracker_records_and_scores_the_solutions_it_sent_to_the_flight_computer(pty_pair, tmp_path):
    """No host in the stand: the telemetry is what the emulator put on the line, decoded as a receiver decodes it,
    scored against the truth at each exposure (the clock inverted by the emulator, which the peer may set)."""
    from drivers.star_tracker.codec import Solution, StarTrackerCodec, Subscribe
    from drivers.star_tracker.slip import SlipDecoder

    codec = StarTrackerCodec()
    subscribe = codec.encode(Subscribe(codec.solution_id, 0.0), codec.default_address)
    device = {"name": "st1", "kind": "star_tracker", "boot_time_s": 0.5}
    code, log, summary, events, out, peer = _run(tmp_path, pty_pair, device, [subscribe], hello=subscribe,
                                                 spacecraft={"omega_BN_B_deg_s": [0.1, -0.1, 0.05]})
    assert code == 0 and summary["status"] == "completed", log
    assert summary["device_counters"]["st1"]["rejected_frames"] == 0
    sent = [r for r in (codec.decode_body(b) for b in SlipDecoder(codec.max_body).feed(bytes(peer.rx)))
            if isinstance(r, Solution)]
    tel = telemetry.load(out)
    t_exp = tel["st1.t_exposure_s"]
    assert len(sent) >= 5 and summary["device_counters"]["st1"]["solutions"] >= len(sent)
    assert np.isfinite(t_exp[-1]) and np.isfinite(tel["st1.q_TN"][-1]).all()
    scored = np.isfinite(t_exp)
    # The emulator's default noise is a few arcsec across the boresight (the Earth is in this field, so none is
    # valid, but each is scored against the truth at its exposure): within 60 arcsec, none unscored.
    assert scored.sum() >= 5 and np.all(tel["st1.err_cross"][scored] < 60.0)
