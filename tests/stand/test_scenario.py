"""Scenario validation: every refusal names the field, the value and what is allowed."""

import math

import pytest

from stand import scenario
from stand.errors import ScenarioError


def test_default_scenario_is_valid_and_in_si():
    sc = scenario.load(scenario.DEFAULT_SCENARIO)
    assert sc.name == "detumble"
    assert sc.step_s == 0.1 and sc.duration_s == 5677.0
    assert sc.spacecraft.omega_BN_B == pytest.approx([0.17453292519943295] * 3)
    assert sc.orbit.i_rad == pytest.approx(math.radians(97.4))
    assert sc.devices[0].kind == "magnetorquer"


def bad(data, write_scenario):
    with pytest.raises(ScenarioError) as info:
        scenario.load(write_scenario(data))
    return info.value


@pytest.mark.parametrize("section, key, value, field, allowed", [
    ("spacecraft", "inertia_kg_m2", [0.02, -0.02, 0.01], "spacecraft.inertia_kg_m2", "positive"),
    ("spacecraft", "inertia_kg_m2", [0.01, 0.01, 0.03], "spacecraft.inertia_kg_m2", "triangle inequality"),
    ("orbit", "e", -0.1, "orbit.e", ">= 0"),
    ("orbit", "i_deg", 200.0, "orbit.i_deg", "<= 180"),
    ("spacecraft", "q_BN", [1.0, 0.5, 0.0, 0.0], "spacecraft.q_BN", "unit quaternion"),
    ("dynamics", "step_s", 0.0, "dynamics.step_s", ">= 1e-06"),
    ("scenario", "epoch", "2026-02-30T00:00:00Z", "scenario.epoch", "ISO 8601"),
    ("spacecraft", "omega_BN_B_deg_s", [3000.0, 0.0, 0.0], "dynamics.step_s", "too large"),
    ("controller", "rate_hz", 3.0, "controller.rate_hz", "whole number of dynamics steps"),
    ("scenario", "duraton_s", 10.0, "scenario.duraton_s", "not known here"),
])
def test_bad_values_are_named(scenario_dict, write_scenario, section, key, value, field, allowed):
    scenario_dict[section][key] = value
    err = bad(scenario_dict, write_scenario)
    assert err.field == field
    assert allowed in str(err)
    assert str(err).startswith(field)


def test_unknown_device_kind_is_named(scenario_dict, write_scenario):
    scenario_dict["devices"][0]["kind"] = "warp_drive"
    err = bad(scenario_dict, write_scenario)
    assert err.field == "devices[0].kind" and "'magnetorquer'" in str(err) and "'warp_drive'" in str(err)


def test_perigee_below_the_surface_is_refused(scenario_dict, write_scenario):
    del scenario_dict["orbit"]["altitude_km"]
    scenario_dict["orbit"].update(a_km=7000.0, e=0.2)
    err = bad(scenario_dict, write_scenario)
    assert "perigee" in str(err) and err.field == "orbit.a_km"


def test_inconsistent_a_and_e_is_refused(scenario_dict, write_scenario):
    del scenario_dict["orbit"]["altitude_km"]
    scenario_dict["orbit"].update(a_km=7000.0, e=1.5)
    assert "negative semi-major axis" in str(bad(scenario_dict, write_scenario))


def test_bdot_without_a_magnetorquer_is_refused(scenario_dict, write_scenario):
    scenario_dict["devices"] = []
    err = bad(scenario_dict, write_scenario)
    assert err.field == "controller.kind" and "magnetorquer" in str(err)


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(ScenarioError, match="a scenario file or a shipped name"):
        scenario.load(tmp_path / "nope.toml")
    p = tmp_path / "broken.toml"
    p.write_text("[scenario\nname = 1")
    with pytest.raises(ScenarioError, match="valid TOML"):
        scenario.load(p)
