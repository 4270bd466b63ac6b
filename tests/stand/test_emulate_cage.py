"""``stand emulate cage``: the cage emulator alone in its own process on Modbus TCP (127.0.0.1),
driven by the host driver; a bad port is one sentence and exit 2."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from drivers.cage.host import CageHost
from stand.cli import main

REPO = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_emulate_cage_serves_modbus_tcp_in_wall_time_for_a_bounded_duration():
    port = _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "stand.cli", "emulate", "cage", "--port", f"tcp://127.0.0.1:{port}",
                             "--duration", "4"], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        banner = proc.stdout.readline()  # printed once the server listens (or EOF if it exits)
        assert banner.startswith(f"stand emulate: cage on tcp://127.0.0.1:{port} for 4 s"), proc.stderr.read()
        with CageHost.open(f"tcp://127.0.0.1:{port}", timeout_s=2.0) as host:
            host.enable()
            host.command_currents((0.5, 0.0, -0.2))
            deadline = time.monotonic() + 2.0
            sample = host.take_field()
            while sample.currents_A[0] < 0.5 - 1e-5 and time.monotonic() < deadline:  # 50 ms ramp at 10 A/s
                time.sleep(0.02)
                host.heartbeat()
                sample = host.take_field()
            assert sample.currents_A == pytest.approx((0.5, 0.0, -0.2), abs=1e-5)
            assert sample.valid and sample.t_s > 0.0
        out, err = proc.communicate(timeout=15)  # stops by itself after --duration
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    report = json.loads(out.strip().splitlines()[-1])
    assert report["device"] == "cage" and report["t_s"] >= 3.9
    assert report["counters"]["received"] >= 4 and report["counters"]["rejected"] == 0


def test_a_bad_cage_port_is_one_sentence_and_exit_2(capsys):
    assert main(["emulate", "cage", "--port", "tcp://127.0.0.1"]) == 2
    err = capsys.readouterr().err
    assert "tcp://HOST:PORT" in err and "Traceback" not in err
