"""Controller kinds: one registry, one contract, so the scenario loader and composition name no controller.

A controller kind (``[controller] kind = ...``) is a :class:`ControllerKind`: the scenario keys it takes and how
they are validated, what it costs a telemetry row, what ``stand check`` says of it and how it is built over the
scene's devices. The reference B-dot, the reference pointing ADCS and the plug-in loader build flight code from
:mod:`stand.adcs`, which sees the spacecraft only through host drivers; ``none`` runs open loop and ``external``
leaves the loop to a flight computer outside, through the served devices.

Kinds are found by name in :data:`CONTROLLERS` (``name -> "module:attribute"``, imported on first use, as
:mod:`stand.devices` finds device kinds) and in the entry-point group ``adcs_stand.controllers``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from stand.checks import ScenarioError, Table, rate
from stand.controllers.spacecraft import unwritten, unwritten_text
from stand.registry import installed_names, load_named

ENTRY_POINT_GROUP = "adcs_stand.controllers"

#: The controller kinds shipped with the stand: name -> "module:attribute" of a ControllerKind instance. The order
#: is the one a scenario error lists them in.
CONTROLLERS = {
    "bdot": "stand.controllers.bdot:KIND",
    "none": "stand.controllers.open_loop:NONE",
    "plugin": "stand.controllers.plugin:KIND",
    "external": "stand.controllers.open_loop:EXTERNAL",
    "pointing": "stand.controllers.pointing:KIND",
}
#: ``controller.budget_s`` when not given: wall-clock seconds one call into the flight code may take.
DEFAULT_BUDGET_S = 1.0

_loaded: dict[str, ControllerKind] = {}


@dataclass(frozen=True)
class ControllerSpec:
    """The validated ``[controller]`` table: the kind, its rate and what the kind took of the rest."""

    kind: str
    rate_hz: float
    params: dict = field(default_factory=dict)


class ControllerKind:
    """A kind of controller: its scenario keys and their validation, its cost, its description and its build.

    ``scenario`` arguments are :class:`stand.scenario.Scenario` objects; ``devices`` in :meth:`parse` the parsed
    device specs, in :meth:`build` the scene's built devices (name -> :class:`stand.devices.Device`)."""

    name: str = ""
    #: The keys of ``[controller]`` this kind takes beside ``kind``: another kind's key is refused as unused.
    keys: tuple[str, ...] = ("rate_hz", "budget_s")
    #: Whether the stand runs this controller in its loop (False: open loop, or a flight computer outside).
    in_stand: bool = True
    #: Floats it adds to a telemetry row, for the estimate made before t = 0 (``stand.compose.budget``).
    row_floats: int = 0
    #: Criteria metrics read from a controller's telemetry columns by convention: name -> description with unit.
    metrics: dict[str, str] = {}
    #: Metrics that need ``at_s``.
    metrics_at: tuple[str, ...] = ()
    #: Its flight code's telemetry columns -> a one-line meaning, written into the telemetry's schema.json and the
    #: generated docs/telemetry_columns.md.
    column_meanings: dict[str, str] = {}

    def parse(self, t: Table, step_s: float, devices) -> ControllerSpec:
        """The ``[controller]`` table (``kind`` already read): its rate, its call budget and :meth:`parse_params`."""
        rate_hz = rate(t, "rate_hz", step_s)
        # Wall-clock seconds one call into the flight code may take before the run ends aborted (stand.loop).
        params: dict = {"budget_s": t.number("budget_s", DEFAULT_BUDGET_S, lo=0.01, hi=3600.0)}
        self.parse_params(t, rate_hz, step_s, devices, params)
        return ControllerSpec(self.name, rate_hz, params)

    def parse_params(self, t: Table, rate_hz: float, step_s: float, devices, params: dict) -> None:
        """Validate the kind's own keys into ``params``."""

    #: Whether the columns it records are known only once it is built (a plug-in's ``telemetry_columns()``): then
    #: :meth:`check_scenario` leaves the criteria's columns to the build and ``stand check``.
    columns_when_built: bool = False

    def check_scenario(self, scenario) -> None:
        """Checks that need the whole scenario, at load (ScenarioError): by default, that no criterion reads a
        controller's column (``adcs_q_RN``...) this kind never records (it records those of its own ``metrics``)."""
        if self.columns_when_built:
            return
        problems = [p for p in unwritten(scenario.criteria, ()) if p[1] not in self.metrics]
        if problems:
            k = next(i for i, c in enumerate(scenario.criteria) if c.name == problems[0][0])
            raise ScenarioError(f"criteria[{k}].metric", problems[0][1], "a metric whose telemetry is recorded: "
                                + unwritten_text(problems[:1], f"controller.kind = {self.name!r}").rstrip("."),
                                scenario.source)

    def describe(self, scenario) -> str:
        return f"at {scenario.controller.rate_hz:g} Hz through the host drivers"

    def build(self, scenario, devices: dict, base: Path | None) -> Any:
        """The controller over the scene's devices, or None (a failure at construction is a PluginError)."""
        return None

    def check(self, scenario, base: Path | None) -> None:
        """What ``stand check`` does: construct the controller over unopened devices (:class:`NotOpened`)."""


