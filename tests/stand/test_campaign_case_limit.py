"""The per-case limit of a Dask worker process (``stand.campaign.case._watchdog``): one thread for the process's
life, re-armed by each case, which still ends the process when a case overruns, a shorter limit after a longer one
included (docs/campaigns.md, "Local pool and Dask")."""

import subprocess
import sys
import threading

from stand.campaign import case
from stand.campaign.case import EXIT_OVERRUN


def _task(index: int, limit_s: float) -> dict:
    return {"index": index, "exit_after_s": limit_s, "client_pid": -1}  # not this process: the limit applies


def test_cases_in_a_row_share_one_limit_thread(monkeypatch):
    starts: list[str] = []
    real_start = threading.Thread.start

    def counted(self):
        starts.append(self.name)
        real_start(self)

    monkeypatch.setattr(threading.Thread, "start", counted)
    for k in range(4):
        limit = case._watchdog(_task(k, 3600.0))
        assert limit is not None
        limit.cancel()
    assert len(starts) <= 1, starts  # a thread per case before (threading.Timer)
    assert [t.name for t in threading.enumerate()].count("stand-case-limit") == 1
    assert case._watchdog({**_task(9, 3600.0), "client_pid": __import__("os").getpid()}) is None


SCRIPT = """
import threading
from stand.campaign import case
first = case._watchdog({"index": 3, "exit_after_s": 3600.0, "client_pid": -1})
first.cancel()
case._watchdog({"index": 4, "exit_after_s": 0.2, "client_pid": -1})
threading.Event().wait(60.0)  # bounded: the limit ends the process long before
print("still running")
"""


def test_a_case_over_its_limit_ends_its_process_even_after_a_longer_one():
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=120)
    assert done.returncode == EXIT_OVERRUN, (done.returncode, done.stdout, done.stderr)
    assert "campaign case 4 still running after the per-case limit of 0.2 s" in done.stderr
    assert "still running\n" not in done.stdout
