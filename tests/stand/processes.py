"""The stand in another OS process, for the cross-process link tests."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def stand_env() -> dict:
    """The environment for a child process that imports this checkout's packages."""
    return {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def run_stand_polling(args: list[str], cwd, on_poll: Callable[[], None], timeout_s: float = 60.0) -> tuple[int, str]:
    """Run ``stand ARGS`` in another process and call ``on_poll()`` every 10 ms while it runs (at most ``timeout_s``,
    then it is killed). Returns its exit code and output (stdout and stderr together)."""
    stand = subprocess.Popen([sys.executable, "-m", "stand.cli", *args], env=stand_env(), cwd=cwd,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + timeout_s
        while stand.poll() is None and time.monotonic() < deadline:
            on_poll()
            time.sleep(0.01)
        log, _ = stand.communicate(timeout=30)
    finally:
        if stand.poll() is None:
            stand.kill()
            stand.communicate()
    return stand.returncode, log


def private_netns_ok() -> bool:
    """True where ``unshare --net`` may make a private network namespace with loopback multicast routing (what
    python-can's udp_multicast needs between processes without touching the machine's network)."""
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return False
    probe = subprocess.run(["unshare", "--net", "sh", "-c", "ip link set lo up && ip route add 224.0.0.0/4 dev lo"],
                           capture_output=True, timeout=10)
    return probe.returncode == 0


def run_beside_device(script: str, device_port: str, scenario_path: Path, out: Path, cwd) -> tuple[int, str]:
    """A device emulator ``script`` in another process on ``device_port`` (given 8 s; it prints ``ready`` once it
    listens), and ``stand run`` of ``scenario_path`` at 4x real time into ``out`` in this one. Returns the stand's
    exit code and the device process's output."""
    from stand.cli import main

    emu = subprocess.Popen([sys.executable, "-c", script, device_port, "8"], env=stand_env(), cwd=cwd,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert emu.stdout.readline().strip() == "ready"
        code = main(["run", str(scenario_path), "--speed", "4", "--out", str(out), "--no-progress", "--no-plots"])
    finally:
        emu_out, _ = emu.communicate(timeout=30)
    return code, emu_out
