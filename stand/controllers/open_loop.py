"""The controller kinds the stand does not run: ``none`` (open loop) and ``external`` (a flight computer outside
closes the loop through the served devices, ``[[devices]] link = "served"``)."""

from __future__ import annotations

from stand.checks import Table
from stand.controllers import ControllerKind, ControllerSpec


class OpenLoop(ControllerKind):
    name = "none"
    keys = ()
    in_stand = False

    def parse(self, t: Table, step_s: float, devices) -> ControllerSpec:
        return ControllerSpec(self.name, 1.0 / step_s)

    def describe(self, scenario) -> str:
        return "no controller in the scenario: open loop"


class External(OpenLoop):
    name = "external"

    def parse(self, t: Table, step_s: float, devices) -> ControllerSpec:
        if not any(d.link == "served" for d in devices):
            raise t.error("kind", self.name, "a scenario with served devices ([[devices]] link = 'served') for the "
                          "flight computer outside to close the loop through")
        return super().parse(t, step_s, devices)

    def describe(self, scenario) -> str:
        return ("a flight computer outside closes the loop through the served devices ("
                + ", ".join(d.name for d in scenario.devices if d.link == "served") + "); the run is paced")


NONE = OpenLoop()
EXTERNAL = External()
