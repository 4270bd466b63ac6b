"""A key the scenario's other settings leave unused is refused before t = 0 (issue 22, item 4).

A campaign that dispersed such a key recorded different inputs for identical runs (``era0_deg`` under the IAU 2006
Earth, ``gravity_degree`` under J2). Each refusal is one sentence naming the key, its value, the setting that makes
it unused and what to do; the shipped scenarios, their documented overrides and dispersion files still load.
A required key written without its unit suffix is named as the mistake, with the key it probably meant.
"""

from __future__ import annotations

import copy
import tomllib

import pytest

from stand import campaign as cm
from stand import scenario
from stand.cli import main
from stand.errors import ScenarioError

DIR = scenario.SCENARIO_DIR
DISPERSIONS = DIR / "detumble_dispersions.toml"
IGRF = ["environment.magnetic_field=igrf", "environment.earth_rotation=iau2006"]


def refusal(name: str, overrides: list[str]) -> str:
    with pytest.raises(ScenarioError) as info:
        scenario.load(name, overrides)
    text = str(info.value)
    assert "\n" not in text and text.endswith("."), text
    return text


# (scenario, overrides, the key and value named, the setting named, what to do)
UNUSED = [
    ("detumble", [*IGRF, "environment.era0_deg=90"], "environment.era0_deg = 90",
     "environment.earth_rotation = 'iau2006'", "set earth_rotation = 'uniform'"),
    ("detumble_igrf", ["environment.era0_deg=45.0"], "environment.era0_deg = 45.0",
     "environment.earth_rotation = 'iau2006'", "disperse scenario.epoch instead"),
    ("detumble", ["environment.eop=none"], "environment.eop = 'none'",
     "environment.earth_rotation = 'uniform'", "set earth_rotation = 'iau2006'"),
    ("detumble", ["environment.igrf_degree=10"], "environment.igrf_degree = 10",
     "environment.magnetic_field = 'dipole'", "set magnetic_field = 'igrf'"),
    ("detumble", ["orbit.gravity_degree=12"], "orbit.gravity_degree = 12", "orbit.gravity = 'j2'",
     "set gravity = 'jgm3'"),
    ("detumble", ["orbit.gravity=point", "orbit.gravity_degree=8"], "orbit.gravity_degree = 8",
     "orbit.gravity = 'point'", "set gravity = 'jgm3'"),
    # Scenes that evaluate no field or nothing Earth-fixed at all (no magnetic torque, no magnetometer).
    ("pointing_star_tracker", ["environment.magnetic_field=igrf"], "environment.magnetic_field = 'igrf'",
     "a scene without a magnetic field", "remove it"),
    ("pointing_star_tracker", ["environment.earth_rotation=uniform", "environment.era0_deg=30"],
     "environment.earth_rotation = 'uniform'", "a scene with nothing Earth-fixed", "remove it"),
    ("rendezvous_shadow", ["environment.igrf_degree=5"], "environment.igrf_degree = 5",
     "a scene without a magnetic field", "remove it"),
    # The controller's keys of another kind.
    ("detumble", ["controller.module=my_adcs"], "controller.module = 'my_adcs'", "controller.kind = 'bdot'",
     "it is a key of kind 'plugin'"),
    ("detumble", ["controller.kind=none", "controller.gain_A_m2_s_per_T=1.0"], "controller.gain_A_m2_s_per_T = 1.0",
     "controller.kind = 'none'", "it is a key of kind 'bdot'"),
    ("pointing_star_tracker", ["controller.duty_cycle=0.5"], "controller.duty_cycle = 0.5",
     "controller.kind = 'pointing'", "it is a key of kind 'bdot'"),
]


@pytest.mark.parametrize("name, overrides, named, setting, todo", UNUSED,
                         ids=[f"{u[0]}:{u[2].split(' =')[0]}" for u in UNUSED])
def test_a_key_its_settings_leave_unused_is_refused(name, overrides, named, setting, todo):
    text = refusal(name, overrides)
    assert named in text and setting in text and "leaves this key unused" in text and todo in text, text


def test_bdot_keys_are_refused_under_kind_none():
    # detumble's controller table is a B-dot one: with kind = none each of its keys is unused, the first named.
    text = refusal("detumble", ["controller.kind=none"])
    assert "controller.kind = 'none' leaves this key unused" in text and "a key of kind 'bdot'" in text, text


def test_at_s_of_a_metric_that_takes_no_time_is_refused(scenario_dict, write_scenario):
    data = copy.deepcopy(scenario_dict)
    data["criteria"][0]["at_s"] = 100.0
    assert data["criteria"][0]["metric"] == "final_rate_deg_s"
    with pytest.raises(ScenarioError, match=r"criteria\[0\]\.at_s = 100\.0 .*metric = 'final_rate_deg_s' \(it takes "
                       r"no time\) leaves this key unused.*remove it"):
        scenario.load(write_scenario(data))


def test_a_margin_without_datasheets_is_refused():
    overrides = ["controller.datasheet={}", "controller.options.tracker_sigma_rad=[1e-5, 5e-5]",
                 "controller.options.gyro_arw_rad_s05=3e-6", "controller.options.gyro_rrw_rad_s15=2e-8",
                 "controller.options.sigma_bias_rad_s=1e-5"]
    text = refusal("pointing_star_tracker", overrides)  # the shipped file's datasheet_margin = 1.3 stays
    assert "controller.datasheet_margin = 1.3" in text and "a controller without datasheets" in text, text


