"""The 1 kHz pacing case of ``stand bench pacing`` is the case the issue names, and says what limits it."""

from stand.benches import BENCHES
from stand.benches.pacing import FAST_TICK_S, fast_case, limit_of


def test_the_1khz_case_has_a_1ms_tick_a_200hz_gyro_and_1khz_wheels():
    sc = fast_case(3.0)
    assert sc.step_s == 1e-3 and sc.duration_s == 3.0 and sc.criteria == ()
    gyros = [d for d in sc.devices if d.kind == "gyro"]
    wheels = [d for d in sc.devices if d.kind == "reaction_wheel"]
    assert [g.output_rate_hz for g in gyros] == [200.0]
    assert len(wheels) == 4 and all(w.telemetry_rate_hz == 1.0 / FAST_TICK_S for w in wheels)
    assert BENCHES["pacing"] == "stand.benches.pacing:bench_pacing"


def test_limit_names_the_tick_work_when_it_does_not_fit():
    assert "does not fit the 1000 us tick" in limit_of(1200.0, 5.0, 300)
    assert "the late ticks are the slow ones" in limit_of(300.0, 0.4, 2)
    assert limit_of(300.0, 0.05, 0).startswith("within the goal")
