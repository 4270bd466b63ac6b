"""What a run leaves behind: ``summary.json`` with the pass criteria, PNG plots, ``report.md``.

Criteria are evaluated from the telemetry as written (``stand.telemetry.load``), so the report
states what the log shows, not what the loop believed.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from . import devices
from .adcs.metrics import METRICS as POINTING_METRICS
from .adcs.metrics import value as pointing_metric
from .compose import Scene
from .loop import RunResult
from .scenario import METRIC_UNITS, Criterion, all_metrics
from .telemetry import load


def _rate_deg_s(tel) -> np.ndarray:
    return np.degrees(np.linalg.norm(tel["omega_BN_B"], axis=1))


def metric_value(c: Criterion, tel, result: RunResult, scene_devices=()) -> float:
    t = tel["t_s"]
    if c.metric == "final_rate_deg_s":
        return float(_rate_deg_s(tel)[-1]) if len(t) else math.nan
    if c.metric == "rate_deg_s_at":
        i = int(np.searchsorted(t, c.at_s - 1e-9))
        return float(_rate_deg_s(tel)[i]) if i < len(t) else math.nan
    if c.metric == "max_rate_deg_s_after":
        sel = t >= c.at_s - 1e-9
        return float(_rate_deg_s(tel)[sel].max()) if np.any(sel) else math.nan
    if c.metric == "frames_rejected":
        return float(_rejected(result.counters))
    if c.metric in POINTING_METRICS:
        return pointing_metric(c.metric, c.at_s, tel)
    if c.metric == "overruns":
        return float(result.timing.get("overruns", 0))
    for d in scene_devices:
        kind = devices.get(d.kind)
        if c.metric in kind.metrics:
            names = [x.name for x in scene_devices if x.kind == d.kind]
            return kind.metric(c.metric, c.at_s, tel, names)
    raise ValueError(f"unknown metric {c.metric!r}; known: {', '.join(all_metrics())}")


def _rejected(counters: dict) -> int:
    """Every frame any codec rejected, in nested counter dicts too (trackers report host and emulator)."""
    total = 0
    for k, v in counters.items():
        if isinstance(v, dict):
            total += _rejected(v)
        elif k.startswith("rejected") and isinstance(v, int | float):
            total += v
    return total


def metric_unit(metric: str) -> str:
    """The unit of a metric: the run's table, else the unit its name ends with (``..._rms_nT``)."""
    if metric in METRIC_UNITS:
        return METRIC_UNITS[metric]
    tail = metric.rsplit("_", 1)[-1]
    return tail if tail in ("nT", "arcsec", "deg", "s", "ms") else ""


def evaluate(criteria, tel, result: RunResult, scene_devices=()) -> list[dict]:
    out = []
    for c in criteria:
        v = metric_value(c, tel, result, scene_devices)
        ok = math.isfinite(v) and (c.max is None or v <= c.max) and (c.min is None or v >= c.min)
        limit = {"max": c.max} if c.min is None else {"min": c.min} if c.max is None else {"min": c.min, "max": c.max}
        out.append({"name": c.name, "metric": c.metric, "value": v, "unit": metric_unit(c.metric),
                    "limit": limit, "pass": bool(ok),
                    **({"at_s": c.at_s} if c.at_s is not None else {})})
    return out


def write_summary(scene: Scene, result: RunResult, out_dir, plots: bool = True) -> dict:
    """summary.json, and with ``plots`` the PNG plots and report.md (a campaign's runs leave them out)."""
    out_dir = Path(out_dir)
    sc = scene.scenario
    tel = load(out_dir)
    criteria = evaluate(sc.criteria, tel, result, sc.devices)
    # Nothing simulated proves nothing: such a run never passes.
    passed = result.status == "completed" and result.sim_duration_s > 0 and all(c["pass"] for c in criteria)
    rate = _rate_deg_s(tel)
    checkpoints = {}
    for ts in (0.0, 600.0, 1800.0, 3600.0, sc.duration_s):
        i = int(np.searchsorted(tel["t_s"], ts - 1e-9))
        if i < len(rate):
            checkpoints[f"{ts:g}"] = round(float(rate[i]), 4)
    summary = {
        "scenario": sc.name,
        "source": sc.source,
        "status": result.status,
        "error": result.error,
        "sim_duration_s": result.sim_duration_s,
        "wall_time_s": round(result.wall_time_s, 4),
        "realtime_factor": round(result.sim_duration_s / result.wall_time_s, 2) if result.wall_time_s > 0 else None,
        "criteria": criteria,
        "pass": passed,
        "models": {
            "built": [{"model": c.model, "reason": c.reason} for c in scene.choices if c.built],
            "left_out": [{"model": c.model, "reason": c.reason} for c in scene.choices if not c.built],
        },
        "timing": result.timing,
        "rate_deg_s_at": checkpoints,
        "device_counters": result.counters,
        "telemetry_rows": int(len(tel["t_s"])),
    }
    write_json_atomic(out_dir / "summary.json", summary)
    if not plots:
        return summary
    try:
        made = write_plots(tel, out_dir, rate_limits=rate_limits(sc.criteria))
        for d in sc.devices:
            made += devices.get(d.kind).plots(tel, d.name, out_dir, criteria)
        from .view.export import report_panorama

        made += [p for p in [report_panorama(out_dir, sc)] if p]
        write_markdown(summary, made, out_dir)
    except OSError as exc:  # a full disk: the summary above is what matters, and it is whole
        summary["report_error"] = f"plots or report.md not written: {exc.strerror or exc}"
        write_json_atomic(out_dir / "summary.json", summary)
    return summary


