"""``[[faults]]``: validation before t = 0, triggers and ends, each measurement fault's effect on what reaches the
host, and a run whose faults do nothing unchanged to the bit.

Expected effects are closed forms against the same run without the fault (the same seeds draw the same noise):
a bias adds exactly the bias (to the gyro datagram's least significant bit), a scale multiplies, a dead axis reads
zero, a stuck output repeats one value; outside the fault's window the two runs are bit-identical.
"""

from __future__ import annotations

import copy
import json
import math
import tomllib

import numpy as np
import pytest

from drivers.gyro.codec import GyroCodec
from stand import compose, loop, report, scenario
from stand.errors import ScenarioError
from stand.faults import FAULT_TYPES
from stand.scenario import SCENARIO_DIR
from stand.telemetry import load

BASE = tomllib.loads((SCENARIO_DIR / "pointing_star_tracker.toml").read_text())
#: The gyro datagram's rate LSB (fixtures/devices/gyro.toml): a bias survives quantisation to within it.
LSB = GyroCodec().rate_lsb_rad_s


def _data(faults=None, duration_s=12.0) -> dict:
    data = copy.deepcopy(BASE)
    data["scenario"]["duration_s"] = duration_s
    data["criteria"] = []
    # No flight code: the truth does not react to a faulted measurement, so a run with a fault and one without see
    # the same truth and the same noise, and the fault's effect is the whole difference.
    data["controller"] = {"kind": "none"}
    if faults is not None:
        data["faults"] = faults
    return data


def _run(tmp_path, name, faults=None, duration_s=12.0, live=False):
    sc = scenario.parse(_data(faults, duration_s), name)
    out = tmp_path / name
    with compose.build(sc, live_faults=live) as scene:
        result = loop.run(scene, out)
        summary = report.write_summary(scene, result, out, plots=False)
    events = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]
    return load(out), summary, events, out


@pytest.fixture(scope="module")
def nominal(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("nominal"), "nominal")


def _window(tel, t0, t1):
    t = tel["t_s"]
    return (t >= t0 + 0.1) & (t < t1)  # the first sample after the start carries the fault


def _outside(tel, t0, t1):
    t = tel["t_s"]
    return (t < t0) | (t >= t1 + 0.5)


#: How far the faulted datagram may be from the closed form applied to the nominal datagram, in LSB: the nominal
#: value was rounded to the LSB (0.5) and the faulted one is rounded again (0.5); a factor k scales the first.
@pytest.mark.parametrize("fault, expect, lsb", [
    ({"type": "bias_step", "bias_rad_s": [0.01, -0.02, 0.0]}, lambda w0: w0 + np.array([0.01, -0.02, 0.0]), 1.0),
    ({"type": "scale_factor", "factor": [2.0, 1.0, -1.0]}, lambda w0: w0 * np.array([2.0, 1.0, -1.0]), 1.5),
    ({"type": "dead_axis", "axis": "z"}, lambda w0: w0 * np.array([1.0, 1.0, 0.0]), 0.0),
    ({"type": "saturation", "limit_rad_s": 2e-4}, lambda w0: np.clip(w0, -2e-4, 2e-4), 1.0),
])
def test_measurement_fault_on_the_wire(tmp_path, nominal, fault, expect, lsb):
    tel0 = nominal[0]
    tel, summary, events, _ = _run(tmp_path, "f", [{"device": "imu", "at_s": 4.0, "duration_s": 4.0, **fault}])
    inside, outside = _window(tel, 4.0, 8.0), _outside(tel, 4.0, 8.0)
    w, w0 = tel["imu.omega_S"], tel0["imu.omega_S"]
    # The host's datagram carries the faulted measurement, to one LSB of the codec.
    assert np.max(np.abs(w[inside] - expect(w0[inside]))) <= lsb * LSB * (1 + 1e-9)
    assert np.any(np.abs(w[inside] - w0[inside]) > LSB)
    # Before and after the fault, nothing differs to the bit.
    assert np.array_equal(w[outside], w0[outside]) and np.array_equal(tel["q_BN"], tel0["q_BN"])
    kinds = [e["kind"] for e in events if e["kind"].startswith("fault_")]
    assert kinds == ["fault_injected", "fault_cleared"]
    assert summary["faults"][f"imu.{fault['type']}"]["occurrences"] == [[4.0, 8.0]]


