"""``stand bench campaign``: a detumble campaign with the shipped dispersions, on 1 and 2 local workers and on a
Dask LocalCluster (2 worker processes on 127.0.0.1) that runs in a process of its own, as a cluster does for
``stand campaign --scheduler ADDRESS``: its scheduler and nannies are not counted as the client's work.

Rows: runs per minute for each; the overhead one run costs a worker beyond its loop (the ``stand.loop.run`` call),
measured between cases on the same worker so the pool's start is not in it, plus the client's serial work per run
(receiving the record, handing out the next case, writing), with a limit of 10 ms; the scaling from 1 to 2 workers
as measured here, and the scaling of a 16-worker pool computed from that overhead and the run time (Amdahl, limit
0.9); for Dask, the CPU time of the cluster's own process per run; the pool's start and the client's checks
before the first run (once per campaign, not per run); whether the three campaigns gave identical per-run results
(SHA-256 of each case's summary and telemetry), and whether one case re-run alone reproduces its record bit for bit.

The full bench is 200 runs of ``STAND_BENCH_CAMPAIGN_DURATION_S`` simulated seconds each (default 600 s: 200
runs take several minutes on two shared cores); ``--quick`` is 8 runs of the same duration.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

FULL_RUNS = 200
QUICK_RUNS = 8
DEFAULT_DURATION_S = 600.0
#: Per-run overhead allowed (ms) and the scaling a 16-worker pool must reach (issue 26).
OVERHEAD_LIMIT_MS = 10.0
POOL_WORKERS = 16
SCALING_LIMIT = 0.9


def bench_campaign(quick: bool = False) -> list[dict]:
    from stand import campaign as cm
    from stand.scenario import SCENARIO_DIR

    runs = QUICK_RUNS if quick else FULL_RUNS
    duration = float(os.environ.get("STAND_BENCH_CAMPAIGN_DURATION_S", DEFAULT_DURATION_S))
    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=duration)
    what = f"{runs} detumble runs of {duration:g} s, shipped dispersions"
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="stand-bench-campaign-") as tmp:
        results, load, records = _campaigns(cm, spec, runs, Path(tmp))
        for label, r in results.items():
            ex = r["execution"]
            rows.append({"name": f"campaign.{label}.runs_per_min", "value": ex["runs_per_min"], "unit": "runs/min",
                         "note": f"{what}; {ex['executor']} x{ex['workers']}, {ex['wall_s']:.1f} s wall "
                                 f"({_start_included(ex)}); machine load {load[label][0]:.1f} -> {load[label][1]:.1f} "
                                 f"on {os.cpu_count()} cores"})
        rows += _scaling_rows(results, records)
        for label, r in results.items():
            rows += _overhead_rows(label, r, records[label])
        ex1 = results["local_1"]["execution"]
        rows.append({"name": "campaign.checks_before_first_run", "value": round(1e3 * ex1["validate_cpu_s"], 1),
                     "unit": "ms", "note": f"CPU time ({1e3 * ex1['validate_s']:.0f} ms wall), once per campaign: the "
                                           "dispersion file, its [[faults]], every choice's values and case 0 through "
                                           "the scenario's validation on the client; every case is validated by its "
                                           "worker (the parse that runs it)"})
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


def _campaigns(cm, spec, runs: int, tmp: Path) -> tuple[dict, dict, dict]:
    """The campaign on 1 and 2 local workers and, where Dask is installed, a LocalCluster of 2: results, machine
    load before and after, and the case records (with their timings)."""
    results, load, records = {}, {}, {}
    for label, kw in (("local_1", {"workers": 1}), ("local_2", {"workers": 2})):
        before = os.getloadavg()[0]
        results[label] = cm.run_campaign(spec, tmp / label, runs, plots=False, **kw)
        load[label] = (before, os.getloadavg()[0])
    try:
        import distributed  # noqa: F401 - only whether it is there
    except ImportError:
        pass
    else:
        before = os.getloadavg()[0]
        with _ClusterProcess(workers=2) as cluster:
            idle_ms_s = cluster.idle_cpu_ms_per_s()
            # The workers warmed as the campaign warms them, twice: the second time measures what the campaign's own
            # warming (already warm workers: one scene each) adds to the workers' CPU time, which is not per run.
            cluster.ask("warm", spec)
            warm_s = cluster.ask("warm", spec)
            cpu0, workers0 = cluster.cpu_s(), cluster.ask("workers_cpu")
            results["dask_2"] = cm.run_campaign(spec, tmp / "dask_2", runs, plots=False, scheduler=cluster.address)
            workers1 = cluster.ask("workers_cpu")
            results["dask_2"]["execution"]["cluster_process"] = {
                "cpu_s": cluster.cpu_s() - cpu0, "idle_cpu_ms_per_s": idle_ms_s,
                "workers_cpu_s": [b - a - w for a, b, w in zip(workers0, workers1, warm_s, strict=True)]}
        load["dask_2"] = (before, os.getloadavg()[0])
    for label in results:
        records[label] = list(cm.finished(tmp / label).values())
    return results, load, records


class _ClusterProcess:
    """A Dask LocalCluster (``workers`` worker processes of one thread, on 127.0.0.1) in a process of its own, as
    ``stand campaign --scheduler ADDRESS`` meets a cluster: the scheduler and the workers' nannies are not in the
    client's process, whose CPU time is then the client's alone (``client_cpu_s``). The cluster's own CPU time is
    asked for over a pipe; the process ends its cluster when the pipe closes (this process ended, or ``close``)."""

    def __init__(self, workers: int):
        import multiprocessing

        from stand.campaign import DASK_HTTP_ADDRESS

        ctx = multiprocessing.get_context("spawn")
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_cluster_main, args=(child, workers, DASK_HTTP_ADDRESS),
                                name="stand-bench-dask-cluster")
        self.proc.start()
        child.close()
        try:
            self.address = self.conn.recv() if self.conn.poll(120.0) else None
        except EOFError:  # the process ended before its cluster answered
            self.address = None
        if self.address is None:
            self.close()
            raise RuntimeError(f"the bench's Dask LocalCluster did not start within 120 s (its process: "
                               f"{'still running' if self.proc.is_alive() else f'exit code {self.proc.exitcode}'})")

    def cpu_s(self) -> float:
        """The cluster process's CPU time so far (the scheduler's and the nannies'), s."""
        return self.ask("cpu")

    def ask(self, what: str, *args):
        """``cpu``: as ``cpu_s``; ``workers_cpu``: the CPU time so far of the worker processes and of their event loop
        threads, s; ``warm`` (a spec): the workers warmed as a campaign of it warms them, and what that cost them
        (the same two), s."""
        self.conn.send((what, *args))
        return self.conn.recv()

    def idle_cpu_ms_per_s(self, wait_s: float = 1.0) -> float:
        """The cluster process's CPU time per second of wall time while no case runs (its periodic work), ms/s,
        after as long again for its start to settle."""
        import time

        time.sleep(wait_s)
        cpu0, t0 = self.cpu_s(), time.monotonic()
        time.sleep(wait_s)
        return 1e3 * (self.cpu_s() - cpu0) / (time.monotonic() - t0)

    def close(self) -> None:
        self.conn.close()
        self.proc.join(60.0)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _cluster_main(conn, workers: int, http_address: str) -> None:
    """The cluster process of ``_ClusterProcess``: answers its questions (``ask``) until the pipe closes. Its workers
    run with the settings docs/campaigns.md recommends for a campaign's workers (``WORKER_CONFIG``, and
    ``NANNY_CONFIG`` for the environment their nannies start them in)."""
    import os
    import time

    from stand.campaign.dask_executor import NANNY_CONFIG, WORKER_CONFIG, _warm, dask_worker_env

    # As ``dask worker`` is started (docs/campaigns.md): a worker process reads some settings when it imports Dask
    # (distributed.comm.offload), before its nanny hands it the configuration below.
    os.environ.update(dask_worker_env())
    import dask
    from distributed import Client, LocalCluster

    with dask.config.set({**WORKER_CONFIG, **NANNY_CONFIG}), \
            LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                         dashboard_address=http_address) as cluster, \
            Client(cluster, set_as_default=False) as client:  # never port 8787
        conn.send(cluster.scheduler_address)
        while True:
            try:
                what, *args = conn.recv()
            except (EOFError, OSError):
                return
            if what == "workers_cpu":
                conn.send(_workers_cpu_s(client))
            elif what == "warm":
                before = _workers_cpu_s(client)
                client.run(_warm, args[0], 0)
                conn.send([b - a for a, b in zip(before, _workers_cpu_s(client), strict=True)])
            else:
                conn.send(time.process_time())


