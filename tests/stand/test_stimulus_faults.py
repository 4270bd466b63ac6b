"""Physics faults a real sensor sees through its stimulator: the Helmholtz cage adds a field step the
magnetometer in it reads; the star screen shows the sky of a wrong attitude."""

from __future__ import annotations

import copy
import math
import tomllib

import numpy as np

from drivers.magnetorquer.emulator import EmulatorConfig
from stand import compose, loop, scenario
from stand.devices.star_screen_link import ScreenTracker
from stand.telemetry import load

LSB_T = EmulatorConfig().mag_lsb_T


def _cage_run(tmp_path, name, faults):
    data = tomllib.loads((scenario.SCENARIO_DIR / "detumble_cage.toml").read_text())
    data["scenario"]["duration_s"] = 20.0
    data["criteria"] = []
    data["controller"] = {"kind": "none"}  # the truth must not react: the step is then the whole difference
    if faults:
        data["faults"] = faults
    out = tmp_path / name
    with compose.build(scenario.parse(copy.deepcopy(data), name)) as scene:
        assert loop.run(scene, out).status == "completed"
    return load(out)


def test_a_cage_field_step_is_read_by_the_magnetometer_in_the_cage(tmp_path):
    step = np.array([2e-6, 0.0, -1e-6])
    a = _cage_run(tmp_path, "a", None)
    b = _cage_run(tmp_path, "b", [{"device": "cage", "type": "cage_field_step", "step_T": step.tolist(),
                                   "at_s": 5.0, "duration_s": 10.0}])
    t, d = a["t_s"], b["mtq.mag_S"] - a["mtq.mag_S"]
    # The board's magnetometer is mounted along the body axes (q_SB identity) and samples the cage's field, which
    # follows the command within the coils' lag: after 0.5 s the step is the whole difference, to the sensor's LSB
    # (each reading rounded once in each run).
    on = (t >= 5.5) & (t < 15.0)
    assert np.max(np.abs(d[on] - step)) <= 1.0 * LSB_T * (1 + 1e-6)
    assert np.all(d[(t < 5.0) | (t >= 15.5)] == 0.0)
    assert np.array_equal(b["q_BN"], a["q_BN"])


def test_a_screen_wrong_attitude_rotates_the_sky_the_screen_shows():
    class Stream:
        sent: list = []

        def send(self, q, t_ns, v, w):
            self.sent.append(q)
            return True

    tracker = object.__new__(ScreenTracker)  # only what drawing a frame reads
    tracker.stream, tracker._speed, tracker._start, tracker.latency_s, tracker._step_s = Stream(), 1.0, 0.0, 0.0, 0.1
    tracker._lateness, tracker.frames_late, tracker._frames = [], 0, []
    tracker._truth = type("Truth", (), {"v_N": (0.0, 0.0, 0.0)})
    q = (1.0, 0.0, 0.0, 0.0)
    tracker._send_frame(0.0, 0.0, q, (0.0, 0.0, 0.0), 0.0)
    tracker.screen_misid_rad = (0.0, 0.0, math.radians(2.0))
    tracker._send_frame(0.0, 0.0, q, (0.0, 0.0, 0.0), 0.0)
    nominal, wrong = Stream.sent
    assert nominal == q
    # Composition with identity: the shown attitude is the error rotation itself, 2 deg about the tracker's z.
    assert np.allclose(wrong, (math.cos(math.radians(1.0)), 0.0, 0.0, math.sin(math.radians(1.0))), atol=1e-15)
