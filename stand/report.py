"""What a run leaves behind: ``summary.json`` with the pass criteria, PNG plots, ``report.md``.

Criteria are evaluated from the telemetry as written (``stand.telemetry.load``), so the report
states what the log shows, not what the loop believed.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .compose import Scene
from .loop import RunResult
from .scenario import METRICS, Criterion
from .telemetry import load


def _rate_deg_s(tel) -> np.ndarray:
    return np.degrees(np.linalg.norm(tel["omega_BN_B"], axis=1))


def metric_value(c: Criterion, tel, result: RunResult) -> float:
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
    if c.metric.startswith("tracker_"):
        sol = _tracker_solutions(tel)
        if sol is None:
            return math.nan
        if c.metric == "tracker_availability_after":
            sel = sol["t"] >= c.at_s - 1e-9
            return float(sol["valid"][sel].mean()) if np.any(sel) else math.nan
        err = sol["cross" if "cross" in c.metric else "roll"][sol["valid"] == 1.0]
        err = err[np.isfinite(err)]
        return float(np.percentile(err, 95)) if len(err) else math.nan
    if c.metric == "overruns":
        return float(result.timing.get("overruns", 0))
    raise ValueError(f"unknown metric {c.metric!r}; known: {', '.join(METRICS)}")


def _rejected(counters: dict) -> int:
    """Every frame any codec rejected, in nested counter dicts too (trackers report host and emulator)."""
    total = 0
    for k, v in counters.items():
        if isinstance(v, dict):
            total += _rejected(v)
        elif k.startswith("rejected") and isinstance(v, int | float):
            total += v
    return total


def _tracker_solutions(tel) -> dict | None:
    """The first star tracker's solutions, one per exposure (telemetry repeats the newest)."""
    names = sorted(k[: -len(".t_exposure_s")] for k in tel if k.endswith(".t_exposure_s"))
    if not names:
        return None
    n = names[0]
    t = tel[f"{n}.t_exposure_s"]
    ok = np.isfinite(t)
    _, first = np.unique(t[ok], return_index=True)
    idx = np.flatnonzero(ok)[first]
    return {"t": t[idx], "valid": tel[f"{n}.valid"][idx], "cross": tel[f"{n}.err_cross"][idx],
            "roll": tel[f"{n}.err_roll"][idx]}


def evaluate(criteria, tel, result: RunResult) -> list[dict]:
    out = []
    for c in criteria:
        v = metric_value(c, tel, result)
        ok = math.isfinite(v) and (c.max is None or v <= c.max) and (c.min is None or v >= c.min)
        limit = {"max": c.max} if c.min is None else {"min": c.min} if c.max is None else {"min": c.min, "max": c.max}
        out.append({"name": c.name, "metric": c.metric, "value": v, "limit": limit, "pass": bool(ok),
                    **({"at_s": c.at_s} if c.at_s is not None else {})})
    return out


def write_summary(scene: Scene, result: RunResult, out_dir) -> dict:
    out_dir = Path(out_dir)
    sc = scene.scenario
    tel = load(out_dir)
    criteria = evaluate(sc.criteria, tel, result)
    passed = result.status == "completed" and all(c["pass"] for c in criteria)
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
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    plots = write_plots(tel, out_dir, rate_limits=rate_limits(sc.criteria))
    write_markdown(summary, plots, out_dir)
    return summary


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
    return made


def write_markdown(summary: dict, plots: list[str], out_dir: Path) -> None:
    lines = [f"# Run report: {summary['scenario']}", "",
             f"**{'PASS' if summary['pass'] else 'FAIL'}** ({summary['status']})", ""]
    if summary["error"]:
        lines += [f"Error: {summary['error']}", ""]
    lines += [f"Simulated {summary['sim_duration_s']:g} s in {summary['wall_time_s']:g} s of wall time "
              f"({summary['realtime_factor']} x real time).", "", "| criterion | value | limit | pass |",
              "|---|---|---|---|"]
    for c in summary["criteria"]:
        lines.append(f"| {c['name']} | {c['value']:.4g} | {c['limit']} | {'yes' if c['pass'] else 'NO'} |")
    lines += ["", "## Models", ""]
    lines += [f"- built `{m['model']}`: {m['reason']}" for m in summary["models"]["built"]]
    lines += [f"- left out `{m['model']}`: {m['reason']}" for m in summary["models"]["left_out"]]
    lines += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots]
    (out_dir / "report.md").write_text("\n".join(lines) + "\n")