def test_the_same_keys_where_they_are_used_still_load():
    sc = scenario.load("detumble", ["environment.era0_deg=90"])
    assert sc.environment.era0_rad == pytest.approx(1.5707963267948966)
    sc = scenario.load("detumble", [*IGRF, "environment.igrf_degree=10", "environment.eop=none"])
    assert (sc.environment.igrf_degree, sc.environment.eop) == (10, "none")
    sc = scenario.load("detumble", ["orbit.gravity=jgm3", "orbit.gravity_degree=12"])
    assert sc.orbit.gravity_degree == 12


@pytest.mark.parametrize("name", sorted(scenario.shipped()))
def test_every_shipped_scenario_checks(name, capsys):
    assert main(["check", name]) == 0, capsys.readouterr().err


@pytest.mark.parametrize("overrides", [[], IGRF, [*IGRF, "environment.eop=none"], ["criteria.detumbled.max=5"]])
def test_the_documented_overrides_of_the_default_scenario_still_load(overrides):
    scenario.load("detumble", overrides)


def test_the_shipped_dispersion_file_validates_and_its_era0_entry_is_refused_under_iau2006():
    # As docs/campaigns.md runs it.
    spec = cm.make_spec("detumble", DISPERSIONS, overrides=["criteria.detumbled.max=5"], duration_s=600.0)
    assert len(cm.validate(spec, 8)) == 8
    # The combination docs/campaigns.md mentions: the epoch turns the Earth there, era0_deg would change nothing.
    spec = cm.make_spec("detumble", DISPERSIONS, overrides=IGRF)
    with pytest.raises(cm.CampaignError, match=r"case 0: dispersions\[\d+\] \(environment\.era0_deg, .*"
                       r"environment\.earth_rotation = 'iau2006'.* leaves this key unused"):
        cm.validate(spec, 1)


def test_a_gravity_degree_dispersion_under_j2_is_refused(tmp_path):
    dfile = tmp_path / "d.toml"
    dfile.write_text('[[dispersions]]\nfield = "orbit.gravity_degree"\ndistribution = "uniform"\nmin = 2\nmax = 20\n'
                     'integer = true\n')
    spec = cm.make_spec("detumble", dfile)
    with pytest.raises(cm.CampaignError, match=r"orbit\.gravity_degree = \d+ .*orbit\.gravity = 'j2'"):
        cm.validate(spec, 1)


# --- a key written without its unit suffix ---------------------------------------------------------------------------

def test_a_required_key_without_its_unit_is_named_with_the_key_meant(scenario_dict, write_scenario):
    data = copy.deepcopy(scenario_dict)
    data["scenario"]["duration"] = data["scenario"].pop("duration_s")
    with pytest.raises(ScenarioError) as info:
        scenario.load(write_scenario(data))
    text = str(info.value)
    assert text.startswith("scenario.duration = 5677.0 in scenario.toml is not allowed: this key is not known here; "
                           "did you mean 'duration_s'"), text
    assert "missing" not in text


@pytest.mark.parametrize("table, meant, given", [("spacecraft", "mass_kg", "mass"), ("dynamics", "step_s", "step"),
                                                 ("orbit", "altitude_km", "altitude_m")])
def test_other_keys_given_in_another_unit_or_none(scenario_dict, write_scenario, table, meant, given):
    data = copy.deepcopy(scenario_dict)
    data[table][given] = data[table].pop(meant)
    with pytest.raises(ScenarioError, match=rf"^{table}\.{given} = .*did you mean '{meant}'"):
        scenario.load(write_scenario(data))


def test_an_unknown_optional_key_suggests_the_known_one(scenario_dict, write_scenario):
    data = copy.deepcopy(scenario_dict)
    data["orbit"]["step"] = data["orbit"].pop("step_s")  # optional: the default applies, the typo is still named
    with pytest.raises(ScenarioError, match=r"^orbit\.step = 10\.0 .*did you mean 'step_s'\?"):
        scenario.load(write_scenario(data))


def test_the_shipped_files_hold_no_unused_key():
    """Guard on the fixtures themselves: the shipped scenarios parse (above) and none sets era0_deg, which would
    make the documented IAU 2006 override fail."""
    for name in scenario.shipped():
        data = tomllib.loads((DIR / f"{name}.toml").read_text())
        assert "era0_deg" not in data.get("environment", {}), name


def test_a_criterion_asks_the_kinds_for_their_timed_metrics_once(scenario_dict, write_scenario, monkeypatch):
    """Which metrics take ``at_s`` is asked of every controller and device kind once per criterion (it was asked
    twice, in every run's and every campaign case's parse); a missing at_s and an unused one are still refused."""
    from stand.scenario import loader

    calls = []
    real = loader._metrics_at
    monkeypatch.setattr(loader, "_metrics_at", lambda: calls.append(1) or real())
    data = copy.deepcopy(scenario_dict)
    n = len(data["criteria"])
    scenario.load(write_scenario(data))
    assert len(calls) == n
    data["criteria"][0] = {"name": "later", "metric": "rate_deg_s_at", "max": 1.0}
    with pytest.raises(ScenarioError, match=r"criteria\[0\]\.at_s"):
        scenario.load(write_scenario(data))
