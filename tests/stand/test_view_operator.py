"""Issue 25, item 2 (the operator page) without a browser: the page of a finished `stand run --view` stays served,
the token's flag named per command, and what the pointing panel is given (tests/stand/test_view_page_browser.py
drives Chromium)."""

from __future__ import annotations

import json
import os
import pty
import queue
import re
import signal
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from stand.cli import main

ROOT = Path(__file__).resolve().parents[2]


def test_stand_view_elsewhere_names_its_own_token_flag(tmp_path, capsys):
    """`stand view --bind 0.0.0.0` used to tell the user to pass --view-token, which `stand view` refuses."""
    out = tmp_path / "run"
    # too short to detumble
    assert main(["run", "--out", str(out), "--duration", "1", "--no-progress", "--no-plots"]) == 1
    capsys.readouterr()
    assert main(["view", str(out), "--bind", "127.0.0.2:0"]) == 2
    err = capsys.readouterr().err
    assert "pass --token" in err and "--view-token" not in err
    assert main(["run", "--view", "127.0.0.2:0", "--out", str(tmp_path / "o"), "--duration", "1"]) == 2
    assert "pass --view-token" in capsys.readouterr().err


def _read_until(proc, pattern: str, timeout_s: float = 180.0) -> tuple[re.Match, str]:
    """Lines of the process's stdout until one matches ``pattern`` (bounded; a thread reads the pipe, since a
    buffered text pipe hides its lines from select)."""
    if not hasattr(proc, "lines"):
        proc.lines = queue.Queue()
        threading.Thread(target=lambda: [proc.lines.put(line) for line in proc.stdout], daemon=True).start()
    seen = ""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            line = proc.lines.get(timeout=1.0)
        except queue.Empty:
            if proc.poll() is not None and proc.lines.empty():
                break
            continue
        seen += line
        m = re.search(pattern, line)
        if m:
            return m, seen
    raise AssertionError(f"no line matching {pattern!r} in:\n{seen}")


def _get(url: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


def _start(args, tmp_path, interactive: bool):
    """`stand run ... --view` with stdin a terminal (a pseudo-terminal) or not."""
    master = slave = None
    if interactive:
        master, slave = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "stand.cli", "run", *args, "--view", "--no-progress"], cwd=ROOT,
                            stdin=slave if interactive else subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    if slave is not None:
        os.close(slave)
    return proc, master


def _end(proc, master):
    if proc.poll() is None:
        proc.kill()
        proc.wait(timeout=10)
    proc.stdout.close()
    proc.stderr.close()
    if master is not None:
        os.close(master)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_finished_run_keeps_its_page_until_the_operator_stops_it(tmp_path, sig):
    """`stand run --view` at the default speed ends in about a second: from a terminal its page stays served, with
    the verdict, until Ctrl-C or SIGTERM; the exit code stays the run's."""
    out = tmp_path / "run"
    # The default detumble cut at 600 s, its 'detumbled' limit raised from 0.5 to 10 deg/s so the cut run passes
    # (the rate falls from 17 to about 7 deg/s by then): a passing verdict and exit code 0 as the whole orbit gives,
    # without the whole orbit's loop. The page of the whole default run is test_view_page_browser.py's. Without the
    # plots, the stand says the page stays milliseconds after the run's end: the page must serve the verdict by then.
    proc, master = _start(["--out", str(out), "--duration", "600", "--set", "criteria.detumbled.max=10", "--no-plots"],
                          tmp_path, interactive=True)
    try:
        m, _ = _read_until(proc, r"live view at (http://127\.0\.0\.1:\d+/)")
        url = m.group(1)
        m, seen = _read_until(proc, r"its page stays at (http://\S+) until you press Ctrl-C \(or send SIGTERM\)")
        assert m.group(1) == url and "PASS: detumble" in seen  # the verdict came first
        assert (out / "summary.json").is_file() and not (out / "view_url.json").exists()
        for _ in range(3):  # still there a while after the run's end
            status, body = _get(url + "api/meta")
            meta = json.loads(body)
            assert status == 200 and meta["status"] == "finished" and meta["summary"]["pass"] is True
            time.sleep(0.5)
        assert _get(url)[0] == 200 and proc.poll() is None
        status, body = _get(url + "api/samples")
        assert status == 200 and b'"t_s"' in body
        proc.send_signal(sig)
        assert proc.wait(timeout=30) == 0  # the run passed; stopping the page does not change that
        with pytest.raises(OSError):
            urllib.request.urlopen(url + "api/meta", timeout=5)
    finally:
        _end(proc, master)


