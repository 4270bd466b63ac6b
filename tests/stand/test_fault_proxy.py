"""``stand fault-proxy`` across OS processes: a device emulator in one process, the proxy in another, the host driver
in a third (or in the test), over two socat pty pairs (serial) or two python-can ``udp_multicast`` groups inside a
private network namespace (CAN). The proxy drops, corrupts and delays frames; the counters on every side agree with
what it did."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from contextlib import ExitStack
from pathlib import Path

import pytest

from stand.cli import main
from tests.oracles import require_tool
from tests.stand.processes import private_netns_ok, stand_env

GYRO_DEVICE = """
import json, sys
from drivers.gyro.emulator import GyroEmulator, GyroEmulatorConfig

port, duration = sys.argv[1], float(sys.argv[2])
emu = GyroEmulator(port, lambda t: (0.01, -0.02, 0.03), GyroEmulatorConfig(output_period_s=0.05))
with emu:
    print("ready", flush=True)
    emu.run(duration)
    print(json.dumps(emu.counters), flush=True)
"""

RATE_LEN = 24  # bytes of the gyro's RATE datagram (fixtures/devices/gyro.toml)


def _socat_pair(stack: ExitStack, tmp_path: Path, name: str) -> tuple[str, str]:
    """Two linked ptys ``(a, b)`` made by socat, stopped when ``stack`` closes."""
    require_tool("socat", "socat")
    a, b = tmp_path / f"{name}-a", tmp_path / f"{name}-b"
    proc = subprocess.Popen(["socat", f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    stack.callback(_stop, proc)
    deadline = time.monotonic() + 5
    while not (a.exists() and b.exists()) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert a.exists() and b.exists(), "socat made no pty pair within 5 s"
    return str(a), str(b)


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)


def _ready(proc: subprocess.Popen, word: str, timeout_s: float = 30.0) -> None:
    """Wait (bounded) for the child's first line; it must contain ``word``."""
    deadline = time.monotonic() + timeout_s
    line = ""
    while time.monotonic() < deadline and proc.poll() is None:
        line = proc.stdout.readline()
        if line:
            break
    assert word in line, f"expected {word!r} from the child, got {line!r}"