def names() -> tuple[str, ...]:
    """Every controller kind known: the shipped ones, then those of installed packages."""
    return (*CONTROLLERS, *_installed())


@functools.cache
def _installed() -> tuple[str, ...]:
    return installed_names(ENTRY_POINT_GROUP, CONTROLLERS)


def get(name: str) -> ControllerKind:
    """The controller kind called ``name`` (imported on first use). KeyError for an unknown name."""
    return load_named(name, CONTROLLERS, ENTRY_POINT_GROUP, _loaded)


def parse_controller(t: Table, step_s: float, devices) -> ControllerSpec:
    """The ``[controller]`` table: the kind (default ``none``), no key of another kind, then the kind's own keys."""
    kind = get(t.choice("kind", names(), "none"))
    keys = {name: get(name).keys for name in names()}
    for key in sorted({k for ks in keys.values() for k in ks} - set(kind.keys)):
        owners = [name for name, ks in keys.items() if key in ks and name != kind.name]
        t.refuse_unused(key, f"controller.kind = {kind.name!r}", f"remove it (it is a key of kind "
                        f"{' or '.join(repr(o) for o in owners)})")
    spec = kind.parse(t, step_s, devices)
    t.check_unknown()
    return spec


def metrics() -> tuple[dict[str, str], set[str]]:
    """The criteria metrics every controller kind declares, and those of them that need ``at_s``."""
    out: dict[str, str] = {}
    at: set[str] = set()
    for name in names():
        out.update(get(name).metrics)
        at.update(get(name).metrics_at)
    return out, at


def build_controller(scenario, devices: dict, base: Path | None = None):
    """The scenario's controller over the scene's devices (name -> Device), or None. Plug-in failures at
    construction are PluginError (a scenario error)."""
    return get(scenario.controller.kind).build(scenario, devices, base)


def check_controller(scenario, base: Path | None = None) -> None:
    """What ``stand check`` does for the controller: import the plug-in and construct it over unopened devices,
    so a missing module, a wrong path or bad options fail here in one sentence, not at t = 0."""
    get(scenario.controller.kind).check(scenario, base)


class NotOpened:
    """What ``stand check`` hands a controller for each device: nothing is opened, so any use says so."""

    def __init__(self, name: str):
        self._name = name

    def __getattr__(self, attr):
        raise RuntimeError(f"device {self._name!r} is not opened by `stand check` (the plug-in used .{attr} in its "
                           "constructor; devices are only for update())")


def not_opened(scenario) -> dict:
    """Device name -> :class:`NotOpened`, for every device of the scenario."""
    return {d.name: NotOpened(d.name) for d in scenario.devices}
