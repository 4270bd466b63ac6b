"""Dispersions: the dispersion file, dotted paths into scenario dicts, and the draws of one case."""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import MISSING, ScenarioError, shown
from ..faults.spec import TRIGGERS
from .errors import CampaignError

DISTRIBUTIONS = ("normal", "uniform", "rotation", "uniform_rotation", "choice")
#: Keys each distribution takes (besides ``field`` and ``distribution``).
KEYS = {
    "normal": ("mean", "sigma", "sigma_percent", "min", "max"),
    "uniform": ("min", "max", "integer"),
    "rotation": ("sigma_deg",),
    "uniform_rotation": (),
    "choice": ("values", "weights"),
}

#: Largest bound of an integer uniform dispersion (whole numbers a float holds exactly).
MAX_INTEGER = 2**53


# ------------------------------------------------------------------------------ dotted paths in scenario dicts
#: Per list: the keys a table drawn for a whole entry leaves as the entry has them unless the drawn table gives
#: a key of the first group. A fault keeps its trigger (and an ``after``'s delay_s) unless the table gives one of
#: its own, so which fault happens and when it happens are dispersed apart (``faults.probe`` a choice of fault
#: tables, ``faults.probe.at_s`` a uniform time); ``delay_s`` alone is no trigger (tracker_slow's parameter has
#: that name). An entry always keeps its name.
KEPT = {"faults": (TRIGGERS, (*TRIGGERS, "delay_s"))}


def _entry(entries: list, name: str, path: str, parent: str, where: str) -> dict:
    """The entry of a list of tables named ``name`` (list entries are addressed by their ``name``)."""
    match = [d for d in entries if isinstance(d, dict) and d.get("name") == name]
    if not match:
        names = [str(d.get("name")) for d in entries if isinstance(d, dict) and "name" in d]
        unnamed = sum(1 for d in entries if not (isinstance(d, dict) and "name" in d))
        hint = f"; {unnamed} entries without a name, which a path cannot address: give them name = ..." if unnamed \
            else ""
        raise CampaignError(f"{where}: field = {path!r} is not allowed: {parent} has no entry named {name!r} "
                            f"(entries: {', '.join(names) or 'none'}{hint}).")
    return match[0]


def _locate(data: dict, path: str, where: str) -> tuple[dict | list, str]:
    """The table holding ``path``'s last key, or the list whose entry named by the last part ``path`` is (a whole
    ``[[faults]]`` entry: ``faults.NAME``); list entries are addressed by their ``name``."""
    parts = path.split(".")
    if not path or any(not p for p in parts):
        raise CampaignError(f"{where}: field = {path!r} is not allowed: a dotted scenario key such as "
                            "spacecraft.omega_BN_B_deg_s or devices.mtq.mag_noise_nT.")
    node: Any = data
    for i, part in enumerate(parts[:-1]):
        so_far = ".".join(parts[: i + 1])
        if isinstance(node, list):
            node = _entry(node, part, path, ".".join(parts[:i]), where)
        elif isinstance(node, dict):
            if part not in node:
                raise CampaignError(f"{where}: field = {path!r} is not allowed: the scenario has no {so_far} (a "
                                    "dispersion varies what the scenario sets; it never adds a table).")
            node = node[part]
        else:
            raise CampaignError(f"{where}: field = {path!r} is not allowed: {'.'.join(parts[:i])} is a value, "
                                "not a table.")
    if isinstance(node, list):  # the path names a whole entry of a list of tables
        _entry(node, parts[-1], path, ".".join(parts[:-1]), where)
        return node, parts[-1]
    if not isinstance(node, dict):
        raise CampaignError(f"{where}: field = {path!r} is not allowed: {'.'.join(parts[:-1])} is a value, "
                            "not a table.")
    return node, parts[-1]


def get_field(data: dict, path: str, where: str = "dispersion"):
    """The value at ``path``; a whole list entry (``faults.NAME``) is its table."""
    node, key = _locate(data, path, where)
    if isinstance(node, list):
        return _entry(node, key, path, "", where)
    return node.get(key, MISSING)


def put_field(data: dict, path: str, value, where: str = "dispersion") -> None:
    """Set the value at ``path``. A table put at a whole list entry (``faults.NAME``) replaces the entry's keys
    except its name, and except the keys :data:`KEPT` for that list unless the table gives one of them."""
    node, key = _locate(data, path, where)
    if not isinstance(node, list):
        node[key] = value
        return
    entry = _entry(node, key, path, "", where)
    if not isinstance(value, dict):
        raise CampaignError(f"{where}: field = {path!r} names a whole entry: a table of its keys is required, not "
                            f"{shown(value)}.")
    gives, kept = KEPT.get(path.split(".")[-2], ((), ()))
    keep = ("name",) if any(k in value for k in gives) else ("name", *kept)
    old = {k: entry[k] for k in keep if k in entry}
    entry.clear()
    entry.update(old)
    entry.update(value)


