"""A wall-clock deadline for fuzz tests: a call that would hang raises :class:`Hung` instead.

SIGALRM interrupts a blocking system call in the main thread (where pytest runs tests) and the
handler's exception propagates out of it (PEP 475), so a write stuck on a full pty ends the test
with a failure rather than freezing the suite. The deadline only guards against hangs; it is far
above any normal run time and asserts nothing about speed.
"""

from __future__ import annotations

import signal
from contextlib import contextmanager


class Hung(AssertionError):
    """The guarded block did not finish by its deadline."""


@contextmanager
def deadline(seconds: float, what: str):
    def fire(signum, frame):
        raise Hung(f"{what} did not finish within {seconds:g} s: something blocked.")

    previous = signal.signal(signal.SIGALRM, fire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
