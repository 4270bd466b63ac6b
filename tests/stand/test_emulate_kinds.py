"""``stand emulate gyro|sun-sensor|reaction-wheel|magnetometer``: each kind served in its own OS process for a
flight program (the kind's host driver) in this one, over a socat pty pair (the wheel and the magnetometer over
serial-line CAN on it); SIGTERM stops it with exit 0 and its counters; a port it holds is refused to a second
emulator (exit 2). A kind of an installed package is served the same way, through its own declaration."""

from __future__ import annotations

import argparse
import json
import math
import signal
import subprocess
import sys
import time

import pytest

from stand import devices
from stand.cli import main
from stand.devices.serving import ServeOption, Serving
from tests.stand.processes import REPO, stand_env


def _emulate(kind: str, *argv: str) -> tuple[subprocess.Popen, str]:
    """The emulator in another process; its banner line (printed once the port is open) or '' if it exited."""
    proc = subprocess.Popen([sys.executable, "-m", "stand.cli", "emulate", kind, *argv], cwd=REPO, env=stand_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return proc, proc.stdout.readline()


def _terminate(proc: subprocess.Popen) -> tuple[int, dict, str]:
    """SIGTERM (like Ctrl-C); its exit code, the counters line and stderr."""
    proc.send_signal(signal.SIGTERM)
    try:
        out, err = proc.communicate(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise
    return proc.returncode, json.loads(out.strip().splitlines()[-1]), err


def _refused_while_held(kind: str, port: str, *argv: str) -> None:
    second = subprocess.run([sys.executable, "-m", "stand.cli", "emulate", kind, "--port", port, *argv,
                             "--duration", "2"], cwd=REPO, env=stand_env(), capture_output=True, text=True, timeout=60)
    assert second.returncode == 2, second.stdout + second.stderr
    held = port.removeprefix("serial:")
    assert f"serial port {held!r} is in use" in second.stderr and "Traceback" not in second.stderr


def _until(ready, what: str):
    for _ in range(500):  # bounded: 5 s of 10 ms polls
        got = ready()
        if got:
            return got
        time.sleep(0.01)
    raise AssertionError(f"no {what} from the emulator process")


def test_gyro_serves_a_flight_program_in_another_process(pty_pair):
    from drivers.gyro.host import GyroHost

    stand_end, fc_end = pty_pair
    proc, banner = _emulate("gyro", "--port", stand_end, "--rate-deg-s", "10,-20,30", "--period-s", "0.02",
                            "--duration", "30")
    try:
        assert banner.startswith(f"stand emulate: gyro on {stand_end} for 30 s"), banner
        with GyroHost(fc_end, name="fc gyro") as host:
            host.set_output_period(0.01)  # a command the emulator must apply
            rate = host.read_rate(timeout_s=5.0)
            lsb = 1.0652644360316953e-06  # rad/s, RATE in fixtures/devices/gyro.toml
            assert rate.omega_rad_s == pytest.approx([math.radians(v) for v in (10, -20, 30)], abs=lsb)
            assert rate.valid and host.counters["rejected_crc"] == 0
        _refused_while_held("gyro", stand_end)
    finally:
        code, report, err = _terminate(proc)
    assert code == 0, err
    assert report["device"] == "gyro" and report["counters"]["commands_applied"] == 1
    assert report["counters"]["rejected_crc"] == 0 and report["counters"]["sent"] >= 1


def test_sun_sensor_serves_a_flight_program_in_another_process(pty_pair):
    from drivers.sun_sensor.host import SunSensorHost

    stand_end, fc_end = pty_pair
    proc, banner = _emulate("sun-sensor", "--port", stand_end, "--angles-deg", "12,-5", "--period-s", "0",
                            "--duration", "30")
    try:
        assert banner.startswith(f"stand emulate: fine sun sensor on {stand_end} for 30 s"), banner
        with SunSensorHost(fc_end, name="fc sun") as host:
            sample = host.request_sun(timeout_s=5.0)  # period 0: it only answers requests
            assert sample.angles_rad == pytest.approx((math.radians(12), math.radians(-5)), abs=1e-6)  # LSB 1 urad
            assert sample.valid
        _refused_while_held("sun-sensor", stand_end)
    finally:
        code, report, err = _terminate(proc)
    assert code == 0, err
    assert report["device"] == "sun-sensor" and report["counters"]["requests"] == 1
    assert report["counters"]["sent"] == 1 and report["counters"]["rejected_crc"] == 0


def test_reaction_wheel_serves_a_flight_program_over_serial_line_can_in_another_process(pty_pair):
    from drivers.reaction_wheel.host import ReactionWheelHost

    stand_end, fc_end = pty_pair
    proc, banner = _emulate("reaction-wheel", "--port", f"serial:{stand_end}", "--wheel", "2", "--speed-rad-s",
                            "50", "--duration", "30")
    try:
        assert banner.startswith(f"stand emulate: reaction wheel 2 on CAN serial:{stand_end} for 30 s"), banner
        host = ReactionWheelHost.open("serial", fc_end, wheel=2, name="fc wheel")
        try:
            assert float(host.read_speed(timeout_s=5.0)) == pytest.approx(50.0, abs=0.1)
            seq = host.command_torque(0.01)

            def applied():
                host.poll()
                st = host.latest_status
                return st is not None and st.seq_ack == seq

            _until(applied, "status acknowledging the torque command")
        finally:
            host.close()
        _refused_while_held("reaction-wheel", f"serial:{stand_end}")
    finally:
        code, report, err = _terminate(proc)
    assert code == 0, err
    assert report["device"] == "reaction-wheel" and report["counters"]["commands_accepted"] >= 1
    assert report["rejected_frames"] == 0


@pytest.mark.slow
def test_magnetometer_serves_a_flight_program_over_serial_line_can_in_another_process(pty_pair):
    from drivers.magnetometer.host import MagnetometerHost

    stand_end, fc_end = pty_pair
    proc, banner = _emulate("magnetometer", "--port", f"serial:{stand_end}", "--field-nT", "21000,-3500,-41250",
                            "--duration", "30")
    try:
        assert banner.startswith(f"stand emulate: magnetometer on CAN serial:{stand_end} for 30 s"), banner
        host = MagnetometerHost.open("serial", fc_end, name="fc mag")
        try:
            sample = host.read_sample(timeout_s=5.0)
            # noise-free by default; the field to half its 1 nT step
            assert sample.b_T == pytest.approx((21000e-9, -3500e-9, -41250e-9), abs=0.5e-9)
            assert sample.valid and not sample.coil_active
            seq = host.set_mode("OFF")

            def applied():
                host.poll()
                st = host.latest_status
                return st is not None and st.mode_seq_ack == seq and st.mode == "OFF"

            _until(applied, "status acknowledging the mode command")
        finally:
            host.close()
        _refused_while_held("magnetometer", f"serial:{stand_end}")
    finally:
        code, report, err = _terminate(proc)
    assert code == 0, err
    assert report["device"] == "magnetometer" and report["counters"]["commands_accepted"] == 1
    assert report["rejected_frames"] == 0 and report["counters"]["sent"] >= 1


@pytest.mark.parametrize("argv, message", [
    (["gyro", "--port", "loop://", "--rate-deg-s", "1,2"], "--rate-deg-s '1,2' is not allowed"),
    (["sun-sensor", "--port", "loop://", "--type", "coarse", "--currents-mA", "1"], "--currents-mA '1' is not allowed"),
    (["reaction-wheel", "--port", "virtual:x", "--wheel", "16"], "--wheel 16 is not allowed"),
    (["reaction-wheel", "--port", "can0"], "--port 'can0' is not allowed for the reaction wheel"),
    (["gyro", "--port", "/nonexistent/tty"], "cannot open serial port '/nonexistent/tty'"),
    (["gyro", "--port", "loop://", "--field-nT", "1,2,3"], "--field-nT is not an option of the gyro; it is for the "
                                                         "magnetorquer and the magnetometer only"),
    (["magnetometer", "--port", "virtual:x", "--field-nT", "1,2"], "--field-nT '1,2' is not allowed"),
    (["magnetometer", "--port", "virtual:x", "--noise-nT", "-3"], "--noise-nT -3 is not allowed"),
    (["magnetometer", "--port", "can0"], "--port 'can0' is not allowed for the magnetometer"),
])
def test_usage_errors_of_the_new_kinds_are_one_sentence_and_exit_2(argv, message, capsys):
    assert main(["emulate", *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


class _ProbeKind(devices.DeviceKind):
    """A kind of an installed package (entry point ``adcs_stand.devices``) that declares how it is served."""

    name = "probe_sensor"

    def __init__(self):
        self.served: list[argparse.Namespace] = []

        def serve(args, fail):
            if args.level < 0:
                return fail(f"--level {args.level} is not allowed; give 0 or more.")
            self.served.append(args)
            return 0

        self.serving = Serving(summary="a probe", port_help="anything", serve=serve,
                               options=(ServeOption("--level", "a level", 1, int),))


def test_a_kind_of_an_installed_package_is_served_through_its_own_declaration(monkeypatch, capsys):
    kind = _ProbeKind()
    monkeypatch.setattr(devices, "_installed_kinds", lambda: ("probe_sensor",))
    monkeypatch.setitem(devices._loaded, "probe_sensor", kind)
    assert main(["emulate", "probe-sensor", "--port", "somewhere", "--level", "3", "--duration", "1"]) == 0
    (args,) = kind.served
    assert (args.port, args.level, args.duration, args.device) == ("somewhere", 3, 1.0, "probe-sensor")
    assert main(["emulate", "probe-sensor", "--port", "somewhere", "--level", "-1"]) == 2
    assert "--level -1 is not allowed" in capsys.readouterr().err
    assert main(["emulate", "probe-sensor", "--port", "x", "--scenario", "detumble"]) == 2  # no port_fields
    assert "--scenario is not available for 'probe-sensor'" in capsys.readouterr().err


@pytest.mark.slow
def test_gyro_closed_loop_serves_the_scenarios_true_rate_with_scenario_and_name(pty_pair, tmp_path):
    import numpy as np

    from drivers.gyro.host import GyroHost
    from stand import telemetry
    from tests.stand.conftest import to_toml
    from tests.stand.processes import run_stand_polling
    from tests.stand.test_gyro_wheel_links import RATE_LSB_RAD_S, small_scenario

    stand_end, fc_end = pty_pair
    gyros = [{"name": name, "kind": "gyro", "output_rate_hz": 10.0, "ideal": True} for name in ("imu0", "imu1")]
    path = tmp_path / "gyros.toml"
    path.write_text(to_toml(small_scenario(gyros, 20.0)))
    out = tmp_path / "out"
    samples = []
    with GyroHost(fc_end, name="fc gyro") as host:

        def take():
            s = host.take_rate()
            if s is not None:
                samples.append(s)

        code, log = run_stand_polling(["emulate", "gyro", "--port", stand_end, "--scenario", str(path), "--name",
                                       "imu1", "--speed", "4", "--duration", "5", "--out", str(out)], tmp_path, take)
    assert code == 0, log
    assert "gyro 'imu1' of scenario links, served on" in log
    summary = json.loads((out / "summary.json").read_text())["device_counters"]
    # imu1 served to the host outside (no host of the stand's own), imu0 emulated as the scenario has it
    assert summary["imu1"]["emulator_counters"]["sent"] >= 40 and "host_counters" not in summary["imu1"]
    assert summary["imu0"]["host_counters"]["frames_received"] >= 40
    tel = telemetry.load(out)
    rows = {round(t * 1e6): k for k, t in enumerate(tel["t_s"])}
    matched = [(s, rows[s.time_us]) for s in samples if s.time_us in rows]
    assert len(matched) >= 20
    for s, k in matched:  # the true body rate of its tick, to within half an LSB (ideal gyro, sensor = body axes)
        assert np.max(np.abs(np.array(s.omega_rad_s) - tel["omega_BN_B"][k])) <= 0.5 * RATE_LSB_RAD_S * (1 + 1e-9)
