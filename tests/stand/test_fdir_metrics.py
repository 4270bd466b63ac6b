"""FDIR criteria (issue 24): fdir_detect_s, fdir_safe_s, fault_worst_pointing_deg and fault_recovery_s from the
telemetry and the run's fault events, on a hand-made record whose answers are known; a criterion that cannot be
computed says why; the scenario's criterion fields ``fault`` and ``within_deg`` are checked."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from sim.rotations import quat_from_axis_angle
from stand import scenario
from stand.adcs.metrics import MetricUnavailable, fault_value, fault_windows
from stand.errors import ScenarioError
from stand.report import evaluate, run_faults
from stand.scenario import Criterion

Z = np.array([0.0, 0.0, 1.0])


def _tel(errors_deg, fdir, mode, dt=1.0):
    n = len(errors_deg)
    q_RN = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    q_BN = np.array([quat_from_axis_angle(Z, math.radians(e)) for e in errors_deg])
    return {"t_s": np.arange(n) * dt, "q_BN": q_BN, "adcs_q_RN": q_RN, "adcs_fdir": np.asarray(fdir, dtype=float),
            "adcs_mode": np.asarray(mode, dtype=float)}


#          t =  0    1    2    3    4    5    6    7    8    9
ERR = [0.0, 0.0, 0.0, 2.0, 5.0, 3.0, 1.0, 0.05, 0.2, 0.01]
FDIR = [0, 0, 0, 4, 1, 1, 1, 1, 1, 1]
MODE = [2, 2, 2, 2, 2, 2, 1, 2, 2, 2]
WINDOWS = {"rw2_seizure": (2.5, 6.0)}


def test_fault_windows_take_the_first_injection_and_the_first_clearing_after_it():
    events = [{"kind": "start"}, {"kind": "fault_cleared", "fault": "a", "t_s": 1.0},  # before any injection
              {"kind": "fault_injected", "fault": "a", "t_s": 2.0},
              {"kind": "fault_injected", "fault": "a", "t_s": 5.0},
              {"kind": "fault_cleared", "fault": "a", "t_s": 3.0}, {"kind": "fault_cleared", "fault": "a", "t_s": 6.0},
              {"kind": "fault_injected", "fault": "b", "t_s": float("nan")}, {"kind": "fault_injected", "t_s": 1.0},
              {"kind": "fault_injected", "fault": "c", "t_s": 4.0}]
    assert fault_windows(events) == {"a": (2.0, 3.0), "c": (4.0, None)}


def test_each_fault_metric_on_a_known_record():
    tel = _tel(ERR, FDIR, MODE)
    assert fault_value("fdir_detect_s", "rw2_seizure", tel, WINDOWS) == pytest.approx(0.5)  # bit 4 at t = 3
    assert fault_value("fdir_safe_s", "rw2_seizure", tel, WINDOWS) == pytest.approx(1.5)  # bit 1 at t = 4
    assert fault_value("fault_worst_pointing_deg", "rw2_seizure", tel, WINDOWS) == pytest.approx(5.0, rel=1e-9)
    # After the clearing at 6 s the error is back under 0.1 deg at t = 7, out again at 8, under for good from 9.
    assert fault_value("fault_recovery_s", "rw2_seizure", tel, WINDOWS, within_deg=0.1) == pytest.approx(3.0)
    assert fault_value("fault_recovery_s", "rw2_seizure", tel, WINDOWS, within_deg=1.0) == pytest.approx(0.0)
    # A fall back of the mode is a safe mode too.
    tel_mode = _tel(ERR, [0] * 10, MODE)
    assert fault_value("fdir_safe_s", "rw2_seizure", tel_mode, WINDOWS) == pytest.approx(3.5)


@pytest.mark.parametrize(("metric", "windows", "kw", "tel_change", "why"), [
    ("fdir_detect_s", {}, {}, None, "no fault_injected event for fault 'rw2_seizure' (faults injected: none)"),
    ("fdir_detect_s", WINDOWS, {}, "no_fdir", "adcs_fdir never changed after fault 'rw2_seizure' started at t = 2.5"),
    ("fdir_safe_s", WINDOWS, {}, "no_fdir", "neither adcs_mode fell back nor adcs_fdir reported a reconfiguration"),
    ("fdir_detect_s", WINDOWS, {}, "no_column", "the telemetry has no adcs_fdir column"),
    ("fault_recovery_s", {"rw2_seizure": (2.5, None)}, {"within_deg": 1.0}, None, "never cleared during the run"),
    ("fault_recovery_s", WINDOWS, {"within_deg": 0.001}, None, "still 0.01 deg > within_deg = 0.001 deg at the end"),
    ("fault_recovery_s", WINDOWS, {}, None, "needs the criterion's within_deg"),
])
def test_a_metric_that_cannot_be_computed_says_why(metric, windows, kw, tel_change, why):
    tel = _tel(ERR, FDIR, MODE)
    if tel_change == "no_fdir":
        tel = _tel(ERR, [0] * 10, [2] * 10)
    elif tel_change == "no_column":
        del tel["adcs_fdir"]
    with pytest.raises(MetricUnavailable, match=why.replace("(", r"\(").replace(")", r"\)")):
        fault_value(metric, "rw2_seizure", tel, windows, **kw)


def test_the_report_reads_the_events_and_gives_the_reason(tmp_path):
    (tmp_path / "events.jsonl").write_text("\n".join([
        json.dumps({"kind": "start", "message": "x"}), "{not json",
        json.dumps({"kind": "fault_injected", "message": "m", "t_s": 2.5, "fault": "rw2_seizure"}),
        json.dumps({"kind": "fault_cleared", "message": "m", "t_s": 6.0, "fault": "rw2_seizure"})]) + "\n")
    windows = run_faults(tmp_path)
    assert windows == WINDOWS
    crit = [Criterion("detect", "fdir_detect_s", 1.0, None, None, fault="rw2_seizure"),
            Criterion("lost", "fdir_detect_s", 1.0, None, None, fault="other")]
    out = evaluate(crit, _tel(ERR, FDIR, MODE), None, (), windows)
    assert out[0]["pass"] and out[0]["value"] == pytest.approx(0.5) and out[0]["fault"] == "rw2_seizure"
    assert out[0]["unit"] == "s"
    assert not out[1]["pass"] and out[1]["value"] is None
    assert out[1]["reason"].startswith("the run's events.jsonl has no fault_injected event for fault 'other'")


def _with_criterion(data: dict, crit: dict) -> dict:
    data["criteria"] = [crit]
    return data


def test_criterion_fields_fault_and_within_deg_are_checked(scenario_dict, write_scenario):
    def load(crit):
        return scenario.load(write_scenario(_with_criterion(dict(scenario_dict), crit)))

    c = load({"metric": "fault_recovery_s", "fault": "x", "within_deg": 0.5, "max": 60.0}).criteria[0]
    assert (c.fault, c.within_deg) == ("x", 0.5)
    with pytest.raises(ScenarioError, match=r"criteria\[0\]\.fault .*non-empty string"):
        load({"metric": "fdir_detect_s", "max": 5.0})
    with pytest.raises(ScenarioError, match=r"criteria\[0\]\.fault .*it is about no fault"):
        load({"metric": "final_rate_deg_s", "fault": "x", "max": 5.0})
    with pytest.raises(ScenarioError, match=r"criteria\[0\]\.within_deg .*fault_recovery_s's limit"):
        load({"metric": "fdir_detect_s", "fault": "x", "within_deg": 1.0, "max": 5.0})
    with pytest.raises(ScenarioError, match=r"criteria\[0\]\.within_deg"):
        load({"metric": "fault_recovery_s", "fault": "x", "max": 5.0})
