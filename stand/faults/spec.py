"""``[[faults]]`` tables: parsed and validated before t = 0, one sentence naming the fault, the field and what is
allowed for anything wrong.

A fault names a device (``device``), a ``type`` (:data:`stand.faults.types.FAULT_TYPES`), the type's parameters
(units in the keys; a measurement fault's keys carry the device's measurement unit: ``bias_rad_s`` on a gyro,
``bias_T`` on a magnetometer), one trigger and an end:

* ``at_s``: at a time;
* ``after``: after an event, ``"fault:NAME"`` (another fault starts), ``"cleared:NAME"`` (it clears),
  ``"mode:VALUE"`` (the flight code's ``adcs_mode`` telemetry takes the value), ``"column:NAME>X"`` or
  ``"column:NAME<X"`` (a telemetry column crosses a value: a criterion met); ``delay_s`` after it;
* ``period_s``: recurring, first at ``at_s`` (default 0);
* ``rate_per_s``: at random, a Poisson process from ``at_s`` (default 0), drawn from the scenario's seed and the
  fault's index;
* the end: ``duration_s`` (each occurrence), or none: until the run ends. An instant fault (a reboot, a clock jump)
  takes no duration.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from stand import devices as kinds
from stand.checks import MISSING, NAME_PATTERN, ScenarioError, Table

from .types import AXES, FAULT_TYPES, Param

#: ``after = "..."`` forms.
AFTER = re.compile(r"(?P<what>fault|cleared|mode):(?P<arg>[A-Za-z0-9_.-]{1,100})$"
                   r"|column:(?P<col>[A-Za-z0-9_.\[\]-]{1,100})(?P<op>[<>])(?P<x>[-+0-9.eE]{1,40})$")
TRIGGERS = ("at_s", "after", "period_s", "rate_per_s")


@dataclass(frozen=True)
class After:
    """An event trigger: ``what`` is fault, cleared, mode or column; ``arg`` the fault's name, the mode or column;
    ``op`` and ``value`` for a column (and a numeric mode)."""

    what: str
    arg: str
    op: str = "="
    value: float | str = math.nan


@dataclass(frozen=True)
class FaultSpec:
    index: int
    name: str
    type: str
    device: str
    params: dict = field(default_factory=dict)  # SI, keys as the type declares them (``{unit}`` filled in)
    at_s: float | None = None
    after: After | None = None
    delay_s: float = 0.0
    period_s: float | None = None
    rate_per_s: float | None = None
    duration_s: float | None = None
    #: The parameters under the keys the scenario gave them (``bias_rad_s``), SI, for events and the summary.
    shown: dict = field(default_factory=dict)

    @property
    def where(self) -> str:
        return f"faults[{self.index}]"

    def describe(self) -> str:
        if self.after is not None:
            a = self.after
            when = f"after {a.what} {a.arg}" + (f" {a.op} {a.value:g}" if a.what == "column" else "")
            when += f" + {self.delay_s:g} s" if self.delay_s else ""
        elif self.period_s is not None:
            when = f"every {self.period_s:g} s from {self.at_s or 0.0:g} s"
        elif self.rate_per_s is not None:
            when = f"at random, {self.rate_per_s:g} per s from {self.at_s or 0.0:g} s"
        else:
            when = f"at {self.at_s:g} s"
        end = f" for {self.duration_s:g} s" if self.duration_s is not None else ""
        return f"{self.name}: {self.type} on {self.device}, {when}{end}"


def taps_of(spec) -> dict:
    """The taps a device of ``spec`` offers: tap -> its details (``{"n": 3, "unit": "rad_s"}`` for a measurement)."""
    return dict(kinds.get(spec.kind).fault_taps(spec))


def parse(raw, devices, duration_s: float, source: str | None = None, start_index: int = 0) -> tuple[FaultSpec, ...]:
    """The ``[[faults]]`` array of a scenario against its devices (``DeviceSpec`` list)."""
    if raw is MISSING or raw is None:
        return ()
    if not isinstance(raw, list):
        raise ScenarioError("faults", raw, "an array of [[faults]] tables is expected", source)
    by_name = {d.name: d for d in devices}
    out = [one(Table(f, f"faults[{k + start_index}]", source), k + start_index, by_name, duration_s)
           for k, f in enumerate(raw)]
    check_names(out, source)
    return tuple(out)


def check_names(faults, source=None, known=()) -> None:
    names = [f.name for f in faults]
    for f in faults:
        if names.count(f.name) > 1 or f.name in known:
            raise ScenarioError(f"{f.where}.name", f.name, "a name no other fault has (two faults on one device "
                                "of one type need names of their own)", source)
    all_names = set(names) | set(known)
    for f in faults:
        if f.after is not None and f.after.what in ("fault", "cleared") and f.after.arg not in all_names:
            raise ScenarioError(f"{f.where}.after", f"{f.after.what}:{f.after.arg}", "the name of another fault "
                                f"of this scenario ({', '.join(sorted(all_names - {f.name})) or 'none'})", source)
        if f.after is not None and f.after.what in ("fault", "cleared") and f.after.arg == f.name:
            raise ScenarioError(f"{f.where}.after", f"{f.after.what}:{f.after.arg}", "another fault: a fault "
                                "cannot wait for itself", source)


def one(t: Table, index: int, by_name: dict, duration_s: float) -> FaultSpec:
    type_name = t.choice("type", tuple(FAULT_TYPES))
    ftype = FAULT_TYPES[type_name]
    device = t.choice("device", tuple(by_name))
    spec = by_name[device]
    offered = taps_of(spec)
    if ftype.tap not in offered:
        able = sorted(n for n, ft in FAULT_TYPES.items() if ft.tap in offered)
        raise t.error("type", type_name, f"a fault type device {device!r} ({spec.kind}, {spec.link} link) can "
                      f"take: {', '.join(able) or 'none'} ({type_name} needs its {ftype.tap} tap)")
    name = t.text("name", f"{device}.{type_name}")
    if not NAME_PATTERN.fullmatch(name):
        raise t.error("name", name, "a plain name of letters, digits, '_', '.' and '-' (events and the page show it)")
    info = offered[ftype.tap] or {}
    params = {p.key: _param(t, p, info) for p in ftype.params}
    shown = {p.key.replace("{unit}", info.get("unit", "si")): params[p.key] for p in ftype.params}
    trig = [k for k in TRIGGERS if t.has(k)]
    if not trig:
        raise t.error("at_s", MISSING, "a trigger: at_s (a time), after (an event), period_s (recurring) or "
                      "rate_per_s (at random)")
    if len(trig) > 1 and not (trig[0] == "at_s" and trig[1] in ("period_s", "rate_per_s") and len(trig) == 2):
        raise t.error(trig[1], t.data[trig[1]], f"one trigger only ({' and '.join(trig)} given); at_s may only "
                      "come with period_s or rate_per_s, as the first occurrence's earliest time")
    at_s = t.number("at_s", lo=0.0, hi=duration_s) if t.has("at_s") else None
    after = _after(t) if t.has("after") else None
    delay_s = t.number("delay_s", 0.0, lo=0.0, hi=duration_s) if after is not None else 0.0
    if after is None:
        t.refuse_unused("delay_s", "a fault without after", "remove it, or trigger the fault with after = ...")
    period_s = t.number("period_s", lo=0.0, lo_open=True, hi=duration_s) if t.has("period_s") else None
    rate_per_s = t.number("rate_per_s", lo=0.0, lo_open=True, hi=1e3) if t.has("rate_per_s") else None
    duration = None
    if t.has("duration_s"):
        if ftype.instant:
            t.refuse_unused("duration_s", f"type = {type_name!r} (it happens at an instant)", "remove it")
        duration = t.number("duration_s", lo=0.0, lo_open=True, hi=duration_s)
        if period_s is not None and duration >= period_s:
            raise t.error("duration_s", duration, f"a duration shorter than period_s = {period_s:g} s, so each "
                          "occurrence ends before the next begins")
    elif (period_s is not None or rate_per_s is not None) and not ftype.instant:
        raise t.error("duration_s", MISSING, "a duration for each occurrence of a recurring fault")
    t.check_unknown()
    return FaultSpec(index, name, type_name, device, params, at_s, after, delay_s, period_s, rate_per_s, duration,
                     shown)


def _param(t: Table, p: Param, info: dict):
    key = p.key.replace("{unit}", info.get("unit", "si"))
    n = int(info.get("n", 3))
    if "{unit}" in p.key and key not in t.data:
        stem = p.key.split("{unit}")[0]
        other = [k for k in t.data if isinstance(k, str) and k.startswith(stem)]
        if other:  # the unit of another kind's measurement (bias_T on a gyro)
            raise t.error(other[0], t.data[other[0]], f"this device measures in {info.get('unit')}: the key is "
                          f"{key!r}")
    if p.shape == "choice":
        return t.choice(key, p.options, p.default)
    if p.shape == "axis":
        v = t.raw(key, p.default)
        v = AXES.get(v, v) if isinstance(v, str) else v
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < n:
            raise t.error(key, t.data.get(key, MISSING), f"an axis: an index from 0 to {n - 1}"
                          + (", or 'x', 'y', 'z'" if n == 3 else ""))
        return v
    if p.shape in ("vector", "vector3"):
        m = 3 if p.shape == "vector3" else n
        v = t.raw(key, MISSING)
        if p.shape == "vector" and isinstance(v, int | float) and not isinstance(v, bool):
            arr = [t.number(key, lo=p.lo, hi=p.hi)] * m  # one number: every axis
        else:
            arr = t.vector(key, m, MISSING if p.default is None else p.default, lo=p.lo, hi=p.hi).tolist()
        if p.shape == "vector3" and not sum(x * x for x in arr) > 0.0:
            raise t.error(key, arr, "a non-zero vector")
        return [float(x) * p.scale for x in arr]
    default = MISSING if p.default is None else p.default
    integer = p.shape == "integer"
    return t.number(key, default, lo=p.lo, hi=p.hi, integer=integer) * (p.scale if not integer else 1)


def _after(t: Table) -> After:
    text = t.text("after")
    m = AFTER.fullmatch(text)
    if m is None:
        raise t.error("after", text, "an event: 'fault:NAME', 'cleared:NAME', 'mode:VALUE' or 'column:NAME>X' "
                      "(or <X)")
    if m.group("col"):
        try:
            x = float(m.group("x"))
        except ValueError:
            raise t.error("after", text, "a column condition with a number: 'column:NAME>X'") from None
        if not math.isfinite(x):
            raise t.error("after", text, "a finite threshold")
        return After("column", m.group("col"), m.group("op"), x)
    return After(m.group("what"), m.group("arg"))
