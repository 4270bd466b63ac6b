"""The local process pool: spawned workers watched by the client (worker deaths, per-case limit), and the
inline executor (every case in this process)."""

from __future__ import annotations

import pickle
import time

from .case import _error_record, _raised, case_task, run_case, warm
from .errors import CampaignError

#: Times a case may end its worker process (os._exit, a signal, a crash) before it is recorded as an error.
WORKER_DEATHS = 2
#: A worker's next case is sent while it runs the current one (so it starts it without waiting for the client)
#: when the pickled case is at most this big: the pipe's buffer holds it, and the client never blocks on a send.
QUEUED_BYTES = 32 << 10

def _worker_main(conn, first: dict | None = None, spec=None) -> None:
    """A local pool worker: cases from ``conn`` one at a time, each answered with its record. ``first``: a case
    whose scene warms the process (``warm``) before it says it is ready. ``spec``: the campaign's, sent once: a
    case then comes as its index (and where to write it), and is drawn and validated here, not by the client."""
    import signal

    # Ctrl-C goes to the whole process group; the client stops the campaign and ends its workers. A worker that
    # acted on it would record a half-run case as "stopped".
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    warm(case_task(spec, first["index"]) if spec is not None and first is not None else first)
    conn.send(("ready", None))  # a case's wall-clock limit starts when it is handed over, not before the imports
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):  # the client is gone
            return
        if task is None:
            return
        result = run_case(task if spec is None else {**task, "spec": spec})
        try:
            conn.send(("result", result))
        except Exception as exc:  # noqa: BLE001 - e.g. a value that does not pickle: the case is still recorded
            case = task if spec is None else case_task(spec, task["index"])
            conn.send(("result", {"record": _error_record(case, f"its result could not be sent back: "
                                                                 f"{_raised(exc)}"), "files": {}}))


def _exit_text(code: int | None) -> str:
    import signal

    if code is not None and code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


class _Slot:
    """One worker process of the local pool, the case it runs (``task``) and the one sent to run next (``queued``).
    """

    def __init__(self, ctx, first: dict | None = None, spec=None):
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_worker_main, args=(child, first, spec), name="stand-campaign-worker")
        self.proc.start()
        child.close()
        self.task: dict | None = None
        self.queued: dict | None = None
        self.since = 0.0
        self.ready = False

    def idle(self) -> bool:
        return self.ready and self.task is None

    def give(self, task: dict) -> None:
        self.task, self.since = task, time.monotonic()
        self._send(pickle.dumps(task, pickle.HIGHEST_PROTOCOL))

    def queue(self, task: dict) -> bool:
        """Send ``task`` to run after the current one, if it is small enough to wait in the pipe."""
        data = pickle.dumps(task, pickle.HIGHEST_PROTOCOL)
        if len(data) > QUEUED_BYTES:
            return False
        self.queued = task
        self._send(data)
        return True

    def done(self) -> dict:
        """The current case answered: the queued one (the worker has started it) becomes the current one."""
        task, self.task, self.queued, self.since = self.task, self.queued, None, time.monotonic()
        return task

    def _send(self, data: bytes) -> None:
        try:
            self.conn.send_bytes(data)  # what Connection.send does, the size known first
        except OSError:  # the worker died since it said ready: the pool sees its end and gives the case again
            pass

    def end(self, kill: bool = False) -> None:
        if not kill and self.proc.is_alive():
            try:
                self.conn.send(None)
            except OSError:
                kill = True
            self.proc.join(5.0)
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join()
        self.conn.close()


