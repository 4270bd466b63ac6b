"""One case: run in a temporary folder (in a worker or this process), its record, files and digest."""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import secrets
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

from .. import devices
from ..compose import build
from ..loop import run
from ..report import write_summary
from ..scenario import parse
from ..telemetry import load_with_bytes
from .errors import CampaignError
from .fault_groups import started
from .spec import Spec, dispersions_of, parse_case
from .store import sees_campaign, write_record

log = logging.getLogger(__name__)

#: Exit code of a Dask worker process ended by the per-case limit.
EXIT_OVERRUN = 70

#: Files of a run that travel back from the worker (plots are drawn for the campaign, not per run).
RUN_FILES = ("summary.json", "events.jsonl", "telemetry/schema.json", "telemetry/rows.f64")
#: The file beside a Dask worker's whole case that holds its record's writing CPU time (``publish``), removed by the
#: client as it takes the case.
DONE_TIMING = ".record_write_cpu_s"
#: Summary keys that depend on the wall clock, left out when two runs of a case are compared.
WALL_CLOCK_KEYS = ("wall_time_s", "realtime_factor", "source")

# One run at a time per process: emulated buses (python-can ``virtual``) are process-wide names, and a Dask
# worker may run several tasks on threads.
_RUN_LOCK = threading.Lock()


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
            "faults": task.get("faults", []),
            "host": os.uname().nodename, "pid": os.getpid(), "status": "error", "passed": False, "error": reason,
            "criteria": [], "timing": {"worker_start": now if t_start is None else t_start, "worker_end": now}}


def _raised(exc: BaseException) -> str:
    """One line for what a run raised; a SystemExit says so (its text alone is just the exit code); a
    CampaignError (a case the scenario refuses) is the campaign's own sentence, as the command line shows it."""
    if isinstance(exc, CampaignError):
        return str(exc)
    if isinstance(exc, SystemExit):
        return f"SystemExit: the run's code called sys.exit({exc.code!r})"
    return f"{type(exc).__name__}: {exc}"


def case_task(spec: Spec, index: int, **extra) -> dict:
    """The task of case ``index`` drawn where it runs (a worker holds the spec: only the index travels), with the
    spec, so the parse that runs it is also its validation (``parse_case``: a refused value names its dispersion)."""
    return {**spec.case(index, dispersions_of(spec)), **extra, "spec": spec}


def run_case(task: dict, *, interruptible: bool = False) -> dict:
    """Run one case and return its record and files (what a worker sends back).

    Where the task names a ``dest`` folder (a worker on the client's machine: the local pool, or this process), the
    run is written there once, as the campaign keeps it, and only the record travels back (``dir``); elsewhere (a
    Dask worker, perhaps on another machine) the run goes to a temporary folder and its files travel back.
    Anything the run raises, SystemExit and other BaseExceptions included, is recorded as an error case: a
    plug-in's ``sys.exit(0)`` must not end a campaign. ``interruptible`` (the case runs in the operator's own
    process): Ctrl-C stops the campaign instead of being recorded.
    ``task`` is a case's (``Spec.case``, or ``case_task`` with its spec), or ``{"index": k, "spec": spec, ...}``:
    the case is then drawn here, in its worker, and counted in its overhead.
    """
    t_start, cpu_start = time.time(), time.process_time()
    if "data" not in task:
        task = case_task(task["spec"], task["index"], **{k: v for k, v in task.items() if k not in ("spec", "index")})
    part, dest = task.get("dest"), _destination(task)
    task = {**task, "dest": dest}
    with _RUN_LOCK, (contextlib.nullcontext(dest) if dest else tempfile.TemporaryDirectory(prefix="stand-case-")
                     ) as tmp:
        watchdog = _watchdog(task)
        t_lock = time.time()
        out = Path(dest) if dest else Path(tmp) / "run"
        try:
            if dest:
                shutil.rmtree(out, ignore_errors=True)  # what a worker that died running this case left
            out.mkdir(parents=True)
            rec, files = _run_into(task, out, interruptible, t_start, t_lock)
        except BaseException as exc:  # one failing run is recorded; the campaign goes on
            if dest:
                shutil.rmtree(out, ignore_errors=True)
            if interruptible and isinstance(exc, KeyboardInterrupt):
                raise
            return {"record": _error_record(task, _raised(exc), t_start), "files": {}}
        finally:
            if watchdog is not None:
                watchdog.cancel()
    rec["timing"]["worker_end"] = time.time()
    # The CPU time of this process for the case beyond its loop, which a loaded machine does not inflate.
    rec["timing"]["overhead_cpu_s"] = time.process_time() - cpu_start - rec["timing"]["loop_cpu_s"]
    if not dest:
        return {"record": rec, "files": files}
    # The record too is written where the campaign keeps the case, last, by the worker (not by the client, whose
    # work per case no other process shares); the client's rename makes the folder count. Its CPU time travels
    # back with the record, not in the file (it is measured once the file is written).
    cpu_write = time.process_time()
    try:
        write_record(out, rec)
    except OSError:  # the client writes it, and says so if it cannot either
        return {"record": rec, "files": files, "dir": str(out)}
    timing = {**rec["timing"], "record_write_cpu_s": time.process_time() - cpu_write}
    if dest != part:  # a Dask worker's own folder: handed to the client through the campaign folder, not over Dask
        return {"record": {**rec, "timing": timing}, "files": files, "written": True,
                "dir": publish(out, part, timing["record_write_cpu_s"])}
    return {"record": {**rec, "timing": timing}, "files": files, "dir": str(out), "written": True}