def _workers_cpu_s(client) -> list[float]:
    """The CPU time so far of all the cluster's worker processes and of their event loop threads, s."""
    cpu = client.run(_worker_cpu_s).values()
    return [sum(c[0] for c in cpu), sum(c[1] for c in cpu)]


def _worker_cpu_s() -> tuple[float, float]:
    """On a Dask worker, by ``Client.run`` (which calls it on the worker's event loop thread): the process's CPU time
    and that thread's, s."""
    import time

    return time.process_time(), time.thread_time()


def _start_included(ex: dict) -> str:
    if ex["executor"] != "dask":
        return "pool start included"
    return ("the cluster started and its workers warmed before: the bench measures the workers' CPU time from a warm "
            "start, the worker_process_cpu row")


def _steady_rate(records: list[dict]) -> float:
    """Runs per minute from the first case's start to the last one's end (the pool's start left out)."""
    t = [r["timing"] for r in records]
    span = max(x["worker_end"] for x in t) - min(x["worker_start"] for x in t)
    return 60.0 * len(t) / span


def per_run_overhead_s(result: dict) -> tuple[float, float, float]:
    """(the mean loop time T, the worker's overhead per run o, the client's serial work per run c), s: o is
    measured between cases on the same worker (``between_runs``), c is the client's writing of each case (the
    rename alone where the worker wrote it; the client's other work per case is in the CPU time only)."""
    loop = result["loop_time_s"]["mean"]
    o = result["overhead_s"]["between_runs_s"].get("mean", 0.0)
    c = result["execution"]["client_write_s"]
    return loop, o, c


