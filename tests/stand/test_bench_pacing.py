"""The 1 kHz pacing case of ``stand bench pacing`` is the case the issue names, and says what limits it."""

import pytest

from stand.benches import BENCHES
from stand.benches.pacing import FAST_TICK_S, bare_loop, fast_case, limit_of
from tests.stand.test_pacing_telemetry import FakeClock


def test_the_1khz_case_has_a_1ms_tick_a_200hz_gyro_and_1khz_wheels():
    sc = fast_case(3.0)
    assert sc.step_s == 1e-3 and sc.duration_s == 3.0 and sc.criteria == ()
    gyros = [d for d in sc.devices if d.kind == "gyro"]
    wheels = [d for d in sc.devices if d.kind == "reaction_wheel"]
    assert [g.output_rate_hz for g in gyros] == [200.0]
    assert len(wheels) == 4 and all(w.telemetry_rate_hz == 1.0 / FAST_TICK_S for w in wheels)
    assert BENCHES["pacing"] == "stand.benches.pacing:bench_pacing"


def test_limit_names_the_tick_work_when_it_does_not_fit():
    assert "does not fit the 1000 us tick" in limit_of(1200.0, 5.0, {"overruns": 300, "overruns_work": 300})
    assert limit_of(300.0, 0.05, {"overruns": 0}).startswith("within the goal")


def test_limit_names_the_stand_when_gc_or_its_own_work_overran_and_the_machine_otherwise():
    stand = limit_of(300.0, 0.4, {"overruns": 5, "overruns_gc": 1, "overruns_work": 2, "overruns_stall": 2,
                                  "overrun_episodes_gc": 1, "overrun_episodes_work": 1, "overrun_episodes_stall": 2},
                     {"overruns": 3})
    assert stand.startswith("the stand for at most 3 of 5 overruns, the machine for the rest: 1 from garbage "
                            "collection (1 episodes), 2 from the tick's own work over the period (1 episodes), 2 from "
                            "stalls (2 episodes)")
    assert "the bare loop pacing nothing saw 3 overruns" in stand
    machine = limit_of(300.0, 0.4, {"overruns": 4, "overruns_gc": 0, "overruns_work": 0, "overruns_stall": 4},
                       {"overruns": 6})
    assert machine.startswith("the machine:") and "the 4 overruns are stalls" in machine and "chrt -f" in machine


def test_the_bare_loop_control_paces_nothing_with_the_same_pacer():
    clock = FakeClock()
    stats = bare_loop(0.5, 1e-3, clock=clock, sleep=clock.sleep)
    assert stats["ticks"] == 500 and stats["paced"] and stats["overruns"] == 0
    assert clock.now - 100.0 == pytest.approx(0.499, abs=2e-4)  # the last deadline, 499 ticks after the first
