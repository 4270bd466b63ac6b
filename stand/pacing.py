"""Pacing: as fast as possible, or locked to the wall clock with a speed factor.

A paced run sleeps until each tick's wall-clock deadline ``start + t_sim / factor``; the last
half millisecond is spun rather than slept because ``time.sleep`` on Linux overshoots by 50-100 us
and more under load. Deadlines are absolute, so lateness never accumulates (a late tick does not
push the next one back), and every tick's lateness goes into the summary: percentiles, and the
count of overruns (ticks that started more than one tick period late). The statistics are kept in
fixed-size form (a lateness histogram, running sums of the tick-to-tick period), so a run of any
length holds the same memory: 1 us bins up to 10 ms of lateness, 100 us bins up to 1 s, and the
worst value exactly.

Why a tick overran (``overruns_gc``, ``overruns_work``, ``overruns_stall`` in the stats): at the first overrun of a
run of late ticks the pacer looks at the tick's work before it (from the previous tick's start to this wait): time
the cyclic garbage collector spent inside it (``gc.callbacks``), the thread's own CPU time (``time.thread_time``)
against its wall time, and whether the work ended before its deadline at all. A collection that explains the
overrun counts as ``gc``; time off the CPU (the process was descheduled) or a sleep that woke late counts as a
``stall`` (the operating system, the virtual machine); what is left, the tick's own CPU time over the period, as
``work``. A virtual machine's stolen time looks like CPU time from inside, so a ``work`` count is an upper bound:
``stand bench pacing`` compares with a bare loop pacing nothing for the same time. The later ticks of the same run
of overruns are counted under the same cause, and each run once (``overrun_episodes_gc`` and so on): one stall of
50 ms is 49 overruns but one episode.

Garbage collection in slack time (paced runs the loop hands ``collector=gc``): during the run the automatic
collector's gen-0 threshold is raised ``GC_DEFER`` times, and the pacer runs the young collection the collector
would have run (gen 0, or gen 1 when gen 1 is due) at a tick's start when at least ``GC_SLACK_S`` is left before
the deadline, so collections happen while the pacer would only have slept. A run without that slack still
collects, automatically, at the raised threshold; ``end`` puts the thresholds back.

Work ahead in slack time (``ahead``: the loop hands the orbit track's ``work_ahead``): work that comes in lumps, such
as the orbit track's next chunk (8,192 points, 1.8-3.3 ms in one tick at 1 ms steps, two or three overruns every
4.1 s), is done a piece at a time in the slack of the ticks before it is needed. A piece starts only when more than
``AHEAD_MIN_S`` is left before the spin, and is sized from the measured cost of the piece before to take
``AHEAD_PIECE_S``; one piece a tick. Its time counts as the tick's work when a tick overruns.

The first tick is the run's start-up (every device's first exchange, the orbit track's first chunk, the first
solutions: 3-6 ms at 1 kHz, cold caches included), not part of the schedule: when it takes longer than its period,
the clock's zero moves by the excess (``startup_ms`` in the stats) and the second tick starts on time. Every later
tick keeps its absolute deadline.

The clock and the sleep are injected (tests drive a fake clock; the stand passes
``time.monotonic``); nothing in ``sim`` ever sees them.
"""

from __future__ import annotations

import math
import time

from .errors import shown

