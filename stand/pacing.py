"""Pacing: as fast as possible, or locked to the wall clock with a speed factor.

A paced run sleeps until each tick's wall-clock deadline ``start + t_sim / factor``; the last
half millisecond is spun rather than slept because ``time.sleep`` on Linux overshoots by 50-100 us
and more under load. Deadlines are absolute, so lateness never accumulates (a late tick does not
push the next one back), and every tick's lateness is kept for the summary: percentiles, and the
count of overruns (ticks that started more than one tick period late).

The clock and the sleep are injected (tests drive a fake clock; the stand passes
``time.monotonic``); nothing in ``sim`` ever sees them.
"""

from __future__ import annotations

import time

import numpy as np

from .errors import shown

SPIN_S = 0.0005


#: The pacing factors ``--speed`` takes (times real time): below, a tick's deadline runs past what a sleep can wait
#: for (1e-300 overflows it); above, a paced run is a run as fast as possible with extra work.
SPEED_RANGE = (1e-3, 1e6)


def parse_speed(text: str) -> float | None:
    """``afap`` -> None; ``realtime`` -> 1.0; a factor from 0.001 to 1e6 -> that factor (else ValueError, one
    sentence naming --speed and what is allowed)."""
    t = str(text).strip().lower()
    if t == "afap":
        return None
    if t in ("realtime", "rt"):
        return 1.0
    try:
        f = float(t)
    except ValueError:
        f = float("nan")
    lo, hi = SPEED_RANGE
    if not lo <= f <= hi:  # nan, inf, 0, negative and subnormal factors included
        raise ValueError(f"--speed {shown(text)} is not allowed: use afap, realtime or a factor of real time from "
                         f"{lo:g} to {hi:.0f}, such as 2 or 0.5.")
    return f


class Pacer:
    def __init__(self, factor: float | None, tick_s: float, clock=time.monotonic, sleep=time.sleep):
        self.factor = factor
        self.tick_s = tick_s
        self.clock = clock
        self.sleep = sleep
        self.start = None
        self._lateness: list[float] = []
        self._starts: list[float] = []
        self.overruns = 0

    def begin(self) -> None:
        self.start = self.clock()

    def wait(self, t_sim_s: float) -> None:
        """Block until the wall-clock deadline of sim time ``t_sim_s`` (no-op for afap)."""
        if self.factor is None:
            return
        deadline = self.start + t_sim_s / self.factor
        now = self.clock()
        if deadline - now > SPIN_S:
            self.sleep(deadline - now - SPIN_S)
        now = self.clock()
        while now < deadline:
            now = self.clock()
        late = now - deadline
        self._lateness.append(late)
        self._starts.append(now)
        if late > self.tick_s / self.factor:
            self.overruns += 1

    def hold(self, t_sim_s: float) -> None:
        """Sleep until the wall-clock time of sim time ``t_sim_s`` if it is still ahead (no statistics, no spin):
        the frame-end wait before a paced tick takes in what devices outside sent during the frame."""
        if self.factor is None:
            return
        left = self.start + t_sim_s / self.factor - self.clock()
        if left > 0:
            self.sleep(left)

    def stats(self) -> dict:
        out = {"paced": self.factor is not None, "speed_factor": self.factor, "overruns": self.overruns}
        if self._lateness:
            lat = np.asarray(self._lateness) * 1e3
            out.update({
                "lateness_ms_p50": round(float(np.percentile(lat, 50)), 4),
                "lateness_ms_p99": round(float(np.percentile(lat, 99)), 4),
                "lateness_ms_max": round(float(lat.max()), 4),
            })
        if len(self._starts) > 2:
            # Tick-to-tick periods in wall time, against the nominal tick_s / factor.
            period = np.diff(self._starts) * 1e3
            nominal = self.tick_s / self.factor * 1e3
            out.update({
                "period_ms_nominal": round(nominal, 4),
                "period_ms_std": round(float(period.std()), 4),
                "period_ms_worst_late": round(float(period.max() - nominal), 4),
            })
        return out