class _LocalPool:
    """Worker processes on this machine (spawned: nothing of the parent's threads or buses is inherited), each
    watched by the client: a worker that dies is replaced and its case given again, up to ``deaths`` times, then
    recorded as an error; a case over ``case_timeout_s`` of wall time is recorded as an error and its worker
    replaced. The other cases never notice (a shared pool would lose every pending case with one worker)."""

    name = "local"

    def __init__(self, workers: int, case_timeout_s: float = 0.0, deaths: int = 2, spec=None):
        import multiprocessing

        # ``spec``: the campaign's, given to each worker once; the tasks are then indices (``case_task``).
        self.workers, self.case_timeout_s, self.deaths, self.spec = workers, case_timeout_s, deaths, spec
        self.ctx = multiprocessing.get_context("spawn")
        self.slots: list[_Slot] = []
        self.first: dict | None = None
        #: The client's CPU time spent starting worker processes (once per campaign, and per replaced worker): not
        #: the client's work per case.
        self.start_cpu_s = self.start_thread_cpu_s = 0.0

    def results(self, tasks: list[dict]):
        """``(index, result, None)`` for a case that ran, ``(index, None, reason)`` for one recorded as an error."""
        from collections import deque

        pending = deque(tasks)
        died: dict[int, list[str]] = {}
        self.first = tasks[0] if tasks else None
        cpu0, thread0 = time.process_time(), time.thread_time()
        self.slots = [_Slot(self.ctx, self.first, self.spec) for _ in range(min(self.workers, len(pending)))]
        self._started(cpu0, thread0)
        while pending or any(s.task is not None for s in self.slots):
            self._hand_out(pending)
            watched = [s for s in self.slots if s.task is not None or not s.ready]
            outcomes = [o for s, answered in self._wait(watched)
                        if (o := self._check(s, died, pending, answered)) is not None]
            self._hand_out(pending)  # before the client writes what came back
            yield from outcomes

    def _hand_out(self, pending) -> None:
        """A case to every idle worker, and one more to each busy worker while more cases wait than there are
        workers (near the end, a case queued behind a long one would keep an idle worker waiting)."""
        for s in self.slots:
            if s.idle() and pending:
                s.give(pending.popleft())
        for s in self.slots:
            if s.task is not None and s.queued is None and len(pending) > len(self.slots):
                task = pending.popleft()
                if not s.queue(task):
                    pending.appendleft(task)

    def _wait(self, watched: list[_Slot]) -> list[tuple[_Slot, bool]]:
        """The slots with something to look at: an answer, an ended process, or a case over its limit (only these
        are checked: with many workers, polling every one after each answer would be the client's work per case
        growing with the pool), each with whether its pipe has something to read (then it need not be polled
        again: a poll is a wait of its own)."""
        from multiprocessing.connection import wait

        timeout = None
        busy = [s for s in watched if s.task is not None]
        if self.case_timeout_s and busy:
            now = time.monotonic()
            timeout = max(0.0, min(s.since + self.case_timeout_s - now for s in busy))
        ready = set(wait([s.conn for s in watched] + [s.proc.sentinel for s in watched], timeout))
        now = time.monotonic()
        return [(s, s.conn in ready) for s in watched if s.conn in ready or s.proc.sentinel in ready
                or (self.case_timeout_s and s.task is not None and now - s.since >= self.case_timeout_s)]

    def _check(self, s: _Slot, died: dict, pending, answered: bool = False) -> tuple | None:
        if answered or s.conn.poll():  # an answer waits (even if the process ended right after sending it)
            try:
                kind, result = s.conn.recv()
            except (EOFError, OSError):
                kind, result = None, None
            if kind == "ready":
                s.ready = True
                return None
            if kind == "result" and s.task is not None:
                return s.done()["index"], result, None
        if not s.proc.is_alive():
            s.proc.join()
            if s.task is None:  # it died importing the stand: no case is to blame and none can run
                raise CampaignError(f"--workers {self.workers}: a local worker process could not start "
                                    f"({_exit_text(s.proc.exitcode)}); try --workers 0 to see why.")
            task = s.task
            died.setdefault(task["index"], []).append(_exit_text(s.proc.exitcode))
            if s.queued is not None:  # not started, or started and lost with the worker: given again, unblamed
                pending.appendleft(s.queued)
            self._replace(s)
            if len(died[task["index"]]) < self.deaths:
                pending.appendleft(task)  # maybe a passing crash (out of memory): once more, first
                return None
            return task["index"], None, (f"its worker process died {len(died[task['index']])} times while running "
                                         f"it ({', '.join(died[task['index']])}); not run again")
        if s.task is not None and self.case_timeout_s and time.monotonic() - s.since >= self.case_timeout_s:
            index = s.task["index"]
            if s.queued is not None:
                pending.appendleft(s.queued)
            self._replace(s, kill=True)
            return index, None, (f"still running after the per-case limit of {self.case_timeout_s:g} s of wall time "
                                 "(--case-timeout); its worker process was ended")
        return None

    def _started(self, cpu0: float, thread0: float) -> None:
        self.start_cpu_s += time.process_time() - cpu0
        self.start_thread_cpu_s += time.thread_time() - thread0

    def _replace(self, s: _Slot, kill: bool = False) -> None:
        """A new worker process in this slot, the old one ended (killed if it still runs)."""
        s.end(kill=kill)
        cpu0, thread0 = time.process_time(), time.thread_time()
        fresh = _Slot(self.ctx, self.first, self.spec)
        self._started(cpu0, thread0)
        s.conn, s.proc, s.task, s.queued, s.since, s.ready = fresh.conn, fresh.proc, None, None, 0.0, False

    def close(self, cancel: bool = False) -> None:
        for s in self.slots:
            s.end(kill=cancel)
        self.slots = []


class _Inline:
    """Every case in this process, one after another (``workers = 0``: debugging and tests). A case that ends
    the process (``os._exit``, a crash) ends the campaign too: use a pool for untrusted code."""

    name = "inline"
    workers = 1
    start_cpu_s = start_thread_cpu_s = 0.0

    def __init__(self, spec=None):
        self.spec = spec

    def results(self, tasks: list[dict]):
        for task in tasks:
            yield task["index"], run_case(task if self.spec is None else {**task, "spec": self.spec},
                                          interruptible=True), None

    def close(self, cancel: bool = False):
        pass