def with_faults(scenario: dict, faults) -> dict:
    """A deep copy of a scenario dict with ``faults`` (a dispersion file's ``[[faults]]``) after its own."""
    data = json.loads(json.dumps(scenario))
    if faults:
        own = data.get("faults", [])
        data["faults"] = [*own, *json.loads(json.dumps(list(faults)))] if isinstance(own, list) else own
    return data


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
        return _choice(entry, where, fld, nominal, whole=isinstance(_locate(scenario, fld, where)[0], list))
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


def _choice(entry, where, fld, nominal, whole: bool = False) -> Dispersion:
    """One of ``values``; for a whole list entry (``faults.NAME``), each value a table of the entry's keys."""
    p = _Params(entry, where, ())
    values = entry.get("values", MISSING)
    if not isinstance(values, list) or not values:
        raise p.error("values", values, "a non-empty list of the values to choose from")
    for k, v in enumerate(values if whole else ()):
        if not isinstance(v, dict) or not v:
            raise p.error(f"values[{k}]", v, f"a table of the keys of entry {fld} (it names a whole entry: the drawn "
                          "table replaces the entry's keys but its name), e.g. {type = 'stuck', device = 'imu'}")
        if "name" in v:
            raise p.error(f"values[{k}].name", v["name"], f"no name: the drawn table keeps the entry's own name "
                          f"({fld.split('.')[-1]!r}), which the other dispersions and the report address")
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
    #: The file's ``[[faults]]``: faults every case has, after the scenario's own (dispersions address them by
    #: name like the scenario's), so a nominal scenario runs under a campaign of faults unchanged.
    faults: tuple = ()


def parse_dispersions(text: str, scenario: dict, source: str = "<string>") -> Dispersions:
    """Read a dispersion file against the scenario dict it disperses; CampaignError names the first bad key."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CampaignError(f"--dispersions {source} is not allowed: valid TOML is required ({exc}).") from None
    unknown = sorted(set(data) - {"campaign", "dispersions", "faults"})
    if unknown:
        raise CampaignError(f"{unknown[0]} in {source} is not allowed: a dispersion file has a [campaign] table, "
                            "[[dispersions]] entries and [[faults]] tables.")
    added = data.get("faults", [])
    if not isinstance(added, list) or not all(isinstance(f, dict) for f in added):
        raise CampaignError(str(ScenarioError("faults", added, "[[faults]] tables: faults every case of the campaign "
                                              "has, after the scenario's own", source)))
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
        base = with_faults(scenario, added)
        items = tuple(_dispersion(e, k, base) for k, e in enumerate(entries))
    except CampaignError as exc:  # the entry's sentence, with the file it is in
        raise CampaignError(f"{source}: {exc}") from None
    fields = [d.field for d in items]
    dup = sorted({f for f in fields if fields.count(f) > 1})
    if dup:
        raise CampaignError(f"dispersions in {source}: field {dup[0]!r} is dispersed twice; one entry per field.")
    if any(f in ("scenario.seed", "scenario.duration_s") for f in fields):
        raise CampaignError(f"dispersions in {source}: scenario.seed and scenario.duration_s are set by the "
                            "campaign (the case seed, --duration), not dispersed.")
    return Dispersions(items, seed, text, source, tuple(added))


def case_values(dispersions: Dispersions, seed: int, index: int) -> tuple[int, dict]:
    """``(run seed, {field: value})`` of case ``index``, from ``SeedSequence((seed, index))`` alone."""
    children = np.random.SeedSequence((seed, index)).spawn(len(dispersions.items) + 1)
    run_seed = int(children[0].generate_state(1, np.uint64)[0] >> np.uint64(1))
    values = {d.field: d.draw(np.random.default_rng(ss)) for d, ss in zip(dispersions.items, children[1:],
                                                                              strict=True)}
    return run_seed, values


def apply(scenario: dict, values: dict, run_seed: int, duration_s: float | None, faults=()) -> dict:
    """A deep copy of the scenario dict with the dispersion file's ``faults``, the case's values, seed and
    duration. A table goes in before the keys under it (``faults.probe`` before ``faults.probe.at_s``): a key
    dispersed on its own is not undone by the table drawn for its entry, whatever the order in the file."""
    data = with_faults(scenario, faults)
    for fld, value in sorted(values.items(), key=lambda item: item[0].count(".")):
        put_field(data, fld, value)
    data.setdefault("scenario", {})["seed"] = run_seed
    if duration_s is not None:
        data["scenario"]["duration_s"] = duration_s
    return data


# ------------------------------------------------------------------------------------------------ the spec