def publish(folder: Path, part: str, record_write_cpu_s: float) -> str:
    """Make a Dask worker's whole case ``folder`` (``NNNNN.part.*``, its ``case.json`` written) the case's
    ``NNNNN.part.done`` (``done_dir``), with the CPU time its record took to write beside it (``DONE_TIMING``: the
    record cannot hold it), and return that folder (``folder`` itself where that fails). The client, told by the
    scheduler that the case's task ended, takes the case from there (``take_done``) instead of fetching its record
    through the scheduler. The rename is atomic: the client sees a whole case or none. Where a second run of the
    case (the scheduler may start a case twice) made it first, this one goes: both are the same case, bit for
    bit."""
    done, timing = done_dir(part), folder / DONE_TIMING
    try:
        timing.write_text(repr(record_write_cpu_s))
        os.rename(folder, done)
        return done
    except OSError:
        if os.path.isfile(os.path.join(done, "case.json")):  # another run of this case made it first
            shutil.rmtree(folder, ignore_errors=True)
            return done
    # Neither (a full disk, a rename refused): the case stays in this worker's folder, as before, and the client
    # fetches its record through the scheduler and renames the folder.
    timing.unlink(missing_ok=True)
    return str(folder)


def done_dir(part: str) -> str:
    """Where a Dask worker leaves case ``part`` (its ``NNNNN.part`` path) whole for the client (``publish``)."""
    return f"{part}.done"


def take_done(part: str) -> dict | None:
    """The result of case ``part`` (its ``NNNNN.part`` path) that a Dask worker left whole (``publish``), the
    worker's CPU time writing its record taken back into it (and its file removed from the case's folder); None where
    no worker left it there (it does not see the campaign folder, or the case ended in an error record)."""
    done = Path(done_dir(part))
    try:
        cpu_s = float((done / DONE_TIMING).read_text())
        rec = json.loads((done / "case.json").read_bytes())
        os.unlink(done / DONE_TIMING)
    except (OSError, ValueError):
        return None
    rec["timing"]["record_write_cpu_s"] = cpu_s
    return {"record": rec, "files": {}, "dir": str(done), "written": True}


def _destination(task: dict) -> str | None:
    """Where this worker writes the case: ``dest`` (a local worker); with a ``token`` (a Dask worker), a folder of
    its own beside ``dest`` if it sees the campaign folder (the client's machine, or a shared file system), else
    None: a temporary folder, and the files travel back."""
    dest, token = task.get("dest"), task.get("token")
    if dest is None or token is None:
        return dest
    if not sees_campaign(dest, token):
        return None
    return f"{dest}.{os.getpid()}-{secrets.token_hex(4)}"  # the scheduler may run a case twice at once


def _run_into(task: dict, out: Path, interruptible: bool, t_start: float, t_lock: float) -> tuple[dict, dict]:
    """Parse, build, run and summarise the case into ``out``; its record and (without ``dest``) its files."""
    # A case of a spec: the parse is its validation, and a value the scenario refuses names its dispersion.
    sc = parse_case(task["spec"], task) if "spec" in task else parse(task["data"], task["source"])
    # out_dir: the estimate before t = 0 checks the free space where this case's telemetry goes (not ./runs).
    with build(sc, None, Path(task["base"]), out_dir=out) as scene:
        t_built, cpu_built = time.time(), time.process_time()
        result = run(scene, out, progress=False)
        t_ran, cpu_ran = time.time(), time.process_time()
    if interruptible and result.status == "stopped":
        raise KeyboardInterrupt  # the operator's Ctrl-C reached the loop: stop, do not record
    # The telemetry read once: the summary judges its columns, the digest hashes the same bytes.
    try:
        tel, rows = load_with_bytes(out)
    except FileNotFoundError:  # no telemetry at all: the summary says so (load raises the same again there)
        tel, rows = None, b""
    summary = write_summary(scene, result, out, plots=False, tel=tel)
    files: dict[str, bytes] = {}
    if task.get("dest"):
        _keep_only_run_files(out)
    else:
        for name in RUN_FILES:
            p = out / name
            if p.exists():
                files[name] = p.read_bytes()
    rec = {"index": task["index"], "seed": task["seed"], "values": task["values"], "scalars": task["scalars"],
           "host": os.uname().nodename, "pid": os.getpid(),
           "faults": started(task.get("faults", []), summary),
           "status": summary["status"], "passed": bool(summary["pass"]), "error": summary["error"],
           "criteria": [{k: c.get(k) for k in ("name", "metric", "value", "unit", "limit", "pass")}
                        for c in summary["criteria"]],
           "rate_deg_s_at": summary.get("rate_deg_s_at", {}),
           "digest": digest(summary, rows)}
    t_end = time.time()
    rec["timing"] = {"worker_start": t_start, "wait_s": t_lock - t_start, "build_s": t_built - t_lock,
                     "run_s": result.wall_time_s, "loop_s": t_ran - t_built, "loop_cpu_s": cpu_ran - cpu_built,
                     "summary_s": t_end - t_ran}
    return rec, files


