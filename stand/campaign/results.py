"""Results: campaign.json from the cases on disk (pass rates with Clopper-Pearson intervals, metric
distributions, worst cases)."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np

from ..report import write_json_atomic
from .fault_groups import group
from .store import finished

#: Worst cases listed per criterion.
WORST = 5
CONFIDENCE = 0.95


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
                for k in ("wait_s", "build_s", "summary_s", "transfer_s", "write_s", "overhead_cpu_s", "write_cpu_s")}
    overhead["between_runs_s"] = _stats(between_runs(records))
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
        # A campaign of faults: pass rates by the type and by the device of the faults the cases ran with.
        **({"by_fault_type": group(records, "type", clopper_pearson),
            "by_fault_device": group(records, "device", clopper_pearson)}
           if any(r.get("faults") for r in records) else {}),
        "failed_cases": [{"case": r["index"], "status": r.get("status"), "error": r.get("error"),
                          "failed": [c["name"] for c in r.get("criteria", []) if not c["pass"]]}
                         for r in records if not r.get("passed")],
        "run_time_s": _stats(run_s),
        "loop_time_s": _stats([t["loop_s"] for t in timing if "loop_s" in t]),
        "loop_cpu_s": _stats([t["loop_cpu_s"] for t in timing if "loop_cpu_s" in t]),
        "overhead_s": overhead,
        "execution": ex,
        "cases": [{"case": r["index"], "seed": r["seed"], "status": r.get("status"), "pass": r.get("passed"),
                   "values": r.get("values"), "criteria": {c["name"]: c["value"] for c in r.get("criteria", [])},
                   **({"faults": [f"{f['type']}@{f['device']}" for f in r["faults"]]} if r.get("faults") else {}),
                   "digest": r.get("digest")} for r in records],
    }
    write_json_atomic(out / "campaign.json", result)
    return result


def between_runs(records: list[dict]) -> list[float]:
    """What each run cost its worker beyond its loop (the ``stand.loop.run`` call), s: from the start of one case
    to the start of the next on the same worker process, less the first one's loop. Parse, build, summary, the
    record's way back and the client's handing over of the next case are in it; the pool's start is not."""
    by_worker: dict[tuple, list[dict]] = {}
    for r in records:
        t = r.get("timing", {})
        if "worker_start" in t and r.get("pid") is not None:
            by_worker.setdefault((r.get("host"), r["pid"]), []).append(t)
    gaps = []
    for times in by_worker.values():
        times.sort(key=lambda t: t["worker_start"])
        for a, b in itertools.pairwise(times):
            if "loop_s" in a:
                gaps.append(b["worker_start"] - a["worker_start"] - a["loop_s"])
    return gaps


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
