"""Parsing a scenario's dict: each section in turn, devices through their kinds (:mod:`stand.devices`), the
controller through its kind (:mod:`stand.controllers`), optional sections through :data:`SECTIONS`, criteria
against every metric known. Nothing here names a device or controller kind."""

from __future__ import annotations

import importlib
from dataclasses import replace

import numpy as np

from sim.time import Epoch
from stand import controllers
from stand import devices as kinds
from stand import faults as fault_specs
from stand.adcs.metrics import FAULT_METRICS
from stand.checks import CONTROL, MISSING, NAME_PATTERN, ScenarioError, Table, rate
from stand.devices import DeviceSpec

from .model import Criterion, Scenario
from .physics import TORQUES, _check_environment_used, _check_torque_reach, _environment, _orbit, _spacecraft

#: Optional top-level sections handled outside the core: key -> "module:attribute" of an object with ``model`` (the
#: name ``stand check`` lists it under), ``parse(table, parts)`` (``parts``: ``duration_s``, ``orbit``, ...) and
#: ``describe(spec)``. Imported only when a scenario has the section.
SECTIONS = {"rendezvous": "stand.rendezvous:SECTION"}


def section(key: str):
    """The declaration of optional section ``key`` (imported on first use)."""
    module, _, attr = SECTIONS[key].partition(":")
    return getattr(importlib.import_module(module), attr)


#: Metrics of the run itself; controller and device kinds add theirs (``ControllerKind.metrics``,
#: ``DeviceKind.metrics``).
METRICS = {
    "final_rate_deg_s": "body rate |omega| at the end of the run (deg/s)",
    "rate_deg_s_at": "body rate |omega| at time at_s (deg/s)",
    "max_rate_deg_s_after": "largest body rate |omega| after time at_s (deg/s)",
    "frames_rejected": "device frames rejected by any codec (count)",
    "overruns": "ticks that ran past their real-time deadline (count, paced runs only)",
}
#: Units of the metrics, for the console and the report.
METRIC_UNITS = {"final_rate_deg_s": "deg/s", "rate_deg_s_at": "deg/s", "max_rate_deg_s_after": "deg/s",
                "frames_rejected": "frames", "overruns": "ticks", "tracker_availability_after": "",
                "tracker_error_cross_arcsec_p95": "arcsec", "tracker_error_roll_arcsec_p95": "arcsec",
                "pointing_error_arcsec_p95_after": "arcsec", "knowledge_error_arcsec_p95_after": "arcsec",
                "knowledge_within_3sigma_fraction": ""}



def all_metrics() -> dict[str, str]:
    """The run's metrics, those of every controller kind and those of every device kind."""
    out = dict(METRICS)
    out.update(controllers.metrics()[0])
    for name in kinds.kind_names():
        out.update(kinds.get(name).metrics)
    return out


def parse(data: dict, source: str | None = None) -> Scenario:
    root = Table(data, "", source)
    sc = root.table("scenario")
    name = sc.text("name")
    if not NAME_PATTERN.fullmatch(name):
        raise sc.error("name", name, "a plain name of letters, digits, '_', '.' and '-' (at most 100, not "
                       "starting with '.'): it names the run's folder, which stays inside the output folder")
    description = sc.raw("description", "")
    epoch_text = sc.text("epoch")
    try:
        epoch = Epoch.from_iso(epoch_text)
    except ValueError as exc:
        # The value is already in the sentence (cut to its first 200 characters); the model's message repeats it.
        raise sc.error("epoch", epoch_text, str(exc).replace(f"epoch {epoch_text!r}", "the epoch").rstrip(".")) \
            from None
    duration_s = sc.number("duration_s", lo=0, lo_open=True, hi=30 * 86400)
    if not isinstance(description, str) or len(description) > 2000 or CONTROL.search(description):
        # It is printed on consoles and in reports: no control characters (terminal escapes, NUL), no novels.
        raise sc.error("description", description, "a string of at most 2000 characters without control characters")
    seed = int(sc.number("seed", 0, lo=0, integer=True))
    sc.check_unknown()

    dyn = root.table("dynamics")
    step_s = dyn.number("step_s", lo=1e-6, hi=10.0)
    # Fixed-step methods only: an adaptive one restarting at every control step is what the issue
    # criticises in Basilisk; DOP853 stays an offline reference (stand bench accuracy).
    integrator = dyn.choice("integrator", ("rk4", "rkmk4", "implicit_midpoint"), "rk4")
    torques = dyn.raw("torques", ["magnetic", "gravity_gradient"])
    if not isinstance(torques, list) or any(t not in TORQUES for t in torques):
        raise dyn.error("torques", torques, "a list drawn from " + ", ".join(repr(t) for t in TORQUES))
    if step_s > duration_s:
        raise dyn.error("step_s", step_s, f"a step no longer than the run (scenario.duration_s = {duration_s:g} s): "
                        "a run simulates whole steps")
    dyn.check_unknown()

    orbit = _orbit(root.table("orbit"))
    spacecraft = _spacecraft(root.table("spacecraft"), step_s, integrator)
    env_table = root.table("environment", required=False)
    environment = _environment(env_table, epoch)

    devices_raw = root.raw("devices", [])
    if not isinstance(devices_raw, list):
        raise root.error("devices", devices_raw, "an array of [[devices]] tables is expected")
    devices = tuple(_device(Table(d, f"devices[{k}]", source), step_s) for k, d in enumerate(devices_raw))
    names = [d.name for d in devices]
    if len(set(names)) != len(names):
        raise root.error("devices", names, "device names must be unique")
    _check_refs(devices, source)
    _check_environment_used(env_table, environment, epoch, torques, orbit, devices)

    controller = controllers.parse_controller(root.table("controller", required=False), step_s, devices)
    _check_torque_reach(spacecraft, orbit, devices, torques, controller, step_s, integrator, source)
    crit_raw = root.raw("criteria", [])
    if not isinstance(crit_raw, list):
        raise root.error("criteria", crit_raw, "an array of [[criteria]] tables is expected")
    criteria = tuple(_criterion(Table(c, f"criteria[{k}]", source), duration_s) for k, c in enumerate(crit_raw))

    faults = fault_specs.parse(root.raw("faults", None), devices, duration_s, source)

    rec = root.table("recording", required=False)
    record_rate_hz = rate(rec, "rate_hz", step_s, default=1.0 / step_s)
    rec.check_unknown()
    parts = {"duration_s": duration_s, "step_s": step_s, "orbit": orbit, "devices": devices}
    sections = {key: section(key).parse(root.table(key), parts) for key in SECTIONS if root.has(key)}
    root.check_unknown()
    sc = Scenario(name, description, source or "<string>", epoch, duration_s, seed, step_s, integrator,
                  tuple(torques), orbit, spacecraft, environment, devices, controller, criteria,
                  record_rate_hz, sections, faults)
    controllers.get(controller.kind).check_scenario(sc)
    return sc


