"""Logging: the standard library's ``logging``, loggers named by module, a log file per run.

The library only logs (``logging.getLogger(__name__)``: ``stand.loop``, ``stand.devices``, ``stand.compose``, ...),
never per tick, and never configures logging itself; what it logs goes where the program that uses it says. A
bench routes them by name (``logging.getLogger("stand.devices").addHandler(...)``).

* Every event of a run's ``events.jsonl`` is also a log record (:func:`log_event`), under the logger of the module
  that logged the event, at the level :data:`EVENT_LEVELS` gives its kind (INFO otherwise), with the event's kind
  in ``record.stand_event``.
* ``RUN/stand.log`` (:class:`RunLog`, opened by the loop for the length of a run): every record of the ``stand``,
  ``drivers``, ``sim`` and ``star_screen`` loggers at INFO and above, one line each with the wall-clock time. Each
  run adds one handler and takes it away when it ends, so runs after each other in one process (a campaign's
  worker) never write twice or into another run's file. While two runs go on at once in one process (threads),
  each file takes only the records of the thread that runs it.
* The console (``stand -v`` / ``-q``, :class:`Console`): WARNING and above by default, INFO with ``-v``, DEBUG with
  ``-vv``, ERROR only with ``-q``. What the command prints at the end anyway (the error that ended a run) is not
  printed twice: events of the kinds in :data:`REPORTED_AT_END` go only to the file.
"""

from __future__ import annotations

import logging
import sys
import threading
from pathlib import Path

#: The packages whose loggers a run's file collects.
PACKAGES = ("stand", "drivers", "sim", "star_screen")
RUN_LOG = "stand.log"
FILE_FORMAT = "%(asctime)s %(levelname)-7s %(name)s: %(message)s"
CONSOLE_FORMAT = "stand: %(levelname)s %(name)s: %(message)s"
#: Event kinds (events.jsonl) that are not INFO.
EVENT_LEVELS = {
    "device_silent": logging.WARNING, "device_unheard": logging.WARNING, "frames_rejected": logging.WARNING,
    "device_conflict": logging.WARNING, "overruns": logging.WARNING,
    "device_exception": logging.ERROR, "controller_exception": logging.ERROR, "controller_over_budget": logging.ERROR,
    "truth_exception": logging.ERROR, "writer_exception": logging.ERROR, "pacer_exception": logging.ERROR,
    "observer_exception": logging.ERROR, "loop_exception": logging.ERROR, "aborted": logging.ERROR,
    "fault_exception": logging.ERROR,
}
#: Event kinds whose message the command line prints when the run ends (``stand: run aborted: ...``).
REPORTED_AT_END = frozenset(k for k, level in EVENT_LEVELS.items() if level >= logging.ERROR) | {"stopped", "end"}
_MARK = "_stand_console"


def log_event(module: str, kind: str, message: str) -> None:
    """An event of the run's events.jsonl as a log record of ``module``'s logger."""
    logger = logging.getLogger(module)
    level = EVENT_LEVELS.get(kind, logging.INFO)
    if logger.isEnabledFor(level):
        logger.log(level, message, extra={"stand_event": kind})


class _NotReportedAtEnd(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return getattr(record, "stand_event", None) not in REPORTED_AT_END


class _Stderr(logging.StreamHandler):
    """A handler on whatever ``sys.stderr`` is when a record comes (as ``logging.lastResort`` does)."""

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):
        pass


class Console:
    """The command line's console handler (stderr) for the length of a command (:meth:`close` takes it away and
    puts the loggers' levels back), at the level ``verbosity`` gives: -1 (``-q``) ERROR, 0 WARNING, 1 (``-v``)
    INFO, 2 (``-vv``) and more DEBUG. A handler a previous command left is replaced, never doubled."""

    def __init__(self, verbosity: int = 0):
        self.level = {-1: logging.ERROR, 0: logging.WARNING, 1: logging.INFO}.get(max(-1, verbosity), logging.DEBUG)
        root = logging.getLogger()
        for h in [h for h in root.handlers if getattr(h, _MARK, False)]:
            root.removeHandler(h)
        self.handler = _Stderr()
        setattr(self.handler, _MARK, True)
        self.handler.setLevel(self.level)
        self.handler.setFormatter(logging.Formatter(CONSOLE_FORMAT))
        self.handler.addFilter(_NotReportedAtEnd())
        root.addHandler(self.handler)
        self._levels = {name: logging.getLogger(name).level for name in PACKAGES}
        for name in PACKAGES:  # the stand's loggers let through what the console (or a run's file) wants
            logging.getLogger(name).setLevel(min(self.level, logging.INFO))

    def close(self) -> None:
        logging.getLogger().removeHandler(self.handler)
        for name, level in self._levels.items():
            logging.getLogger(name).setLevel(level)


class _RunFile(logging.FileHandler):
    """A run's file: a record that cannot be written (a full disk) is counted in ``lost``, never printed as a
    traceback in the middle of the run (events.jsonl and the summary stay the record)."""

    lost = 0

    def handleError(self, record: logging.LogRecord) -> None:
        self.lost += 1


class RunLog:
    """``RUN/stand.log`` for the length of one run: a handler on the stand's package loggers, removed by
    :meth:`close` (idempotent). A log that cannot be opened (a full disk) is left out; the run goes on."""

    _open = 0
    _lock = threading.Lock()
    _levels: dict[str, int] = {}  # the package loggers' own levels while runs have them at INFO

    def __init__(self, run_dir: str | Path):
        self.path = Path(run_dir) / RUN_LOG
        self.thread = threading.get_ident()
        self.handler: logging.Handler | None = None
        try:
            handler = _RunFile(self.path, encoding="utf-8", delay=False)
        except OSError:
            return
        handler.setLevel(logging.INFO)
        handler.setFormatter(logging.Formatter(FILE_FORMAT))
        handler.addFilter(self._mine)
        self.handler = handler
        with RunLog._lock:
            RunLog._open += 1
            for name in PACKAGES:
                logger = logging.getLogger(name)
                if RunLog._open == 1 and logger.getEffectiveLevel() > logging.INFO:
                    # A library user who set no level still gets INFO in the file; put back by the last close.
                    RunLog._levels[name] = logger.level
                    logger.setLevel(logging.INFO)
                logger.addHandler(handler)

    def _mine(self, record: logging.LogRecord) -> bool:
        """Alone in the process, a run takes every record (its device threads' too); beside another run, only its
        own thread's."""
        return RunLog._open <= 1 or record.thread == self.thread

    def close(self) -> None:
        if self.handler is None:
            return
        handler, self.handler = self.handler, None
        with RunLog._lock:
            for name in PACKAGES:
                logging.getLogger(name).removeHandler(handler)
            RunLog._open -= 1
            if RunLog._open == 0:
                for name, level in RunLog._levels.items():
                    logging.getLogger(name).setLevel(level)
                RunLog._levels.clear()
        try:
            handler.close()
        except (OSError, ValueError):  # the last flush on a full disk
            handler.lost += 1
