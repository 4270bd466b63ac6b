"""Cases on a Dask distributed scheduler."""

from __future__ import annotations

import os
import time

from .case import _raised, case_task, run_case, warm
from .errors import CampaignError
from .spec import Spec

#: The HTTP address of the scheduler of a Dask LocalCluster the stand starts (bench, tests): loopback, any free port.
#: ``dashboard_address=None`` is not "none": the scheduler still serves HTTP on 8787 and warns when it is taken.
DASK_HTTP_ADDRESS = "127.0.0.1:0"
#: Cases per graph message to the scheduler: a case's task is about 135 bytes, so a message stays near 0.5 MB, under
#: Dask's large-graph warning (10 MB, which 100 000 cases in one message would pass).
CASES_PER_MESSAGE = 4096

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

    def results(self, tasks: list[dict]):
        from distributed import as_completed

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
        mapped = self.client.map(_run_case, [spec] * len(tasks), [{**t, **limit} for t in tasks], key=keys, pure=False,
                                 batch_size=CASES_PER_MESSAGE)
        futures = {f: t["index"] for f, t in zip(mapped, tasks, strict=True)}
        for f in as_completed(list(futures), loop=self.client.loop):
            index = futures.pop(f)
            yield (index, *self._outcome(f))

    def _outcome(self, f) -> tuple:
        import asyncio

        from distributed.scheduler import KilledWorker

        try:
            return f.result(), None
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


def _warm(spec: Spec, index: int | None) -> None:
    warm(None if index is None else case_task(spec, index))


def _run_case(spec: Spec, task: dict) -> dict:
    """Case ``task["index"]`` of ``spec``, drawn and validated on its Dask worker."""
    return run_case({**task, "spec": spec})


class _Lost(str):
    """A reason that is not the case's: the case stays unrecorded and the next invocation runs it."""
