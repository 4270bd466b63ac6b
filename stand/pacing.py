"""Pacing: as fast as possible, or locked to the wall clock with a speed factor.

A paced run sleeps until each tick's wall-clock deadline ``start + t_sim / factor``; the last
half millisecond is spun rather than slept because ``time.sleep`` on Linux overshoots by 50-100 us
and more under load. Deadlines are absolute, so lateness never accumulates (a late tick does not
push the next one back), and every tick's lateness goes into the summary: percentiles, and the
count of overruns (ticks that started more than one tick period late). The statistics are kept in
fixed-size form (a lateness histogram, running sums of the tick-to-tick period), so a run of any
length holds the same memory: 1 us bins up to 10 ms of lateness, 100 us bins up to 1 s, and the
worst value exactly.

The clock and the sleep are injected (tests drive a fake clock; the stand passes
``time.monotonic``); nothing in ``sim`` ever sees them.
"""

from __future__ import annotations

import math
import time

from .errors import shown

SPIN_S = 0.0005
#: A paced run with more overruns than this share of its ticks is not a plain PASS: its verdict says
#: "PASS, paced with N % overruns" (docs/architecture.md, "Pacing"); a scenario that must fail then gives an
#: ``overruns`` criterion.
OVERRUN_SHARE_LIMIT = 0.01


def overrun_share(timing: dict) -> float | None:
    """Overruns over ticks of a paced run's timing (``RunResult.timing``), or None for a run not paced or without
    ticks."""
    ticks = timing.get("ticks") or 0
    if not timing.get("paced") or ticks <= 0:
        return None
    return timing.get("overruns", 0) / ticks
#: Lateness histogram: FINE_BINS bins of FINE_S, then COARSE_BINS bins of COARSE_S; later still goes in the last bin.
FINE_S, FINE_BINS = 1e-6, 10_000
COARSE_S, COARSE_BINS = 1e-4, 9_900


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
        self._late_hist = [0] * (FINE_BINS + COARSE_BINS)
        self._late_n = 0
        self._late_max = 0.0
        # Tick-to-tick periods: count, running mean and sum of squared deviations (Welford), longest.
        self._prev_start: float | None = None
        self._period_n = 0
        self._period_mean = 0.0
        self._period_m2 = 0.0
        self._period_max = 0.0
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
        self._note(late, now)
        if late > self.tick_s / self.factor:
            self.overruns += 1

    def _note(self, late: float, now: float) -> None:
        """Add one tick's lateness and start time to the fixed-size statistics."""
        i = int(late / FINE_S)
        if i >= FINE_BINS:
            i = min(FINE_BINS + int((late - FINE_BINS * FINE_S) / COARSE_S), FINE_BINS + COARSE_BINS - 1)
        self._late_hist[i] += 1
        self._late_n += 1
        if late > self._late_max:
            self._late_max = late
        if self._prev_start is not None:
            period = now - self._prev_start
            self._period_n += 1
            delta = period - self._period_mean
            self._period_mean += delta / self._period_n
            self._period_m2 += delta * (period - self._period_mean)
            if period > self._period_max:
                self._period_max = period
        self._prev_start = now

    def _late_percentile_s(self, q: float) -> float:
        """The q-th percentile of the lateness, to its bin's resolution (the bin's middle; the worst value when
        it falls in the bin of the worst)."""
        rank = q / 100.0 * (self._late_n - 1)
        seen = 0
        for i, n in enumerate(self._late_hist):
            seen += n
            if seen > rank:
                if i < FINE_BINS:
                    mid = (i + 0.5) * FINE_S
                else:
                    mid = FINE_BINS * FINE_S + (i - FINE_BINS + 0.5) * COARSE_S
                return min(mid, self._late_max)
        return self._late_max

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
        if self._late_n:
            out.update({
                "lateness_ms_p50": round(self._late_percentile_s(50) * 1e3, 4),
                "lateness_ms_p99": round(self._late_percentile_s(99) * 1e3, 4),
                "lateness_ms_max": round(self._late_max * 1e3, 4),
            })
        if self._period_n > 1:
            # Tick-to-tick periods in wall time, against the nominal tick_s / factor.
            nominal = self.tick_s / self.factor * 1e3
            out.update({
                "period_ms_nominal": round(nominal, 4),
                "period_ms_std": round(math.sqrt(self._period_m2 / self._period_n) * 1e3, 4),
                "period_ms_worst_late": round(self._period_max * 1e3 - nominal, 4),
            })
        return out
