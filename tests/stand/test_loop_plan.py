"""What the loop's tick calls (``stand.loop._Flight.plan``): every device step that does something, and not the
base class's steps that do nothing. Call counts, never wall time."""

from __future__ import annotations

import cProfile
import dataclasses
import pstats

from stand.compose import build
from stand.devices import Device
from stand.loop import run
from stand.scenario import SCENARIO_DIR, load


def _short_pointing():
    return dataclasses.replace(load(SCENARIO_DIR / "pointing_star_tracker.toml"), duration_s=1.0)


def test_the_tick_does_not_call_the_base_class_steps_that_do_nothing(tmp_path):
    # The tracker and the gyro take no commands: their receive is Device.receive, which does nothing. Before, the
    # tick called it for both on every tick.
    sc = _short_pointing()
    profile = cProfile.Profile()
    with build(sc) as scene:
        kept = [d.name for d in scene.devices.values() if type(d).receive is Device.receive]
        result = profile.runcall(run, scene, tmp_path / "run")
    assert result.status == "completed" and result.ticks == round(sc.duration_s / sc.step_s)
    assert len(kept) >= 2  # the scenario still has sensors that take no commands, or this test proves nothing
    base = Device.receive.__code__
    stats = pstats.Stats(profile).stats  # type: ignore[attr-defined]
    calls = {name: v[1] for (path, line, name), v in stats.items()
             if path == base.co_filename and line == base.co_firstlineno}
    assert calls.get("receive", 0) == 0, f"Device.receive called {calls} times"


def test_a_step_set_on_the_device_itself_is_still_called_every_tick(tmp_path):
    # A test harness or a fault tap may put its own receive on one device object: the tick calls that one.
    sc = _short_pointing()
    with build(sc) as scene:
        gyro = next(d for d in scene.devices.values() if type(d).receive is Device.receive)
        seen = []
        gyro.receive = seen.append
        result = run(scene, tmp_path / "run")
    assert result.status == "completed"
    # receive runs on ticks 0 to n (the last tick records its row before the loop ends), at t = k step_ns / 1e9
    step_ns = round(sc.step_s * 1e9)
    assert seen == [k * step_ns / 1e9 for k in range(result.ticks + 1)]
