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

import compiled_paths
from sim.time import seconds_to_ns

from . import devices
from .adcs.metrics import FAULT_METRICS, MetricUnavailable, fault_value, fault_windows
from .adcs.metrics import METRICS as POINTING_METRICS
from .adcs.metrics import value as pointing_metric
from .compose import Scene, ticks_per
from .controllers.spacecraft import METRIC_COLUMNS
from .loop import RunResult
from .pacing import OVERRUN_SHARE_LIMIT, overrun_share
from .scenario import METRIC_UNITS, Criterion, all_metrics
from .telemetry import load


def _rate_deg_s(tel) -> np.ndarray:
    return np.degrees(np.linalg.norm(tel["omega_BN_B"], axis=1))


def metric_value(c: Criterion, tel, result: RunResult, scene_devices=(), faults: dict | None = None,
                 rate_deg_s: np.ndarray | None = None) -> float:
    """``faults``: fault name -> (start s, clearing s or None), from the run's events (:func:`run_faults`);
    ``rate_deg_s``: the body rate of every row (``_rate_deg_s(tel)``) where the caller has it already."""
    t = tel["t_s"]
    if c.metric in FAULT_METRICS:
        return fault_value(c.metric, c.fault, tel, faults or {}, c.within_deg)
    if c.metric in RATE_METRICS:
        rate = _rate_deg_s(tel) if rate_deg_s is None else rate_deg_s
        if c.metric == "final_rate_deg_s":
            return float(rate[-1]) if len(t) else math.nan
        if c.metric == "rate_deg_s_at":
            i = int(np.searchsorted(t, c.at_s - 1e-9))
            return float(rate[i]) if i < len(t) else math.nan
        sel = t >= c.at_s - 1e-9
        return float(rate[sel].max()) if np.any(sel) else math.nan
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


def _why_no_value(c: Criterion, tel, scene_devices=()) -> str:
    """Why a criterion has no finite value, in words (summary.json's ``reason`` and the printed line)."""
    t = tel["t_s"]
    if not len(t):
        return "the telemetry has no rows (the run ended before its first record)"
    after = f" after t = {c.at_s:g} s" if c.at_s is not None else ""
    if c.at_s is not None and c.at_s > t[-1] + 1e-9:
        return f"the telemetry ends at t = {t[-1]:g} s, before t = {c.at_s:g} s"
    missing = [col for col in METRIC_COLUMNS.get(c.metric, ()) if col not in tel]
    if missing:
        return (f"the telemetry has no column {', '.join(missing)}: the controller does not record it (a plug-in "
                "reports its attitude estimate and commanded attitude through telemetry_columns(), docs/plugins.md)")
    for col in METRIC_COLUMNS.get(c.metric, ()):
        sel = t >= (c.at_s or 0.0) - 1e-9
        if not np.any(np.all(np.isfinite(np.asarray(tel[col]).reshape(len(t), -1)[sel]), axis=1)):
            return f"the controller recorded no finite {col}{after} (NaN in every row)"
    for d in scene_devices:
        valid = tel.get(f"{d.name}.valid")
        if c.metric in devices.get(d.kind).metrics and valid is not None:
            sel = t >= (c.at_s or 0.0) - 1e-9
            if not np.any(np.asarray(valid)[sel] == 1.0):
                return f"{d.name} never reported a valid measurement{after}"
    return f"the telemetry holds no valid sample for {c.metric}{after}"


def run_faults(out_dir: Path) -> dict:
    """Fault name -> (start s, clearing s or None) from the run's ``events.jsonl`` (unreadable lines skipped)."""
    try:
        lines = (Path(out_dir) / "events.jsonl").read_text(errors="replace").splitlines()
    except OSError:
        return {}
    events = []
    for line in lines:
        if '"fault_' in line:  # most lines are not about faults: no need to parse them
            try:
                e = json.loads(line)
            except ValueError:
                continue
            if isinstance(e, dict):
                events.append(e)
    return fault_windows(events)


