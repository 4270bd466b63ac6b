"""Monte Carlo campaigns: one scenario run many times with dispersed inputs.

A dispersion file (TOML) names scenario fields by their dotted path, as ``stand run --set`` does (a
``[[devices]]`` entry by its name: ``devices.mtq.mag_noise_nT``), each with a distribution::

    [campaign]
    seed = 2026                        # optional; --seed wins; default: the scenario's seed

    [[dispersions]]
    field = "spacecraft.inertia_kg_m2"
    distribution = "normal"            # mean (default: the scenario's value), sigma or sigma_percent,
    sigma_percent = 5.0                #   optional min / max (a truncated normal)
    min = 0.001

    [[dispersions]]
    field = "devices.mtq.q_SB"
    distribution = "rotation"          # a small random rotation composed onto the scenario's quaternion
    sigma_deg = 0.5                    #   (rotation vector normal per axis, degrees)

    [[dispersions]]
    field = "scenario.epoch"
    distribution = "choice"            # one of a list, optionally weighted
    values = ["2026-03-20T12:00:00Z", "2026-06-21T00:00:00Z"]

Distributions: ``normal``, ``uniform`` (min, max; ``integer = true`` for whole numbers), ``rotation``,
``uniform_rotation`` (any attitude, uniformly), ``choice``. Every parameter is a number or, for a vector
field, a list with one number per axis (per-axis dispersions).

Values are applied to the scenario's parsed TOML dict and the result goes through ``stand.scenario.parse``, so
every dispersed value meets the same validation as a hand-written one; all cases are validated before the
first run starts. Case ``k`` of a campaign with seed ``S`` draws from ``numpy.random.SeedSequence((S, k))``:
its first child seeds the run (``[scenario] seed``), the next ones the dispersions in file order, so any case
re-runs alone and adding runs never changes the earlier ones.

Runs go to a local process pool or to a Dask distributed scheduler. A worker runs the case in a temporary
folder and returns its files; the client writes them under ``DIR/cases/NNNNN/``, so workers need no shared
file system. Finished cases (a ``case.json``) are never redone; a run that raises is recorded as an error and
the others go on. ``aggregate`` turns the cases into ``campaign.json`` and ``write_report`` into
``report.md`` with plots.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import shutil
import sys
import tempfile
import threading
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .errors import MISSING, ScenarioError, shown

DISTRIBUTIONS = ("normal", "uniform", "rotation", "uniform_rotation", "choice")
#: Keys each distribution takes (besides ``field`` and ``distribution``).
KEYS = {
    "normal": ("mean", "sigma", "sigma_percent", "min", "max"),
    "uniform": ("min", "max", "integer"),
    "rotation": ("sigma_deg",),
    "uniform_rotation": (),
    "choice": ("values", "weights"),
}
MAX_RUNS = 100_000
#: Default wall-clock limit of one case (``--case-timeout``): the backstop for a case that hangs. A full-orbit
#: detumble takes 5 to 20 s on a loaded 2-core machine; an hour leaves room for long scenarios on slow workers.
CASE_TIMEOUT_S = 3600.0
MAX_CASE_TIMEOUT_S = 30 * 86400.0
#: Times a case may end its worker process (os._exit, a signal, a crash) before it is recorded as an error.
WORKER_DEATHS = 2
#: Exit code of a Dask worker process ended by the per-case limit.
EXIT_OVERRUN = 70
#: The HTTP address of the scheduler of a Dask LocalCluster the stand starts (bench, tests): loopback, any free port.
#: ``dashboard_address=None`` is not "none": the scheduler still serves HTTP on 8787 and warns when it is taken.
DASK_HTTP_ADDRESS = "127.0.0.1:0"
#: Largest bound of an integer uniform dispersion (whole numbers a float holds exactly).
MAX_INTEGER = 2**53
CASE_DIGITS = 5
#: Files of a run that travel back from the worker (plots are drawn for the campaign, not per run).
RUN_FILES = ("summary.json", "events.jsonl", "telemetry/schema.json", "telemetry/rows.f64")
#: Summary keys that depend on the wall clock, left out when two runs of a case are compared.
WALL_CLOCK_KEYS = ("wall_time_s", "realtime_factor", "source")
#: Worst cases listed per criterion.
WORST = 5
CONFIDENCE = 0.95

# One run at a time per process: emulated buses (python-can ``virtual``) are process-wide names, and a Dask
# worker may run several tasks on threads.
_RUN_LOCK = threading.Lock()


class CampaignError(ValueError):
    """A campaign's inputs are wrong (dispersion file, output folder, options): one sentence, as ScenarioError."""


# ------------------------------------------------------------------------------ dotted paths in scenario dicts
def _locate(data: dict, path: str, where: str) -> tuple[dict, str]:
    """The table holding ``path``'s last key; list entries are addressed by their ``name``."""
    parts = path.split(".")
    if not path or any(not p for p in parts):
        raise CampaignError(f"{where}: field = {path!r} is not allowed: a dotted scenario key such as "
                            "spacecraft.omega_BN_B_deg_s or devices.mtq.mag_noise_nT.")
    node: Any = data
    for i, part in enumerate(parts[:-1]):
        so_far = ".".join(parts[: i + 1])
        if isinstance(node, list):
            names = [d.get("name") for d in node if isinstance(d, dict)]
            match = [d for d in node if isinstance(d, dict) and d.get("name") == part]
            if not match:
                raise CampaignError(f"{where}: field = {path!r} is not allowed: {'.'.join(parts[:i])} has no entry "
                                    f"named {part!r} (entries: {', '.join(map(str, names)) or 'none'}).")
            node = match[0]
        elif isinstance(node, dict):
            if part not in node:
                raise CampaignError(f"{where}: field = {path!r} is not allowed: the scenario has no {so_far} (a "
                                    "dispersion varies what the scenario sets; it never adds a table).")
            node = node[part]
        else:
            raise CampaignError(f"{where}: field = {path!r} is not allowed: {'.'.join(parts[:i])} is a value, "
                                "not a table.")
    if isinstance(node, list):
        raise CampaignError(f"{where}: field = {path!r} is not allowed: {'.'.join(parts[:-1])} is a list of "
                            "tables; name an entry, e.g. devices.NAME.KEY.")
    if not isinstance(node, dict):
        raise CampaignError(f"{where}: field = {path!r} is not allowed: {'.'.join(parts[:-1])} is a value, "
                            "not a table.")
    return node, parts[-1]


def get_field(data: dict, path: str, where: str = "dispersion"):
    table, key = _locate(data, path, where)
    return table.get(key, MISSING)


def put_field(data: dict, path: str, value, where: str = "dispersion") -> None:
    table, key = _locate(data, path, where)
    table[key] = value


# ------------------------------------------------------------------------------------------- dispersions
def _to_python(x):
    """numpy values to TOML-like Python values (floats, ints, nested lists)."""
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return x