def _device(t: Table, step_s: float) -> DeviceSpec:
    """The common part of a ``[[devices]]`` table; the kind's own module validates the rest."""
    kind_name = t.choice("kind", kinds.kind_names())
    kind = kinds.get(kind_name)
    name = t.text("name")
    if not NAME_PATTERN.fullmatch(name):
        raise t.error("name", name, "a plain name of letters, digits, '_', '.' and '-' (it names telemetry columns)")
    link = t.choice("link", kind.links, kind.default_link)
    q_SB = t.vector("q_SB", 4, [1.0, 0.0, 0.0, 0.0], lo=-2.0, hi=2.0)
    if abs(np.linalg.norm(q_SB) - 1.0) > 1e-6:
        raise t.error("q_SB", q_SB.tolist(), "a unit quaternion [w, x, y, z] (sensor frame relative to body)")
    return kind.parse(t, DeviceSpec(name=name, kind=kind_name, link=link, q_SB=q_SB), step_s)


def _check_refs(specs, source) -> None:
    """A device that takes something from another (a magnetometer reading a cage's field) names one that exists
    and provides it."""
    by_name = {d.name: d for d in specs}
    for k, d in enumerate(specs):
        for key, (target, what) in kinds.get(d.kind).refs(d).items():
            providers = [x.name for x in specs if what in kinds.get(x.kind).provides]
            if target not in by_name or target not in providers:
                raise ScenarioError(f"devices[{k}].{key}", target, "'truth' or the name of a device that makes the "
                                    f"{what.replace('_', ' ')} ({', '.join(providers) or 'none in this scenario'})",
                                    source)


def _criterion(t: Table, duration_s: float) -> Criterion:
    metric = t.choice("metric", tuple(all_metrics()))
    c = Criterion(
        name=t.text("name", metric),
        metric=metric,
        max=t.number("max") if t.has("max") else None,
        min=t.number("min") if t.has("min") else None,
        at_s=t.number("at_s", lo=0.0, hi=duration_s) if t.has("at_s") else None,
    )
    if c.max is None and c.min is None:
        raise t.error("max", MISSING, "a max or a min limit for the criterion")
    c = _fault_fields(t, c)
    timed = _metrics_at()  # once: it asks every controller and device kind
    if metric in timed and c.at_s is None:
        raise t.error("at_s", MISSING, f"a time in [0, {duration_s:g}] s for metric {metric!r}")
    t.check_unknown()
    if metric not in timed:
        t.refuse_unused("at_s", f"metric = {metric!r} (it takes no time)", "remove it, or choose a metric that "
                        "takes one (" + ", ".join(sorted(timed)) + ")")
    return c


def _fault_fields(t: Table, c: Criterion) -> Criterion:
    """``fault`` (required by an FDIR metric, refused elsewhere) and ``within_deg`` (fault_recovery_s only)."""
    if c.metric not in FAULT_METRICS:
        t.refuse_unused("fault", f"metric = {c.metric!r} (it is about no fault)", "remove it, or choose a fault "
                        "metric (" + ", ".join(FAULT_METRICS) + ")")
        t.refuse_unused("within_deg", f"metric = {c.metric!r}", "remove it (it is fault_recovery_s's limit)")
        return c
    fault = t.text("fault")
    if c.metric != "fault_recovery_s":
        t.refuse_unused("within_deg", f"metric = {c.metric!r}", "remove it (it is fault_recovery_s's limit)")
        return replace(c, fault=fault)
    return replace(c, fault=fault, within_deg=t.number("within_deg", lo=0.0, lo_open=True, hi=180.0))


def _metrics_at() -> set[str]:
    out = {"rate_deg_s_at", "max_rate_deg_s_after", *controllers.metrics()[1]}
    for name in kinds.kind_names():
        out.update(kinds.get(name).metrics_at)
    return out
