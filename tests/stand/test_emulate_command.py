"""``stand emulate star-tracker``: the emulator alone in its own process, on a pty (the test holds
the master side) and on a socat pty pair (two processes each see a tty path; skipped without
socat); usage errors are one sentence and exit 2."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from drivers.serial_port import pty_pair
from drivers.star_tracker.codec import NackError
from drivers.star_tracker.host import StarTrackerHost
from stand.cli import main
from tests.oracles import require_tool

REPO = Path(__file__).resolve().parents[2]
FAST = ["--boot-time-s", "0", "--interval-s", "0.05", "--delay-s", "0.01"]


def _emulate(port: str, *extra: str) -> tuple[subprocess.Popen, str]:
    """Start the emulator process and wait for its banner (the port is open then: pyserial flushes
    its input when it opens a port, so a request sent earlier would be lost)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "stand.cli", "emulate", "star-tracker", "--port", port, *FAST, *extra],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    banner = proc.stdout.readline()  # bounded: the process prints it or exits (EOF)
    return proc, banner


def _first_solution(host: StarTrackerHost):
    for _ in range(300):  # the first solution comes one output delay after boot: wait for it
        try:
            return host.request_solution(timeout_s=2.0)
        except NackError:
            time.sleep(0.01)
    raise AssertionError("no solution from the emulator process")