@dataclass(frozen=True)
class Dispersion:
    """One dispersed field: ``draw(rng)`` gives its value for a case; ``scalars(value)`` names the numbers a
    scatter plot sets against the metrics."""

    field: str
    distribution: str
    shape: tuple  # () for a scalar, (3,) for a vector, ...
    nominal: Any
    params: dict

    def draw(self, rng: np.random.Generator):
        p, shape = self.params, self.shape
        if self.distribution == "normal":
            from scipy.special import ndtr, ndtri

            mean, sigma = p["mean"], p["sigma"]
            lo = np.where(sigma > 0, ndtr((p["min"] - mean) / np.where(sigma > 0, sigma, 1.0)), 0.0)
            hi = np.where(sigma > 0, ndtr((p["max"] - mean) / np.where(sigma > 0, sigma, 1.0)), 1.0)
            u = np.clip(rng.random(shape), 1e-300, None)  # 0 would map to an infinite draw
            # Inverse CDF of the normal truncated to [min, max]: exact, one draw per axis, no rejection loop.
            x = mean + sigma * ndtri(lo + u * (hi - lo))
            return _to_python(np.clip(np.where(sigma > 0, x, mean), p["min"], p["max"]))
        if self.distribution == "uniform":
            if p["integer"]:
                return _to_python(rng.integers(p["min"].astype(np.int64), p["max"].astype(np.int64) + 1, shape))
            return _to_python(rng.uniform(p["min"], p["max"], shape))
        if self.distribution == "rotation":
            from sim.rotations import canonical, compose, quat_from_axis_angle

            rotvec = np.radians(p["sigma_deg"]) * rng.standard_normal(3)
            angle = float(np.linalg.norm(rotvec))
            dq = quat_from_axis_angle(rotvec / angle, angle) if angle > 0 else np.array([1.0, 0.0, 0.0, 0.0])
            return _to_python(canonical(compose(dq, np.asarray(self.nominal, dtype=float))))
        if self.distribution == "uniform_rotation":
            from sim.rotations import canonical

            q = rng.standard_normal(4)
            return _to_python(canonical(q / np.linalg.norm(q)))
        k = int(rng.choice(len(p["values"]), p=p["weights"]))
        return p["values"][k]

    def scalars(self, value) -> dict[str, float]:
        if self.distribution in ("normal", "uniform"):
            arr = np.asarray(value, dtype=float)
            if arr.ndim == 0:
                return {self.field: float(arr)}
            return {f"{self.field}[{','.join(map(str, i))}]": float(arr[i]) for i in np.ndindex(arr.shape)}
        if self.distribution in ("rotation", "uniform_rotation"):
            from sim.rotations import angle_between

            ref = self.nominal if self.distribution == "rotation" else [1.0, 0.0, 0.0, 0.0]
            return {f"{self.field} angle_deg": float(np.degrees(angle_between(np.asarray(value, float),
                                                                              np.asarray(ref, float))))}
        return {f"{self.field} choice": float(self.params["values"].index(value))}


class _Params:
    """The keys of one ``[[dispersions]]`` entry, each checked with a sentence naming it."""

    def __init__(self, entry: dict, where: str, shape: tuple):
        self.entry, self.where, self.shape = entry, where, shape

    def error(self, key, value, allowed) -> CampaignError:
        return CampaignError(str(ScenarioError(f"{self.where}.{key}", value, allowed)))

    def numbers(self, key, default=MISSING, *, lo=-math.inf, lo_open=False, hi=math.inf) -> np.ndarray:
        value = self.entry.get(key, default)
        n = "one number" if not self.shape else f"a number or a list of shape {list(self.shape)} (one per axis)"
        if value is MISSING:
            raise self.error(key, value, f"{n} is required")
        try:
            ok_type = not _has_bool(value)
            arr = np.asarray(value, dtype=float) if ok_type else None
        except (TypeError, ValueError):
            arr = None
        if arr is None or not (arr.shape == () or arr.shape == self.shape) or not np.all(np.isfinite(arr)):
            raise self.error(key, value, f"{n}, finite")
        if np.any(arr < lo) or (lo_open and np.any(arr == lo)):
            bound = f"{'>' if lo_open else '>='} {lo:g}"
            raise self.error(key, value, f"a number {bound}" if not self.shape else f"{n}, each {bound}")
        if np.any(arr > hi):
            raise self.error(key, value, f"a number <= {hi:g}" if not self.shape else f"{n}, each <= {hi:g}")
        return np.broadcast_to(arr, self.shape).astype(float)


def _has_bool(value) -> bool:
    if isinstance(value, bool):
        return True
    return isinstance(value, list) and any(_has_bool(v) for v in value)


def _shape_of(value) -> tuple | None:
    """The shape of a number or a (nested) list of numbers, None for anything else."""
    if _has_bool(value):
        return None
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
    return arr.shape if arr.dtype.kind == "f" else None


def _dispersion(entry, k: int, scenario: dict) -> Dispersion:
    where = f"dispersions[{k}]"
    if not isinstance(entry, dict):
        raise CampaignError(f"{where} = {entry!r} is not allowed: a [[dispersions]] table with field and "
                            "distribution.")
    fld = entry.get("field", MISSING)
    if not isinstance(fld, str):
        raise CampaignError(str(ScenarioError(f"{where}.field", fld, "a dotted scenario key (a string) such as "
                                              "spacecraft.omega_BN_B_deg_s")))
    where = f"{where} ({fld})"
    dist = entry.get("distribution", MISSING)
    if dist not in DISTRIBUTIONS:
        raise CampaignError(str(ScenarioError(f"{where}.distribution", dist,
                                              "one of " + ", ".join(repr(d) for d in DISTRIBUTIONS))))
    unknown = sorted(set(entry) - {"field", "distribution", *KEYS[dist]})
    if unknown:
        raise CampaignError(str(ScenarioError(f"{where}.{unknown[0]}", entry[unknown[0]],
                                              f"a key a {dist} dispersion takes: "
                                              + (", ".join(KEYS[dist]) or "none besides field and distribution"))))
    nominal = get_field(scenario, fld, where)
    if dist in ("rotation", "uniform_rotation"):
        return _rotation(entry, where, fld, dist, nominal)
    if dist == "choice":
        return _choice(entry, where, fld, nominal)
    shape = _shape_of(nominal) if nominal is not MISSING else None
    if nominal is not MISSING and shape is None:
        raise CampaignError(f"{where}: the scenario's value {nominal!r} is not a number or a list of numbers; a "
                            f"{dist} dispersion draws numbers (use distribution = 'choice' for other values).")
    if shape is None:  # the scenario leaves the field to its default: the dispersion's own numbers give the shape
        probe = entry.get("mean", entry.get("min", MISSING))
        shape = _shape_of(probe) if probe is not MISSING else None
        if shape is None or (dist == "normal" and "mean" not in entry):
            raise CampaignError(f"{where}: the scenario does not set {fld}, so the dispersion must give its "
                                f"{'mean' if dist == 'normal' else 'min and max'} (numbers, one per axis for a "
                                "vector).")
    p = _Params(entry, where, shape)
    return Dispersion(fld, dist, shape, nominal, _uniform(p) if dist == "uniform" else _normal(p, nominal))


def _uniform(p: _Params) -> dict:
    """min, max and integer of a uniform dispersion, checked."""
    integer = p.entry.get("integer", False)
    if not isinstance(integer, bool):
        raise p.error("integer", integer, "true or false")
    lo, hi = p.numbers("min"), p.numbers("max")
    if np.any(lo > hi) or (not integer and np.any(lo == hi)):
        raise p.error("max", p.entry["max"], f"a bound above min ({p.entry['min']!r}) on every axis")
    if integer and (np.any(lo != np.round(lo)) or np.any(hi != np.round(hi))):
        raise p.error("min", p.entry["min"], "whole numbers when integer = true")
    if integer and (np.any(np.abs(lo) > MAX_INTEGER) or np.any(np.abs(hi) > MAX_INTEGER)):
        raise p.error("max", p.entry["max"], f"whole numbers from -2**53 to 2**53 when integer = true (min "
                      f"{p.entry['min']!r})")
    with np.errstate(over="ignore"):
        finite_span = bool(np.all(np.isfinite(hi - lo)))
    if not finite_span:  # numpy cannot draw from a range wider than the largest float
        raise p.error("max", p.entry["max"], f"a bound whose distance to min ({p.entry['min']!r}) is a finite number")
    return {"min": lo, "max": hi, "integer": integer}


