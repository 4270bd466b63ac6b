"""Issue 26 item 6: the pacer collects garbage and works ahead in slack time and says why each overrun happened
(fake clocks, a fake collector: nothing here is timed)."""

import gc

import numpy as np

from stand import telemetry
from stand.compose import build
from stand.loop import run
from stand.pacing import AHEAD_FIRST, AHEAD_MIN_S, AHEAD_PIECE_S, GC_DEFER, GC_SLACK_S, SPIN_S, Pacer
from tests.stand.test_pacing_telemetry import FakeClock
from tests.stand.test_run import short

TICK_S = 1e-3


class FakeCollector:
    """The part of the ``gc`` module the pacer uses; a collection costs ``cost_s`` of the fake clock."""

    def __init__(self, clock, cost_s=1e-4):
        self.clock, self.cost_s = clock, cost_s
        self.callbacks = []
        self.threshold = (700, 10, 10)
        self.count = [0, 0, 0]
        self.collected = []  # (generation, time left before the deadline being waited for)

    def get_threshold(self):
        return self.threshold

    def set_threshold(self, *th):
        self.threshold = th

    def get_count(self):
        return tuple(self.count)

    def collect(self, generation=2):
        for cb in list(self.callbacks):
            cb("start", {"generation": generation})
        self.clock.now += self.cost_s
        for cb in list(self.callbacks):
            cb("stop", {"generation": generation})
        self.collected.append(generation)
        self.count = [0, 0, 0] if generation == 2 else ([0, 0, self.count[2] + 1] if generation == 1
                                                           else [0, self.count[1] + 1, self.count[2]])


class CpuClock:
    """The thread's CPU time: advanced by the test only for work done on the CPU."""

    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def paced(collector=None):
    clock = FakeClock()
    gc_ = FakeCollector(clock) if collector is None else collector(clock)
    cpu = CpuClock()
    pacer = Pacer(1.0, TICK_S, clock=clock, sleep=clock.sleep, collector=gc_, thread_clock=cpu)
    return pacer, clock, gc_, cpu


def start(pacer):
    """The first two ticks, on time: the first one's work is the run's start-up, which moves the clock's zero when it
    overruns (test_a_first_tick_over_its_period_moves_the_clock_s_zero_not_the_later_deadlines)."""
    pacer.begin()
    pacer.wait(0.0)
    pacer.wait(TICK_S)


def test_a_paced_run_raises_the_gen0_threshold_and_end_gives_it_back():
    pacer, clock, gc_, _ = paced()
    pacer.begin()
    assert gc_.threshold == (700 * GC_DEFER, 10, 10) and gc_.callbacks == [pacer._on_gc]
    pacer.end()
    pacer.end()  # idempotent: the loop's clean end calls it whatever happened before
    assert gc_.threshold == (700, 10, 10) and gc_.callbacks == []


def test_a_second_paced_run_at_the_same_time_leaves_the_collector_to_the_first():
    first, clock, gc_, _ = paced()
    second = Pacer(1.0, TICK_S, clock=clock, sleep=clock.sleep, collector=gc_)
    first.begin()
    second.begin()
    assert gc_.threshold == (700 * GC_DEFER, 10, 10) and gc_.callbacks == [first._on_gc]
    first.end()
    second.end()
    assert gc_.threshold == (700, 10, 10) and gc_.callbacks == []


def test_an_afap_pacer_leaves_the_collector_alone():
    clock = FakeClock()
    gc_ = FakeCollector(clock)
    pacer = Pacer(None, TICK_S, clock=clock, sleep=clock.sleep, collector=gc_)
    pacer.begin()
    pacer.wait(0.0)
    assert gc_.threshold == (700, 10, 10) and gc_.callbacks == [] and gc_.collected == []


def test_slack_collection_runs_only_when_slack_exceeds_its_bound_and_a_collection_is_due():
    pacer, clock, gc_, _ = paced()
    pacer.begin()
    pacer.wait(0.0)
    gc_.count[0] = 700
    clock.now += TICK_S - GC_SLACK_S + 2e-4  # work leaves 0.2 ms less than the bound before the next deadline
    pacer.wait(1 * TICK_S)
    assert gc_.collected == []
    clock.now += TICK_S - GC_SLACK_S - 2e-4  # now 0.2 ms more than the bound
    pacer.wait(2 * TICK_S)
    assert gc_.collected == [0] and pacer.gc_in_slack == 1
    gc_.count[0] = 699  # fewer allocations than the collector's own threshold: nothing to collect
    pacer.wait(3 * TICK_S)
    assert gc_.collected == [0]
    gc_.count[:2] = [700, 10]  # gen 1 due as well: the young collection the collector would have run
    pacer.wait(4 * TICK_S)
    assert gc_.collected == [0, 1] and pacer.stats()["overruns"] == 0