def _finish(proc: subprocess.Popen) -> tuple[str, str]:
    try:
        out, err = proc.communicate(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise
    return out, err


def test_emulate_serves_a_pty_for_a_bounded_duration_and_prints_counters():
    master, slave_path, slave_fd = pty_pair()
    proc, banner = _emulate(slave_path, "--duration", "3", "--ra", "30", "--dec", "40", "--roll", "0")
    try:
        with StarTrackerHost(master, timeout_s=2.0) as host:
            sol = _first_solution(host)
            # boresight at (30, 40) deg: the third row of dcm(q_TN) is the boresight in GCRS
            from sim.rotations import dcm

            z = dcm(sol.q_TN)[2]
            assert z == pytest.approx([0.66341395, 0.38302222, 0.64278761], abs=1e-4)
            status = host.request_status()
            assert status.frames_received >= 2
        out, err = _finish(proc)  # stops by itself after --duration
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        master.close()
        os.close(slave_fd)
    assert proc.returncode == 0, err
    lines = out.strip().splitlines()
    assert banner.startswith(f"stand emulate: star tracker at address 0x21 on {slave_path} for 3 s")
    report = json.loads(lines[-1])
    assert report["device"] == "star-tracker" and report["counters"]["frames_received"] >= 2
    assert report["counters"]["sent"] >= 2


def test_two_processes_over_a_socat_pty_pair_and_sigterm_stops_the_emulator(tmp_path):
    require_tool("socat", "socat")
    a, b = tmp_path / "ttyST_A", tmp_path / "ttyST_B"
    socat = subprocess.Popen(["socat", f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    proc = None
    try:
        for _ in range(500):
            if a.exists() and b.exists():
                break
            time.sleep(0.01)
        assert a.exists() and b.exists(), "socat did not create its pty pair"
        proc, banner = _emulate(str(b), "--duration", "20", "--address", "0x30")
        assert "address 0x30" in banner
        with StarTrackerHost(str(a), address=0x30, timeout_s=2.0) as host:
            sol = _first_solution(host)
            # default pointing (ra 0, dec 0, roll 0): boresight along GCRS +x
            from sim.rotations import dcm

            assert dcm(sol.q_TN)[2] == pytest.approx([1.0, 0.0, 0.0], abs=1e-4)
            assert host.counters["rejected_crc"] == 0
        proc.send_signal(signal.SIGTERM)  # like Ctrl-C: stop and print the counters
        out, err = _finish(proc)
        assert proc.returncode == 0, err
        assert json.loads(out.strip().splitlines()[-1])["counters"]["frames_received"] >= 1
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.communicate()
        socat.send_signal(signal.SIGTERM)
        socat.wait(5)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["emulate", "flux-capacitor", "--port", "loop://"],
         "device 'flux-capacitor' is not known; available: magnetorquer, star-tracker, sun-sensor, cage, gyro, "
         "reaction-wheel"),
        (["emulate", "star-tracker", "--port", "loop://", "--duration", "-1"], "--duration -1.0 is not allowed"),
        (["emulate", "star-tracker", "--port", "loop://", "--dec", "95"], "--dec 95.0 is not allowed"),
        (["emulate", "star-tracker", "--port", "loop://", "--rate-deg-s", "1,2"], "--rate-deg-s '1,2' is not allowed"),
        (["emulate", "star-tracker", "--port", "/nonexistent/tty"], "cannot open serial port '/nonexistent/tty'"),
    ],
)
def test_usage_errors_are_one_sentence_and_exit_2(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_emulate_on_loop_url_stops_after_duration(capsys):
    assert main(["emulate", "star-tracker", "--port", "loop://", "--duration", "0.2"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert json.loads(out[-1])["port"] == "loop://"
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL or callable(signal.getsignal(signal.SIGTERM))


def test_magnetorquer_emulator_serves_a_flight_computer_on_can(capsys):
    """`stand emulate magnetorquer` on a virtual bus; a 'flight computer' thread uses the host driver."""
    import threading

    import numpy as np

    from drivers.can_bus import open_bus
    from drivers.magnetorquer.host import MagnetorquerBoard
    from stand.cli import main

    got = {}

    def flight_computer():
        with MagnetorquerBoard(open_bus("virtual", "emulate-test"), owns_bus=True) as board:
            got["sample"] = board.read_sample(timeout_s=3.0)
            board.command_dipole((0.1, 0.0, -0.1), 2.0)  # on past the next 1 Hz status
            got["status"] = None
            for _ in range(300):  # bounded: status comes at 1 Hz
                board.poll()
                if board.latest_status is not None and any(board.latest_status.coil_active):
                    got["status"] = board.latest_status
                    break
                threading.Event().wait(0.01)

    fc = threading.Thread(target=flight_computer)
    fc.start()
    code = main(["emulate", "magnetorquer", "--port", "virtual:emulate-test", "--duration", "2.5",
                 "--field-nT", "21000,-3000,-41000"])
    fc.join(timeout=10)
    out = capsys.readouterr().out
    assert code == 0 and '"commands_accepted": 1' in out
    # The board's default magnetometer noise is 50 nT and bias a few hundred nT.
    np.testing.assert_allclose(got["sample"].b_T, [21000e-9, -3000e-9, -41000e-9], atol=1.5e-6)
    assert got["status"] is not None


def test_magnetorquer_port_must_name_interface_and_channel(capsys):
    from stand.cli import main

    assert main(["emulate", "magnetorquer", "--port", "can0", "--duration", "1"]) == 2
    assert "INTERFACE:CHANNEL" in capsys.readouterr().err


# -- a port in use -------------------------------------------------------------------------------------------------


def _stand(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "stand.cli", *argv], cwd=REPO, capture_output=True, text=True,
                          timeout=60)


def test_a_port_one_emulator_serves_is_refused_to_a_second_emulator_and_to_a_run(pty_pair, tmp_path, capsys):
    from tests.stand.conftest import to_toml
    from tests.stand.test_gyro_wheel_links import small_scenario

    stand_end, peer_end = pty_pair
    first, banner = _emulate(stand_end, "--duration", "30")
    try:
        assert "star tracker at address" in banner
        second = _stand("emulate", "star-tracker", "--port", stand_end, "--duration", "2")
        assert second.returncode == 2, second.stdout + second.stderr
        assert f"serial port {stand_end!r} is in use" in second.stderr and "Traceback" not in second.stderr
        # A run serving a tracker on that port is refused the same way, before t = 0.
        served = {"name": "st1", "kind": "star_tracker", "link": "served", "port": stand_end}
        path = tmp_path / "served.toml"
        path.write_text(to_toml(small_scenario([served], 5.0)))
        capsys.readouterr()
        assert main(["run", str(path), "--speed", "2", "--out", str(tmp_path / "out"), "--no-progress"]) == 2
        assert f"serial port {stand_end!r} is in use" in capsys.readouterr().err
        # The first emulator never lost a byte to them: it still answers on the line.
        with StarTrackerHost(peer_end, name="fc") as host:
            assert _first_solution(host) is not None
    finally:
        first.terminate()
        out, _ = _finish(first)
    assert json.loads(out.strip().splitlines()[-1])["counters"]["rejected_crc"] == 0


def test_a_serial_can_line_one_board_serves_is_refused_to_a_second_board(pty_pair):
    stand_end, _ = pty_pair
    first = subprocess.Popen([sys.executable, "-m", "stand.cli", "emulate", "magnetorquer", "--port",
                              f"serial:{stand_end}", "--duration", "30"], cwd=REPO, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        assert "magnetorquer board on CAN serial" in first.stdout.readline()
        second = _stand("emulate", "magnetorquer", "--port", f"serial:{stand_end}", "--duration", "2")
        assert second.returncode == 2, second.stdout + second.stderr
        assert f"serial port {stand_end!r} is in use" in second.stderr and "Traceback" not in second.stderr
    finally:
        first.terminate()
        _finish(first)
    assert first.returncode == 0


def test_open_port_holds_a_device_path_exclusively_and_lets_go_on_close(pty_pair):
    from drivers.errors import ConnectError
    from drivers.serial_port import open_port

    stand_end, _ = pty_pair
    port, owned = open_port(stand_end, name="first")
    assert owned
    with pytest.raises(ConnectError, match=r"second: serial port .* is in use"):
        open_port(stand_end, name="second")
    port.close()
    again, _ = open_port(stand_end, name="third")  # closing released it
    again.close()