def evaluate(criteria, tel, result: RunResult, scene_devices=(), faults: dict | None = None,
             rate_deg_s: np.ndarray | None = None) -> list[dict]:
    """Each criterion's value against its limits; one that cannot be computed fails with a ``reason``.
    ``rate_deg_s``: as :func:`metric_value` takes it."""
    out = []
    for c in criteria:
        reason = None
        try:
            v = float(metric_value(c, tel, result, scene_devices, faults, rate_deg_s))
        except MetricUnavailable as exc:
            v, reason = math.nan, str(exc)
        except (ArithmeticError, IndexError, KeyError, TypeError) as exc:
            v, reason = math.nan, f"computing {c.metric} failed ({type(exc).__name__}: {exc})"
        if not math.isfinite(v):
            reason = reason or _why_no_value(c, tel, scene_devices)
        ok = reason is None and (c.max is None or v <= c.max) and (c.min is None or v >= c.min)
        limit = {"max": c.max} if c.min is None else {"min": c.min} if c.max is None else {"min": c.min, "max": c.max}
        out.append({"name": c.name, "metric": c.metric, "value": v if reason is None else None,
                    "unit": metric_unit(c.metric), "limit": limit, "pass": bool(ok),
                    **({"at_s": c.at_s} if c.at_s is not None else {}),
                    **({"fault": c.fault} if c.fault is not None else {}), **({"reason": reason} if reason else {})})
    return out


def expected_rows(sc, sim_duration_s: float, step_ns: int) -> int:
    """Rows a whole record of ``sim_duration_s`` holds: one every recording period from t = 0, and the last tick."""
    n_steps = seconds_to_ns(sim_duration_s) // step_ns
    every = ticks_per(sc.record_rate_hz, sc.step_s)
    return n_steps // every + 1 + (1 if n_steps % every else 0)


def unvouched(scene: Scene, result: RunResult, tel, out_dir: Path, duration_s: float | None = None) -> list[str]:
    """Why the stand cannot vouch for this run's record (empty: it can). A PASS needs an empty list: the run
    completed its whole duration, the telemetry covers it row for row, and every device, the controller and the
    telemetry writer ended cleanly, whatever the loop believed."""
    sc = scene.scenario
    if result.status != "completed":  # it says so itself; what follows would only repeat it
        return [f"the run was {result.status}" + (f": {result.error}" if result.error else "")]
    why = [f"the run reported an error: {result.error}"] if result.error else []
    step_ns = getattr(scene.truth, "step_ns", None) or seconds_to_ns(sc.step_s)
    wanted_s = sc.duration_s if duration_s is None else duration_s
    wanted_s = (seconds_to_ns(wanted_s) // step_ns) * step_ns / 1e9
    if result.sim_duration_s <= 0:
        why.append("nothing was simulated")
    elif result.sim_duration_s < wanted_s - 1e-9:
        why.append(f"the run simulated {result.sim_duration_s:g} s of the {wanted_s:g} s asked for")
    t = tel["t_s"]
    want = expected_rows(sc, result.sim_duration_s, step_ns)
    half_step = step_ns / 2e9
    if len(t) != want or not len(t) or abs(t[0]) > half_step or abs(t[-1] - result.sim_duration_s) > half_step \
            or np.any(np.diff(t) <= 0):
        end = f"ends at t = {t[-1]:g} s" if len(t) else "is empty"
        why.append(f"the telemetry holds {len(t)} rows and {end}, where {result.sim_duration_s:g} s of simulation "
                   f"record {want} rows from t = 0")
    for name, counters in result.counters.items():
        if isinstance(counters, dict) and "summary_error" in counters:
            why.append(f"device {name} did not end cleanly: {counters['summary_error']}")
    why += _event_problems(out_dir)
    return why


def _event_problems(out_dir: Path) -> list[str]:
    """What the event log says went wrong: a plug-in exception, or no end event saying "completed"."""
    try:
        lines = (out_dir / "events.jsonl").read_text().splitlines()
        events = [json.loads(x) for x in lines if x.strip()]
    except (OSError, ValueError) as exc:
        return [f"the event log cannot be read ({exc})"]
    why = [f"the controller raised: {e.get('message')}" for e in events if e.get("kind") == "controller_exception"]
    if not events or events[-1].get("kind") != "end" or events[-1].get("message") != "completed":
        why.append("the event log does not end with the run completed")
    return why


def _json_safe(x):
    """``x`` with every NaN or infinity as None (null: summary.json is strict JSON) and numpy numbers as Python's."""
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_json_safe(v) for v in x]
    if isinstance(x, bool | np.bool_):
        return bool(x)
    if isinstance(x, int | np.integer):
        return int(x)
    if isinstance(x, float | np.floating):
        return float(x) if math.isfinite(x) else None
    return x


