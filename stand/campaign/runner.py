"""Run (or resume) a campaign: validate, pick an executor, write each case as it arrives, aggregate."""

from __future__ import annotations

import logging
import math
import sys
import time
from pathlib import Path

from ..errors import ScenarioError
from .case import _error_record, case_task
from .dask_executor import _Dask, _Lost
from .errors import CampaignError
from .pool import WORKER_DEATHS, _Inline, _LocalPool
from .results import aggregate
from .spec import MAX_RUNS, Spec, validate
from .store import TOKEN_FILE, _prepare, _write_case, finished, part_dir, remove_parts, write_token
from .summary_report import write_report

log = logging.getLogger(__name__)

#: Default wall-clock limit of one case (``--case-timeout``): the backstop for a case that hangs. A full-orbit
#: detumble takes 5 to 20 s on a loaded 2-core machine; an hour leaves room for long scenarios on slow workers.
CASE_TIMEOUT_S = 3600.0
MAX_CASE_TIMEOUT_S = 30 * 86400.0


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
    t0, cpu0 = time.time(), time.process_time()
    # What is wrong for every case is refused before anything runs: the dispersion file, its [[faults]], every
    # value of every choice, and the first case. Each case is then drawn and validated by its worker, where the
    # parse that runs it is its validation: a value the scenario refuses is that case's error, with the same
    # sentence, and the client's serial work per case is writing it (docs/campaigns.md, "Measured").
    validate(spec, 1)
    validate_cpu_s = time.process_time() - cpu0
    _prepare(out, spec)
    t_ready = time.time()
    done = {k: r for k, r in finished(out).items() if k < runs}
    resumed = len(done)
    bar = CampaignProgress(runs, progress)
    for rec in done.values():
        bar.add(rec, resumed=True)
    todo = _tasks(out, runs, done, remote=scheduler is not None)
    if scheduler is not None:
        executor = _Dask(scheduler, spec, case_timeout_s)
    elif workers == 0:
        executor = _Inline(spec)
    else:
        executor = _LocalPool(workers, case_timeout_s, worker_deaths, spec)
    execution = {"executor": executor.name, "workers": executor.workers, "case_timeout_s": case_timeout_s,
                 "resumed": resumed, "validate_s": round(t_ready - t0, 3),
                 "validate_cpu_s": round(validate_cpu_s, 4), "started_at": t_ready, "lost": [],
                 **({"scheduler": executor.address} if scheduler is not None else {}),
                 **getattr(executor, "execution", {})}
    if "dask_worker_advice" in execution:
        log.warning("campaign %s: %s", out, execution["dask_worker_advice"])
    stopped = True
    cpu_collect, thread_collect = time.process_time(), time.thread_time()
    log.info("campaign %s: %d case(s) to run on %s (%s worker(s))", out, len(todo), executor.name, executor.workers)
    bar.show()
    try:
        _collect(executor, spec, todo, out, done, bar, execution)
        stopped = False
    finally:
        # The client's CPU time per case while the workers run (receiving, handing out, writing, the progress line),
        # the workers' start and end left out: its serial work per run, which bounds how many workers it can keep
        # busy. ``client_thread_cpu_s``: this thread's alone (a Dask client's own event loop thread, and a
        # LocalCluster's scheduler in it, are in client_cpu_s only).
        client_cpu_s = time.process_time() - cpu_collect - executor.start_cpu_s
        thread_cpu_s = time.thread_time() - thread_collect - executor.start_thread_cpu_s
        executor.close(cancel=stopped)
        (out / TOKEN_FILE).unlink(missing_ok=True)
        remove_parts(out)
        bar.show(final=True)
        execution.update(runs_this_session=bar.new, wall_s=round(time.time() - t_ready, 3),
                         client_cpu_s=round(client_cpu_s, 4), client_thread_cpu_s=round(thread_cpu_s, 4))
        if stopped:  # campaign.json must not keep saying "running": what is recorded, counted as incomplete
            execution["stopped"] = True
            aggregate(out, runs, execution)
    result = aggregate(out, runs, execution)
    if plots:
        write_report(out, result)
    return result


def _tasks(out: Path, runs: int, done: dict, remote: bool) -> list[dict]:
    """The cases left to run, each its index (its worker draws it from the spec) and where to write it: a worker on
    this machine writes the run once, where the campaign keeps it; a Dask worker too where it sees the campaign
    folder (``token``: this machine, or a shared file system), else it sends the run's files back."""
    token = {"token": write_token(out)} if remote else {}
    return [{"index": k, "dest": str(part_dir(out.absolute(), k)), **token} for k in range(runs) if k not in done]


class _Account:
    """Means over a session's answers: from a worker's end to the client's receipt (``transfer_s``), the client's
    writing of the case (``client_write_s``, wall time: the rename alone when the worker wrote the case), and the
    CPU time a worker took to write its record (``worker_record_write_cpu_s``: its own record cannot hold it)."""

    def __init__(self):
        self.n = self.n_written = 0
        self.transfer_s = self.write_s = self.record_cpu_s = 0.0

    def add(self, rec: dict, write_s: float) -> None:
        timing = rec["timing"]
        self.n, self.write_s = self.n + 1, self.write_s + write_s
        self.transfer_s += timing["transfer_s"]
        if "record_write_cpu_s" in timing:
            self.n_written, self.record_cpu_s = self.n_written + 1, self.record_cpu_s + timing["record_write_cpu_s"]

    def means(self) -> dict:
        return {"transfer_s": self.transfer_s / self.n, "client_write_s": self.write_s / self.n,
                "worker_record_write_cpu_s": self.record_cpu_s / max(1, self.n_written)}


def _collect(executor, spec: Spec, todo: list[dict], out: Path, done: dict, bar: CampaignProgress,
             execution: dict) -> None:
    """Write every case the executor answers: its files, or an error record with the reason (the case's values
    drawn again here: its worker did not answer). ``execution`` gets the lost cases and ``_Account``'s means."""
    lost, account = execution["lost"], _Account()
    for index, result, reason in executor.results(todo):
        if isinstance(reason, _Lost):  # the infrastructure failed, not the case: the next invocation runs it
            lost.append(f"case {index}: {reason}")
            log.warning("case %d lost (%s): the next invocation runs it again", index, reason)
            continue
        if result is None:
            log.info("case %d recorded as an error: %s", index, reason)
            result = {"record": _error_record(case_task(spec, index), reason), "files": {}}
        received = time.time()
        rec = _write_case(out, result, received)
        account.add(rec, time.time() - received)
        execution.update(account.means())
        done[index] = rec
        bar.add(rec)
        bar.show()
