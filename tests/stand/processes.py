"""The stand in another OS process, for the cross-process link tests."""

from __future__ import annotations

import os
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