def _keep_only_run_files(out: Path, prefix: str = "") -> None:
    """Leave the campaign's files of a run (RUN_FILES) and nothing else, as the files sent back would be. One
    directory listing per folder that holds a kept file (``prefix``: the folder's path in RUN_FILES' terms); a
    folder that holds none goes whole."""
    with os.scandir(out) as entries:
        for entry in entries:
            name = prefix + entry.name
            if entry.is_dir(follow_symlinks=False):
                if any(k.startswith(name + "/") for k in RUN_FILES):
                    _keep_only_run_files(Path(entry.path), name + "/")
                else:
                    shutil.rmtree(entry.path, ignore_errors=True)
            elif name not in RUN_FILES:
                os.unlink(entry.path)


def _watchdog(task: dict) -> _CaseLimit | None:
    """On a Dask worker, the per-case limit: a case still running after ``exit_after_s`` ends its worker process
    (a thread cannot be stopped); the nanny starts a new one and the scheduler's retries end in KilledWorker,
    which the client records as an error. The local pool enforces the limit from the client instead."""
    limit = task.get("exit_after_s")
    if not limit or task.get("client_pid") == os.getpid():  # never end the operator's own process
        return None
    warm()  # a worker the nanny restarted has imported nothing yet: that is not the case's time
    _CASE_LIMIT.arm(limit, task["index"])
    return _CASE_LIMIT


class _CaseLimit:
    """The per-case limit of a Dask worker process: one thread for the process's life, armed with each case's
    deadline and disarmed when the case ends. A thread started per case (``threading.Timer``) cost every case a
    thread's start and end on the worker (docs/campaigns.md, "Measured"); this one sleeps until the earliest
    deadline it was told of, and wakes before it only when a case comes with an earlier one."""

    def __init__(self):
        self._cond = threading.Condition()
        self._case: tuple[float, float, int] | None = None  # (deadline on time.monotonic, limit s, case index)
        self._wake_at: float | None = None  # when the thread wakes next (None: when told)
        self._thread: threading.Thread | None = None

    def arm(self, limit_s: float, index: int) -> None:
        deadline = time.monotonic() + limit_s
        with self._cond:
            self._case = (deadline, limit_s, index)
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._watch, name="stand-case-limit", daemon=True)
                self._thread.start()
            elif self._wake_at is None or self._wake_at > deadline:
                self._cond.notify()

    def cancel(self) -> None:
        with self._cond:  # the thread, if awake at the old deadline, finds no case (or a later one) and sleeps on
            self._case = None

    def _watch(self) -> None:
        with self._cond:
            while True:
                case = self._case
                now = time.monotonic()
                if case is not None and now >= case[0]:
                    print(f"stand: campaign case {case[2]} still running after the per-case limit of {case[1]:g} s; "
                          "ending this worker process", file=sys.stderr, flush=True)
                    os._exit(EXIT_OVERRUN)
                self._wake_at = None if case is None else case[0]
                self._cond.wait(None if case is None else case[0] - now)


_CASE_LIMIT = _CaseLimit()


# ------------------------------------------------------------------------------------------------ executors
def warm(task: dict | None = None) -> None:
    """Import what a run needs once per worker process, so the first case's timings are its own. With a campaign's
    ``task``, also build its scene's devices once and close them, unrun (without its controller and faults: no
    flight or plug-in code runs here): the modules the devices import and the data files they load (tables,
    catalogues, coefficients) are then loaded once per process, not in the first case. A case then starts as in
    a process that ran others before it (the bench and the tests check that it reproduces a fresh process's
    record bit for bit); a scene that fails to build here fails in its case, where it is recorded."""
    for name in devices.kind_names():
        devices.get(name)
    if task is None:
        return
    try:
        sc = parse(task["data"], task["source"])
        sc = dataclasses.replace(sc, controller=dataclasses.replace(sc.controller, kind="none"), faults=())
        with _RUN_LOCK, build(sc, None, Path(task["base"])):
            pass
    except (Exception, SystemExit) as exc:  # recorded by the case that meets it
        log.debug("warming the worker with case %s failed: %s", task.get("index"), _raised(exc))