def test_an_overrun_after_a_collection_in_the_work_is_put_down_to_gc():
    pacer, clock, gc_, cpu = paced(lambda clock: FakeCollector(clock, cost_s=2.5e-3))
    start(pacer)
    cpu.now += 2.6e-3
    gc_.collect(1)  # automatic, inside the tick's work: 2.5 ms
    clock.now += 1e-4
    pacer.wait(2 * TICK_S)
    stats = pacer.stats()
    assert stats["overruns"] == 1 and stats["overruns_gc"] == 1 and stats["overruns_work"] == 0


def test_work_over_the_period_on_the_cpu_counts_as_work_and_the_run_of_late_ticks_with_it():
    pacer, clock, _, cpu = paced()
    start(pacer)
    clock.now += 3.5e-3  # the tick's own work, on the CPU: the next two ticks start more than a tick late
    cpu.now += 3.5e-3
    for k in range(2, 7):
        pacer.wait(k * TICK_S)
    stats = pacer.stats()
    assert (stats["overruns"], stats["overruns_work"], stats["overruns_stall"], stats["overruns_gc"]) == (2, 2, 0, 0)
    assert stats["overrun_episodes_work"] == 1  # one run of two late ticks


def test_time_off_the_cpu_or_a_late_wake_up_counts_as_a_stall():
    pacer, clock, _, cpu = paced()
    start(pacer)
    clock.now += 2.5e-3  # descheduled: the wall clock moves, the thread's CPU time hardly
    cpu.now += 1e-4
    pacer.wait(2 * TICK_S)
    pacer.wait(3 * TICK_S)  # half a tick late: the end of that run of late ticks
    late_sleep = clock.sleep

    def oversleep(s):
        late_sleep(s + 2.5e-3)

    pacer.sleep = oversleep  # the work fits, the sleep wakes 2.5 ms late
    pacer.wait(5 * TICK_S)
    stats = pacer.stats()
    assert (stats["overruns"], stats["overruns_stall"], stats["overruns_work"], stats["overruns_gc"]) == (2, 2, 0, 0)
    assert stats["overrun_episodes_stall"] == 2


def test_a_paced_run_collects_in_slack_with_its_heap_frozen_and_gives_gc_back(scenario_dict, write_scenario,
                                                                               tmp_path):
    """In a paced run (a fake clock: nothing waits) the collector's gen-0 threshold is raised and the heap that existed
    at the start is frozen; afterwards gc's thresholds and callbacks are what they were."""
    seen = []

    class Observer:
        def record(self, t_s, row):
            seen.append((gc.get_threshold(), gc.get_freeze_count() > 0, len(gc.callbacks)))

        def poll_control(self):
            return None

    before = (gc.get_threshold(), list(gc.callbacks))
    clock = FakeClock()
    with build(short(scenario_dict, write_scenario, 3.0)) as scene:
        result = run(scene, tmp_path / "paced", speed=1.0, clock=clock, sleep=clock.sleep, observer=Observer())
    assert result.status == "completed" and result.timing["overruns"] == 0
    assert result.timing["overruns_gc"] == result.timing["overruns_work"] == result.timing["overruns_stall"] == 0
    th0 = before[0][0]
    assert seen and all(s == ((th0 * GC_DEFER, *before[0][1:]), True, len(before[1]) + 1) for s in seen)
    assert (gc.get_threshold(), list(gc.callbacks)) == before and gc.get_freeze_count() == 0


def test_an_afap_run_leaves_gc_thresholds_alone(scenario_dict, write_scenario, tmp_path):
    seen = []

    class Observer:
        def record(self, t_s, row):
            seen.append(gc.get_threshold())

        def poll_control(self):
            return None

    before = gc.get_threshold()
    with build(short(scenario_dict, write_scenario, 3.0)) as scene:
        run(scene, tmp_path / "afap", observer=Observer())
    assert seen and set(seen) == {before} and gc.get_threshold() == before