#: The verdict of a completed run whose scenario names no criteria (exit 1: nothing held, so nothing passed).
NOT_JUDGED = "NOT JUDGED (the scenario has no [[criteria]])"


def verdict_text(passed: bool, status: str, timing: dict) -> str:
    """The run's verdict in words: PASS, FAIL, ABORTED or STOPPED; a pass of a paced run whose overruns exceed
    ``OVERRUN_SHARE_LIMIT`` of its ticks is "PASS, paced with N % overruns" (still a pass, exit 0: the criteria
    held, but the devices in wall time did not see the scenario's timing; an ``overruns`` criterion makes it fail)."""
    if not passed:
        return {"aborted": "ABORTED", "stopped": "STOPPED"}.get(status, "FAIL")
    share = overrun_share(timing)
    if share is not None and share > OVERRUN_SHARE_LIMIT:
        return f"PASS, paced with {100 * share:.1f} % overruns"
    return "PASS"


def write_summary(scene: Scene, result: RunResult, out_dir, plots: bool = True,
                  duration_s: float | None = None, tel: dict | None = None) -> dict:
    """summary.json, and with ``plots`` the PNG plots and report.md (a campaign's runs leave them out).

    ``duration_s``: the simulated time the run was asked for (default the scenario's). The summary says PASS only
    when the stand can vouch for the record (``unvouched``) and every criterion holds; a run whose record is not
    whole although the loop called it completed is reported aborted. ``tel``: the run's telemetry as
    ``stand.telemetry.load`` reads it from ``out_dir`` after the run (default: read here), for a caller that
    needs the file's bytes too (``stand.telemetry.load_with_bytes``)."""
    out_dir = Path(out_dir)
    sc = scene.scenario
    tel = load(out_dir) if tel is None else tel
    rate = _rate_deg_s(tel)  # once: the checkpoints below and the rate criteria read it
    criteria = evaluate(sc.criteria, tel, result, sc.devices, run_faults(out_dir), rate)
    problems = unvouched(scene, result, tel, out_dir, duration_s)
    # A run with nothing to judge is not a success the stand can vouch for: no criteria, no PASS.
    passed = not problems and bool(criteria) and all(c["pass"] for c in criteria)
    status, error = result.status, result.error
    if status == "completed" and problems:
        status, error = "aborted", "the record is not whole: " + "; ".join(problems)
    checkpoints = {}
    for ts in (0.0, 600.0, 1800.0, 3600.0, sc.duration_s):
        i = int(np.searchsorted(tel["t_s"], ts - 1e-9))
        if i < len(rate):
            checkpoints[f"{ts:g}"] = round(float(rate[i]), 4)
    summary = _json_safe({
        "scenario": sc.name,
        "source": sc.source,
        "status": status,
        "error": error,
        "sim_duration_s": result.sim_duration_s,
        "wall_time_s": round(result.wall_time_s, 4),
        "realtime_factor": round(result.sim_duration_s / result.wall_time_s, 2) if result.wall_time_s > 0 else None,
        "criteria": criteria,
        "pass": passed,
        "verdict": NOT_JUDGED if status == "completed" and not problems and not criteria
        else verdict_text(passed, status, result.timing),
        "not_vouched": problems,
        "models": {
            "built": [{"model": c.model, "reason": c.reason} for c in scene.choices if c.built],
            "left_out": [{"model": c.model, "reason": c.reason} for c in scene.choices if not c.built],
        },
        "timing": result.timing,
        "rate_deg_s_at": checkpoints,
        "device_counters": result.counters,
        "telemetry_rows": int(len(tel["t_s"])),
        "compiled_paths": compiled_paths.active(),  # which hot paths ran compiled (docs/fast_paths.md)
        # What was injected and when (docs/faults.md); absent from a run that takes no faults.
        **({"faults": scene.faults.summary()} if getattr(scene, "faults", None) is not None else {}),
    })
    write_summary_file(out_dir, summary)
    if not plots:
        return summary
    try:
        made, notes = _draw_plots(scene, tel, out_dir, criteria)
        if notes:
            summary["plots_skipped"] = notes
            write_summary_file(out_dir, summary)
        write_markdown(summary, made, out_dir)
    except OSError as exc:  # a full disk: the summary above is what matters, and it is whole
        summary["report_error"] = f"plots or report.md not written: {exc.strerror or exc}"
        try:
            write_summary_file(out_dir, summary)
        except OSError:
            pass  # the summary written above stays, whole; only this note is lost
    return summary