def _normal(p: _Params, nominal) -> dict:
    """mean, sigma and bounds of a (truncated) normal dispersion, checked."""
    mean = p.numbers("mean") if "mean" in p.entry else p.numbers("mean", nominal)
    if ("sigma" in p.entry) == ("sigma_percent" in p.entry):
        raise p.error("sigma", p.entry.get("sigma", MISSING), "exactly one of sigma (in the field's unit) or "
                      "sigma_percent (of the mean) is required")
    if "sigma" in p.entry:
        sigma = p.numbers("sigma", lo=0.0)
    else:
        percent = p.numbers("sigma_percent", lo=0.0)
        if np.any((mean == 0) & (percent > 0)):
            # A percentage of zero is zero: the field would be drawn at its mean in every case, silently.
            raise p.error("sigma_percent", p.entry["sigma_percent"], f"a percentage of a mean that is not zero (the "
                          f"mean is {_to_python(mean)!r}: a percentage of zero is zero, so every case would draw "
                          "it unchanged); use sigma in the field's unit")
        with np.errstate(over="ignore"):
            sigma = np.abs(mean) * percent / 100.0
    if not np.all(np.isfinite(sigma)):
        raise p.error("sigma_percent", p.entry["sigma_percent"], "a percentage whose sigma (of the mean "
                      f"{_to_python(mean)!r}) is a finite number")
    lo = p.numbers("min") if "min" in p.entry else np.full(p.shape, -np.inf)
    hi = p.numbers("max") if "max" in p.entry else np.full(p.shape, np.inf)
    if np.any(lo >= hi):
        raise p.error("max", p.entry.get("max"), f"a bound above min ({p.entry.get('min')!r}) on every axis")
    if np.any(mean < lo) or np.any(mean > hi):
        raise p.error("mean", _to_python(mean), f"a mean within [min, max] on every axis (min {p.entry.get('min')!r}, "
                      f"max {p.entry.get('max')!r})")
    return {"mean": mean, "sigma": sigma, "min": lo, "max": hi}


def _rotation(entry, where, fld, dist, nominal) -> Dispersion:
    if nominal is MISSING:
        nominal = [1.0, 0.0, 0.0, 0.0]  # every quaternion of a scenario defaults to the identity
    q = np.asarray(nominal, dtype=float) if _shape_of(nominal) == (4,) else None
    if q is None or abs(np.linalg.norm(q) - 1.0) > 1e-6:
        raise CampaignError(f"{where}: the scenario's value {nominal!r} is not a unit quaternion [w, x, y, z]; a "
                            f"{dist} dispersion applies to quaternions (attitudes and mounts).")
    params = {}
    if dist == "rotation":
        # Beyond half a turn a "small rotation" wraps around; any attitude is uniform_rotation.
        params["sigma_deg"] = _Params(entry, where, (3,)).numbers("sigma_deg", lo=0.0, hi=180.0)
    return Dispersion(fld, dist, (4,), [float(x) for x in q], params)


def _choice(entry, where, fld, nominal) -> Dispersion:
    p = _Params(entry, where, ())
    values = entry.get("values", MISSING)
    if not isinstance(values, list) or not values:
        raise p.error("values", values, "a non-empty list of the values to choose from")
    weights = entry.get("weights", MISSING)
    if weights is MISSING:
        w = np.full(len(values), 1.0 / len(values))
    else:
        w = _Params(entry, where, (len(values),)).numbers("weights", lo=0.0)
        if w.max() <= 0:
            raise p.error("weights", weights, "weights with a positive sum")
        w = w / w.max()  # first to at most 1, so that the sum of huge weights cannot overflow
        w = w / w.sum()
    return Dispersion(fld, "choice", (), nominal, {"values": values, "weights": w})


@dataclass(frozen=True)
class Dispersions:
    items: tuple[Dispersion, ...]
    seed: int | None  # the file's [campaign] seed
    text: str
    source: str


def parse_dispersions(text: str, scenario: dict, source: str = "<string>") -> Dispersions:
    """Read a dispersion file against the scenario dict it disperses; CampaignError names the first bad key."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CampaignError(f"--dispersions {source} is not allowed: valid TOML is required ({exc}).") from None
    unknown = sorted(set(data) - {"campaign", "dispersions"})
    if unknown:
        raise CampaignError(f"{unknown[0]} in {source} is not allowed: a dispersion file has a [campaign] table "
                            "and [[dispersions]] entries.")
    camp = data.get("campaign", {})
    if not isinstance(camp, dict) or set(camp) - {"seed"}:
        raise CampaignError(f"[campaign] in {source} is not allowed: it takes only seed = N.")
    seed = camp.get("seed")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63):
        raise CampaignError(str(ScenarioError("campaign.seed", seed, "a whole number from 0 to 2**63 - 1", source)))
    entries = data.get("dispersions", [])
    if not isinstance(entries, list) or not entries:
        raise CampaignError(f"dispersions in {source} is not allowed: at least one [[dispersions]] entry with "
                            "field and distribution is required.")
    try:
        items = tuple(_dispersion(e, k, scenario) for k, e in enumerate(entries))
    except CampaignError as exc:  # the entry's sentence, with the file it is in
        raise CampaignError(f"{source}: {exc}") from None
    fields = [d.field for d in items]
    dup = sorted({f for f in fields if fields.count(f) > 1})
    if dup:
        raise CampaignError(f"dispersions in {source}: field {dup[0]!r} is dispersed twice; one entry per field.")
    if any(f in ("scenario.seed", "scenario.duration_s") for f in fields):
        raise CampaignError(f"dispersions in {source}: scenario.seed and scenario.duration_s are set by the "
                            "campaign (the case seed, --duration), not dispersed.")
    return Dispersions(items, seed, text, source)


def case_values(dispersions: Dispersions, seed: int, index: int) -> tuple[int, dict]:
    """``(run seed, {field: value})`` of case ``index``, from ``SeedSequence((seed, index))`` alone."""
    children = np.random.SeedSequence((seed, index)).spawn(len(dispersions.items) + 1)
    run_seed = int(children[0].generate_state(1, np.uint64)[0] >> np.uint64(1))
    values = {d.field: d.draw(np.random.default_rng(ss)) for d, ss in zip(dispersions.items, children[1:],
                                                                              strict=True)}
    return run_seed, values


def apply(scenario: dict, values: dict, run_seed: int, duration_s: float | None) -> dict:
    """A deep copy of the scenario dict with the case's values, seed and duration."""
    data = json.loads(json.dumps(scenario))
    for fld, value in values.items():
        put_field(data, fld, value)
    data.setdefault("scenario", {})["seed"] = run_seed
    if duration_s is not None:
        data["scenario"]["duration_s"] = duration_s
    return data


# ------------------------------------------------------------------------------------------------ the spec
@dataclass(frozen=True)
class Spec:
    """What fixes every case of a campaign (kept in campaign.json; a resumed campaign must match it)."""

    scenario_text: str
    scenario_name: str
    scenario_base: str  # the folder plug-in paths are relative to
    dispersions_text: str
    dispersions_source: str
    seed: int
    overrides: tuple[str, ...] = ()
    duration_s: float | None = None

    @property
    def key(self) -> str:
        blob = json.dumps([self.scenario_text, self.dispersions_text, self.seed, list(self.overrides),
                           self.duration_s])
        return hashlib.sha256(blob.encode()).hexdigest()[:16]

    def scenario_dict(self) -> dict:
        from . import scenario as scenario_mod

        data = scenario_mod.loads(self.scenario_text, self.scenario_name)
        for item in self.overrides:
            scenario_mod.set_value(data, item)
        return data

    def dispersions(self) -> Dispersions:
        return parse_dispersions(self.dispersions_text, self.scenario_dict(), self.dispersions_source)

    def case(self, index: int, dispersions: Dispersions | None = None) -> dict:
        """The task of case ``index``: its scenario dict (dispersed, seeded), values and seed."""
        disp = dispersions or self.dispersions()
        run_seed, values = case_values(disp, self.seed, index)
        data = apply(self.scenario_dict(), values, run_seed, self.duration_s)
        scalars: dict[str, float] = {}
        for d in disp.items:
            scalars.update(d.scalars(values[d.field]))
        return {"index": index, "seed": run_seed, "values": values, "scalars": scalars, "data": data,
                "source": f"{self.scenario_name}#case{index}", "base": self.scenario_base}

    def to_json(self) -> dict:
        return {**dataclasses.asdict(self), "overrides": list(self.overrides), "key": self.key}

    @classmethod
    def from_json(cls, d: dict) -> Spec:
        fields = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: (tuple(v) if k == "overrides" else v) for k, v in d.items() if k in fields})