def test_stuck_holds_one_value_and_noise_is_seeded(tmp_path):
    tel, *_ = _run(tmp_path, "a", [{"device": "imu", "type": "stuck", "at_s": 3.0, "duration_s": 3.0},
                                   {"device": "imu", "type": "noise_increase", "sigma_rad_s": 0.01, "at_s": 7.0,
                                    "duration_s": 2.0}])
    w = tel["imu.omega_S"]
    held = w[_window(tel, 3.0, 6.0)]
    assert len(held) > 10 and np.all(held == held[0])
    noisy = w[_window(tel, 7.0, 9.0)]
    assert 0.005 < np.std(noisy[:, 0]) < 0.02  # sigma 0.01 over ~20 samples
    again, *_ = _run(tmp_path, "b", [{"device": "imu", "type": "stuck", "at_s": 3.0, "duration_s": 3.0},
                                     {"device": "imu", "type": "noise_increase", "sigma_rad_s": 0.01, "at_s": 7.0,
                                      "duration_s": 2.0}])
    assert np.array_equal(again["imu.omega_S"], w)  # the fault's stream comes from the scenario's seed


def test_bias_drift_grows_linearly(tmp_path, nominal):
    tel, *_ = _run(tmp_path, "d", [{"device": "imu", "type": "bias_drift", "drift_rad_s_per_s": [1e-3, 0, 0],
                                    "at_s": 2.0}])
    sel = tel["t_s"] > 2.5
    before = tel["t_s"] < 2.0
    d = tel["imu.omega_S"][:, 0] - nominal[0]["imu.omega_S"][:, 0]
    # The gyro samples at 20 Hz; a row shows the newest sample, taken up to one sample period before the row.
    t = tel["t_s"][sel]
    assert np.all(d[sel] <= 1e-3 * (t - 2.0) + LSB) and np.all(d[sel] >= 1e-3 * (t - 2.0 - 0.05) - LSB)
    assert np.array_equal(tel["imu.omega_S"][before], nominal[0]["imu.omega_S"][before])


def test_faults_that_never_fire_change_nothing(tmp_path, nominal):
    # Faults whose triggers come too late, and a run open to live faults: the same bits as without.
    tel, summary, _, out = _run(tmp_path, "late", [{"device": "imu", "type": "bias_step", "bias_rad_s": 1.0,
                                                    "after": "column:t_s>11.95", "delay_s": 0.5},
                                                   {"device": "rw1", "type": "frame_drop", "after": "fault:x"},
                                                   {"name": "x", "device": "imu", "type": "stuck",
                                                    "after": "column:t_s>100"}])
    assert (out / "telemetry" / "rows.f64").read_bytes() == (nominal[3] / "telemetry" / "rows.f64").read_bytes()
    live, *_, out2 = _run(tmp_path, "live", live=True)
    assert (out2 / "telemetry" / "rows.f64").read_bytes() == (nominal[3] / "telemetry" / "rows.f64").read_bytes()
    assert "faults" not in nominal[1]


def test_triggers_after_recurring_and_random(tmp_path):
    faults = [
        {"name": "first", "device": "imu", "type": "dead_axis", "axis": 0, "at_s": 1.0, "duration_s": 1.0},
        {"name": "then", "device": "imu", "type": "dead_axis", "axis": 1, "after": "cleared:first", "delay_s": 0.5,
         "duration_s": 1.0},
        {"name": "col", "device": "imu", "type": "dead_axis", "axis": 2, "after": "column:t_s>5.05",
         "duration_s": 0.5},
        {"name": "tick", "device": "imu", "type": "stuck", "period_s": 3.0, "at_s": 6.0, "duration_s": 1.0},
        {"name": "rnd", "device": "imu", "type": "noise_increase", "sigma_rad_s": 1e-3, "rate_per_s": 0.5,
         "duration_s": 0.2},
    ]
    _, summary, events, _ = _run(tmp_path, "t", faults)
    f = summary["faults"]
    assert f["first"]["occurrences"] == [[1.0, 2.0]]
    assert f["then"]["occurrences"] == [[2.5, 3.5]]
    # The column condition shows on the row of t = 5.1 s (a row every 0.1 s step), recorded at the end of that
    # tick: the fault starts at the next tick and lasts its whole duration.
    assert f["col"]["occurrences"] == [[pytest.approx(5.2), pytest.approx(5.7)]]
    assert [o[0] for o in f["tick"]["occurrences"]] == [6.0, 9.0, 12.0]  # the last tick (t = 12 s) included
    starts = [o[0] for o in f["rnd"]["occurrences"]]
    assert starts and all(0.0 < s <= 12.0 for s in starts)
    _, again, _, _ = _run(tmp_path, "t2", faults)
    assert again["faults"]["rnd"]["occurrences"] == f["rnd"]["occurrences"]  # drawn from the scenario's seed
    injected = [e for e in events if e["kind"] == "fault_injected"]
    assert all({"fault", "type", "device", "t_s", "params", "layer"} <= set(e) for e in injected)