def _draw_plots(scene: Scene, tel, out_dir: Path, criteria: list[dict]) -> tuple[list[str], list[str]]:
    """The run's plots, and a note for each one not drawn: a record too short to plot, or a plot that failed (the
    summary and the report come first). A full disk (OSError) is left to the caller."""
    sc = scene.scenario
    n = len(tel["t_s"])
    if n < 2:
        return [], [f"no plots: the telemetry has {n} row{'s' if n != 1 else ''}; a plot needs at least 2"]
    # lazy: the panorama loads matplotlib and the star catalogue, which only drawing a report needs
    from .view.export import report_panorama

    made, notes = [], []
    makers = [("rate, attitude and pointing plots", lambda: write_plots(tel, out_dir,
                                                                        rate_limits=rate_limits(sc.criteria)))]
    kinds: dict[str, list[str]] = {}  # kind -> its devices, in the scenario's order
    for d in sc.devices:
        kinds.setdefault(d.kind, []).append(d.name)
    makers += [(f"plots of the {kind} devices", lambda kind=kind, names=names: devices.get(kind).kind_plots(
        tel, names, out_dir)) for kind, names in kinds.items()]
    makers += [(f"plots of {d.name}", lambda d=d: devices.get(d.kind).plots(tel, d.name, out_dir, criteria))
               for d in sc.devices]
    makers.append(("panorama.png", lambda: [p for p in [report_panorama(out_dir, sc)] if p]))
    for what, draw in makers:
        try:
            made += draw()
        except OSError:
            raise
        except Exception as exc:  # noqa: BLE001 - one plot must not cost the report; the note says why
            notes.append(f"{what} not drawn: {type(exc).__name__}: {exc}")
    return made, notes


#: Bytes of summary.json written before t = 0: a disk that fills during the run still has room for the summary.
SUMMARY_RESERVE_BYTES = 256 * 1024


def reserve_summary(out_dir, sc) -> None:
    """Write a placeholder summary.json (not passed, "unfinished") padded to SUMMARY_RESERVE_BYTES before the run
    starts. The final summary replaces it by a rename, or, when the disk is full, is written over it in place."""
    text = json.dumps({"scenario": sc.name, "source": sc.source, "status": "unfinished", "pass": False,
                       "error": "the run ended before its summary was written (killed, or the machine stopped)",
                       "criteria": []}, indent=2) + "\n"
    with open(Path(out_dir) / "summary.json", "w") as f:
        f.write(text + " " * max(0, SUMMARY_RESERVE_BYTES - len(text)))


