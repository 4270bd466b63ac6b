"""Served and hardware links of the gyro (serial, through a socat pty pair) and of the reaction wheel (CAN, python-can
``udp_multicast`` only inside a private network namespace), each with its other end in another OS process."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stand import telemetry
from tests.stand.processes import private_netns_ok, run_beside_device, run_stand_polling, stand_env

from .conftest import to_toml

#: One LSB of the gyro's RATE datagram: 2^-14 deg/s.
RATE_LSB_RAD_S = np.radians(2.0 ** -14)


def small_scenario(devices: list[dict], duration_s: float, controller: dict | None = None) -> dict:
    """A spacecraft tumbling torque-free in a 500 km orbit, with only the devices given."""
    return {
        "scenario": {"name": "links", "epoch": "2026-03-20T12:00:00Z", "duration_s": duration_s, "seed": 5},
        "dynamics": {"step_s": 0.1, "integrator": "rk4", "torques": []},
        "orbit": {"altitude_km": 500.0, "i_deg": 97.4},
        "spacecraft": {"mass_kg": 4.0, "inertia_kg_m2": [0.02, 0.03, 0.01], "q_BN": [1.0, 0.0, 0.0, 0.0],
                       "omega_BN_B_deg_s": [1.0, -2.0, 3.0]},
        "devices": devices,
        "controller": controller or {"kind": "none"},
        "recording": {"rate_hz": 10.0},
    }


def test_served_gyro_streams_the_true_rate_to_a_host_in_another_process(pty_pair, tmp_path):
    from drivers.gyro.host import GyroHost

    stand_end, peer_end = pty_pair
    gyro = {"name": "imu", "kind": "gyro", "link": "served", "port": stand_end, "output_rate_hz": 10.0,
            "ideal": True}
    path = tmp_path / "served.toml"
    path.write_text(to_toml(small_scenario([gyro], 20.0)))
    out = tmp_path / "out"
    samples = []
    with GyroHost(peer_end, name="fc gyro") as host:

        def take():
            s = host.take_rate()
            if s is not None:
                samples.append(s)

        code, log = run_stand_polling(["run", str(path), "--speed", "4", "--out", str(out), "--no-progress",
                                       "--no-plots"], tmp_path, take)
        host.poll()
        counters = dict(host.counters)
    assert code == 0, log
    emu = json.loads((out / "summary.json").read_text())["device_counters"]["imu"]["emulator_counters"]
    assert counters["samples"] == emu["sent"] >= 150 and counters["rejected_crc"] == counters["rejected_other"] == 0
    assert all(s.valid for s in samples) and len(samples) >= 40
    # Each rate the host outside decoded is the true body rate of its sample tick, to within half an LSB.
    tel = telemetry.load(out)
    rows = {round(t * 1e6): k for k, t in enumerate(tel["t_s"])}
    matched = [(s, rows[s.time_us]) for s in samples if s.time_us in rows]
    assert len(matched) >= 40
    for s, k in matched:
        assert np.max(np.abs(np.array(s.omega_rad_s) - tel["omega_BN_B"][k])) <= 0.5 * RATE_LSB_RAD_S * (1 + 1e-9)
        assert tuple(tel["imu.omega_S"][k]) == s.omega_rad_s


GYRO_EMULATOR = """
import json, sys
from drivers.gyro.emulator import GyroEmulator, GyroEmulatorConfig

port, duration = sys.argv[1], float(sys.argv[2])
emu = GyroEmulator(port, lambda t: (0.01, -0.02, 0.03), GyroEmulatorConfig(output_period_s=0.05))
with emu:
    print("ready", flush=True)
    emu.run(duration)
    print(json.dumps({"counters": emu.counters}), flush=True)
