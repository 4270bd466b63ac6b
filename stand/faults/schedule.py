"""The fault schedule of a run: starts and clears faults on their triggers, first in a tick.

It exists only in a run that has ``[[faults]]`` or takes faults live (``stand run --view``): the loop adds its
:meth:`FaultSchedule.tick` ahead of the devices then, and a scene without it pays nothing. A tick with nothing due
costs one comparison. Every start and clear is an event (``fault_injected``, ``fault_cleared`` in
``events.jsonl``, with the fault's name, type, device, parameters and sim time), and :meth:`summary` gives each
fault's occurrences for ``summary.json``.

Live faults (:meth:`inject`, :meth:`clear`) come from the operator page through the loop's control poll, in the
loop's thread: they are validated by the same parser as the scenario's and applied at the next tick.
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from stand.checks import ScenarioError, Table

from . import spec as specs
from . import taps
from .types import FAULT_TYPES, Activation

#: Spawn-key prefix of the faults' random streams: the devices' streams (spawned from the same seed) stay as they
#: were, so adding a fault changes nothing else's draws.
STREAM = 0x46415554
EPS_S = 1e-9


class _Occurrence:
    """One start of a fault (and its end), live or scheduled."""

    def __init__(self, fault: specs.FaultSpec, start_s: float, k: int):
        self.fault, self.start_s, self.k = fault, start_s, k
        self.end_s = math.inf if fault.duration_s is None else start_s + fault.duration_s
        self.tap = self.handle = self.activation = None

    def __lt__(self, other):  # ordered by start, then by the fault's index (the scenario's order)
        return (self.start_s, self.fault.index, self.k) < (other.start_s, other.fault.index, other.k)


class FaultSchedule:
    """The faults of one run over its built devices (``scene.devices``)."""

    def __init__(self, faults, devices: dict, device_specs: dict, seed: int, duration_s: float, controller=None,
                 source=None):
        self.devices, self.seed, self.duration_s, self.source = devices, seed, duration_s, source
        self.specs = device_specs  # name -> DeviceSpec
        self.controller = controller
        self.faults = list(faults)
        self.events = None
        self.pending: list[_Occurrence] = []
        self.active: list[_Occurrence] = []
        self.links: list = []
        self.watch: list[specs.FaultSpec] = []  # faults waiting for a mode or a column
        self.record: dict[str, dict] = {}
        self.commands: list = []
        self.offsets: dict[str, int] = {}
        self.next_s = math.inf
        self.t_s = 0.0
        for f in self.faults:
            self._plan(f)

    # -- planning -----------------------------------------------------------------------------------------------

    def _rng(self, f: specs.FaultSpec) -> np.random.Generator:
        return np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(STREAM, f.index)))

    def _plan(self, f: specs.FaultSpec, now_s: float = 0.0) -> None:
        self.record[f.name] = {"type": f.type, "device": f.device, "layer": FAULT_TYPES[f.type].layer,
                               "trigger": f.describe(), "params": f.shown, "occurrences": []}
        if f.after is not None:
            if f.after.what in ("mode", "column"):
                self.watch.append(f)
            return
        first = max(f.at_s or 0.0, now_s)
        if f.period_s is not None:
            n = int(math.floor((self.duration_s - first) / f.period_s + EPS_S)) + 1
            for k in range(max(n, 0)):
                self._add(_Occurrence(f, first + k * f.period_s, k))
        elif f.rate_per_s is not None:
            rng, t, k = self._rng(f), first, 0
            while True:  # a Poisson process: exponential gaps, bounded by the run's length
                t += float(rng.exponential(1.0 / f.rate_per_s))
                if t > self.duration_s or k >= 1_000_000:
                    break
                self._add(_Occurrence(f, t, k))
                k += 1
        else:
            self._add(_Occurrence(f, first, 0))

    def _add(self, occ: _Occurrence) -> None:
        bisect.insort(self.pending, occ)
        self.next_s = min(self.next_s, occ.start_s)

    def bind_columns(self, columns) -> bool:
        """Learn where each telemetry column sits in a row (``(name, width, unit)`` in order); True when a fault
        waits for a mode or a column, so the loop hands :meth:`row` every recorded row."""
        at = 0
        for name, width, _unit in columns:
            self.offsets[name] = at
            at += width
        for f in self.watch:
            col = "adcs_mode" if f.after.what == "mode" else f.after.arg
            if col not in self.offsets:
                raise ScenarioError(f"{f.where}.after", f"{f.after.what}:{f.after.arg}", "a telemetry column this "
                                    "run records (" + ", ".join(n for n, _w, _u in columns[:40]) + ")", self.source)
        return bool(self.watch)

    # -- the loop's calls ---------------------------------------------------------------------------------------

    def start(self, events) -> None:
        self.events = events

    def tick(self, t_s: float) -> None:
        """First in a tick: start and clear what is due, take live commands, release delayed frames."""
        self.t_s = t_s
        if self.commands:
            self._obey(t_s)
        if t_s + EPS_S >= self.next_s:
            self._due(t_s)
        for link in self.links:
            link.advance(t_s)

    def row(self, t_s: float, row: tuple) -> None:
        """A recorded row: start the faults waiting for a mode or a column that it shows."""
        for f in list(self.watch):
            a = f.after
            if a.what == "mode":
                x = row[self.offsets["adcs_mode"]]
                want = a.arg if not _is_number(a.arg) else float(a.arg)
                codes = getattr(self.controller, "mode_codes", {})
                hit = x == (codes.get(want, math.nan) if isinstance(want, str) else want)
            else:
                x = row[self.offsets[a.arg]]
                hit = x > a.value if a.op == ">" else x < a.value
            if hit:
                self.watch.remove(f)
                self._add(_Occurrence(f, t_s + f.delay_s, 0))

    def _due(self, t_s: float) -> None:
        for occ in [o for o in self.active if o.end_s <= t_s + EPS_S]:
            self._stop(occ, t_s)
        while self.pending and self.pending[0].start_s <= t_s + EPS_S:
            self._start(self.pending.pop(0), t_s)
        ends = [o.end_s for o in self.active]
        self.next_s = min([*ends, self.pending[0].start_s if self.pending else math.inf])

    def _start(self, occ: _Occurrence, t_s: float) -> None:
        f = occ.fault
        ftype = FAULT_TYPES[f.type]
        device = self.devices[f.device]
        occ.tap = taps.find(device, ftype.tap)
        info = specs.taps_of(self.specs[f.device])
        occ.activation = Activation(t_s, self._rng(f) if occ.k == 0 else
                                    np.random.default_rng(np.random.SeedSequence(
                                        self.seed, spawn_key=(STREAM, f.index, occ.k))), info.get(ftype.tap) or {})
        occ.handle = ftype.start(occ.tap, f.params, occ.activation)
        if ftype.tap == "link" and occ.tap not in self.links:
            self.links.append(occ.tap)
        rec = self.record[f.name]["occurrences"]
        rec.append([t_s, None if not ftype.instant else t_s])
        self._log("fault_injected", f"{f.name}: {f.type} on {f.device} at t = {t_s:.3f} s", f, t_s)
        if ftype.instant:
            self._followers("cleared", f.name, t_s)
        else:
            # Started at this tick (a fault seen on a row starts at the next one): it lasts its whole duration.
            occ.end_s = math.inf if f.duration_s is None else t_s + f.duration_s
            self.active.append(occ)
        self._followers("fault", f.name, t_s)

    def _stop(self, occ: _Occurrence, t_s: float) -> None:
        f = occ.fault
        FAULT_TYPES[f.type].stop(occ.tap, occ.handle, occ.activation)
        self.active.remove(occ)
        occ.activation.t_s = t_s
        self.record[f.name]["occurrences"][-1][1] = t_s
        self._log("fault_cleared", f"{f.name}: cleared at t = {t_s:.3f} s", f, t_s)
        self._followers("cleared", f.name, t_s)

    def _followers(self, what: str, name: str, t_s: float) -> None:
        for g in self.faults:
            if g.after is not None and g.after.what == what and g.after.arg == name:
                self._add(_Occurrence(g, t_s + g.delay_s, len(self.record[g.name]["occurrences"])))
        self.next_s = min(self.next_s, self.pending[0].start_s if self.pending else math.inf)

    def _log(self, kind: str, text: str, f: specs.FaultSpec, t_s: float) -> None:
        if self.events is not None:
            self.events.log(kind, text, t_s=t_s, fault=f.name, type=f.type, device=f.device,
                            layer=FAULT_TYPES[f.type].layer, params=f.shown)

    # -- live ---------------------------------------------------------------------------------------------------

    def inject(self, table: dict) -> str:
        """Validate a fault table (a ``[[faults]]`` table; no trigger: now) and queue it for the next tick; its
        name back. Raises ScenarioError with the reason for a bad table."""
        if not isinstance(table, dict):
            raise ScenarioError("fault", table, "a table of the fault's keys (device, type, parameters)")
        index = len(self.faults)
        data = dict(table)
        if not any(k in data for k in specs.TRIGGERS):
            data["at_s"] = 0.0  # now: at the next tick
        f = specs.one(Table(data, f"faults[{index}]", "live"), index, self.specs, self.duration_s)
        specs.check_names([*self.faults, f], "live")
        self.faults.append(f)
        self.commands.append(("inject", f))
        return f.name

    def clear(self, name: str) -> None:
        """Clear fault ``name`` at the next tick (its active occurrences end, its pending ones are dropped).
        KeyError for a fault this run does not know."""
        if name not in {f.name for f in self.faults}:
            raise KeyError(name)
        self.commands.append(("clear", name))

    def _obey(self, t_s: float) -> None:
        commands, self.commands = self.commands, []
        for what, x in commands:
            if what == "inject":
                self._plan(x, now_s=t_s)
            else:
                self.pending = [o for o in self.pending if o.fault.name != x]
                self.watch = [f for f in self.watch if f.name != x]
                for occ in [o for o in self.active if o.fault.name == x]:
                    self._stop(occ, t_s)
        self.next_s = min([*(o.end_s for o in self.active), self.pending[0].start_s if self.pending else math.inf])

    # -- the end ------------------------------------------------------------------------------------------------

    def active_names(self) -> list[str]:
        return [o.fault.name for o in self.active]

    def summary(self) -> dict:
        """Each fault's type, device, trigger, parameters and occurrences ``[start_s, end_s]`` (end None: still on
        when the run ended), and the counters of every link a fault touched."""
        out = {name: dict(r, occurrences=[list(o) for o in r["occurrences"]]) for name, r in self.record.items()}
        for f in self.faults:
            tap = getattr(self.devices.get(f.device), "_fault_taps", {}).get("link")
            if tap is not None and FAULT_TYPES[f.type].tap == "link":
                out[f.name]["link_counters"] = dict(tap.counters)
        return out


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def build(scenario, devices: dict, controller=None, live: bool = False, duration_s: float | None = None
          ) -> FaultSchedule | None:
    """The schedule of a run of ``duration_s`` (default the scenario's), or None when it has no faults and takes
    none live (it then costs nothing)."""
    faults = getattr(scenario, "faults", ())
    if not faults and not live:
        return None
    return FaultSchedule(faults, devices, {d.name: d for d in scenario.devices}, scenario.seed,
                         scenario.duration_s if duration_s is None else duration_s, controller, scenario.source)