def make_spec(scenario: str, dispersions_path: str | Path, seed: int | None = None,
              overrides: list[str] | None = None, duration_s: float | None = None) -> Spec:
    from . import scenario as scenario_mod

    path = scenario_mod.find(scenario)
    text = path.read_text(encoding="utf-8")
    dpath = Path(dispersions_path)
    try:
        dtext = dpath.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise CampaignError(f"--dispersions {dpath} is not allowed: a readable UTF-8 TOML file is required "
                            f"({getattr(exc, 'strerror', None) or exc}).") from None
    data = scenario_mod.loads(text, str(path))
    for item in overrides or []:
        scenario_mod.set_value(data, item)
    nominal = scenario_mod.parse(json.loads(json.dumps(data)), path.name)
    if nominal.wall_time_links:
        raise CampaignError(f"SCENARIO {path.name} is not allowed in a campaign: its devices "
                            f"{', '.join(nominal.wall_time_links)} are on hardware or served links, which run in wall "
                            "time on one bench; a campaign runs emulated devices (--set devices.NAME.link=emulated).")
    disp = parse_dispersions(dtext, data, dpath.name)
    if duration_s is not None and not (nominal.step_s <= duration_s <= 30 * 86400):
        raise CampaignError(str(ScenarioError("--duration", duration_s, f"seconds from the step "
                                              f"({nominal.step_s:g} s) to 30 days")))
    if seed is None:
        seed = disp.seed if disp.seed is not None else nominal.seed
    if not 0 <= seed < 2**63:
        raise CampaignError(str(ScenarioError("--seed", seed, "a whole number from 0 to 2**63 - 1")))
    return Spec(text, path.name, str(path.parent.resolve()), dtext, dpath.name, int(seed), tuple(overrides or ()),
                duration_s)


def validate(spec: Spec, runs: int) -> list[dict]:
    """Every case's task, each scenario parsed before the first run; CampaignError names the dispersion and
    the case whose value the scenario refuses."""
    from .scenario import parse

    disp = spec.dispersions()
    tasks = []
    for k in range(runs):
        task = spec.case(k, disp)
        try:
            parse(json.loads(json.dumps(task["data"])), task["source"])
        except ScenarioError as exc:
            raise CampaignError(f"case {k}: {_culprit(spec, disp, task, exc)}") from None
        tasks.append(task)
    return tasks


def _culprit(spec: Spec, disp: Dispersions, task: dict, exc: ScenarioError) -> str:
    """Which dispersion (alone) makes the scenario refuse a case's values, with the scenario's sentence."""
    from .scenario import parse

    base = spec.scenario_dict()
    for k, d in enumerate(disp.items):
        data = apply(base, {d.field: task["values"][d.field]}, task["seed"], spec.duration_s)
        try:
            parse(data, task["source"])
        except ScenarioError as alone:
            return (f"dispersions[{k}] ({d.field}, {d.distribution}, in {disp.source}) drew "
                    f"{shown(task['values'][d.field])}, which the scenario refuses (a value it does not allow, or a "
                    f"key its other settings leave unused, which would not be applied): {alone}")
    return (f"the values of dispersions {', '.join(d.field for d in disp.items)} (in {disp.source}) are refused "
            f"together by the scenario: {exc}")


# ------------------------------------------------------------------------------------------------- one run
def comparable(summary: dict) -> dict:
    """A summary without what depends on the wall clock: equal for every run of the same case."""
    return {k: v for k, v in summary.items() if k not in WALL_CLOCK_KEYS}


def digest(summary: dict, rows: bytes) -> str:
    """SHA-256 over the comparable summary and the telemetry bytes: a case's fingerprint."""
    h = hashlib.sha256(json.dumps(comparable(summary), sort_keys=True, default=float).encode())
    h.update(rows)
    return h.hexdigest()


def _error_record(task: dict, reason: str, t_start: float | None = None) -> dict:
    """The record of a case that gave no summary: an error, counted as failed, with the reason in one line."""
    now = time.time()
    return {"index": task["index"], "seed": task["seed"], "values": task["values"], "scalars": task["scalars"],
            "host": os.uname().nodename, "pid": os.getpid(), "status": "error", "passed": False, "error": reason,
            "criteria": [], "timing": {"worker_start": now if t_start is None else t_start, "worker_end": now}}


def _raised(exc: BaseException) -> str:
    """One line for what a run raised; a SystemExit says so (its text alone is just the exit code)."""
    if isinstance(exc, SystemExit):
        return f"SystemExit: the run's code called sys.exit({exc.code!r})"
    return f"{type(exc).__name__}: {exc}"


def run_case(task: dict, *, interruptible: bool = False) -> dict:
    """Run one case in a temporary folder and return its record and files (what a worker sends back).

    Anything the run raises, SystemExit and other BaseExceptions included, is recorded as an error case: a
    plug-in's ``sys.exit(0)`` must not end a campaign. ``interruptible`` (the case runs in the operator's own
    process): Ctrl-C stops the campaign instead of being recorded.
    """
    t_start = time.time()
    from .compose import build
    from .loop import run
    from .report import write_summary
    from .scenario import parse

    rec = {"index": task["index"], "seed": task["seed"], "values": task["values"], "scalars": task["scalars"],
           "host": os.uname().nodename, "pid": os.getpid()}
    files: dict[str, bytes] = {}
    with _RUN_LOCK, tempfile.TemporaryDirectory(prefix="stand-case-") as tmp:
        watchdog = _watchdog(task)
        t_lock = time.time()
        out = Path(tmp) / "run"
        try:
            sc = parse(task["data"], task["source"])
            with build(sc, None, Path(task["base"])) as scene:
                t_built = time.time()
                out.mkdir()
                result = run(scene, out, progress=False)
                t_ran = time.time()
            if interruptible and result.status == "stopped":
                raise KeyboardInterrupt  # the operator's Ctrl-C reached the loop: stop, do not record
            summary = write_summary(scene, result, out, plots=False)
            for name in RUN_FILES:
                p = out / name
                if p.exists():
                    files[name] = p.read_bytes()
        except BaseException as exc:  # one failing run is recorded; the campaign goes on
            if interruptible and isinstance(exc, KeyboardInterrupt):
                raise
            return {"record": _error_record(task, _raised(exc), t_start), "files": {}}
        finally:
            if watchdog is not None:
                watchdog.cancel()
    t_end = time.time()
    rec.update(status=summary["status"], passed=bool(summary["pass"]), error=summary["error"],
               criteria=[{k: c.get(k) for k in ("name", "metric", "value", "unit", "limit", "pass")}
                         for c in summary["criteria"]],
               rate_deg_s_at=summary.get("rate_deg_s_at", {}),
               digest=digest(summary, files.get("telemetry/rows.f64", b"")),
               timing={"worker_start": t_start, "wait_s": t_lock - t_start, "build_s": t_built - t_lock,
                       "run_s": result.wall_time_s, "loop_s": t_ran - t_built, "summary_s": t_end - t_ran,
                       "worker_end": t_end})
    return {"record": rec, "files": files}


def _watchdog(task: dict) -> threading.Timer | None:
    """On a Dask worker, the per-case limit: a case still running after ``exit_after_s`` ends its worker process
    (a thread cannot be stopped); the nanny starts a new one and the scheduler's retries end in KilledWorker,
    which the client records as an error. The local pool enforces the limit from the client instead."""
    limit = task.get("exit_after_s")
    if not limit or task.get("client_pid") == os.getpid():  # never end the operator's own process
        return None
    warm()  # a worker the nanny restarted has imported nothing yet: that is not the case's time

    def overrun():
        print(f"stand: campaign case {task['index']} still running after the per-case limit of {limit:g} s; "
              "ending this worker process", file=sys.stderr, flush=True)
        os._exit(EXIT_OVERRUN)

    timer = threading.Timer(limit, overrun)
    timer.daemon = True
    timer.start()
    return timer


# ------------------------------------------------------------------------------------------------ executors
def warm() -> None:
    """Import what a run needs once per worker process, so the first case's timings are its own."""
    from . import compose, devices, loop, report  # noqa: F401

    for name in devices.kind_names():
        devices.get(name)


def _worker_main(conn) -> None:
    """A local pool worker: cases from ``conn`` one at a time, each answered with its record and files."""
    import signal

    # Ctrl-C goes to the whole process group; the client stops the campaign and ends its workers. A worker that
    # acted on it would record a half-run case as "stopped".
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    warm()
    conn.send(("ready", None))  # a case's wall-clock limit starts when it is handed over, not before the imports
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):  # the client is gone
            return
        if task is None:
            return
        result = run_case(task)
        try:
            conn.send(("result", result))
        except Exception as exc:  # noqa: BLE001 - e.g. a value that does not pickle: the case is still recorded
            conn.send(("result", {"record": _error_record(task, f"its result could not be sent back: "
                                                                 f"{_raised(exc)}"), "files": {}}))