"""


def test_hardware_gyro_reads_an_emulator_in_another_process(pty_pair, tmp_path):
    stand_end, device_end = pty_pair
    gyro = {"name": "imu", "kind": "gyro", "link": "hardware", "port": stand_end, "output_rate_hz": 10.0}
    path = tmp_path / "hw.toml"
    path.write_text(to_toml(small_scenario([gyro], 12.0)))
    out = tmp_path / "hw"
    code, emu_out = run_beside_device(GYRO_EMULATOR, device_end, path, out, tmp_path)
    assert code == 0, emu_out
    sent = json.loads(emu_out.strip().splitlines()[-1])["counters"]["sent"]
    host = json.loads((out / "summary.json").read_text())["device_counters"]["imu"]["host_counters"]
    assert 40 <= host["samples"] <= sent and host["rejected_crc"] == host["rejected_other"] == 0
    tel = telemetry.load(out)
    got = np.isfinite(tel["imu.omega_S"][:, 0])
    assert got.sum() >= 100 and np.all(tel["imu.valid"][got] == 1.0)
    # The device's rates, as quantised on the wire (the stand simulates nothing for a hardware gyro).
    expected = np.round(np.array([0.01, -0.02, 0.03]) / RATE_LSB_RAD_S) * RATE_LSB_RAD_S
    assert np.allclose(tel["imu.omega_S"][got], expected, rtol=0, atol=1e-12)
    assert not np.allclose(tel["omega_BN_B"][got][:, 0], expected[0], rtol=0, atol=1e-3)



def test_a_hardware_gyro_takes_protocol_faults_between_the_real_port_and_its_host(pty_pair, tmp_path):
    """On a hardware link the stand puts the faults on the host's own port (the in-process proxy): bit errors the
    host's CRC check catches, frames lost before the host sees them."""
    stand_end, device_end = pty_pair
    data = small_scenario([{"name": "imu", "kind": "gyro", "link": "hardware", "port": stand_end,
                            "output_rate_hz": 10.0}], 12.0)
    data["faults"] = [{"name": "bits", "device": "imu", "type": "bit_error", "probability": 0.5, "at_s": 3.0,
                       "duration_s": 3.0},
                      {"name": "loss", "device": "imu", "type": "frame_drop", "probability": 0.5, "at_s": 7.0,
                       "duration_s": 3.0}]
    path = tmp_path / "hw_faults.toml"
    path.write_text(to_toml(data))
    out = tmp_path / "hw_faults"
    code, emu_out = run_beside_device(GYRO_EMULATOR, device_end, path, out, tmp_path)
    assert code == 0, emu_out
    summary = json.loads((out / "summary.json").read_text())
    host = summary["device_counters"]["imu"]["host_counters"]
    link = summary["faults"]["loss"]["link_counters"]  # one link, both faults: its counters are the line's
    assert link == summary["faults"]["bits"]["link_counters"]
    assert link["corrupted"] > 0 and link["dropped"] > 0
    # Every corrupted datagram (24 bytes) is dropped whole by the host, most by its CRC check.
    assert host["bytes_dropped"] == 24 * link["corrupted"] and 0 < host["rejected_crc"] <= link["corrupted"]
    tel = telemetry.load(out)
    t, got = tel["t_s"], np.isfinite(tel["imu.omega_S"][:, 0])
    assert got[(t > 1.0)].all()  # the telemetry holds the newest sample the host took: never a garbled one
    expected = np.round(np.array([0.01, -0.02, 0.03]) / RATE_LSB_RAD_S) * RATE_LSB_RAD_S
    assert np.allclose(tel["imu.omega_S"][got], expected, rtol=0, atol=1e-12)


def _in_private_namespace(tmp_path: Path, peer: str, peer_args: str, stand_args: list[str]) -> tuple[str, str]:
    """Run ``peer`` (a Python script) and ``stand run`` side by side inside ``unshare --net`` with loopback multicast
    routing; returns the stand's output and the peer's log. Skips where a private namespace is not permitted."""
    if not private_netns_ok():
        pytest.skip("unshare --net with loopback multicast routing is not permitted here (needs root or user "
                    "namespaces); udp_multicast is never used in the default namespace")
    (tmp_path / "peer.py").write_text(peer)
    script = (
        "ip link set lo up && ip route add 224.0.0.0/4 dev lo || exit 9; "
        f"{sys.executable} {tmp_path / 'peer.py'} {peer_args} > {tmp_path / 'peer.log'} 2>&1 & peer=$!; "
        f"sleep 1; {sys.executable} -m stand.cli {' '.join(stand_args)}; rc=$?; wait $peer; exit $rc"
    )
    proc = subprocess.run(["unshare", "--net", "sh", "-c", script], env=stand_env(), cwd=tmp_path, capture_output=True,
                          text=True, timeout=300)
    log = (tmp_path / "peer.log").read_text() if (tmp_path / "peer.log").exists() else ""
    assert proc.returncode == 0, proc.stdout + proc.stderr + log
    return proc.stdout, log


