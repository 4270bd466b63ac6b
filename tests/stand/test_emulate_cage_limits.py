"""``stand emulate cage`` in its own OS process under abuse (issue 22 item 7): more connections than it
serves, past its file-descriptor limit, with its output never drained, a pipelined flood from one client
beside a host that keeps the heartbeat; SIGTERM always ends it. Every socket is on 127.0.0.1 and every
process is ended by the test."""

from __future__ import annotations

import json
import os
import resource
import signal
import socket
import struct
import subprocess
import sys
import threading
import time

import pytest

from drivers.cage.emulator import MAX_CONNECTIONS
from drivers.cage.host import CageHost
from tests.stand.processes import REPO, stand_env


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(port: int, stderr, fd_limit: int | None = None, duration_s: float = 60.0) -> subprocess.Popen:
    def limit():
        if fd_limit is not None:
            resource.setrlimit(resource.RLIMIT_NOFILE, (fd_limit, fd_limit))

    proc = subprocess.Popen([sys.executable, "-m", "stand.cli", "emulate", "cage", "--port",
                             f"tcp://127.0.0.1:{port}", "--duration", str(duration_s)], cwd=REPO, env=stand_env(),
                            stdout=subprocess.PIPE, stderr=stderr, preexec_fn=limit)
    banner = proc.stdout.readline().decode()
    assert banner.startswith(f"stand emulate: cage on tcp://127.0.0.1:{port}"), banner
    return proc


def _finish(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.communicate(timeout=10)  # also closes its pipes


def _connect_many(port: int, n: int) -> list[socket.socket]:
    out = []
    for _ in range(n):
        try:
            out.append(socket.create_connection(("127.0.0.1", port), timeout=2.0))
        except OSError:  # the listen backlog of a server that is not accepting: enough to show it
            break
    return out


def _ended_by_sigterm(proc: subprocess.Popen, within_s: float = 15.0) -> bool:
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(within_s)
        return True
    except subprocess.TimeoutExpired:
        return False


def test_connections_beyond_the_maximum_are_closed_with_one_log_line_and_the_host_goes_on(tmp_path):
    port = _free_port()
    err_path = tmp_path / "stderr.txt"
    with err_path.open("wb") as err:
        proc = _start(port, err)
    try:
        with CageHost.open(f"tcp://127.0.0.1:{port}", timeout_s=2.0) as host:  # the first connection
            extra = _connect_many(port, MAX_CONNECTIONS + 20)
            assert len(extra) == MAX_CONNECTIONS + 20
            # accepted in the order they came: the host and the next MAX - 1 are served, the rest closed at once
            served, refused = extra[:MAX_CONNECTIONS - 1], extra[MAX_CONNECTIONS - 1:]
            closed = 0
            for s in refused:
                s.settimeout(5.0)
                try:
                    closed += s.recv(1) == b""
                except ConnectionResetError:
                    closed += 1
            for s in served:
                s.settimeout(0.05)
                with pytest.raises(TimeoutError):  # still open, waiting for a request
                    s.recv(1)
            assert closed == len(refused)
            host.enable()
            assert host.status().output_on  # the host that was there first is still served
            for s in extra:
                s.close()
        assert _ended_by_sigterm(proc)
        out = proc.communicate(timeout=10)[0].decode()
    finally:
        _finish(proc)
    counters = json.loads(out.strip().splitlines()[-1])["counters"]
    assert counters["connections_refused"] == closed
    lines = [li for li in err_path.read_text().splitlines() if "refused a connection" in li]
    assert len(lines) == 1 and f"{MAX_CONNECTIONS} connections are open" in lines[0]


def test_past_its_fd_limit_with_output_not_drained_it_writes_little_and_sigterm_ends_it():
    port = _free_port()
    proc = _start(port, subprocess.PIPE, fd_limit=40)  # stderr is a pipe this test never reads until the end
    socks: list[socket.socket] = []
    try:
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:  # keep knocking while it is out of descriptors
            socks += _connect_many(port, 20)
            for s in socks[:-60]:
                s.close()
            socks = socks[-60:]
            time.sleep(0.05)
        assert _ended_by_sigterm(proc), "the emulator did not end on SIGTERM"
        err = proc.communicate(timeout=10)[1]
    finally:
        for s in socks:
            s.close()
        _finish(proc)
    assert b"Traceback" not in err
    assert len(err) < 4096, f"{len(err)} bytes of output in 3 s: {err[:400]!r}"


def test_a_pipelined_flood_from_one_client_does_not_trip_a_hosts_heartbeat(tmp_path):
    port = _free_port()
    with (tmp_path / "stderr.txt").open("wb") as err:
        proc = _start(port, err)
    stop = threading.Event()

    def flood():
        frame = struct.pack(">HHHB", 1, 0, 6, 1) + bytes([3, 0, 0, 0, 6])
        burst = frame * (720_000 // len(frame))
        with socket.create_connection(("127.0.0.1", port), timeout=5.0) as s:
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            threading.Thread(target=lambda: _drain(s, stop), daemon=True).start()
            for i in range(0, len(burst), 48):  # four frames a write: pymodbus serves one request a read
                if stop.is_set():
                    break
                try:
                    s.sendall(burst[i:i + 48])
                except OSError:
                    break

    try:
        with CageHost.open(f"tcp://127.0.0.1:{port}", timeout_s=2.0) as host:
            host.enable()
            flooder = threading.Thread(target=flood, daemon=True)
            flooder.start()
            worst_s = 0.0
            for _ in range(40):  # 4 s of a 10 Hz host
                t = time.monotonic()
                host.heartbeat()
                worst_s = max(worst_s, time.monotonic() - t)
                time.sleep(0.1)
            st = host.status()
            stop.set()
            flooder.join(10)
        assert _ended_by_sigterm(proc)
        out = proc.communicate(timeout=10)[0].decode()
    finally:
        stop.set()
        _finish(proc)
    assert st.output_on and st.values["heartbeat_trips"] == 0, (worst_s, st.values["heartbeat_trips"])
    assert worst_s < 0.5  # a heartbeat request never waited as long as the cage's timeout
    counters = json.loads(out.strip().splitlines()[-1])["counters"]
    assert counters["throttled"] >= 1  # the flooder was held to its rate


def _drain(s: socket.socket, stop: threading.Event) -> None:
    s.settimeout(0.2)
    while not stop.is_set():
        try:
            if not s.recv(65536):
                return
        except TimeoutError:
            continue
        except OSError:
            return


def test_sigterm_ends_the_emulator_promptly_and_it_reports_its_counters():
    port = _free_port()
    proc = _start(port, subprocess.PIPE)
    try:
        t = time.monotonic()
        assert _ended_by_sigterm(proc)
        took_s = time.monotonic() - t
        out = proc.communicate(timeout=10)[0].decode()
    finally:
        _finish(proc)
    assert proc.returncode == 0 and took_s < 10.0
    assert json.loads(out.strip().splitlines()[-1])["device"] == "cage"
    assert os.path.exists(REPO)  # nothing else to clean up: the process and its sockets are gone