def write_summary_file(out_dir, summary: dict) -> None:
    """summary.json, strict JSON: through a rename; when that fails (a full disk), over the reserved file in place,
    shortened to what fits (the criteria and the verdict first) if need be."""
    path = Path(out_dir) / "summary.json"
    text = json.dumps(summary, indent=2, allow_nan=False) + "\n"
    try:
        write_text_atomic(path, text)
        return
    except OSError as exc:
        try:
            room = path.stat().st_size
        except OSError:
            raise exc from None
    if len(text.encode()) > room:
        keep = ("scenario", "source", "status", "error", "sim_duration_s", "criteria", "pass", "not_vouched")
        text = json.dumps({**{k: summary[k] for k in keep if k in summary},
                           "shortened": "summary.json was cut to fit the space reserved for it (a full disk)"},
                          allow_nan=False) + "\n"
    data = text.encode()
    if len(data) > room:
        raise OSError(f"summary.json ({len(data)} bytes) does not fit the {room} bytes reserved for it")
    with open(path, "r+b") as f:  # the blocks are already allocated: writing over them needs no free space
        f.write(data + b" " * (room - len(data)))
        f.flush()


def write_text_atomic(path: Path, text: str) -> None:
    """Write text through a temporary file and a rename, so the file is either the old one or whole."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise


def write_json_atomic(path: Path, data: dict) -> None:
    """Write JSON through a temporary file and a rename, so the file is either the old one or whole."""
    write_text_atomic(path, json.dumps(data, indent=2, default=float) + "\n")


def limit_text(c: dict) -> str:
    """``0.197 deg/s <= 0.5 deg/s``: a criterion's value against its limits, with units; a criterion without a value
    (``value`` null) says why: ``no value (the telemetry ends at t = 60 s, before t = 600 s); limit <= 0.5 deg/s``."""
    unit = f" {c['unit']}" if c.get("unit") else ""
    value = c.get("value")
    known = value is not None and math.isfinite(value)
    v = f"{value:.4g}{unit}" if known else "value"
    lim = c["limit"]
    parts = []
    if "min" in lim:
        parts.append(f"{v} >= {lim['min']:g}{unit}")
    if "max" in lim:
        parts.append(f"{v} <= {lim['max']:g}{unit}")
    at = f" at t = {c['at_s']:g} s" if "at_s" in c and c["metric"].endswith("_at") else \
        f" after t = {c['at_s']:g} s" if "at_s" in c else ""
    text = " and ".join(parts) + at
    if not known:
        text = f"no value ({c.get('reason') or 'it could not be computed'}); needs {text}"
    return text


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
    """rate.png, attitude.png and, with the reference ADCS's columns, pointing.png: the plots of every run (each
    kind draws its own: ``DeviceKind.kind_plots`` and ``plots``)."""
    # lazy: matplotlib, which only drawing a report needs
    from . import plots

    if len(tel["t_s"]) < 2:
        return []
    made = [plots.plot_rate(tel, out_dir, rate_limits or ()), plots.plot_attitude(tel, out_dir)]
    if all(c in tel for c in ("adcs_q_BN_est", "adcs_sigma3_B", "adcs_q_RN", "adcs_mode")):
        made.append(plots.plot_pointing(tel, out_dir))
    return made


def write_markdown(summary: dict, plots: list[str], out_dir: Path) -> None:
    lines = [f"# Run report: {summary['scenario']}", "",
             f"**{summary.get('verdict') or ('PASS' if summary['pass'] else 'FAIL')}** ({summary['status']})", ""]
    if summary["error"]:
        lines += [f"Error: {summary['error']}", ""]
    if summary.get("not_vouched") and summary["status"] == "completed":
        lines += ["The stand cannot vouch for this run: " + "; ".join(summary["not_vouched"]) + ".", ""]
    lines += [f"Simulated {summary['sim_duration_s']:g} s in {summary['wall_time_s']:g} s of wall time "
              f"({summary['realtime_factor']} x real time).", "", "| criterion | value against limit | pass |",
              "|---|---|---|"]
    for c in summary["criteria"]:
        lines.append(f"| {c['name']} | {limit_text(c)} | {'yes' if c['pass'] else 'NO'} |")
    lines += ["", "## Models", ""]
    lines += [f"- built `{m['model']}`: {m['reason']}" for m in summary["models"]["built"]]
    lines += [f"- left out `{m['model']}`: {m['reason']}" for m in summary["models"]["left_out"]]
    lines += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots]
    lines += [f"- {note}" for note in summary.get("plots_skipped", [])]
    (out_dir / "report.md").write_text("\n".join(lines) + "\n")