def _exit_text(code: int | None) -> str:
    import signal

    if code is not None and code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


class _Slot:
    """One worker process of the local pool and the case it runs."""

    def __init__(self, ctx):
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_worker_main, args=(child,), name="stand-campaign-worker")
        self.proc.start()
        child.close()
        self.task: dict | None = None
        self.since = 0.0
        self.ready = False

    def idle(self) -> bool:
        return self.ready and self.task is None

    def give(self, task: dict) -> None:
        self.task, self.since = task, time.monotonic()
        try:
            self.conn.send(task)
        except OSError:  # the worker died since it said ready: the pool sees its end and gives the case again
            pass

    def end(self, kill: bool = False) -> None:
        if not kill and self.proc.is_alive():
            try:
                self.conn.send(None)
            except OSError:
                kill = True
            self.proc.join(5.0)
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join()
        self.conn.close()


class _LocalPool:
    """Worker processes on this machine (spawned: nothing of the parent's threads or buses is inherited), each
    watched by the client: a worker that dies is replaced and its case given again, up to ``deaths`` times, then
    recorded as an error; a case over ``case_timeout_s`` of wall time is recorded as an error and its worker
    replaced. The other cases never notice (a shared pool would lose every pending case with one worker)."""

    name = "local"

    def __init__(self, workers: int, case_timeout_s: float = 0.0, deaths: int = 2):
        import multiprocessing

        self.workers, self.case_timeout_s, self.deaths = workers, case_timeout_s, deaths
        self.ctx = multiprocessing.get_context("spawn")
        self.slots: list[_Slot] = []

    def results(self, tasks: list[dict]):
        """``(index, result, None)`` for a case that ran, ``(index, None, reason)`` for one recorded as an error."""
        from collections import deque

        pending = deque(tasks)
        died: dict[int, list[str]] = {}
        self.slots = [_Slot(self.ctx) for _ in range(min(self.workers, len(pending)))]
        while pending or any(s.task is not None for s in self.slots):
            for s in self.slots:
                if s.idle() and pending:
                    s.give(pending.popleft())
            watched = [s for s in self.slots if s.task is not None or not s.ready]
            self._wait(watched)
            for s in watched:
                outcome = self._check(s, died, pending)
                if outcome is not None:
                    yield outcome

    def _wait(self, watched: list[_Slot]) -> None:
        from multiprocessing.connection import wait

        timeout = None
        busy = [s for s in watched if s.task is not None]
        if self.case_timeout_s and busy:
            now = time.monotonic()
            timeout = max(0.0, min(s.since + self.case_timeout_s - now for s in busy))
        wait([s.conn for s in watched] + [s.proc.sentinel for s in watched], timeout)

    def _check(self, s: _Slot, died: dict, pending) -> tuple | None:
        if s.conn.poll():  # an answer waits (even if the process ended right after sending it)
            try:
                kind, result = s.conn.recv()
            except (EOFError, OSError):
                kind, result = None, None
            if kind == "ready":
                s.ready = True
                return None
            if kind == "result" and s.task is not None:
                index, s.task = s.task["index"], None
                return index, result, None
        if not s.proc.is_alive():
            s.proc.join()
            if s.task is None:  # it died importing the stand: no case is to blame and none can run
                raise CampaignError(f"--workers {self.workers}: a local worker process could not start "
                                    f"({_exit_text(s.proc.exitcode)}); try --workers 0 to see why.")
            task = s.task
            died.setdefault(task["index"], []).append(_exit_text(s.proc.exitcode))
            self._replace(s)
            if len(died[task["index"]]) < self.deaths:
                pending.appendleft(task)  # maybe a passing crash (out of memory): once more, first
                return None
            return task["index"], None, (f"its worker process died {len(died[task['index']])} times while running "
                                         f"it ({', '.join(died[task['index']])}); not run again")
        if s.task is not None and self.case_timeout_s and time.monotonic() - s.since >= self.case_timeout_s:
            index = s.task["index"]
            self._replace(s, kill=True)
            return index, None, (f"still running after the per-case limit of {self.case_timeout_s:g} s of wall time "
                                 "(--case-timeout); its worker process was ended")
        return None

    def _replace(self, s: _Slot, kill: bool = False) -> None:
        """A new worker process in this slot, the old one ended (killed if it still runs)."""
        s.end(kill=kill)
        fresh = _Slot(self.ctx)
        s.conn, s.proc, s.task, s.since, s.ready = fresh.conn, fresh.proc, None, 0.0, False

    def close(self, cancel: bool = False) -> None:
        for s in self.slots:
            s.end(kill=cancel)
        self.slots = []


class _Inline:
    """Every case in this process, one after another (``workers = 0``: debugging and tests). A case that ends
    the process (``os._exit``, a crash) ends the campaign too: use a pool for untrusted code."""

    name = "inline"
    workers = 1

    def results(self, tasks: list[dict]):
        for task in tasks:
            yield task["index"], run_case(task, interruptible=True), None

    def close(self, cancel: bool = False):
        pass