WHEEL_FLIGHT_COMPUTER = """
import json, sys, time
from drivers.reaction_wheel.host import ReactionWheelHost

group, duration = sys.argv[1], float(sys.argv[2])
speeds = []
with ReactionWheelHost.open("udp_multicast", group, wheel=0) as host:
    t0 = time.monotonic()
    while time.monotonic() - t0 < duration:
        host.command_torque(1e-3)
        s = host.take_speed()
        if s is not None:
            speeds.append(float(s.speed_rad_s))
        time.sleep(0.02)
    print(json.dumps({"speeds": speeds, "counters": host.counters}), flush=True)
"""

GROUP = "239.74.163.7"
WHEEL = {"name": "rw0", "kind": "reaction_wheel", "interface": "udp_multicast", "channel": GROUP, "wheel": 0,
         "spin_axis_B": [0.0, 0.0, 1.0], "inertia_kg_m2": 2e-3, "max_torque_Nm": 4e-3, "ideal": True}
#: A heavy body, so that the rotor's speed relative to it is tau t / J to 1e-4.
HEAVY = {"inertia_kg_m2": [20.0, 20.0, 20.0], "omega_BN_B_deg_s": [0.0, 0.0, 0.0]}


@pytest.mark.slow
def test_served_wheel_is_driven_by_a_flight_computer_in_another_process_over_can(tmp_path):
    data = small_scenario([{**WHEEL, "link": "served"}], 20.0)
    data["spacecraft"].update(HEAVY)
    (tmp_path / "served.toml").write_text(to_toml(data))
    out = tmp_path / "out"
    _, log = _in_private_namespace(tmp_path, WHEEL_FLIGHT_COMPUTER, f"{GROUP} 12", [
        "run", str(tmp_path / "served.toml"), "--speed", "4", "--out", str(out), "--no-progress", "--no-plots",
        "--allow-remote", GROUP])
    fc = json.loads(log.strip().splitlines()[-1])
    rw0 = json.loads((out / "summary.json").read_text())["device_counters"]["rw0"]
    assert rw0["emulator_counters"]["commands_accepted"] >= 100 and fc["counters"]["rejected_other"] == 0
    # 1 mN m held on a 2e-3 kg m^2 rotor for 20 s: 10 rad/s.
    end_rad_s = rw0["speed_end_rpm"] * np.pi / 30.0
    assert end_rad_s == pytest.approx(10.0, rel=0.02)
    speeds = np.array(fc["speeds"])
    assert len(speeds) >= 30 and np.all(np.diff(speeds) >= -1e-3) and speeds[-1] == pytest.approx(end_rad_s, abs=0.3)


WHEEL_DEVICE = """
import json, sys, time
from drivers.can_bus import open_bus
from drivers.reaction_wheel.emulator import ReactionWheelEmulator

group, duration = sys.argv[1], float(sys.argv[2])
emu = ReactionWheelEmulator(open_bus("udp_multicast", group), lambda t: (100.0, 2e-3), wheel=0, owns_bus=True)
t0 = time.monotonic()
while time.monotonic() - t0 < duration:
    emu.service(time.monotonic() - t0)
    time.sleep(0.005)
print(json.dumps({"counters": emu.counters}), flush=True)
emu.close()
"""


@pytest.mark.slow
def test_hardware_wheel_drives_the_truth_by_the_torque_a_wheel_in_another_process_reports(tmp_path):
    data = small_scenario([{**WHEEL, "link": "hardware"}], 20.0)
    data["spacecraft"].update(HEAVY)
    (tmp_path / "hw.toml").write_text(to_toml(data))
    out = tmp_path / "out"
    _, log = _in_private_namespace(tmp_path, WHEEL_DEVICE, f"{GROUP} 12", [
        "run", str(tmp_path / "hw.toml"), "--speed", "4", "--out", str(out), "--no-progress", "--no-plots",
        "--allow-remote", GROUP])
    device = json.loads(log.strip().splitlines()[-1])
    host = json.loads((out / "summary.json").read_text())["device_counters"]["rw0"]["host_counters"]
    assert host["samples"] >= 30 and device["counters"]["sent"] >= host["samples"]
    tel = telemetry.load(out)
    motor = tel["rw0.motor_torque_Nm"]
    reported = motor == 2e-3
    assert reported.sum() >= 150
    # The truth's rotor turns at the reported torque: 2 mN m on 2e-3 kg m^2 is 1 rad/s^2.
    t, w = tel["t_s"][reported], tel["rw0.speed_rad_s"][reported]
    slope = np.polyfit(t, w, 1)[0]
    assert slope == pytest.approx(1.0, rel=0.01)
