"""The controller registry (stand.controllers): the scenario loader, composition and the build reach a controller
kind only through it, so a kind the core has never heard of is validated, planned, estimated and built."""

from __future__ import annotations

import pytest

from stand import controllers, scenario
from stand.checks import Table
from stand.compose import budget, build, plan
from stand.controllers import ControllerKind
from stand.errors import ScenarioError


class Hold:
    """Flight code that commands nothing and records one number."""

    def __init__(self, level: float):
        self.level = level
        self.updates = 0

    def update(self, t_s: float) -> None:
        self.updates += 1


class HoldKind(ControllerKind):
    name = "hold"
    keys = ("rate_hz", "budget_s", "level")
    row_floats = 5

    def parse_params(self, t: Table, rate_hz: float, step_s: float, devices, params: dict) -> None:
        params["level"] = t.number("level", lo=0.0, hi=1.0)

    def describe(self, sc) -> str:
        return f"holding at level {sc.controller.params['level']:g}"

    def build(self, sc, devices, base):
        return Hold(sc.controller.params["level"])


@pytest.fixture
def hold(monkeypatch):
    """A controller kind registered under a name no module of the stand writes."""
    monkeypatch.setitem(controllers.CONTROLLERS, "hold", "tests.stand.test_controllers:KIND")
    monkeypatch.setitem(controllers._loaded, "hold", HoldKind())


def _hold_scenario(scenario_dict, **controller) -> dict:
    scenario_dict["controller"] = {"kind": "hold", "rate_hz": 2.0, "level": 0.5, **controller}
    scenario_dict["criteria"] = []
    return scenario_dict


def test_a_registered_kind_is_parsed_planned_estimated_and_built(hold, scenario_dict):
    sc = scenario.parse(_hold_scenario(scenario_dict), "hold.toml")
    assert (sc.controller.kind, sc.controller.rate_hz, sc.controller.params["level"]) == ("hold", 2.0, 0.5)
    assert sc.controller.params["budget_s"] == controllers.DEFAULT_BUDGET_S
    choice = next(c for c in plan(sc) if c.model == "controller.hold")
    assert choice.built and choice.reason == "holding at level 0.5"
    # The kind's telemetry floats are in the estimate: 5 more than the same scene open loop.
    open_loop = scenario.parse({**scenario_dict, "controller": {"kind": "none"}}, "none.toml")
    assert budget(sc).row_floats - budget(open_loop).row_floats == 5
    with build(sc) as scene:
        assert isinstance(scene.controller, Hold) and scene.controller.level == 0.5


def test_a_kinds_own_key_is_validated_by_it(hold, scenario_dict):
    with pytest.raises(ScenarioError) as info:
        scenario.parse(_hold_scenario(scenario_dict, level=2.0), "hold.toml")
    assert info.value.field == "controller.level" and "<= 1" in str(info.value)


def test_another_kinds_key_is_refused_naming_its_kind(hold, scenario_dict):
    with pytest.raises(ScenarioError) as info:
        scenario.parse(_hold_scenario(scenario_dict, gain_A_m2_s_per_T=1.0), "hold.toml")
    assert info.value.field == "controller.gain_A_m2_s_per_T"
    assert "controller.kind = 'hold' leaves this key unused" in str(info.value) and "kind 'bdot'" in str(info.value)


def test_an_unknown_kind_lists_the_registered_ones(hold, scenario_dict):
    scenario_dict["controller"] = {"kind": "hover"}
    with pytest.raises(ScenarioError) as info:
        scenario.parse(scenario_dict, "hover.toml")
    assert info.value.field == "controller.kind"
    assert "'bdot', 'none', 'plugin', 'external', 'pointing', 'hold'" in str(info.value)