def test_outside_a_terminal_the_page_lingers_as_long_as_asked(tmp_path):
    """Not from a terminal (a script, CI) nobody can press Ctrl-C: no linger unless --view-linger-s asks, and then
    the stand ends by itself."""
    proc, master = _start(["--out", str(tmp_path / "a"), "--duration", "30", "--no-plots"], tmp_path, interactive=False)
    try:
        _read_until(proc, r"page's server stops \(not run from a terminal\): pass --view-linger-s SECONDS")
        assert proc.wait(timeout=30) == 1  # the run's own exit code: 30 s do not detumble
    finally:
        _end(proc, master)
    proc, master = _start(["--out", str(tmp_path / "b"), "--duration", "30", "--view-linger-s", "2", "--no-plots"],
                          tmp_path, interactive=False)
    try:
        m, _ = _read_until(proc, r"its page stays at (http://\S+) for 2 s")
        assert _get(m.group(1) + "api/meta")[0] == 200
        assert proc.wait(timeout=30) == 1
    finally:
        _end(proc, master)


@pytest.mark.parametrize("value", ["-1", "nan", "soon"])
def test_a_bad_linger_is_refused(value, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run", "--view", "--view-linger-s", value, "--duration", "1"])
    assert exc.value.code == 2
    assert f"--view-linger-s {value!r} is not allowed: seconds from 0" in capsys.readouterr().err


def test_the_3d_views_momentum_and_torques_follow_the_scenario(tmp_path):
    """h_wheels_B, h_total_B and torque_wheels_B of the page's samples, against the wheels' axes and rotor inertia
    and the spacecraft's inertia as the scenario file states them."""
    import numpy as np

    from stand.telemetry import load
    from stand.view import state

    out = tmp_path / "run"
    assert main(["run", "pointing_star_tracker", "--duration", "20", "--out", str(out), "--no-progress",
                 "--no-plots"]) in (0, 1)
    s = state.replay_samples(out, state.load_meta(out))
    tel = load(out)
    axes = {"rw0": [0.81649658, 0.0, 0.57735027], "rw1": [0.0, 0.81649658, 0.57735027],
            "rw2": [-0.81649658, 0.0, 0.57735027], "rw3": [0.0, -0.81649658, 0.57735027]}  # the scenario's
    h = sum(2.0e-3 * np.outer(tel[f"{w}.speed_rad_s"], a) for w, a in axes.items())
    tau = -sum(np.outer(tel[f"{w}.net_torque_Nm"], a) for w, a in axes.items())
    inertia = np.array([[1.2, 0.02, -0.01], [0.02, 1.5, 0.015], [-0.01, 0.015, 1.0]])
    assert np.allclose(s["h_wheels_B"], h, rtol=1e-6, atol=1e-12)
    assert np.allclose(s["torque_wheels_B"], tau, rtol=1e-6, atol=1e-15)
    assert np.allclose(s["h_total_B"], tel["omega_BN_B"] @ inertia + h, rtol=1e-6, atol=1e-12)
    # each wheel holds about 0.1 N m s (500 rpm); in the pyramid they nearly cancel, to a few mN m s: not zero
    assert 2.0e-3 * np.abs(tel["rw0.speed_rad_s"]).max() > 0.05 and np.abs(s["h_wheels_B"]).max() > 1e-3
