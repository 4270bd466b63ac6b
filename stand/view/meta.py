"""The page's view of a run's scenario (``view.json``) and the strict JSON it is sent in.

``view.json`` (written beside the telemetry at run start by :func:`write_view_json`) holds what the page needs
from the scenario: the epoch, the Earth-rotation model, and for every device its kind, mount ``q_SB`` and the
layers its kind declares (``DeviceKind.view_layers``, ``view_state``, ``view_error_columns``). :func:`load_meta`
reads it, or rebuilds it from the scenario named in ``summary.json`` for a run recorded before the file existed.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from sim.time import Epoch
from stand import scenario
from stand.devices import DeviceKind
from stand.devices import get as get_kind
from stand.errors import ScenarioError

VIEW_FILE = "view.json"


# --------------------------------------------------------------------------------------------------- strict JSON

def _finite_or_none(obj):
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite_or_none(v) for v in obj]
    return obj


def dumps(obj) -> str:
    """JSON a browser can parse: NaN and infinities (a criterion a tracker that never solved could not score, an
    event's time) become ``null``; Python's ``json`` would write ``NaN``, which ``JSON.parse`` refuses."""
    try:
        return json.dumps(obj, allow_nan=False)
    except ValueError:
        return json.dumps(_finite_or_none(obj), allow_nan=False)


# --------------------------------------------------------------------------------------------------- metadata

def _kind(name: str):
    """The device kind called ``name``, or the bare contract for a kind not installed here (a replay elsewhere)."""
    try:
        return get_kind(name)
    except KeyError:
        return DeviceKind()


def _declared(kind) -> dict:
    """What a kind declares for the page whatever the device's spec: its validity colouring and error columns."""
    out = {"state": kind.view_state} if kind.view_state is not None else {}
    if kind.view_error_columns:
        out["error_columns"] = list(kind.view_error_columns)
    if kind.view_plots:
        out["plots"] = [dict(p) for p in kind.view_plots]
    return out


def _device_view(d) -> dict:
    """Kind, mount and the layers the kind declares (``DeviceKind.view_layers``: fields of view and the like)."""
    kind = _kind(d.kind)
    out = {"name": d.name, "kind": d.kind, "link": d.link, "q_SB": [float(x) for x in d.q_SB]}
    out.update({"fovs": [], **kind.view_layers(d), **_declared(kind)})
    out["fault_taps"] = {tap: dict(info) for tap, info in kind.fault_taps(d).items()}  # what the fault panel offers
    # Its datasheet (ratings: a wheel's spin axis, rotor inertia and speed limit, for the wheel panel and momentum)
    out["datasheet"] = _plain(kind.datasheet(d))
    return out


def _plain(obj):
    """Numbers, tuples and arrays of a datasheet as JSON values (an array's items as floats)."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple) or hasattr(obj, "tolist"):
        obj = obj.tolist() if hasattr(obj, "tolist") else obj
        return [_plain(v) for v in obj] if isinstance(obj, list | tuple) else _plain(obj)
    if isinstance(obj, bool | str | int | float) or obj is None:
        return obj
    return str(obj)


def describe(sc) -> dict:
    """The page's view of a scenario (what ``view.json`` holds)."""
    env = sc.environment
    return {
        "format": 1,
        "scenario": sc.name,
        "description": sc.description,
        "epoch": sc.epoch.iso,
        "duration_s": float(sc.duration_s),
        "step_s": float(sc.step_s),
        "record_rate_hz": float(sc.record_rate_hz),
        "earth_rotation": {"model": env.earth_rotation, "era0_rad": float(env.era0_rad)},
        "spacecraft": {"inertia_kg_m2": _plain(np.asarray(sc.spacecraft.inertia_kg_m2, dtype=float))},
        "devices": [_device_view(d) for d in sc.devices],
        "criteria": [{"name": c.name, "metric": c.metric, "max": c.max, "min": c.min, "at_s": c.at_s}
                     for c in sc.criteria],
        # The scenario's own [[faults]], for the fault panel and `stand fault list` (what happens is in the events).
        "faults": [{"name": f.name, "type": f.type, "device": f.device, "when": f.describe()}
                   for f in getattr(sc, "faults", ())],
    }


def write_view_json(sc, run_dir, duration_s: float | None = None) -> Path:
    """``view.json`` of a run (``duration_s``: the run's own when ``--duration`` changed it)."""
    meta = describe(sc)
    if duration_s is not None:
        meta["duration_s"] = float(duration_s)
    path = Path(run_dir) / VIEW_FILE
    path.write_text(json.dumps(meta, indent=1) + "\n")
    return path


class RunFileError(ValueError):
    """A run folder's ``view.json`` or ``summary.json`` the page cannot use (one sentence naming the file)."""


def _number(x, positive: bool = False) -> bool:
    ok = isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
    return ok and (x > 0 if positive else True)


def _meta_problem(meta) -> str | None:
    """What in a ``view.json`` the page could not draw from, or None."""
    if not isinstance(meta, dict):
        return f"it holds a JSON {type(meta).__name__}, not an object"
    try:
        Epoch.from_iso(meta.get("epoch"))
    except (ValueError, TypeError, AttributeError):
        return f"its epoch {meta.get('epoch')!r} is not an ISO 8601 UTC time"
    for key in ("duration_s", "step_s", "record_rate_hz"):
        if key in meta or key == "duration_s":
            if not _number(meta.get(key), positive=True):
                return f"its {key} {meta.get(key)!r} is not a positive number"
    er = meta.get("earth_rotation", {})
    if not isinstance(er, dict) or er.get("model", "iau2006") not in ("iau2006", "uniform") \
            or not _number(er.get("era0_rad", 0.0)):
        return f"its earth_rotation {er!r} is not {{\"model\": \"iau2006\" or \"uniform\", \"era0_rad\": NUMBER}}"
    devices = meta.get("devices")
    if not isinstance(devices, list):
        return f"its devices {devices!r} are not a list"
    for i, d in enumerate(devices):
        if not (isinstance(d, dict) and isinstance(d.get("name"), str) and isinstance(d.get("kind"), str)
                and isinstance(d.get("q_SB"), list) and len(d["q_SB"]) == 4 and all(map(_number, d["q_SB"]))
                and isinstance(d.get("fovs"), list) and all(isinstance(f, dict) for f in d["fovs"])):
            name = d.get("name") if isinstance(d, dict) else None
            return (f"its device {i + 1} ({name!r}) lacks a name, a kind, a q_SB of 4 numbers or a list of fields "
                    "of view")
    if not isinstance(meta.get("criteria", []), list):
        return "its criteria are not a list"
    return None


def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except UnicodeDecodeError:
        raise RunFileError(f"{path} is not readable: it is not UTF-8 text.") from None
    except json.JSONDecodeError as exc:
        raise RunFileError(f"{path} is not readable: it is not valid JSON ({exc.msg} at line {exc.lineno}, "
                           f"column {exc.colno}).") from None


def load_meta(run_dir) -> dict:
    """``view.json`` of a run, or the same rebuilt from the scenario its summary names; a file the page cannot use
    raises :class:`RunFileError` naming it and what is wrong."""
    run_dir = Path(run_dir)
    path = run_dir / VIEW_FILE
    if path.is_file():
        meta = _read_json(path)
        why = _meta_problem(meta)
        if why is not None:
            raise RunFileError(f"{path} is not a view description the page can use: {why}.")
        for dev in meta["devices"]:  # a view.json written before kinds declared these: the kind's declaration
            for key, value in _declared(_kind(dev["kind"])).items():
                dev.setdefault(key, value)
        return meta
    summary = run_dir / "summary.json"
    if not summary.is_file():
        raise FileNotFoundError(f"{run_dir} is not a run folder: it holds neither {VIEW_FILE} nor summary.json.")
    data = _read_json(summary)
    source = data.get("source") if isinstance(data, dict) else None
    try:
        meta = describe(scenario.load(scenario.find(source)))
        if data.get("status") == "completed" and _number(data.get("sim_duration_s"), positive=True):
            meta["duration_s"] = float(data["sim_duration_s"])  # a --duration run
        return meta
    except (ScenarioError, TypeError, OSError):
        raise FileNotFoundError(f"{run_dir} has no {VIEW_FILE} and its scenario {source!r} is neither a file on this "
                                "machine nor a shipped scenario.") from None
