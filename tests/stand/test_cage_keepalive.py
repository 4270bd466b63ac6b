"""A cage on a hardware link (issue 22 item 8): the emulated cage in wall time on Modbus TCP 127.0.0.1 with its
0.5 s heartbeat timeout, driven by a paced run of ``detumble_cage``. A 2 s operator pause does not switch it off
(the stand's keepalive thread feeds the heartbeat); a trip the stand could not prevent is noticed, logged, and
the cage switched on again (or, when it refuses, the run ends aborted, saying why); the summary counts them."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest

from drivers.cage.calibration import CageCalibration
from drivers.cage.emulator import CageEmulator
from stand import scenario as scenario_mod
from stand import telemetry
from stand.compose import build
from stand.loop import run

DURATION_S = 4.0


class Operator:
    """The operator page's control feed: at the first poll at or after sim time ``at_s`` it calls ``act()``, which
    returns ``"pause"`` (held for ``pause_polls`` polls of 50 ms) or None."""

    def __init__(self, at_s: float, act, pause_polls: int = 0) -> None:
        self.at_s, self.act, self.pause_polls = at_s, act, pause_polls
        self.t_s = 0.0
        self.done = False

    def record(self, t_s, row) -> None:
        self.t_s = t_s

    def poll_control(self):
        if not self.done and self.t_s >= self.at_s:
            self.done = True
            return self.act()
        if self.done and self.pause_polls > 0:
            self.pause_polls -= 1
            return "pause"
        return None


@pytest.fixture
def cage_bench(tmp_path):
    emu = CageEmulator()  # wall time: its watchdog runs whatever the stand does
    _, port = emu.serve_tcp("127.0.0.1", 0)
    cal = CageCalibration.from_config(emu.config).save(tmp_path / "cage_cal.json")
    yield emu, port, cal
    emu.close()
    assert not [t for t in threading.enumerate() if t.name.startswith(("cage-emulator", "cage-keepalive"))]


def _run(tmp_path, port, cal, operator):
    sc = scenario_mod.load("detumble_cage", [
        "devices.cage.link=hardware", f"devices.cage.url=tcp://127.0.0.1:{port}", f"devices.cage.calibration={cal}"])
    out = tmp_path / "run"
    scene = build(sc, 1.0, None, duration_s=DURATION_S, out_dir=out)
    with scene:
        result = run(scene, out, speed=1.0, duration_s=DURATION_S, observer=operator)
    events = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]
    return result, events, out


def test_a_two_second_operator_pause_does_not_switch_the_cage_off(tmp_path, cage_bench):
    emu, port, cal = cage_bench
    result, events, _ = _run(tmp_path, port, cal, Operator(1.0, lambda: "pause", pause_polls=40))
    kinds = [e["kind"] for e in events]
    assert "paused" in kinds and "resumed" in kinds
    resumed = next(e for e in events if e["kind"] == "resumed")
    assert float(resumed["message"].split("after ")[1].split(" s")[0]) >= 1.9  # longer than the 0.5 s timeout
    assert result.status == "completed", result.error
    assert emu.model.events.heartbeat_trips == 0  # the cage itself never switched off
    counters = result.counters["cage"]
    assert counters["trips"] == 0 and counters["keepalive"]["heartbeats"] >= 4 and counters["keepalive"]["errors"] == 0
    assert "cage_trip" not in kinds


def test_a_trip_is_logged_and_the_cage_switched_on_again(tmp_path, cage_bench):
    emu, port, cal = cage_bench

    def trip():  # what a stall the keepalive cannot cover (a process frozen whole) leaves behind
        with emu._lock:
            emu.model._trip("heartbeat_lost")

    result, events, out = _run(tmp_path, port, cal, Operator(1.0, trip))
    assert result.status == "completed", result.error
    kinds = [e["kind"] for e in events]
    assert kinds.count("cage_trip") == 1 and kinds.count("cage_reenabled") == 1
    assert kinds.index("cage_trip") < kinds.index("cage_reenabled")
    trip_event = next(e for e in events if e["kind"] == "cage_trip")
    assert trip_event["interlocks"] == ["heartbeat_lost"] and trip_event["heartbeat_trips"] == 1
    assert result.counters["cage"]["trips"] == 1 and result.counters["cage"]["reenabled"] == 1
    # The cage makes the field again: at the end the difference is the following error (hundreds of nT), not the
    # 43-69 uT of a cage left off.
    tel = telemetry.load(out)
    late = tel["t_s"] >= DURATION_S - 1.0
    err = np.linalg.norm(tel["cage.b_cage_B"][late] - tel["b_true_B"][late], axis=1)
    assert err.max() < 2e-6


def test_a_cage_that_refuses_to_switch_on_again_ends_the_run_aborted_saying_why(tmp_path, cage_bench):
    emu, port, cal = cage_bench

    def overheat():  # a coil above the trip temperature: it stays latched until the coils cool (tau 15 min)
        with emu._lock:
            for ax in emu.model.axes:
                ax.temperature_C = 70.0
            emu.model._trip("over_temperature")

    result, events, _ = _run(tmp_path, port, cal, Operator(1.0, overheat))
    assert result.status == "aborted"
    assert "refused to switch them on again" in result.error and "over_temperature" in result.error
    kinds = [e["kind"] for e in events]
    assert "cage_trip" in kinds and "cage_reenable_failed" in kinds and "cage_reenabled" not in kinds
    assert result.counters["cage"]["trips"] == 1 and result.counters["cage"]["reenabled"] == 0