#: The last part of a wait spun rather than slept. Measured on a 2-core virtual machine for a bare 1 kHz loop: the
#: sleep overshoots by 80-90 us at the median and by 1 ms or more at p99 under load in the normal scheduling class
#: (30 us and 80 us under ``chrt -f``) and beyond 95 us for a tenth of the ticks or more under load: a 100-200 us spin
#: would leave those ticks late, on any machine that is not idle. At 1 kHz the spin costs half a core.
SPIN_S = 0.0005
#: Slack-time collection: at least this much time left before the deadline to start one (gen-0 collections of the
#: 1 kHz pointing case measured 13-350 us, gen 1 up to 1.3 ms), and how many times the automatic gen-0 threshold is
#: raised meanwhile (a run that never has the slack still collects, later).
GC_SLACK_S = 0.0005
GC_DEFER = 10
#: Work ahead (module docstring): the least slack before the spin to start a piece in, the time a piece is sized to
#: take, and the size of a job's first piece, before its cost is known (units of the job: points of the orbit track).
#: A piece costs a fixed part (the numpy calls: about 50 us for the orbit track) and a part per unit (0.3 us a point
#: without the field, 1 us with a dipole, 8 us with the IGRF): sized from the last piece's cost per unit, the sizes
#: grow towards the budget within a few pieces, and come back within a few after a piece the machine slowed.
AHEAD_MIN_S = 0.00025
AHEAD_PIECE_S = 0.0002
AHEAD_FIRST = 16
#: Why an overrun happened (module docstring), the keys ``stats`` reports them under.
CAUSES = ("gc", "work", "stall")
#: The collectors a pacer has raised the thresholds of, until its ``end``.
_COLLECTORS_HELD: list = []
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
    """Waits for each tick's deadline and keeps its statistics; ``collector`` (the ``gc`` module, or a stand-in in
    tests) turns on slack-time collection for the run, ``thread_clock`` is the thread's CPU time for the
    attribution of overruns."""

    def __init__(self, factor: float | None, tick_s: float, clock=time.monotonic, sleep=time.sleep,
                 collector=None, thread_clock=time.thread_time, ahead=()):
        self.factor = factor
        self.tick_s = tick_s
        self.clock = clock
        self.sleep = sleep
        self.start = None
        self.period_s = tick_s / factor if factor is not None else 0.0
        self.thread_clock = thread_clock
        self.collector = collector
        self._thresholds: tuple | None = None  # the collector's own, while raised
        self._gc_s = 0.0  # time spent in collections since begin()
        self._gc_t0 = 0.0
        self.gc_in_slack = 0
        self.startup_s = 0.0  # the first tick's time over its period, by which the clock's zero moved
        self._first = True  # the first tick's work not yet over
        # Work ahead: the jobs (``job(n)`` does up to n units, returns how many it did), each one's measured seconds
        # per unit (None until its first piece), and the pieces done.
        self._ahead = list(ahead) if factor is not None else []
        self._ahead_cost: list = [None] * len(self._ahead)
        self.ahead_pieces = 0
        # The previous tick's start: wall time, CPU time and GC time then (the attribution of an overrun).
        self._release_cpu = 0.0
        self._release_gc = 0.0
        self._streak: str | None = None  # the cause of the current run of overruns
        self.causes = dict.fromkeys(CAUSES, 0)
        self.episodes = dict.fromkeys(CAUSES, 0)  # runs of late ticks, by the cause of their first
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
        if self.factor is not None and self.collector is not None and self.collector not in _COLLECTORS_HELD:
            # One pacer at a time holds a collector (two paced runs in threads of one process: the second leaves
            # it alone, so the thresholds put back at the end are the collector's own).
            gc_ = self.collector
            _COLLECTORS_HELD.append(gc_)
            self._thresholds = gc_.get_threshold()
            gc_.callbacks.append(self._on_gc)
            gc_.set_threshold(self._thresholds[0] * GC_DEFER, *self._thresholds[1:])
        self.start = self.clock()
        self._release_cpu = self.thread_clock()

    def end(self) -> None:
        """Give the collector its thresholds back (idempotent; nothing to do for afap)."""
        if self._thresholds is not None:
            gc_ = self.collector
            gc_.set_threshold(*self._thresholds)
            if self._on_gc in gc_.callbacks:
                gc_.callbacks.remove(self._on_gc)
            self._thresholds = None
            _COLLECTORS_HELD.remove(gc_)

    def _on_gc(self, phase: str, info: dict) -> None:
        """``gc.callbacks``: the time spent in collections."""
        if phase == "start":
            self._gc_t0 = self.clock()
        else:
            self._gc_s += self.clock() - self._gc_t0

    def wait(self, t_sim_s: float) -> None:
        """Block until the wall-clock deadline of sim time ``t_sim_s`` (no-op for afap)."""
        if self.factor is None:
            return
        deadline = self.start + t_sim_s / self.factor
        now = self.clock()
        if self._first and self._prev_start is not None:  # the first tick's work is over (module docstring)
            self._first = False
            if now > deadline:
                self.startup_s = now - deadline
                self.start += self.startup_s
                deadline = now
        if deadline - now > GC_SLACK_S and self._thresholds is not None:
            self._collect_in_slack()
            now = self.clock()
        if self._ahead and deadline - now > SPIN_S + AHEAD_MIN_S:
            self._work_ahead()
            now = self.clock()
        # The tick's work ends here for the attribution of an overrun: slack-time collections and work ahead are
        # its own, not a late wake-up.
        entered, cpu = now, self.thread_clock()
        if deadline - now > SPIN_S:
            self.sleep(deadline - now - SPIN_S)
        now = self.clock()
        while now < deadline:
            now = self.clock()
        late = now - deadline
        prev = self._prev_start
        self._note(late, now)
        if late > self.period_s:
            self.overruns += 1
            if self._streak is None:
                self._streak = self._cause(late, deadline, prev, entered, cpu - self._release_cpu,
                                           self._gc_s - self._release_gc)
                self.episodes[self._streak] += 1
            self.causes[self._streak] += 1
        else:
            self._streak = None
        self._release_cpu, self._release_gc = self.thread_clock(), self._gc_s

    def _work_ahead(self) -> None:
        """One piece of the first job that has work, sized to take ``AHEAD_PIECE_S`` at the cost per unit its last piece
        measured."""
        for i, job in enumerate(self._ahead):
            cost = self._ahead_cost[i]
            n = AHEAD_FIRST if cost is None else max(1, int(AHEAD_PIECE_S / cost))
            t0 = self.clock()
            done = job(n)
            if done:
                self._ahead_cost[i] = (self.clock() - t0) / done
                self.ahead_pieces += 1
                return

    def _collect_in_slack(self) -> None:
        """The young collection the automatic collector would run next, if enough allocations are pending: gen 1
        when gen 1 is due, else gen 0."""
        gc_ = self.collector
        th0, th1, _ = self._thresholds
        count0, count1, _ = gc_.get_count()
        if count0 >= th0:
            gc_.collect(1 if count1 >= th1 else 0)
            self.gc_in_slack += 1

    def _cause(self, late: float, deadline: float, prev: float | None, entered: float, work_cpu_s: float,
               gc_s: float) -> str:
        """Why a tick ``late`` s after its deadline overran (module docstring). Its work ran from the previous tick's
        start ``prev`` to ``entered`` (the wait's start) and took ``work_cpu_s`` of the thread's CPU time; ``gc_s``
        went to collections since ``prev``, in the work or in this wait."""
        if late - gc_s <= self.period_s:
            return "gc"
        if prev is None or entered <= deadline:
            return "stall"  # the work ended in time: the wake-up was late
        off_cpu = (entered - prev) - work_cpu_s
        if late - off_cpu <= self.period_s:
            return "stall"
        return "work"

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
        if self.factor is not None:
            out.update({f"overruns_{cause}": n for cause, n in self.causes.items()})
            out.update({f"overrun_episodes_{cause}": n for cause, n in self.episodes.items()})
            out["startup_ms"] = round(self.startup_s * 1e3, 4)
            out["ahead_pieces"] = self.ahead_pieces
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
