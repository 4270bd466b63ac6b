"""``stand bench campaign``: a detumble campaign with the shipped dispersions, on 1 and 2 local workers and on a
Dask LocalCluster (2 worker processes on 127.0.0.1).

Rows: runs per minute for each, the scaling efficiency from 1 to 2 workers, the time one run costs a worker
beyond its own loop (start, scatter, gather, write; the campaign's wall time x workers / runs - the mean loop
time) with its parts, whether the three campaigns gave identical per-run results (SHA-256 of each case's summary
and telemetry), and whether one case re-run alone reproduces its record bit for bit.

The full bench is 200 runs of ``STAND_BENCH_CAMPAIGN_DURATION_S`` simulated seconds each (default 600 s: 200
full-orbit runs take most of an hour on two shared cores); ``--quick`` is 12 runs of 60 s.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

FULL_RUNS = 200
DEFAULT_DURATION_S = 600.0


def bench_campaign(quick: bool = False) -> list[dict]:
    from stand import campaign as cm
    from stand.scenario import SCENARIO_DIR

    runs = 12 if quick else FULL_RUNS
    duration = 60.0 if quick else float(os.environ.get("STAND_BENCH_CAMPAIGN_DURATION_S", DEFAULT_DURATION_S))
    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=duration)
    what = f"{runs} detumble runs of {duration:g} s, shipped dispersions"
    rows: list[dict] = []
    results = {}
    with tempfile.TemporaryDirectory(prefix="stand-bench-campaign-") as tmp:
        load = {}
        for label, kw in (("local_1", {"workers": 1}), ("local_2", {"workers": 2})):
            before = os.getloadavg()[0]
            results[label] = cm.run_campaign(spec, Path(tmp) / label, runs, plots=False, **kw)
            load[label] = (before, os.getloadavg()[0])
        try:
            from distributed import LocalCluster
        except ImportError:
            LocalCluster = None
        if LocalCluster is not None:
            before = os.getloadavg()[0]
            with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                              dashboard_address=cm.DASK_HTTP_ADDRESS) as cluster:  # never port 8787
                results["dask_2"] = cm.run_campaign(spec, Path(tmp) / "dask_2", runs, plots=False,
                                                    scheduler=cluster.scheduler_address)
            load["dask_2"] = (before, os.getloadavg()[0])
        for label, r in results.items():
            ex = r["execution"]
            rows.append({"name": f"campaign.{label}.runs_per_min", "value": ex["runs_per_min"], "unit": "runs/min",
                         "note": f"{what}; {ex['executor']} x{ex['workers']}, {ex['wall_s']:.1f} s wall "
                                 f"(pool start included); machine load {load[label][0]:.1f} -> {load[label][1]:.1f} "
                                 f"on {os.cpu_count()} cores"})
        r1, r2 = results["local_1"]["execution"], results["local_2"]["execution"]
        rows.append({"name": "campaign.scaling_efficiency_1_to_2", "value": round(r2["runs_per_min"]
                                                                                   / (2 * r1["runs_per_min"]), 3),
                     "unit": "", "note": "rate with 2 workers / (2 x rate with 1); 1.0 is perfect, on 2 cores shared "
                                         "with whatever else runs"})
        for label, r in results.items():
            loop = r["run_time_s"]["mean"]
            rows.append({"name": f"campaign.{label}.run_loop_mean", "value": round(loop, 4), "unit": "s",
                         "note": "the run's own loop (stand.loop.run wall time)"})
            over = r["execution"]["overhead_per_run_s"]
            rows.append({"name": f"campaign.{label}.overhead_per_run", "value": over, "unit": "s",
                         "note": f"beyond the loop, per run and worker ({100 * over / loop:.0f} % of it)"})
            parts = {k: r["overhead_s"][k].get("mean", 0.0) for k in ("build_s", "summary_s", "transfer_s", "write_s")}
            rows.append({"name": f"campaign.{label}.overhead_parts", "value": round(sum(parts.values()), 4),
                         "unit": "s", "note": ", ".join(f"{k[:-2]} {v * 1e3:.1f} ms" for k, v in parts.items())
                         + " (means per run; transfer runs from the worker's end to the client's receipt, so it "
                           "overlaps other work and the parts need not add up to the overhead)"})
        v = results["local_1"]["execution"]["validate_s"]
        rows.append({"name": "campaign.validation_before_first_run", "value": round(v, 2), "unit": "s",
                     "note": f"every case's scenario parsed on the client ({1e3 * v / runs:.1f} ms per case), not "
                             "counted in the rates above"})
        digests = {label: [c["digest"] for c in r["cases"]] for label, r in results.items()}
        same = all(d == digests["local_1"] for d in digests.values())
        rows.append({"name": "campaign.identical_per_run_results", "value": int(same), "unit": "",
                     "note": f"SHA-256 of every case's summary and telemetry equal across {', '.join(digests)}",
                     "pass": same})
        k = int(np.argmax([c["criteria"].get("detumbled", 0.0) for c in results["local_1"]["cases"]]))
        again = cm.run_case(spec.case(k))
        rec = again["record"]
        ok = rec["digest"] == results["local_1"]["cases"][k]["digest"]
        rows.append({"name": "campaign.rerun_case_bit_identical", "value": int(ok), "unit": "",
                     "note": f"case {k} (the worst) re-run alone in this process", "pass": ok})
        r1 = results["local_1"]
        rows.append({"name": "campaign.pass_rate", "value": round(r1["pass_rate"], 3), "unit": "",
                     "note": f"{r1['passed']}/{r1['runs']}, 95 % interval {r1['pass_rate_ci95'][0]:.3f} to "
                             f"{r1['pass_rate_ci95'][1]:.3f} (criteria of the full orbit applied at {duration:g} s)"})
    return rows
