"""The reference FDIR against the stand's own faults on the devices (issue 24): a gyro stuck in its emulator, through
``[[faults]]`` on the ``fault_wheel_seizure`` spacecraft (its wheel fault replaced), read from the run's telemetry
and judged by the FDIR criteria. (A tracker's misidentified stars and a silent gyro line join the list when the
tracker's and the links' fault taps are in: tests/stand/test_fdir.py has both on fake drivers.)"""

from __future__ import annotations

import itertools
import tomllib

import numpy as np
import pytest

from stand import scenario, telemetry
from stand.adcs import metrics
from stand.compose import build
from stand.loop import run
from stand.report import write_summary
from stand.scenario import SCENARIO_DIR

_channel = itertools.count()
AT_S, FOR_S = 20.0, 15.0


def _run(write_scenario, tmp_path, fault: dict):
    data = tomllib.loads((SCENARIO_DIR / "fault_wheel_seizure.toml").read_text())
    data["scenario"]["duration_s"] = 50.0
    k = next(_channel)
    for d in data["devices"]:
        if d["kind"] == "reaction_wheel":
            d["channel"] = f"test-fdir-loop-{k}-{d['name']}"
    data["faults"] = [{"name": "f", "at_s": AT_S, "duration_s": FOR_S, **fault}]
    data["criteria"] = [{"metric": "fdir_detect_s", "fault": "f", "max": 2.0},
                        {"metric": "fault_worst_pointing_deg", "fault": "f", "max": 0.05},
                        {"metric": "fault_recovery_s", "fault": "f", "within_deg": 0.05, "max": 5.0}]
    sc = scenario.load(write_scenario(data, f"{fault['type']}.toml"))
    out = tmp_path / fault["type"]
    with build(sc) as scene:
        result = run(scene, out)
        assert result.status == "completed"
        summary = write_summary(scene, result, out, plots=False)
    return summary, telemetry.load(out)


@pytest.mark.parametrize(("fault", "bits"), [
    ({"type": "stuck", "device": "imu"}, 2),
])
def test_the_fdir_sees_the_fault_reports_it_and_keeps_the_pointing(fault, bits, write_scenario, tmp_path):
    summary, tel = _run(write_scenario, tmp_path, fault)
    failed = [(c["name"], c.get("value"), c.get("reason")) for c in summary["criteria"] if not c["pass"]]
    assert not failed, failed
    t, flags = tel["t_s"], tel["adcs_fdir"].astype(int)
    assert np.all(flags[t < AT_S] == 0)
    during = (t >= AT_S + 6.0) & (t < AT_S + FOR_S)
    assert np.all(flags[during] & bits == bits), sorted(set(flags[during].tolist()))
    assert np.all(flags[t >= AT_S + FOR_S + 3.0] & bits == 0)  # cleared: the gyro, the tracker trusted again
    # And the pointing held while it lasted, well inside the criterion's 0.05 deg.
    e = metrics.pointing_error_rad(tel, AT_S)
    assert np.degrees(np.max(e)) < 0.05