def write_json_atomic(path: Path, data: dict) -> None:
    """Write JSON through a temporary file and a rename, so the file is either the old one or whole."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(json.dumps(data, indent=2, default=float) + "\n")
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise


def limit_text(c: dict) -> str:
    """``0.197 deg/s <= 0.5 deg/s``: a criterion's value against its limits, with units."""
    unit = f" {c['unit']}" if c.get("unit") else ""
    v = f"{c['value']:.4g}{unit}"
    lim = c["limit"]
    parts = []
    if "min" in lim:
        parts.append(f"{v} >= {lim['min']:g}{unit}")
    if "max" in lim:
        parts.append(f"{v} <= {lim['max']:g}{unit}")
    at = f" at t = {c['at_s']:g} s" if "at_s" in c and c["metric"].endswith("_at") else \
        f" after t = {c['at_s']:g} s" if "at_s" in c else ""
    return " and ".join(parts) + at


#: Criteria on the body rate, drawn on the rate plot: metric -> what the limit applies to.
RATE_METRICS = {"final_rate_deg_s": "at the end", "rate_deg_s_at": "at t = {at_s:g} s",
                "max_rate_deg_s_after": "after t = {at_s:g} s"}


def rate_limits(criteria) -> list[tuple[str, float, float | None]]:
    """``(label, value_deg_s, at_s or None)`` of every rate criterion, for ``plots.plot_rate``."""
    out = []
    for c in criteria:
        if c.metric in RATE_METRICS:
            for bound, value in (("at most", c.max), ("at least", c.min)):
                if value is not None:
                    when = RATE_METRICS[c.metric].format(at_s=c.at_s or 0.0)
                    out.append((f"{c.name}: {bound} {value:g} deg/s {when}", value, c.at_s))
    return out


def write_plots(tel, out_dir: Path, *, rate_limits: list | None = None) -> list[str]:
    """rate.png, attitude.png and, when the run commanded or produced a dipole, dipole.png."""
    from . import plots

    if len(tel["t_s"]) < 2:
        return []
    made = [plots.plot_rate(tel, out_dir, rate_limits or ()), plots.plot_attitude(tel, out_dir)]
    produced = {k[: -len(".dipole_B")]: k for k in tel if k.endswith(".dipole_B")}
    commanded = "dipole_cmd_B" if "dipole_cmd_B" in tel else None
    if produced or commanded:
        made.append(plots.plot_dipole(tel, out_dir, produced, commanded))
    if all(c in tel for c in ("adcs_q_BN_est", "adcs_sigma3_B", "adcs_q_RN", "adcs_mode")):
        made.append(plots.plot_pointing(tel, out_dir))
    return made


def write_markdown(summary: dict, plots: list[str], out_dir: Path) -> None:
    lines = [f"# Run report: {summary['scenario']}", "",
             f"**{'PASS' if summary['pass'] else 'FAIL'}** ({summary['status']})", ""]
    if summary["error"]:
        lines += [f"Error: {summary['error']}", ""]
    lines += [f"Simulated {summary['sim_duration_s']:g} s in {summary['wall_time_s']:g} s of wall time "
              f"({summary['realtime_factor']} x real time).", "", "| criterion | value against limit | pass |",
              "|---|---|---|"]
    for c in summary["criteria"]:
        lines.append(f"| {c['name']} | {limit_text(c)} | {'yes' if c['pass'] else 'NO'} |")
    lines += ["", "## Models", ""]
    lines += [f"- built `{m['model']}`: {m['reason']}" for m in summary["models"]["built"]]
    lines += [f"- left out `{m['model']}`: {m['reason']}" for m in summary["models"]["left_out"]]
    lines += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots]
    (out_dir / "report.md").write_text("\n".join(lines) + "\n")