def per_run_overhead_cpu_s(result: dict) -> tuple[float, float, float]:
    """The same three in CPU time (``time.process_time`` of the worker and of the client), which the other loads
    of a shared machine do not inflate: on an idle machine with a core per worker, wall time is this. o is the
    case's CPU time in the worker beyond its loop (drawing and validating the case, build, summary, digest, writing
    the record); c the client's CPU time while the workers run, per run (receiving, handing out, writing, the progress
    line), the workers' start left out."""
    ex = result["execution"]
    loop = result["loop_cpu_s"]["mean"]
    o = result["overhead_s"]["overhead_cpu_s"].get("mean", 0.0) + ex["worker_record_write_cpu_s"]
    c = ex["client_cpu_s"] / max(1, ex["runs_this_session"])
    return loop, o, c


def amdahl_efficiency(loop_s: float, worker_s: float, client_s: float, workers: int) -> float:
    """Scaling efficiency of ``workers`` (speed-up / workers) when each run costs its worker ``loop_s + worker_s``
    and the client ``client_s`` that no worker shares: E(N) = T / (T + o + N c)."""
    return loop_s / (loop_s + worker_s + workers * client_s)


def _scaling_rows(results: dict, records: dict) -> list[dict]:
    r1, r2 = results["local_1"]["execution"], results["local_2"]["execution"]
    steady = _steady_rate(records["local_2"]) / (2 * _steady_rate(records["local_1"]))
    loop, o, c = per_run_overhead_cpu_s(results["local_2"])
    e16 = amdahl_efficiency(loop, o, c, POOL_WORKERS)
    wall = per_run_overhead_s(results["local_2"])
    return [
        {"name": "campaign.scaling_efficiency_1_to_2", "value": round(r2["runs_per_min"] / (2 * r1["runs_per_min"]), 3),
         "unit": "", "note": "rate with 2 workers / (2 x rate with 1), pool start included; 1.0 is perfect, on 2 "
                             "cores shared with whatever else runs"},
        {"name": "campaign.scaling_efficiency_2_measured", "value": round(steady, 3), "unit": "",
         "note": "the same from the first case's start to the last one's end (the pool's start left out); a run's "
                 "loop slows down when the two workers share the machine's cores with other loads"},
        {"name": f"campaign.scaling_efficiency_{POOL_WORKERS}_computed", "value": round(e16, 3), "unit": "",
         "limit": f">= {SCALING_LIMIT:g}", "pass": e16 >= SCALING_LIMIT,
         "note": f"E(N) = T / (T + o + N c) with N = {POOL_WORKERS}, T = {loop * 1e3:.0f} ms the mean loop "
                 f"(stand.loop.run), o = {o * 1e3:.2f} ms a run's overhead on its worker, c = {c * 1e3:.2f} ms the "
                 "client's serial work per run (receiving, handing out, writing), CPU times of the 2-worker "
                 f"campaign (from its wall times, inflated by this machine's load, c the writing alone: "
                 f"{amdahl_efficiency(*wall, POOL_WORKERS):.3f}); each case is drawn and validated by its worker (in "
                 "o); a 16-worker pool also starts 16 processes once (the pool_start rows) after the client's checks "
                 "(checks_before_first_run), neither counted per run"},
    ]


