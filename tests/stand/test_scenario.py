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


# --- Issue 11: values that used to crash, abort mid-run or lie are refused before t = 0 --------------------------

def tracker_dict():
    import tomllib

    return tomllib.loads((scenario.SCENARIO_DIR / "detumble_star_tracker.toml").read_text())


def refused(data, write_scenario, field, *allowed):
    """The file is refused with one sentence that starts with the field and names the file and the limit."""
    err = bad(data, write_scenario)
    text = str(err)
    assert err.field == field and text.startswith(field), text
    assert "in scenario.toml" in text and "\n" not in text
    for a in allowed:
        assert a in text, text
    return err


def test_controller_dipole_beyond_the_board_is_refused(scenario_dict, write_scenario):
    scenario_dict["controller"]["max_dipole_A_m2"] = 1.0  # used to abort at 10 s (the DBC carries 0.32767)
    refused(scenario_dict, write_scenario, "controller.max_dipole_A_m2", "<= 0.2")


def test_controller_dipole_is_bounded_by_the_dbc_through_the_board(scenario_dict, write_scenario):
    scenario_dict["devices"][0]["max_dipole_A_m2"] = 0.5
    refused(scenario_dict, write_scenario, "devices[0].max_dipole_A_m2", "0.32767")


def test_control_period_beyond_the_duration_field_is_refused(scenario_dict, write_scenario):
    scenario_dict["controller"]["rate_hz"] = 0.01  # used to abort at 100 s (duration_ms beyond 65535)
    refused(scenario_dict, write_scenario, "controller.rate_hz", "65.535 s", "rate_hz >= 0.015259")


@pytest.mark.parametrize("key, value, allowed", [
    ("max_dipole_A_m2", 50.0, "<= 0.32767"),
    ("dipole_lsb_A_m2", 0.0, ">= 1e-05"),
])
def test_board_limits_name_the_scenario_field(scenario_dict, write_scenario, key, value, allowed):
    # Used to exit 2 naming EmulatorConfig.* instead of the scenario's field and file.
    scenario_dict["devices"][0][key] = value
    err = refused(scenario_dict, write_scenario, f"devices[0].{key}", allowed)
    assert "EmulatorConfig" not in str(err)


@pytest.mark.parametrize("key, value, allowed", [
    ("min_stars_matched", 100, "<= 50"),
    ("stable_count", 1000, "<= 100"),
])
def test_tracker_limits_name_the_scenario_field(write_scenario, key, value, allowed):
    data = tracker_dict()
    data["devices"][1][key] = value
    err = refused(data, write_scenario, f"devices[1].{key}", allowed)
    assert "EmulatorConfig" not in str(err)


def test_huge_semi_major_axis_is_refused_as_given(scenario_dict, write_scenario):
    del scenario_dict["orbit"]["altitude_km"]
    scenario_dict["orbit"]["a_km"] = 1e306  # used to say "a = inf"
    err = refused(scenario_dict, write_scenario, "orbit.a_km", "<= 1.5e+06")
    assert "inf" not in str(err)


def test_huge_inertia_is_refused_by_check(scenario_dict, write_scenario):
    scenario_dict["spacecraft"]["inertia_kg_m2"] = [1e300, 1e300, 1e300]  # used to pass check, abort at t = 0
    refused(scenario_dict, write_scenario, "spacecraft.inertia_kg_m2", "1e+10")


def test_step_longer_than_the_run_is_refused(scenario_dict, write_scenario):
    # Used to print PASS with 0 s simulated.
    scenario_dict["scenario"]["duration_s"] = 1.0
    scenario_dict["dynamics"]["step_s"] = 10.0
    scenario_dict["spacecraft"]["omega_BN_B_deg_s"] = [0.0, 0.0, 0.0]
    refused(scenario_dict, write_scenario, "dynamics.step_s", "no longer than the run")


@pytest.mark.parametrize("value", ["no", "false", 0, 1])
def test_flags_take_only_booleans(scenario_dict, write_scenario, value):
    scenario_dict["controller"]["skip_coil_active"] = value  # "no" used to become true
    refused(scenario_dict, write_scenario, "controller.skip_coil_active", "true or false")


@pytest.mark.parametrize("where, field", [("scenario", "scenario.name"), ("device", "devices[0].name")])
def test_nul_byte_in_a_name_is_refused(scenario_dict, write_scenario, where, field):
    from tests.stand.conftest import to_toml

    target = scenario_dict["scenario"] if where == "scenario" else scenario_dict["devices"][0]
    target["name"] = "NULHERE"
    path = write_scenario(scenario_dict)
    # TOML writes the NUL as an escape; the loader sees a real NUL byte (used to leak "embedded null byte").
    path.write_text(to_toml(scenario_dict).replace('"NULHERE"', '"a\\u0000b"'))
    if where == "device":
        path.write_text(path.read_text().replace('"a\\u0000b"', '"m\\u0000"', 1))
    with pytest.raises(ScenarioError) as info:
        scenario.load(path)
    err = info.value
    assert err.field == field and "without control characters" in str(err) and "embedded null" not in str(err)
    assert "\x00" not in str(err)


def test_a_body_the_torquers_spin_past_the_step_is_refused(scenario_dict, write_scenario):
    # Found by the fuzzer: a 1e-8 kg m^2 axis passed check, then the saturated torquers spun it to 885 deg/s and the
    # run aborted at t = 0.1 s.
    scenario_dict["spacecraft"]["inertia_kg_m2"] = [0.02, 0.02, 1e-8]
    err = refused(scenario_dict, write_scenario, "spacecraft.inertia_kg_m2", "control period (0.1 s)",
                  "dynamics.step_s = 0.1 s")
    assert "1e-08 kg m^2" in str(err)
    scenario_dict["spacecraft"]["inertia_kg_m2"] = [0.02, 0.02, 1e-3]  # 10x smaller than shipped: still fine
    scenario.load(write_scenario(scenario_dict))
