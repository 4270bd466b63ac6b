"""Cases on a Dask distributed scheduler."""

from __future__ import annotations

import os
import time

from .case import DONE_TIMING, _raised, case_task, done_dir, run_case, take_done, warm
from .errors import CampaignError
from .spec import Spec

#: The HTTP address of the scheduler of a Dask LocalCluster the stand starts (bench, tests): loopback, any free port.
#: ``dashboard_address=None`` is not "none": the scheduler still serves HTTP on 8787 and warns when it is taken.
DASK_HTTP_ADDRESS = "127.0.0.1:0"
#: Cases per graph message to the scheduler: a case's task is about 135 bytes, so a message stays near 0.5 MB, under
#: Dask's large-graph warning (10 MB, which 100 000 cases in one message would pass).
CASES_PER_MESSAGE = 4096
#: The Dask settings a campaign's workers should run with: a worker's periodic work runs on its event loop thread, in
#: the process that runs the case, and costs CPU time whether a case runs or not. Measured with Dask's defaults on
#: 600 s detumble cases (docs/campaigns.md, "Measured"), the threads of two workers took 18 to 25 ms of CPU per
#: case, the statistical profiler (10 ms sampling, for the dashboard's profile page) the largest part, then the
#: memory monitor (100 ms), the system monitor (500 ms) and the event loop's health tick (20 ms); with these, 6 to
#: 8.5 ms. The memory monitor and the tick stay on at a longer interval (the worker still pauses near its memory
#: limit and warns of a blocked event loop); the profiler is off. ``distributed.comm.offload`` off: a worker no
#: longer measures every message it sends (Dask's ``sizeof``, recursive: the case's record, each heartbeat's metrics)
#: to decide whether to serialize it on another thread, which a campaign's messages (a record, or a run's files of
#: about 1.4 MB) never need; it is read when the worker process imports Dask, so it works as an environment variable
#: (or in a YAML file), not as ``dask.config.set`` in the nanny. Environment variables for ``dask worker``:
#: ``dask_worker_env()``.
WORKER_CONFIG = {"distributed.worker.profile.enabled": False, "distributed.worker.memory.monitor-interval": "1s",
                 "distributed.admin.system-monitor.interval": "5s", "distributed.admin.tick.interval": "1s",
                 "distributed.comm.offload": False}
#: The Dask setting a campaign's worker processes should be started with by their nannies: Dask's nanny starts each
#: worker with ``MALLOC_TRIM_THRESHOLD_=65536`` in its environment (``distributed.nanny.pre-spawn-environ``), and
#: setting it also fixes glibc's mmap threshold at 128 KiB: every larger buffer a case allocates (the 1.3 MB of
#: telemetry it reads back for its summary and digest) is then mapped, faulted in page by page and unmapped again,
#: in every case. Measured (docs/campaigns.md, "Measured"): about 320 page faults and 1 ms of system CPU per case
#: on the worker, against about 40 without it. ``None`` leaves the variable unset: glibc adapts its thresholds to
#: what the process frees, as in a local worker. A nanny reads it from Dask's configuration (a YAML file, or
#: ``dask.config.set`` around a ``LocalCluster``): an environment variable cannot unset it.
NANNY_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
#: The environment variable of ``NANNY_CONFIG``, which a campaign looks for in its workers' environments.
MALLOC_TRIM_VARIABLE = "MALLOC_TRIM_THRESHOLD_"
#: The periodic callback (by its name in a Dask worker) each setting of ``WORKER_CONFIG`` starts.
_CALLBACKS = {"profile": "distributed.worker.profile.enabled",
              "memory_monitor": "distributed.worker.memory.monitor-interval",
              "monitor": "distributed.admin.system-monitor.interval",
              "tick": "distributed.admin.tick.interval"}