@pytest.mark.slow
def test_the_serial_proxy_drops_corrupts_and_delays_frames_between_processes(tmp_path):
    from drivers.gyro.codec import SetTime
    from drivers.gyro.host import GyroHost

    counters_file = tmp_path / "proxy.json"
    with ExitStack() as stack:
        host_end, proxy_host_end = _socat_pair(stack, tmp_path, "host")
        proxy_device_end, device_end = _socat_pair(stack, tmp_path, "device")
        # Faults in wall seconds since the proxy started; the device starts streaming about a second after it.
        proxy = subprocess.Popen(
            [sys.executable, "-m", "stand.cli", "fault-proxy", "serial", "--host-port", proxy_host_end,
             "--device-port", proxy_device_end, "--framing", "gyro", "--seed", "3",
             "--fault", "burst_drop:frames=2,direction=to_device",
             "--fault", "drop:rate=0.3,direction=to_host,at_s=2,duration_s=1.5",
             "--fault", "bit_error:rate=0.3,bits=1,direction=to_host,at_s=3.5,duration_s=1.5",
             "--fault", "delay:delay_s=0.25,direction=to_host,at_s=5,duration_s=1",
             "--duration", "60", "--counters", str(counters_file)],
            env=stand_env(), cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        stack.callback(_stop, proxy)
        _ready(proxy, "forwarding")
        host = stack.enter_context(GyroHost(host_end, name="fc gyro"))
        device = subprocess.Popen([sys.executable, "-c", GYRO_DEVICE, device_end, "6"], env=stand_env(),
                                  cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        stack.callback(_stop, device)
        _ready(device, "ready")
        commands = 0
        deadline = time.monotonic() + 30
        next_command = 0.0
        while device.poll() is None and time.monotonic() < deadline:
            if time.monotonic() >= next_command and commands < 6:
                host.send(SetTime(commands * 1_000_000))
                commands += 1
                next_command = time.monotonic() + 0.5
            host.poll()
            time.sleep(0.01)
        device_out, _ = device.communicate(timeout=30)
        emu = json.loads(device_out.strip().splitlines()[-1])
        # Frames still delayed or on their way: settled once nothing more arrived for 1 s (bounded at 10 s).
        end, quiet_from, seen = time.monotonic() + 10.0, time.monotonic(), None
        while time.monotonic() < end and time.monotonic() - quiet_from < 1.0:
            host.poll()
            now = (host.counters["frames_received"], host.counters["bytes_dropped"])
            if now != seen:
                seen, quiet_from = now, time.monotonic()
            time.sleep(0.01)
        host_counters = dict(host.counters)
        proxy.send_signal(signal.SIGTERM)
        proxy_out, _ = proxy.communicate(timeout=30)
    assert proxy.returncode == 0, proxy_out
    report = json.loads(counters_file.read_text())
    assert report["stopped_by"] == "signal" and report["in_flight"] == 0
    c, fw = report["counters"], report["forwarded"]
    dropped_to_host = c["dropped"] - 2  # the first two commands went in the burst
    # How many frames fall in each window depends on the processes' timing; each fault acted on some.
    assert commands == 6 and dropped_to_host >= 1 and c["corrupted"] >= 1 and c["delayed"] >= 1
    # The proxy saw every frame each side sent.
    assert fw["frames_from_device"] == emu["sent"] >= 100
    assert fw["frames_from_host"] == host_counters["sent"] == commands
    # The host received what the device sent less what the proxy dropped or corrupted; its CRC caught the corrupted.
    assert host_counters["frames_received"] == emu["sent"] - dropped_to_host - c["corrupted"]
    assert host_counters["bytes_dropped"] == c["corrupted"] * RATE_LEN and host_counters["rejected_crc"] >= 1
    assert host_counters["samples_lost"] == dropped_to_host + c["corrupted"]
    # The device applied the commands that were not dropped.
    assert emu["frames_received"] == emu["commands_applied"] == commands - 2
    assert emu["rejected_crc"] == emu["rejected_undecodable"] == 0


def test_the_proxy_refuses_bad_faults_and_remote_ports_before_opening_anything(capsys, tmp_path):
    assert main(["fault-proxy", "serial", "--host-port", str(tmp_path / "a"), "--device-port", str(tmp_path / "b"),
                 "--fault", "delay:delay_s=-1"]) == 2
    assert "delay delay_s = -1 is not allowed; allowed: seconds from 0 to 3600" in capsys.readouterr().err
    assert main(["fault-proxy", "serial", "--host-port", "socket://192.0.2.1:7000", "--device-port", "x"]) == 2
    assert "a URL to a host on this machine" in capsys.readouterr().err
    assert main(["fault-proxy", "can", "--host", "udp_multicast:239.1.2.3", "--device", "virtual:x"]) == 2
    assert "224.0.0.0/24" in capsys.readouterr().err
    (tmp_path / "f.toml").write_text('[[faults]]\ntype = "error_frame"\nrate = 0.1\n')
    assert main(["fault-proxy", "serial", "--host-port", "a", "--device-port", "b", "--faults",
                 str(tmp_path / "f.toml")]) == 2
    assert "error_frame' is not possible on a serial link" in capsys.readouterr().err


WHEEL_DEVICE = """
import json, sys, time
from drivers.can_bus import open_bus
from drivers.reaction_wheel.emulator import ReactionWheelEmulator

group, port, duration = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
emu = ReactionWheelEmulator(open_bus("udp_multicast", group, port=port), lambda t: 100.0, wheel=0, owns_bus=True)
t0 = time.monotonic()
for _ in range(100000):
    t = time.monotonic() - t0
    if t >= duration:
        break
    emu.service(t)
    time.sleep(0.005)
time.sleep(0.5)
emu.service(time.monotonic() - t0)
print(json.dumps(emu.counters), flush=True)
emu.close()
"""

WHEEL_HOST = """
import json, os, sys, time
from drivers.can_bus import open_bus
from drivers.reaction_wheel.host import ReactionWheelHost

group, port, duration = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
host = ReactionWheelHost(open_bus("udp_multicast", group, port=port), wheel=0)
open("host.ready", "w").close()
t0 = time.monotonic()
commands = 0
done_at = None
for _ in range(100000):
    t = time.monotonic() - t0
    # Listen `duration` s, and 1 s after the device's process ended however late it started (bounded).
    if os.path.exists("device.done") and done_at is None:
        done_at = t
    if t >= 30.0 or (t >= duration and done_at is not None and t >= done_at + 1.0):
        break
    heard = host.counters["received"] - host.counters["echoes"] > 0
    if commands < 6 and t >= 2.5 + 0.5 * commands and heard:  # once the device listens: it has sent
        host.command_torque(1e-3)
        commands += 1
    host.poll()
    time.sleep(0.005)
print(json.dumps(host.counters), flush=True)
host.bus.shutdown()
"""


@pytest.mark.slow
def test_the_can_proxy_drops_corrupts_and_delays_frames_between_processes_in_a_private_namespace(tmp_path):
    if not private_netns_ok():
        pytest.skip("unshare --net with loopback multicast routing is not permitted here (needs root or user "
                    "namespaces); udp_multicast is never used in the default namespace")
    (tmp_path / "device.py").write_text(WHEEL_DEVICE)
    (tmp_path / "host.py").write_text(WHEEL_HOST)
    py = sys.executable
    proxy_args = ("-m stand.cli fault-proxy can --host udp_multicast:224.0.0.102 --host-bus-arg port=43202 "
                  "--device udp_multicast:224.0.0.101 --device-bus-arg port=43201 --seed 4 "
                  "--fault burst_drop:frames=2,direction=to_device "
                  "--fault drop:rate=0.5,direction=to_host,at_s=4,duration_s=1.5 "
                  "--fault bit_error:rate=0.5,direction=to_host,at_s=5.5,duration_s=1.5 "
                  "--fault delay:delay_s=0.2,direction=to_host,at_s=7,duration_s=1.5 "
                  f"--duration 16 --counters {tmp_path / 'proxy.json'}")
    # The proxy first, then the host, then (once both listen) the device: each at least 1.5 s after the one before,
    # and not before that one says it is ready, however slowly a loaded machine starts them (each wait bounded at
    # 30 s). The host listens until 1 s after the device ended, the proxy longer. Separate UDP ports keep the two
    # groups apart (python-can binds each group's socket to its port on any address).
    def ready(test: str) -> str:
        return f"for i in $(seq 600); do {test} && break; sleep 0.05; done; {test} || exit 8; "

    script = (
        "ip link set lo up && ip route add 224.0.0.0/4 dev lo || exit 9; "
        f"{py} {proxy_args} > proxy.log 2>&1 & proxy=$!; sleep 1.5; " + ready("grep -q forwarding proxy.log")
        + f"{py} host.py 224.0.0.102 43202 9 > host.log 2>&1 & host=$!; sleep 1.5; " + ready("[ -e host.ready ]")
        + f"{py} device.py 224.0.0.101 43201 6 > device.log 2>&1; rc=$?; touch device.done; "
        "wait $host || rc=$?; wait $proxy || rc=$?; exit $rc"
    )
    proc = subprocess.run(["unshare", "--net", "sh", "-c", script], env=stand_env(), cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    logs = {n: (tmp_path / f"{n}.log").read_text() for n in ("proxy", "device", "host")
            if (tmp_path / f"{n}.log").exists()}
    assert proc.returncode == 0, (proc.stdout, proc.stderr, logs)
    report = json.loads((tmp_path / "proxy.json").read_text())
    emu = json.loads(logs["device"].strip().splitlines()[-1])
    host = json.loads(logs["host"].strip().splitlines()[-1])
    c, fw = report["counters"], report["forwarded"]
    dropped_to_host = c["dropped"] - 2
    assert report["stopped_by"] == "duration" and report["in_flight"] == 0
    # How many frames fall in each window depends on the processes' timing; each fault acted on some.
    assert dropped_to_host >= 1 and c["corrupted"] >= 1 and c["delayed"] >= 1
    # The proxy heard every frame the device sent (not its own, which the bus hands back to it).
    assert fw["frames_from_device"] == emu["sent"] >= 50
    assert fw["frames_from_host"] == host["sent"] == 6
    # What the host read: its own commands back (the group loops them), then the device's frames less the dropped;
    # each corrupted frame came as an error frame, which it rejects.
    assert host["received"] - host["echoes"] == emu["sent"] - dropped_to_host
    assert host["rejected_other"] == c["corrupted"] and host["rejected_length"] == host["rejected_unknown_id"] == 0
    # The device took the commands the proxy did not drop.
    assert emu["commands_accepted"] == emu["received"] - emu["echoes"] == 6 - 2


def test_the_serial_proxy_in_process_duplicates_reorders_and_floods_on_schedule():
    """SerialFaultProxy between two in-process lines, stepped in a made-up time: faults start and stop on their
    schedule and the host's counters agree with the proxy's."""
    from drivers.fault_proxy import SerialFaultProxy
    from drivers.gyro.codec import GyroCodec
    from drivers.gyro.emulator import GyroEmulator, GyroEmulatorConfig
    from drivers.gyro.host import GyroHost
    from drivers.serial_port import pipe_pair

    host_end, proxy_host = pipe_pair("host-line")
    proxy_device, device_end = pipe_pair("device-line")
    emu = GyroEmulator(device_end, lambda t: (0.0, 0.0, 0.1), GyroEmulatorConfig(output_period_s=0.1))
    host = GyroHost(host_end)
    seen = []
    host.add_observer(seen.append)
    proxy = SerialFaultProxy(proxy_host, proxy_device, framing=GyroCodec())
    proxy.schedule([{"type": "duplicate", "rate": 0.5, "at_s": 1.0, "duration_s": 2.0},
                    {"type": "reorder", "rate": 0.5, "at_s": 3.0, "duration_s": 2.0},
                    {"type": "babble", "frames_per_s": 50, "length": 10, "direction": "to_host", "at_s": 5.0,
                     "duration_s": 1.0}], seed=2)
    held_at_stop = None
    for k in range(140):
        t = k * 0.05
        if k == 100:  # the reorder ends now: a frame it holds goes out next, in order (no swap to see)
            held_at_stop = proxy.faults.in_flight
        proxy.due(t)
        emu.service(t)
        proxy.step(t, 0.0)
        host.poll()
    report = proxy.report()
    c = report["counters"]
    # Babble: one frame every 1/50 s after its start at 5 s, up to the last step before its end at 6 s (5.95 s).
    assert c["duplicated"] >= 3 and c["reordered"] >= 3 and c["babbled"] == 47
    assert report["forwarded"]["frames_from_device"] == emu.counters["sent"]
    assert host.counters["frames_received"] == emu.counters["sent"] + c["duplicated"]
    assert host.counters["bytes_dropped"] == 47 * 10
    s = [m.seq for m in seen]
    assert sum(1 for a, b in zip(s[:-1], s[1:], strict=True) if a == b) == c["duplicated"]
    assert held_at_stop in (0, 1)
    assert sum(1 for a, b in zip(s[:-1], s[1:], strict=True) if a == b + 1) == c["reordered"] - held_at_stop
    assert proxy.faults.active == [] and report["in_flight"] == 0