class _Dask:
    """Tasks on a Dask distributed scheduler (``--scheduler ADDRESS``) or a cluster object handed in."""

    name = "dask"

    def __init__(self, scheduler, key: str, case_timeout_s: float = 0.0):
        try:
            from distributed import Client
        except ImportError:
            raise CampaignError("--scheduler needs Dask distributed: pip install 'adcs-stand[campaign]'.") from None
        try:
            self.client = Client(scheduler, timeout=30, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise CampaignError(f"--scheduler {scheduler} is not allowed: no Dask scheduler answered there within "
                                f"30 s ({exc}).") from None
        self.key, self.case_timeout_s = key, case_timeout_s
        self.client.run(warm)
        self.workers = max(1, sum(w.get("nthreads", 1) for w in
                                  self.client.scheduler_info().get("workers", {}).values()))
        self.address = self.client.scheduler.address

    def results(self, tasks: list[dict]):
        from distributed import as_completed

        limit = {"exit_after_s": self.case_timeout_s or None, "client_pid": os.getpid()}
        futures = {self.client.submit(run_case, {**t, **limit}, pure=False,
                                      key=f"stand-case-{self.key}-{t['index']}"): t["index"] for t in tasks}
        for f in as_completed(list(futures), loop=self.client.loop):
            index = futures.pop(f)
            yield (index, *self._outcome(f))

    def _outcome(self, f) -> tuple:
        import asyncio

        from distributed.scheduler import KilledWorker

        try:
            return f.result(), None
        except KilledWorker as exc:  # the scheduler gave up after the case ended its workers again and again
            limit = f", or over the per-case limit of {self.case_timeout_s:g} s" if self.case_timeout_s else ""
            return None, (f"its Dask worker died each time it ran it (killed, crashed{limit}); not run again: "
                          f"{_raised(exc)}")
        except KeyboardInterrupt:
            raise
        except (Exception, asyncio.CancelledError) as exc:  # the scheduler or the link failed, not the case: not
            return None, _Lost(_raised(exc))  # recorded, the next invocation runs it
        except BaseException as exc:  # a SystemExit that escaped a worker: the case's doing, recorded
            return None, _raised(exc)

    def close(self, cancel: bool = False):
        self.client.close(timeout=30)


class _Lost(str):
    """A reason that is not the case's: the case stays unrecorded and the next invocation runs it."""


# ------------------------------------------------------------------------------------------------ progress
class CampaignProgress:
    """One line on stderr: runs done, passed, failed (errors among them), rate and time left."""

    def __init__(self, total: int, enabled: bool, stream=sys.stderr):
        self.total, self.enabled, self.stream = total, enabled, stream
        self.done = self.passed = self.failed = self.errors = 0
        self.start = time.monotonic()
        self.new = 0

    def add(self, rec: dict, resumed: bool = False) -> None:
        self.done += 1
        self.new += 0 if resumed else 1
        self.passed += bool(rec.get("passed"))
        self.failed += not rec.get("passed")
        self.errors += rec.get("status") == "error"

    def show(self, final: bool = False) -> None:
        if not self.enabled:
            return
        frac = self.done / self.total if self.total else 1.0
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        elapsed = time.monotonic() - self.start
        rate = self.new / elapsed * 60 if elapsed > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else math.nan
        eta = f"  {left:5.1f} min left" if math.isfinite(left) and not final else ""
        self.stream.write(f"\r[{bar}] {self.done}/{self.total} runs  passed {self.passed}  failed {self.failed}"
                          f"{f' ({self.errors} errors)' if self.errors else ''}  {rate:6.1f} runs/min{eta}   ")
        if final:
            self.stream.write("\n")
        self.stream.flush()


# ----------------------------------------------------------------------------------------------- campaign
def case_dir(out: Path, index: int) -> Path:
    return Path(out) / "cases" / f"{index:0{CASE_DIGITS}d}"


def finished(out: Path) -> dict[int, dict]:
    """Records of the cases already written (a ``case.json`` is written last, so its presence means whole)."""
    found = {}
    for p in sorted((Path(out) / "cases").glob("*/case.json")):
        try:
            rec = json.loads(p.read_bytes().decode("utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            continue
        # A record that is not whole or not its folder's (damaged, edited) is not a finished case: a resume runs
        # it again rather than aggregate what it cannot vouch for.
        if _whole(rec, p.parent.name):
            found[rec["index"]] = rec
    return found


CRITERION_KEYS = frozenset(("name", "metric", "value", "limit", "pass"))


def _is_digest(value) -> bool:
    return value is None or (isinstance(value, str) and len(value) == 64
                             and all(c in "0123456789abcdef" for c in value))


def _whole(rec, folder: str) -> bool:
    """Has a case record what aggregation reads, of the right types, in its own folder?"""
    if not isinstance(rec, dict):
        return False
    index, crit = rec.get("index"), rec.get("criteria")
    return (isinstance(index, int) and not isinstance(index, bool) and folder == f"{index:0{CASE_DIGITS}d}"
            and isinstance(rec.get("seed"), int) and isinstance(rec.get("status"), str)
            and isinstance(crit, list) and all(isinstance(c, dict) and CRITERION_KEYS <= set(c) for c in crit)
            and _is_digest(rec.get("digest")))


def _write_case(out: Path, result: dict, received: float) -> dict:
    rec = result["record"]
    t0 = time.time()
    final = case_dir(out, rec["index"])
    part = final.with_name(final.name + ".part")
    shutil.rmtree(part, ignore_errors=True)
    part.mkdir(parents=True)
    for name, data in result["files"].items():
        (part / name).parent.mkdir(parents=True, exist_ok=True)
        (part / name).write_bytes(data)
    timing = rec.setdefault("timing", {})
    timing["transfer_s"] = max(0.0, received - timing.get("worker_end", received))
    timing["write_s"] = time.time() - t0
    (part / "case.json").write_text(json.dumps(rec, indent=1, default=float) + "\n")
    shutil.rmtree(final, ignore_errors=True)
    os.replace(part, final)
    return rec


def _prepare(out: Path, spec: Spec) -> None:
    from .report import write_json_atomic

    meta = out / "campaign.json"
    if meta.exists():
        try:
            old = json.loads(meta.read_text()).get("spec", {})
        except (OSError, json.JSONDecodeError):
            old = {}
        if old.get("key") != spec.key:
            raise CampaignError(f"--out {out} is not allowed: it holds another campaign (scenario, dispersions, "
                                "seed, --set or --duration differ); use a new folder, or the same inputs to resume.")
    elif out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise CampaignError(f"--out {out} is not allowed: an empty or new folder, or one of the same campaign "
                            "to resume.")
    out.mkdir(parents=True, exist_ok=True)
    (out / "scenario.toml").write_text(spec.scenario_text)
    (out / "dispersions.toml").write_text(spec.dispersions_text)
    if not meta.exists():
        write_json_atomic(meta, {"spec": spec.to_json(), "status": "running"})
    for stale in (out / "cases").glob("*.part"):
        shutil.rmtree(stale, ignore_errors=True)


def run_campaign(spec: Spec, out: str | Path, runs: int, *, workers: int = 1, scheduler=None,
                 progress: bool = False, plots: bool = True, case_timeout_s: float = CASE_TIMEOUT_S,
                 worker_deaths: int = WORKER_DEATHS) -> dict:
    """Run (or resume) a campaign into ``out`` and return its ``campaign.json`` content.

    ``workers``: processes of the local pool (0 runs every case in this process); ``scheduler``: a Dask
    scheduler address, or a ``distributed`` cluster object, instead of the local pool. ``case_timeout_s``: wall
    time after which a case is recorded as an error and its worker ended (0: no limit); ``worker_deaths``: how
    many times a case may end its worker process before it is recorded as an error. Ctrl-C cancels what is not
    finished (resume later with the same command) and re-raises; campaign.json is written in every case.
    """
    if not 1 <= runs <= MAX_RUNS:
        raise CampaignError(str(ScenarioError("--runs", runs, f"a whole number from 1 to {MAX_RUNS}")))
    if not (isinstance(case_timeout_s, int | float) and 0 <= case_timeout_s <= MAX_CASE_TIMEOUT_S):
        raise CampaignError(str(ScenarioError("--case-timeout", case_timeout_s, "seconds of wall time per case, "
                                              f"from 0 (no limit) to {MAX_CASE_TIMEOUT_S:g}")))
    out = Path(out)
    t0 = time.time()
    tasks = validate(spec, runs)
    _prepare(out, spec)
    t_ready = time.time()
    done = {k: r for k, r in finished(out).items() if k < runs}
    resumed = len(done)
    bar = CampaignProgress(runs, progress)
    for rec in done.values():
        bar.add(rec, resumed=True)
    todo = [t for t in tasks if t["index"] not in done]
    del tasks
    if scheduler is not None:
        executor = _Dask(scheduler, spec.key, case_timeout_s)
    elif workers == 0:
        executor = _Inline()
    else:
        executor = _LocalPool(workers, case_timeout_s, worker_deaths)
    execution = {"executor": executor.name, "workers": executor.workers, "case_timeout_s": case_timeout_s,
                 "resumed": resumed, "validate_s": round(t_ready - t0, 3), "lost": [],
                 **({"scheduler": executor.address} if scheduler is not None else {})}
    stopped = True
    bar.show()
    try:
        _collect(executor, todo, out, done, bar, execution["lost"])
        stopped = False
    finally:
        executor.close(cancel=stopped)
        bar.show(final=True)
        execution.update(runs_this_session=bar.new, wall_s=round(time.time() - t_ready, 3))
        if stopped:  # campaign.json must not keep saying "running": what is recorded, counted as incomplete
            execution["stopped"] = True
            aggregate(out, runs, execution)
    result = aggregate(out, runs, execution)
    if plots:
        write_report(out, result)
    return result


def _collect(executor, todo: list[dict], out: Path, done: dict, bar: CampaignProgress, lost: list[str]) -> None:
    """Write every case the executor answers: its files, or an error record with the reason."""
    meta = {t["index"]: {k: t[k] for k in ("index", "seed", "values", "scalars")} for t in todo}
    for index, result, reason in executor.results(todo):
        if isinstance(reason, _Lost):  # the infrastructure failed, not the case: the next invocation runs it
            lost.append(f"case {index}: {reason}")
            continue
        if result is None:
            result = {"record": _error_record(meta[index], reason), "files": {}}
        rec = _write_case(out, result, time.time())
        done[index] = rec
        bar.add(rec)
        bar.show()


# ---------------------------------------------------------------------------------------------- results
def clopper_pearson(k: int, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Exact (Clopper-Pearson) interval of a pass probability from k passes in n runs."""
    from scipy.stats import beta

    if n == 0:
        return (0.0, 1.0)
    a = (1.0 - confidence) / 2
    lo = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a, k + 1, n - k))
    return lo, hi


def _margin(c: dict) -> float:
    """How far a value is on the wrong side of its limit (positive: failed by that much); NaN is worst."""
    v = c["value"]
    if v is None or not math.isfinite(v):
        return math.inf
    lim = c["limit"]
    return max(v - lim["max"] if "max" in lim else -math.inf, lim["min"] - v if "min" in lim else -math.inf)


def _stats(values: list[float]) -> dict:
    a = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if a.size == 0:
        return {"n": 0}
    p = np.percentile(a, [5, 50, 95])
    return {"n": int(a.size), "mean": float(a.mean()), "std": float(a.std(ddof=1)) if a.size > 1 else 0.0,
            "min": float(a.min()), "p5": float(p[0]), "p50": float(p[1]), "p95": float(p[2]), "max": float(a.max())}


def metric_table(records: list[dict]) -> dict[str, list]:
    """Metric name -> per-case values (criteria by name, rate checkpoints as ``rate_deg_s_at_T``)."""
    names: dict[str, None] = {}
    for r in records:
        for c in r.get("criteria", []):
            names[c["name"]] = None
        for t in r.get("rate_deg_s_at", {}):
            names[f"rate_deg_s_at_{t}s"] = None
    table = {}
    for name in names:
        vals = []
        for r in records:
            crit = {c["name"]: c["value"] for c in r.get("criteria", [])}
            rates = {f"rate_deg_s_at_{t}s": v for t, v in r.get("rate_deg_s_at", {}).items()}
            vals.append(crit.get(name, rates.get(name)))
        table[name] = vals
    return table


def aggregate(out: str | Path, runs: int, execution: dict | None = None) -> dict:
    """campaign.json from the cases on disk: pass rates with intervals, metric distributions, worst cases."""
    from .report import write_json_atomic

    out = Path(out)
    meta = json.loads((out / "campaign.json").read_text())
    cases = finished(out)
    records = [cases[k] for k in sorted(cases) if k < runs]
    n = len(records)
    passed = sum(bool(r.get("passed")) for r in records)
    criteria: dict[str, dict] = {}
    for r in records:
        for c in r.get("criteria", []):
            criteria.setdefault(c["name"], {"metric": c["metric"], "unit": c.get("unit") or "", "limit": c["limit"]})
    rates = {}
    for name, info in criteria.items():
        # A case with no value for a criterion (it raised before its summary) counts as failing it.
        k = sum(any(c["name"] == name and c["pass"] for c in r.get("criteria", [])) for r in records)
        lo, hi = clopper_pearson(k, n)
        worst = sorted(((_margin(c), r["index"], c["value"]) for r in records for c in r.get("criteria", [])
                        if c["name"] == name), key=lambda x: (-x[0], x[1]))[:WORST]
        rates[name] = {**info, "passed": k, "runs": n, "rate": k / n if n else None, "ci95": [lo, hi],
                       "worst": [{"case": i, "value": v, "margin": m if math.isfinite(m) else None}
                                 for m, i, v in worst]}
    lo, hi = clopper_pearson(passed, n)
    timing = [r.get("timing", {}) for r in records]
    run_s = [t["run_s"] for t in timing if "run_s" in t]
    overhead = {k: _stats([t[k] for t in timing if k in t])
                for k in ("wait_s", "build_s", "summary_s", "transfer_s", "write_s")}
    ex = dict(execution or meta.get("execution") or {})
    if ex.get("wall_s") and ex.get("runs_this_session"):
        ex["runs_per_min"] = round(ex["runs_this_session"] / ex["wall_s"] * 60, 2)
        mean_run = float(np.mean(run_s)) if run_s else 0.0
        # What one run costs a worker slot beyond its own loop: start, scatter, gather and write included.
        ex["overhead_per_run_s"] = round(ex["wall_s"] * ex["workers"] / ex["runs_this_session"] - mean_run, 4)
    result = {
        "spec": meta["spec"],
        "status": "complete" if n == runs else "incomplete",
        "runs": runs, "finished": n,
        "passed": passed, "failed": n - passed,
        "errors": sum(r.get("status") == "error" for r in records),
        "pass_rate": passed / n if n else None, "pass_rate_ci95": [lo, hi],
        "criteria": rates,
        "metrics": {name: _stats(v) for name, v in metric_table(records).items()},
        "inputs": {name: _stats(v) for name, v in _inputs(records).items()},
        "worst_cases": _worst(records),
        "failed_cases": [{"case": r["index"], "status": r.get("status"), "error": r.get("error"),
                          "failed": [c["name"] for c in r.get("criteria", []) if not c["pass"]]}
                         for r in records if not r.get("passed")],
        "run_time_s": _stats(run_s),
        "overhead_s": overhead,
        "execution": ex,
        "cases": [{"case": r["index"], "seed": r["seed"], "status": r.get("status"), "pass": r.get("passed"),
                   "values": r.get("values"), "criteria": {c["name"]: c["value"] for c in r.get("criteria", [])},
                   "digest": r.get("digest")} for r in records],
    }
    write_json_atomic(out / "campaign.json", result)
    return result


def _inputs(records: list[dict]) -> dict[str, list]:
    names: dict[str, None] = {}
    for r in records:
        names.update(dict.fromkeys(r.get("scalars", {})))
    return {name: [r.get("scalars", {}).get(name) for r in records] for name in names}


def _worst(records: list[dict]) -> list[dict]:
    """Cases ranked by their worst criterion: errors first, then the margin to the limit as a fraction of the
    limit (of 1 when the limit is 0). Criteria with one value over the whole campaign do not rank anything."""
    values: dict[str, set] = {}
    for r in records:
        for c in r.get("criteria", []):
            values.setdefault(c["name"], set()).add(c["value"])
    varying = {n for n, v in values.items() if len(v) > 1}
    rows = []
    for r in records:
        ms = [(_margin(c) / max(abs(v) for v in c["limit"].values()) if any(c["limit"].values()) else _margin(c),
               _margin(c), c["name"]) for c in r.get("criteria", []) if c["name"] in varying or not c["pass"]]
        rel, m, name = max(ms) if ms else ((math.inf, math.inf, "error") if r.get("status") == "error"
                                           else (-math.inf, -math.inf, "-"))
        rows.append((rel, m, r["index"], name, r.get("error")))
    rows.sort(key=lambda x: (-x[0], x[2]))
    return [{"case": i, "criterion": name, "margin": m if math.isfinite(m) else None, "error": err}
            for rel, m, i, name, err in rows[:WORST]]


# ----------------------------------------------------------------------------------------------- report
def write_report(out: str | Path, result: dict) -> list[str]:
    """report.md with pass rates, metric distributions, worst cases and the plots."""
    from . import plots as _plots  # noqa: F401 - the stand's matplotlib settings (Agg figures)

    out = Path(out)
    records = [r for k, r in sorted(finished(out).items()) if k < result["runs"]]
    made = [_plot_pass_rates(result, out), _plot_metrics(result, records, out)]
    made += _plot_scatter(result, records, out)
    made = [m for m in made if m]
    spec, ex = result["spec"], result["execution"]
    lines = [f"# Campaign: {Path(spec['scenario_name']).stem}", "",
             f"{result['finished']} of {result['runs']} runs finished, seed {spec['seed']}, dispersions "
             f"{spec['dispersions_source']}" + (f", {spec['duration_s']:g} s per run" if spec["duration_s"] else "")
             + ".", "",
             f"**Pass rate {_pct(result['pass_rate'])}** (95 % interval {_pct(result['pass_rate_ci95'][0])} to "
             f"{_pct(result['pass_rate_ci95'][1])}, Clopper-Pearson): {result['passed']} passed, "
             f"{result['failed']} failed ({result['errors']} errors).", ""]
    if ex.get("runs_per_min"):
        lines += [f"Ran on {ex['executor']} with {ex['workers']} workers: {ex['runs_per_min']:g} runs per minute, "
                  f"{ex['overhead_per_run_s']:g} s per run beyond the run itself.", ""]
    lines += ["| criterion | limit | passed | rate | 95 % interval |", "|---|---|---|---|---|"]
    for name, c in result["criteria"].items():
        lim = " and ".join(f"{k} {v:g}" for k, v in c["limit"].items())
        lines.append(f"| {name} | {lim} | {c['passed']}/{c['runs']} | {_pct(c['rate'])} | "
                     f"{_pct(c['ci95'][0])} to {_pct(c['ci95'][1])} |")
    for title, table in (("Metrics", result["metrics"]), ("Dispersed inputs", result["inputs"])):
        lines += ["", f"## {title}", "", "| name | n | mean | std | min | p5 | p50 | p95 | max |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for name, s in table.items():
            if s.get("n"):
                lines.append(f"| {name} | {s['n']} | " + " | ".join(f"{s[k]:.5g}" for k in
                                                                    ("mean", "std", "min", "p5", "p50", "p95", "max"))
                             + " |")
    lines += ["", "## Worst cases", "", "| case | criterion | margin to the limit | error |", "|---|---|---|---|"]
    for w in result["worst_cases"]:
        m = "-" if w["margin"] is None else f"{w['margin']:+.5g}"
        lines.append(f"| {w['case']} | {w['criterion']} | {m} | {w['error'] or ''} |")
    lines += ["", f"Re-run one case alone: `stand run --campaign {out} --case K --out DIR`.", "", "## Plots", ""]
    lines += [f"![{m}]({m})" for m in made]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    return made


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def _plot_pass_rates(result: dict, out: Path) -> str | None:
    from matplotlib.figure import Figure

    crit = result["criteria"]
    if not crit:
        return None
    fig = Figure(figsize=(8, 1.2 + 0.5 * len(crit)))
    ax = fig.add_subplot()
    names = list(crit)
    rate = np.array([100 * (crit[n]["rate"] or 0) for n in names])
    lo = np.array([100 * crit[n]["ci95"][0] for n in names])
    hi = np.array([100 * crit[n]["ci95"][1] for n in names])
    y = np.arange(len(names))
    ax.barh(y, rate, color="tab:green", alpha=0.6)
    ax.errorbar(rate, y, xerr=[rate - lo, hi - rate], fmt="none", ecolor="black", capsize=4)
    ax.set_yticks(y, names)
    ax.set_xlim(0, 100)
    ax.set_xlabel("pass rate (%), 95 % Clopper-Pearson interval")
    fig.tight_layout()
    fig.savefig(out / "pass_rates.png", dpi=100)
    return "pass_rates.png"


def _plot_metrics(result: dict, records: list[dict], out: Path) -> str | None:
    from matplotlib.figure import Figure

    table = {k: v for k, v in metric_table(records).items() if result["metrics"].get(k, {}).get("n")}
    if not table:
        return None
    cols = min(3, len(table))
    rows = math.ceil(len(table) / cols)
    fig = Figure(figsize=(4 * cols, 3 * rows))
    for i, (name, vals) in enumerate(table.items()):
        ax = fig.add_subplot(rows, cols, i + 1)
        a = np.asarray([v for v in vals if v is not None and math.isfinite(v)], dtype=float)
        ax.hist(a, bins=min(30, max(5, a.size // 5)), color="tab:blue", alpha=0.7)
        lim = result["criteria"].get(name, {}).get("limit", {})
        for v in lim.values():
            ax.axvline(v, color="black", linestyle="--")
        unit = result["criteria"].get(name, {}).get("unit") or ("deg/s" if name.startswith("rate_deg_s") else "")
        ax.set_title(f"{name} ({unit})" if unit else name, fontsize=9)
        ax.set_ylabel("runs")
    fig.tight_layout()
    fig.savefig(out / "metrics.png", dpi=100)
    return "metrics.png"


def _plot_scatter(result: dict, records: list[dict], out: Path) -> list[str]:
    """One figure per criterion metric: every dispersed input against it, passes and failures coloured."""
    from matplotlib.figure import Figure

    inputs = _inputs(records)
    if not inputs:
        return []
    made = []
    metrics = metric_table(records)
    for k, (name, info) in enumerate(result["criteria"].items()):
        y = np.asarray([np.nan if v is None else v for v in metrics.get(name, [])], dtype=float)
        ok = np.asarray([any(c["name"] == name and c["pass"] for c in r.get("criteria", [])) for r in records])
        cols = min(4, len(inputs))
        rows = math.ceil(len(inputs) / cols)
        fig = Figure(figsize=(3.2 * cols, 2.6 * rows))
        for i, (label, xs) in enumerate(inputs.items()):
            ax = fig.add_subplot(rows, cols, i + 1)
            x = np.asarray([np.nan if v is None else v for v in xs], dtype=float)
            ax.scatter(x[ok], y[ok], s=8, color="tab:green", label="pass")
            ax.scatter(x[~ok], y[~ok], s=8, color="tab:red", label="fail")
            for v in info["limit"].values():
                ax.axhline(v, color="black", linestyle="--", linewidth=0.8)
            ax.set_xlabel(label, fontsize=8)
            ax.set_ylabel(f"{name} ({info['unit']})" if info.get("unit") else name, fontsize=8)
            ax.tick_params(labelsize=7)
        fig.tight_layout()
        fname = f"scatter_{k}.png"
        fig.savefig(out / fname, dpi=90)
        made.append(fname)
    return made


# ------------------------------------------------------------------------------------------ re-run a case
def load_case(campaign_dir: str | Path, index: int):
    """``(Scenario, base folder, recorded case or None)`` of one case of a campaign on disk."""
    from .scenario import parse

    d = Path(campaign_dir)
    try:
        meta = json.loads((d / "campaign.json").read_text())
        spec = Spec.from_json(meta["spec"])
    except (OSError, json.JSONDecodeError, KeyError, TypeError):
        raise CampaignError(f"--campaign {d} is not allowed: a campaign folder (with its campaign.json) written "
                            "by stand campaign.") from None
    if isinstance(index, bool) or not 0 <= index < MAX_RUNS:
        raise CampaignError(str(ScenarioError("--case", index, f"a case index from 0 to {MAX_RUNS - 1}")))
    try:
        task = spec.case(index)
    except (CampaignError, ScenarioError):
        raise
    except (TypeError, ValueError, KeyError, AttributeError) as exc:  # a campaign.json edited by hand
        raise CampaignError(f"--campaign {d} is not allowed: the spec in its campaign.json does not rebuild case "
                            f"{index} ({type(exc).__name__}: {exc}); a campaign.json as stand campaign wrote it."
                            ) from None
    sc = parse(task["data"], task["source"])
    return sc, Path(spec.scenario_base), _case_record(d, index)


def _case_record(d: Path, index: int) -> dict | None:
    """The record of case ``index`` to compare a re-run with, checked: a corrupt case.json is one sentence."""
    path = case_dir(d, index) / "case.json"
    redo = f"delete {path.parent} and run the campaign's command again to redo the case"
    try:
        rec = json.loads(path.read_bytes().decode("utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CampaignError(f"{path} is not allowed: a case record (UTF-8 JSON) as stand campaign writes it; it "
                            f"does not read ({exc}): {redo}.") from None
    if not isinstance(rec, dict):
        raise CampaignError(str(ScenarioError("the record", rec, f"a JSON object as stand campaign writes it: {redo}",
                                              str(path))))
    if rec.get("index") != index or isinstance(rec.get("index"), bool):
        raise CampaignError(str(ScenarioError("index", rec.get("index", MISSING), f"this case's own index, {index}: "
                                              + redo, str(path))))
    dig = rec.get("digest")
    if not _is_digest(dig):
        raise CampaignError(str(ScenarioError("digest", dig, f"a SHA-256 in 64 hexadecimal digits, or none: {redo}",
                                              str(path))))
    return rec


def compare_case(rec: dict | None, run_dir: str | Path) -> tuple[bool | None, str]:
    """Does a re-run reproduce the case recorded by the campaign? ``(same, sentence)``; None: nothing recorded."""
    run_dir = Path(run_dir)
    if rec is None or not rec.get("digest"):
        return None, "the campaign has no finished record of this case to compare with"
    summary = json.loads((run_dir / "summary.json").read_text())
    rows = (run_dir / "telemetry" / "rows.f64").read_bytes()
    mine = digest(summary, rows)
    if mine == rec["digest"]:
        return True, f"reproduces campaign case {rec['index']} bit for bit (summary and telemetry, SHA-256 {mine[:16]})"
    return False, (f"DIFFERS from campaign case {rec['index']}: SHA-256 {mine[:16]} against {rec['digest'][:16]} "
                   "recorded")