def test_live_inject_and_clear(tmp_path, nominal):
    sc = scenario.parse(_data(None, 6.0), "live")
    out = tmp_path / "live"
    with compose.build(sc, live_faults=True) as scene:
        sched = scene.faults

        class Observer:  # the operator: a fault at the first poll, cleared at the next
            calls = 0

            def record(self, t_s, row):
                if self.calls == 0 and t_s >= 2.0:
                    self.name = sched.inject({"device": "imu", "type": "bias_step", "bias_rad_s": 0.5})
                    self.calls = 1
                elif self.calls == 1 and t_s >= 4.0:
                    sched.clear(self.name)
                    self.calls = 2

            def poll_control(self):
                return None

        with pytest.raises(ScenarioError, match=r"faults\[0\]\.type = 'no_such'"):
            sched.inject({"device": "imu", "type": "no_such"})
        with pytest.raises(KeyError):
            sched.clear("nothing")
        loop.run(scene, out, observer=Observer())
    tel = load(out)
    d = tel["imu.omega_S"][:, 0] - nominal[0]["imu.omega_S"][: len(tel["t_s"]), 0]
    assert np.all(np.abs(d[(tel["t_s"] > 2.2) & (tel["t_s"] < 4.0)] - 0.5) <= LSB)
    assert np.all(d[tel["t_s"] < 2.0] == 0.0)


@pytest.mark.parametrize("fault, field, words", [
    ({"type": "nope", "device": "imu", "at_s": 1}, "faults[0].type", "one of"),
    ({"type": "stuck", "device": "ghost", "at_s": 1}, "faults[0].device", "one of"),
    ({"type": "wheel_seized", "device": "imu", "at_s": 1}, "faults[0].type", "can take"),
    ({"type": "stuck", "device": "imu"}, "faults[0].at_s", "a trigger"),
    ({"type": "stuck", "device": "imu", "at_s": 1, "after": "fault:x"}, "faults[0].after", "one trigger only"),
    ({"type": "stuck", "device": "imu", "period_s": 2}, "faults[0].duration_s", "recurring"),
    ({"type": "stuck", "device": "imu", "period_s": 2, "duration_s": 3}, "faults[0].duration_s", "shorter"),
    ({"type": "reboot", "device": "imu", "at_s": 1, "duration_s": 3}, "faults[0].duration_s", "instant"),
    ({"type": "stuck", "device": "imu", "after": "fault:ghost"}, "faults[0].after", "another fault"),
    ({"type": "stuck", "device": "imu", "after": "sometime"}, "faults[0].after", "an event"),
    ({"type": "bias_step", "device": "imu", "at_s": 1, "bias_T": [1, 0, 0]}, "faults[0].bias_T", "'bias_rad_s'"),
    ({"type": "bias_step", "device": "imu", "at_s": 1, "bias_rad_s": [1, math.inf, 0]}, "faults[0].bias_rad_s",
     "finite"),
    ({"type": "dead_axis", "device": "imu", "at_s": 1, "axis": 3}, "faults[0].axis", "index from 0 to 2"),
    ({"type": "stuck", "device": "imu", "at_s": 99}, "faults[0].at_s", "<= 12"),
    ({"type": "stuck", "device": "imu", "at_s": 1, "colour": "red"}, "faults[0].colour", "not known"),
])
def test_bad_fault_tables_are_refused_before_t0(fault, field, words):
    with pytest.raises(ScenarioError) as err:
        scenario.parse(_data([fault]), "bad")
    assert str(err.value).startswith(field), str(err.value)
    assert words in str(err.value)


def test_every_type_is_declared_once_with_a_layer():
    assert len(FAULT_TYPES) >= 20
    assert {t.layer for t in FAULT_TYPES.values()} == {"physics", "protocol", "time"}
    assert all(t.text and t.tap for t in FAULT_TYPES.values())


def test_fault_types_doc_is_generated_from_the_code():
    from stand.faults import doc

    path = SCENARIO_DIR.parents[1] / "docs" / "fault_types.md"
    assert path.read_text() == doc.render(), "regenerate: python -m stand.faults.doc > docs/fault_types.md"