class _Dask:
    """Tasks on a Dask distributed scheduler (``--scheduler ADDRESS``) or a cluster object handed in."""

    name = "dask"

    def __init__(self, scheduler, spec: Spec, case_timeout_s: float = 0.0):
        try:
            from distributed import Client
        except ImportError:
            raise CampaignError("--scheduler needs Dask distributed: pip install 'adcs-stand[campaign]'.") from None
        try:
            self.client = Client(scheduler, timeout=30, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise CampaignError(f"--scheduler {scheduler} is not allowed: no Dask scheduler answered there within "
                                f"30 s ({exc}).") from None
        self.spec, self.key, self.case_timeout_s = spec, spec.key, case_timeout_s
        # The client's CPU time (the process's, this thread's) warming the workers: once per campaign, not per case.
        self.start_cpu_s = self.start_thread_cpu_s = 0.0
        self.workers = max(1, sum(w.get("nthreads", 1) for w in
                                  self.client.scheduler_info().get("workers", {}).values()))
        self.address = self.client.scheduler.address
        # What the workers run beside the cases (campaign.json), and a warning where it costs the cases CPU time.
        self.execution = worker_settings(self.client.run(_periodic_ms), self.client.run(_malloc_trim))

    def results(self, tasks: list[dict]):
        import queue

        limit = {"exit_after_s": self.case_timeout_s or None, "client_pid": os.getpid()}
        # Every worker builds one scene before the first case.
        cpu0, thread0 = time.process_time(), time.thread_time()
        self.client.run(_warm, self.spec, tasks[0]["index"] if tasks else None)
        self.start_cpu_s += time.process_time() - cpu0
        self.start_thread_cpu_s += time.thread_time() - thread0
        # The spec travels once to each worker, as the result of a task (which the scheduler can compute again if
        # the workers holding it die, unlike scattered data); a case's task is its index.
        spec = self.client.submit(Spec.from_json, self.spec.to_json(), key=f"stand-spec-{self.key}")
        # The cases in as few graph messages as fit (``map``): one update for the scheduler, not one per case.
        keys = [f"stand-case-{self.key}-{t['index']}" for t in tasks]
        index_of = {t["index"]: i for i, t in enumerate(tasks)}
        mapped = self.client.map(_run_case, [spec] * len(tasks), [{**t, **limit} for t in tasks], key=keys, pure=False,
                                 batch_size=CASES_PER_MESSAGE)
        # Each case's end is seen on the client's event loop as soon as its task ends, and handed to this thread
        # through a queue: one hand-over per case (``as_completed`` and ``Future.result`` each took one). A case its
        # worker left whole in the campaign folder (``publish``) is taken from there by this thread; any other
        # answer (an error record, a run's files, a task that raised) is fetched through the scheduler first.
        answers: queue.SimpleQueue = queue.SimpleQueue()
        for f, t in zip(mapped, tasks, strict=True):
            self.client.loop.add_callback(_answer, f, t["index"], t.get("dest"), answers)
        for _ in mapped:
            index, result, raised = answers.get()
            if isinstance(result, _Done):
                result = take_done(result.part)
                if result is None:  # gone since the event loop saw it: the scheduler's copy of the answer
                    result, raised = _fetched(mapped[index_of[index]])
            yield (index, *self._outcome(result, raised))

    def _outcome(self, result, raised: BaseException | None) -> tuple:
        import asyncio

        from distributed.scheduler import KilledWorker

        if raised is None:
            return result, None
        try:
            raise raised
        except KilledWorker as exc:  # the scheduler gave up after the case ended its workers again and again
            limit = f", or over the per-case limit of {self.case_timeout_s:g} s" if self.case_timeout_s else ""
            return None, (f"its Dask worker died each time it ran it (killed, crashed{limit}); not run again: "
                          f"{_raised(exc)}")
        except KeyboardInterrupt:
            raise
        except (Exception, asyncio.CancelledError) as exc:  # the scheduler or the link failed, not the case: not
            return None, _Lost(_raised(exc))  # recorded, the next invocation runs it
        except BaseException as exc:  # a SystemExit that escaped a worker: the case's doing, recorded
            return None, _raised(exc)

    def close(self, cancel: bool = False):
        self.client.close(timeout=30)


def dask_worker_env() -> dict[str, str]:
    """``WORKER_CONFIG`` as the environment variables a ``dask worker`` command reads."""
    return {_env_name(key): str(value) for key, value in WORKER_CONFIG.items()}


def _periodic_ms(dask_worker) -> dict[str, float]:
    """The intervals (ms) of the periodic callbacks a Dask worker runs (on the worker, by ``Client.run``)."""
    return {name: pc.callback_time for name, pc in dask_worker.periodic_callbacks.items() if pc.is_running()}


def _malloc_trim(dask_worker=None) -> str | None:
    """The worker process's ``MALLOC_TRIM_THRESHOLD_`` (on the worker, by ``Client.run``), None where unset."""
    return os.environ.get(MALLOC_TRIM_VARIABLE)


def worker_settings(periodic_ms: dict[str, dict[str, float]], malloc_trim: dict[str, str | None] | None = None
                    ) -> dict:
    """What campaign.json records of the workers' periodic work (``periodic_ms``: each worker's ``_periodic_ms``):
    for each periodic callback a setting of ``WORKER_CONFIG`` starts, the shortest interval (ms) a worker runs it at
    (None: none runs it); the ``MALLOC_TRIM_THRESHOLD_`` values the workers run with (``malloc_trim``: each worker's
    ``_malloc_trim``; ``NANNY_CONFIG``), sorted, empty where none sets it; and
    ``dask_worker_advice``, a sentence naming the settings that run more often than ``WORKER_CONFIG`` says (a
    worker's periodic work is CPU time taken from its cases) and the variable where a worker has it, else absent."""
    from dask.utils import parse_timedelta

    settings: dict[str, float | None] = {}
    costly: list[str] = []
    for name, key in _CALLBACKS.items():
        wanted = WORKER_CONFIG[key]  # an interval, or False: not run at all
        wanted_ms = None if wanted is False else parse_timedelta(wanted) * 1e3
        running = [w[name] for w in periodic_ms.values() if name in w]
        settings[name] = min(running) if running else None
        if running and (wanted_ms is None or min(running) < wanted_ms):
            costly.append(key)
    trims = sorted({v for v in (malloc_trim or {}).values() if v is not None})
    out: dict = {"dask_worker_periodic_ms": settings, "dask_worker_malloc_trim_threshold": trims}
    advice = []
    if costly:
        env = " ".join(f"{_env_name(k)}={WORKER_CONFIG[k]}" for k in costly)
        advice.append(f"the Dask workers run {', '.join(costly)} more often than a campaign needs, which takes CPU "
                      f"time from the process that runs each case; start them with {env}")
    if trims:
        advice.append(f"the Dask workers run with {MALLOC_TRIM_VARIABLE}={', '.join(trims)} (Dask's nanny sets it), "
                      "which maps and unmaps every large buffer of every case; set "
                      f"distributed.nanny.pre-spawn-environ.{MALLOC_TRIM_VARIABLE} to null in the Dask configuration "
                      "of the workers' nannies")
    if advice:
        out["dask_worker_advice"] = "; ".join(advice) + " (docs/campaigns.md, \"Local pool and Dask\")"
    return out


def _env_name(key: str) -> str:
    """The environment variable Dask reads for a dotted config ``key``."""
    return "DASK_" + key.upper().replace(".", "__").replace("-", "_")


async def _answer(future, index: int, part: str | None, answers) -> None:
    """On the client's event loop: ``(index, result, None)``, or ``(index, None, what it raised)``, into ``answers``
    once the case's task has ended and its result is here (whatever happens, so the client never waits forever).
    Where the task ended well and its worker left the case whole in the campaign folder (``publish``), the result is
    ``_Done``: the client's thread takes it from there, and nothing is fetched through the scheduler."""
    try:
        # Future._state.wait and Future._result are the coroutines Future.result runs on the event loop: private, so
        # pyproject.toml pins distributed to the versions the Dask tests ran (test_campaign_dask_settings counts the
        # hand-overs, test_campaign_overhead the fetches).
        await future._state.wait()
        if part is not None and future.status == "finished" and os.path.exists(os.path.join(done_dir(part),
                                                                                             DONE_TIMING)):
            answers.put((index, _Done(part), None))
            return
        answers.put((index, await future._result(), None))
    except BaseException as exc:  # noqa: BLE001 - the client's thread sorts it out (_outcome)
        answers.put((index, None, exc))


def _fetched(future) -> tuple:
    """``(result, None)`` or ``(None, what it raised)``: a case's answer fetched through the scheduler (this thread)."""
    try:
        return future.result(), None
    except BaseException as exc:  # noqa: BLE001 - sorted out by _outcome, as on the event loop
        return None, exc


class _Done:
    """An answer left whole in the campaign folder by its worker (``publish``): the case's ``NNNNN.part`` path."""

    __slots__ = ("part",)

    def __init__(self, part: str):
        self.part = part


def _warm(spec: Spec, index: int | None) -> None:
    warm(None if index is None else case_task(spec, index))


def _run_case(spec: Spec, task: dict) -> dict:
    """Case ``task["index"]`` of ``spec``, drawn and validated on its Dask worker."""
    return run_case({**task, "spec": spec})


class _Lost(str):
    """A reason that is not the case's: the case stays unrecorded and the next invocation runs it."""