def _overhead_rows(label: str, r: dict, records: list[dict]) -> list[dict]:
    loop, o, c = per_run_overhead_s(r)
    _, o_cpu, c_cpu = per_run_overhead_cpu_s(r)
    total_ms = (o_cpu + c_cpu) * 1e3
    run = r["run_time_s"]["mean"]
    ex = r["execution"]
    parts = {"build": r["overhead_s"]["build_s"].get("mean", 0.0),
             "summary": r["overhead_s"]["summary_s"].get("mean", 0.0), "record": ex["worker_record_write_cpu_s"],
             "transfer": ex["transfer_s"], "write": ex["client_write_s"]}
    first = min(x["timing"]["worker_start"] for x in records)
    rows = [
        {"name": f"campaign.{label}.run_loop_mean", "value": round(loop, 4), "unit": "s",
         "note": f"the stand.loop.run call per run; {1e3 * (loop - run):.1f} ms of it its own start and end "
                 "(devices' threads, telemetry file), the rest the simulation"},
        {"name": f"campaign.{label}.overhead_per_run", "value": round(total_ms, 2), "unit": "ms",
         "limit": f"<= {OVERHEAD_LIMIT_MS:g}", "pass": total_ms <= OVERHEAD_LIMIT_MS,
         "note": f"CPU time: the worker's {o_cpu * 1e3:.2f} ms beyond the loop (drawing and validating the case, "
                 f"build, summary, digest, writing the record) + the client's {c_cpu * 1e3:.2f} ms (receiving, "
                 f"handing out, writing). Wall time on this machine's load: {o * 1e3:.1f} ms on the worker between "
                 f"one case's loop and the next case's start (the record's way back and the next case's included) + "
                 f"{c * 1e3:.1f} ms on the client. The pool's start is in neither" + _client_threads(ex)},
        {"name": f"campaign.{label}.overhead_parts", "value": round(sum(parts.values()) * 1e3, 2), "unit": "ms",
         "note": ", ".join(f"{k} {v * 1e3:.1f} ms" for k, v in parts.items())
         + " (means per run; build includes drawing and validating the case, record is the worker's CPU time writing "
           "case.json (0 where the client writes it), transfer runs from the worker's end to the client's receipt, "
           "write is the client's (the rename alone where the worker wrote the case))"},
    ]
    rows += _cluster_row(label, r)
    if label.startswith("local"):
        rows.append({"name": f"campaign.{label}.pool_start", "value": round(first - _campaign_start(r), 2),
                     "unit": "s", "note": "from the executor's start to the first case's start: spawned worker "
                                          "processes importing the stand, once per campaign"})
    return rows


