"""``stand run`` feeds a display node started with a shared key: the star-screen link sends through
stand.display's one state sender and signs with the scenario's key file or ``STAND_DISPLAY_KEY`` (issue 23)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
import tomllib
from types import SimpleNamespace

import pytest

from stand import scenario
from stand.cli import main
from stand.display import KEY_ENV, DisplayNode
from stand.errors import ScenarioError
from tests.stand.processes import stand_env

from .conftest import to_toml

NODE_KEY = b"the node's shared key, 32 bytes."
OTHER_KEY = b"another key of the same length.."
RUN_S = 3.0


class _Frames:
    """Stand-in renderer and output: the node's acceptance (allow-list, HMAC, sequencing) is what is tested, not
    the pixels, so each accepted state becomes a record instead of a 1920 x 1080 image."""

    def __init__(self):
        self.pushed: list[int] = []

    def render(self, q_SN, epoch, *, time_tag_ns, **_):
        return SimpleNamespace(time_tag_ns=time_tag_ns, bodies={})

    def push(self, frame) -> None:
        self.pushed.append(frame.time_tag_ns)


def _key_file(tmp_path, name: str, key: bytes, mode: int = 0o600) -> str:
    path = tmp_path / name
    path.write_bytes(key)
    os.chmod(path, mode)
    return str(path)


def _scenario(tmp_path, **tracker) -> str:
    data = tomllib.loads((scenario.SCENARIO_DIR / "detumble_star_tracker_screen.toml").read_text())
    data["devices"][1].update(tracker)
    data["devices"][0]["channel"] = f"screen-signing-{tmp_path.name}"
    data["criteria"] = [c for c in data["criteria"] if c["metric"] == "frames_rejected"]
    path = tmp_path / "signed.toml"
    path.write_text(to_toml(data))
    return str(path)


def _run_against_node(tmp_path, pty_pair, node_key: bytes, **tracker):
    """A display node with ``node_key`` serving in a thread, the open-loop tracker emulator in another process,
    and a 3 s ``stand run`` sending the screen state; (exit code, the run's screen summary, the node's stats)."""
    stand_end, tracker_end = pty_pair
    frames = _Frames()
    node = DisplayNode(("127.0.0.1", 0), frames, frames, key=node_key)
    stop = threading.Event()

    def serve():
        deadline = time.monotonic() + 120  # bounded even if the run never ends
        while not stop.is_set() and time.monotonic() < deadline:
            node.serve(timeout_s=0.2)

    server = threading.Thread(target=serve, daemon=True)
    server.start()
    path = _scenario(tmp_path, port=stand_end, screen_port=f"udp://127.0.0.1:{node.address[1]}", **tracker)
    emu = subprocess.Popen([sys.executable, "-m", "stand.cli", "emulate", "star-tracker", "--port", tracker_end,
                            "--duration", "60", "--boot-time-s", "0.5"], env=stand_env(), cwd=tmp_path,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    out = tmp_path / "run"
    try:
        assert "star tracker at address" in emu.stdout.readline()
        code = main(["run", path, "--speed", "1", "--duration", str(RUN_S), "--out", str(out), "--no-progress",
                     "--no-plots"])
    finally:
        emu.terminate()
        emu.communicate(timeout=20)
        stop.set()
        server.join(timeout=10)
        node.close()
    screen = json.loads((out / "summary.json").read_text())["device_counters"]["st1"]["screen"]
    return code, screen, node.stats, frames


@pytest.mark.slow
def test_a_run_signs_with_the_environment_key_and_the_keyed_node_accepts_every_frame(
        tmp_path, pty_pair, monkeypatch):
    monkeypatch.setenv(KEY_ENV, NODE_KEY.decode())
    code, screen, stats, frames = _run_against_node(tmp_path, pty_pair, NODE_KEY)
    assert code == 0
    assert stats.errors == {}, stats.last_error  # no hmac (nor any other) refusal
    ticks = round(RUN_S / 0.1)
    assert screen["signed"] is True and screen["frames_dropped"] == 0
    assert ticks - 2 <= screen["frames_sent"] <= ticks + 1
    assert stats.received == screen["frames_sent"]
    # The newest of what waits is rendered, the rest superseded: every frame sent is accounted for, none lost.
    assert stats.rendered + stats.superseded == stats.received and stats.rendered >= ticks // 2
    assert frames.pushed == sorted(frames.pushed)


def test_a_run_signed_with_another_key_file_is_refused_by_the_node(tmp_path, pty_pair, monkeypatch):
    monkeypatch.setenv(KEY_ENV, NODE_KEY.decode())  # the scenario's key file wins over the environment
    other = _key_file(tmp_path, "other.key", OTHER_KEY)
    code, screen, stats, frames = _run_against_node(tmp_path, pty_pair, NODE_KEY, screen_key_file=other)
    assert code == 0 and screen["signed"] is True and screen["frames_sent"] >= round(RUN_S / 0.1) - 2
    assert stats.errors == {"hmac": screen["frames_sent"]} and "another key" in stats.last_error
    assert stats.rendered == 0 and frames.pushed == []


@pytest.mark.parametrize("what", ["short", "world_readable", "relative", "missing"])
def test_a_key_file_the_link_cannot_use_is_refused_naming_the_key(tmp_path, monkeypatch, what):
    monkeypatch.delenv(KEY_ENV, raising=False)
    path = {"short": lambda: _key_file(tmp_path, "k", b"too short"),
            "world_readable": lambda: _key_file(tmp_path, "k", NODE_KEY, 0o644),
            "relative": lambda: "display.key",
            "missing": lambda: str(tmp_path / "absent.key")}[what]()
    with pytest.raises(ScenarioError) as info:
        scenario.load(_scenario(tmp_path, screen_key_file=path))
    assert info.value.field == "devices[1].screen_key_file"
    text = str(info.value)
    assert "\n" not in text
    assert {"short": "9 bytes", "world_readable": "chmod 600", "relative": "absolute path",
            "missing": "cannot be read"}[what] in text


def test_a_short_environment_key_is_refused_by_the_scenario_check(tmp_path, monkeypatch):
    monkeypatch.setenv(KEY_ENV, "short")
    with pytest.raises(ScenarioError) as info:
        scenario.load(_scenario(tmp_path))
    assert info.value.field == "devices[1].screen" and f"{KEY_ENV} holds a key of 5 bytes" in str(info.value)