class Job:
    """Work ahead that costs ``cost_s`` of the fake clock per unit and has ``units`` to do."""

    def __init__(self, clock, cost_s, units):
        self.clock, self.cost_s, self.units = clock, cost_s, units
        self.asked = []

    def __call__(self, n):
        self.asked.append(n)
        done = min(n, self.units)
        self.units -= done
        self.clock.now += done * self.cost_s
        return done


def test_work_ahead_runs_in_slack_one_piece_a_tick_sized_from_what_pieces_cost():
    clock = FakeClock()
    job = Job(clock, 1e-6, 10_000)
    pacer = Pacer(1.0, TICK_S, clock=clock, sleep=clock.sleep, ahead=[job])
    pacer.begin()
    pacer.wait(0.0)  # the first deadline is now: no slack
    assert job.asked == []
    for k in range(1, 4):
        clock.now += 1e-4  # the tick's work
        pacer.wait(k * TICK_S)
    # The first piece is AHEAD_FIRST units; then as many as fit in AHEAD_PIECE_S at the cost the last piece measured: a
    # little over 1 us a unit (the fake clock adds 10 us per reading), so a little under 200.
    assert job.asked[0] == AHEAD_FIRST and len(job.asked) == 3
    assert AHEAD_PIECE_S == 2e-4 and all(100 <= n < 200 for n in job.asked[1:]), job.asked
    assert job.asked[2] > job.asked[1]  # the fixed cost of a piece (the clock's readings) weighs less as it grows
    assert pacer.ahead_pieces == 3 and pacer.stats()["overruns"] == 0


def test_no_work_ahead_without_slack_for_it_nor_in_a_run_as_fast_as_possible():
    clock = FakeClock()
    job = Job(clock, 1e-6, 10_000)
    pacer = Pacer(1.0, TICK_S, clock=clock, sleep=clock.sleep, ahead=[job])
    pacer.begin()
    pacer.wait(0.0)
    clock.now += TICK_S - SPIN_S - AHEAD_MIN_S + 2e-5  # the work leaves less than the spin and AHEAD_MIN_S
    pacer.wait(TICK_S)
    assert job.asked == []
    afap = Pacer(None, TICK_S, clock=clock, sleep=clock.sleep, ahead=[job])
    afap.begin()
    for k in range(3):
        afap.wait(k * TICK_S)
    assert job.asked == []


def test_a_tick_made_late_by_work_ahead_counts_it_as_work():
    pacer, clock, _, cpu = paced()

    def slow_piece(n):  # a piece that costs far more than measured before: 2.5 ms on the CPU
        clock.now += 2.5e-3
        cpu.now += 2.5e-3
        return n

    pacer._ahead, pacer._ahead_cost = [slow_piece], [1e-9]
    pacer.begin()
    pacer.wait(0.0)
    pacer.wait(1 * TICK_S)
    stats = pacer.stats()
    assert stats["overruns"] == 1 and stats["overruns_work"] == 1 and stats["overruns_stall"] == 0


def test_a_paced_run_that_works_ahead_writes_the_telemetry_of_a_run_as_fast_as_possible(scenario_dict,
                                                                                          write_scenario, tmp_path):
    """250 s of the default scenario at 0.1 s steps crosses the orbit track's first chunk (200 s): paced against a fake
    clock (every tick has its whole slack) the next chunk is built ahead in pieces, and every sample is the same."""
    sc = short(scenario_dict, write_scenario, 250.0)
    clock = FakeClock()
    with build(sc) as scene:
        paced_run = run(scene, tmp_path / "paced", speed=1.0, clock=clock, sleep=clock.sleep)
        pieces = scene.truth.track.evaluations
    with build(sc) as scene:
        afap_run = run(scene, tmp_path / "afap")
        whole = scene.truth.track.evaluations
    assert paced_run.status == afap_run.status == "completed" and paced_run.timing["overruns"] == 0
    assert pieces > whole  # the paced run built a chunk ahead (the third, beyond the run's end, in part)
    paced_tel, afap_tel = telemetry.load(tmp_path / "paced"), telemetry.load(tmp_path / "afap")
    assert set(paced_tel) == set(afap_tel)
    for name in afap_tel:
        assert np.array_equal(paced_tel[name], afap_tel[name]), name