def _client_threads(ex: dict) -> str:
    """For Dask: how much of the client's CPU time per run is its own thread's, how much its event loop thread's."""
    if ex["executor"] != "dask":
        return ""
    n = max(1, ex["runs_this_session"])
    own, loop = ex["client_thread_cpu_s"] / n, (ex["client_cpu_s"] - ex["client_thread_cpu_s"]) / n
    return (f". Of the client's: its own thread {own * 1e3:.2f} ms, the Dask client's event loop thread "
            f"{loop * 1e3:.2f} ms (the scheduler and the nannies run in the cluster's own process: the "
            "cluster_process_cpu row); the worker's beyond the local pool's is Dask's own handling of a task in the "
            "worker process. The workers run the settings docs/campaigns.md recommends (profiler off, slower "
            "monitors: the worker_process_cpu row), and what their event loop does while a case's loop runs is "
            "counted there, not here")


def _cluster_row(label: str, r: dict) -> list[dict]:
    """The CPU time of the Dask cluster's own process (scheduler and nannies) per run, and how much of it is its
    periodic work, which runs whether cases run or not."""
    cluster = r["execution"].get("cluster_process")
    if cluster is None:
        return []
    n = max(1, r["execution"]["runs_this_session"])
    per_run_s = cluster["cpu_s"] / n
    periodic_s = cluster["idle_cpu_ms_per_s"] * r["execution"]["wall_s"] / n / 1e3
    note = (f"CPU time of the LocalCluster's own process (the Dask scheduler, the {r['execution']['workers']} "
            "workers' nannies and the idle client that asks the workers their CPU times) during the campaign, per "
            "run, the workers' warming included; not the client's. Its "
            f"periodic work alone is {cluster['idle_cpu_ms_per_s']:.1f} ms per second of wall time (measured for 1 s "
            f"before the campaign), {periodic_s * 1e3:.1f} ms per run at this campaign's pace. A deployment runs the "
            "scheduler apart from the client and each nanny beside its worker")
    rows = [{"name": f"campaign.{label}.cluster_process_cpu_per_run", "value": round(per_run_s * 1e3, 2),
             "unit": "ms", "note": note}]
    if "workers_cpu_s" in cluster:
        process_s, event_loop_s = (x / n for x in cluster["workers_cpu_s"])
        from stand.campaign.dask_executor import WORKER_CONFIG

        settings = ", ".join(f"{k.removeprefix('distributed.')} {v}" for k, v in WORKER_CONFIG.items())
        rows.append({"name": f"campaign.{label}.worker_process_cpu_per_run", "value": round(process_s * 1e3, 1),
                     "unit": "ms", "note": f"CPU time of the Dask worker processes per run, everything included (the "
                     f"loop's {r['loop_cpu_s']['mean'] * 1e3:.1f} ms, the overhead row's worker part; the workers' "
                     f"warming left out): {(process_s - r['loop_cpu_s']['mean']) * 1e3:.2f} ms beyond the loop. Of it "
                     f"the workers' event loop threads {event_loop_s * 1e3:.2f} ms (Dask's handling of each task and "
                     "its periodic work), part of it while the case's loop runs, which the case's own measure counts "
                     f"as loop. The workers run the settings docs/campaigns.md recommends ({settings}), which the "
                     "overhead row measures too"})
    return rows


def _campaign_start(result: dict) -> float:
    return result["execution"]["started_at"]
