"""The shipped ``fault_wheel_seizure`` scenario (issue 24): a wheel of the four-wheel pyramid seizes during fine
pointing; with the reference ADCS's FDIR the seized wheel is isolated and the other three keep the pointing (every
criterion passes), without it (``controller.options.fdir = false``) the pointing is lost (its criteria fail, and
the FDIR criteria say why they have no value)."""

from __future__ import annotations

import itertools
import tomllib

import numpy as np
import pytest

from stand import scenario, telemetry
from stand.compose import build
from stand.loop import run
from stand.report import write_summary
from stand.scenario import SCENARIO_DIR

_channel = itertools.count()
SEIZE_S = 30.0


def _run(write_scenario, tmp_path, fdir: bool) -> tuple[dict, dict]:
    data = tomllib.loads((SCENARIO_DIR / "fault_wheel_seizure.toml").read_text())
    k = next(_channel)
    for d in data["devices"]:
        if d["kind"] == "reaction_wheel":
            d["channel"] = f"test-seizure-{k}-{d['name']}"  # tests share a process: buses of their own
    if not fdir:
        data["controller"]["options"]["fdir"] = False
    sc = scenario.load(write_scenario(data, f"seizure_{fdir}.toml"))
    out = tmp_path / f"fdir_{fdir}"
    with build(sc) as scene:
        result = run(scene, out)
        assert result.status == "completed"
        summary = write_summary(scene, result, out, plots=False)
    return summary, telemetry.load(out)


def test_the_seized_wheel_is_isolated_and_three_wheels_keep_the_pointing(write_scenario, tmp_path):
    summary, tel = _run(write_scenario, tmp_path, fdir=True)
    failed = [(c["name"], c.get("value"), c.get("reason")) for c in summary["criteria"] if not c["pass"]]
    assert summary["pass"] and not failed, failed
    t = tel["t_s"]
    # The seizure on the truth: the rotor stops and stays stopped; the body took its momentum.
    after = t >= SEIZE_S + 1.0
    assert np.all(np.abs(tel["rw2.speed_rad_s"][after]) < 1e-3)
    assert abs(tel["rw2.speed_rad_s"][np.searchsorted(t, SEIZE_S) - 1]) > 5.0
    # The FDIR: nothing before the seizure, the wheel isolated within a second after it, and commanded zero.
    f = tel["adcs_fdir"].astype(int)
    assert np.all(f[t < SEIZE_S] == 0)
    isolated = t[(f & 1) == 1]
    assert SEIZE_S < isolated[0] <= SEIZE_S + 1.0 and np.all((f[t >= isolated[0]] & 1) == 1)
    assert np.all(tel["adcs_wheel_torque_cmd"][t > isolated[0] + 0.2, 2] == 0.0)
    crit = {c["metric"]: c for c in summary["criteria"]}
    assert crit["fdir_detect_s"]["value"] == pytest.approx(isolated[0] - SEIZE_S, abs=1e-9)
    assert crit["fdir_detect_s"]["fault"] == "rw2_seizure"


def test_without_the_fdir_the_seizure_costs_the_pointing(write_scenario, tmp_path):
    summary, tel = _run(write_scenario, tmp_path, fdir=False)
    assert not summary["pass"]
    crit = {c["metric"]: c for c in summary["criteria"]}
    assert np.all(tel["adcs_fdir"] == 0.0)
    for metric in ("fdir_detect_s", "fdir_safe_s"):
        assert not crit[metric]["pass"] and crit[metric]["value"] is None
        assert "after fault 'rw2_seizure' started at t = 30 s" in crit[metric]["reason"]
    # The pointing itself fails its limits by far: the dead wheel is still in the allocation (degrees, not arcsec).
    assert crit["fault_worst_pointing_deg"]["value"] > 2.0 * crit["fault_worst_pointing_deg"]["limit"]["max"]
    assert crit["pointing_error_arcsec_p95_after"]["value"] > 10.0 * crit["pointing_error_arcsec_p95_after"][
        "limit"]["max"]
    assert crit["frames_rejected"]["pass"]
