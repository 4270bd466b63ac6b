"""Pacing against a fake clock, and the telemetry log format."""

import json

import numpy as np
import pytest

from stand import telemetry
from stand.pacing import Pacer, parse_speed


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        self.now += 1e-5  # reading a clock takes time; the pacer's final spin relies on it
        return self.now

    def sleep(self, s):
        self.now += s


def test_realtime_pacing_holds_absolute_deadlines():
    clock = FakeClock()
    pacer = Pacer(2.0, 0.1, clock=clock, sleep=clock.sleep)
    pacer.begin()
    for k in range(20):
        pacer.wait(k * 0.1)
        assert clock.now == pytest.approx(100.0 + k * 0.05, abs=1e-3)
        clock.now += 0.01  # work of the tick
    assert pacer.stats()["overruns"] == 0


def test_overruns_are_counted_and_do_not_accumulate():
    clock = FakeClock()
    pacer = Pacer(1.0, 0.1, clock=clock, sleep=clock.sleep)
    pacer.begin()
    pacer.wait(0.0)
    pacer.wait(0.1)
    clock.now += 0.35  # a stall of 3.5 ticks
    for k in range(2, 11):
        pacer.wait(k * 0.1)
        clock.now += 0.001
    stats = pacer.stats()
    assert stats["overruns"] == 2  # ticks 2 and 3 started more than one tick (0.1 s) late; tick 4 only 0.05 s
    assert clock.now == pytest.approx(101.0 + 0.001, abs=1e-3)  # back on the absolute schedule
    assert stats["lateness_ms_max"] == pytest.approx(250.0, abs=1.0)


def test_a_first_tick_over_its_period_moves_the_clock_s_zero_not_the_later_deadlines():
    """The first tick is the run's start-up: its 0.35 s over a 0.1 s period moves the schedule by 0.25 s and is
    reported; a later stall does not move it."""
    clock = FakeClock()
    pacer = Pacer(1.0, 0.1, clock=clock, sleep=clock.sleep)
    pacer.begin()
    pacer.wait(0.0)
    clock.now += 0.35
    pacer.wait(0.1)
    assert pacer.stats()["startup_ms"] == pytest.approx(250.0, abs=0.1)
    assert pacer.stats()["overruns"] == 0 and pacer.stats()["lateness_ms_max"] < 0.1  # the fake clock's readings
    t1 = clock.now
    pacer.wait(0.2)
    assert clock.now == pytest.approx(t1 + 0.1, abs=1e-3)
    clock.now += 0.35
    pacer.wait(0.3)
    stats = pacer.stats()
    assert stats["overruns"] == 1 and stats["startup_ms"] == pytest.approx(250.0, abs=0.1)


@pytest.mark.parametrize("text, factor", [("afap", None), ("realtime", 1.0), ("2.5", 2.5)])
def test_parse_speed(text, factor):
    assert parse_speed(text) == factor


@pytest.mark.parametrize("text", ["0", "-1", "inf", "fast"])
def test_parse_speed_refuses(text):
    with pytest.raises(ValueError, match="--speed"):
        parse_speed(text)


def test_log_round_trip_and_partial_row_is_ignored(tmp_path):
    cols = [("t_s", 1, "s"), ("q_BN", 4, "1")]
    with telemetry.Recorder(tmp_path, cols) as rec:
        for k in range(5000):
            rec.record((k * 0.1, 1.0, 0.0, 0.0, float(k)))
    data = tmp_path / "telemetry" / "rows.f64"
    with open(data, "ab") as f:  # a write cut in the middle of a row, as after a kill
        f.write(np.array([1.0, 2.0], dtype="<f8").tobytes())
    tel = telemetry.load(tmp_path)
    assert tel["t_s"].shape == (5000,) and tel["q_BN"].shape == (5000, 4)
    assert tel["q_BN"][-1, 3] == 4999.0
    assert telemetry.units(tmp_path)["q_BN"] == "1"
    assert json.loads((tmp_path / "telemetry" / "schema.json").read_text())["row_floats"] == 5


def test_load_names_a_directory_without_telemetry(tmp_path):
    with pytest.raises(FileNotFoundError, match="no telemetry"):
        telemetry.load(tmp_path)


# --------------------------------------------------------------------------- no silent loss (issue 22)
COLS = [("t_s", 1, "s"), ("q_BN", 4, "1")]


def test_a_row_of_the_wrong_width_is_refused_where_it_is_recorded_and_the_rows_before_are_kept(tmp_path):
    rec = telemetry.Recorder(tmp_path, COLS)
    for k in range(10):
        rec.record((k * 0.1, 1.0, 0.0, 0.0, 0.0))
    with pytest.raises(telemetry.TelemetryError, match=r"has 6 values but the 2 columns declared hold 5 "
                                                       r"\(t_s 1, q_BN 4\)"):
        rec.record((1.0, 1.0, 0.0, 0.0, 0.0, 9.0))
    rec.close()
    assert len(telemetry.load(tmp_path)["t_s"]) == 10


def test_a_row_that_is_not_numbers_ends_the_writer_loudly_and_keeps_the_rows_before_it(tmp_path):
    rec = telemetry.Recorder(tmp_path, COLS)
    for k in range(10):
        rec.record((k * 0.1, 1.0, 0.0, 0.0, 0.0))
    rec.record((1.0, 1.0, (0.0, 1.0), 0.0, 0.0))  # the right length, but one value is a pair
    with pytest.raises(telemetry.TelemetryError, match=r"at t = 1.0 s .*the rows before are kept"):
        rec.close()  # the bad row and the good ones share one batch: the good ones are written
    assert len(telemetry.load(tmp_path)["t_s"]) == 10


def test_a_writer_failure_of_any_exception_type_is_reported(tmp_path, monkeypatch):
    def broken(self, batch):
        raise RuntimeError("not an OSError")

    monkeypatch.setattr(telemetry.Recorder, "_write", broken)
    rec = telemetry.Recorder(tmp_path, COLS)
    rec.record((0.0, 1.0, 0.0, 0.0, 0.0))
    with pytest.raises(telemetry.TelemetryError, match="telemetry writer stopped .RuntimeError: not an OSError"):
        rec.close()


def _retained_bytes(n_ticks: int) -> int:
    """Memory a paced Pacer still holds after ``n_ticks`` waits (fake clock: no real waiting)."""
    import gc
    import tracemalloc

    clock = FakeClock()
    gc.collect()
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    pacer = Pacer(1.0, 0.1, clock=clock, sleep=clock.sleep)
    pacer.begin()
    for k in range(n_ticks):
        pacer.wait(k * 0.1)
        clock.now += 0.0003 * (k % 7)  # some work per tick: lateness varies
    stats = pacer.stats()
    gc.collect()
    retained = tracemalloc.get_traced_memory()[0] - before
    tracemalloc.stop()
    assert stats["lateness_ms_max"] > 0 and "period_ms_std" in stats
    del pacer
    return retained


def test_the_pacer_holds_the_same_memory_however_long_the_run():
    """Issue 22: a paced run grew about 82 bytes per tick (every tick's lateness and start kept). 20000 ticks more
    may not cost more than 1 byte per tick (the fixed-size statistics need none; the margin is tracemalloc noise)."""
    short_run, long_run = _retained_bytes(2_000), _retained_bytes(22_000)
    assert long_run - short_run < 20_000, (short_run, long_run)


def test_pacer_percentiles_are_numpys_to_the_bin_resolution():
    """The fixed-size statistics against numpy over every sample: 1 us bins below 10 ms, 100 us above."""
    pacer = Pacer(1.0, 0.1)
    rng = np.random.default_rng(5)
    late = np.concatenate([rng.uniform(0.0, 0.002, 970), rng.uniform(0.012, 0.05, 30)])
    rng.shuffle(late)
    starts = np.arange(1000) * 0.1 + late
    for lt, st in zip(late, starts, strict=True):
        pacer._note(float(lt), float(st))
    stats = pacer.stats()
    assert stats["lateness_ms_p50"] == pytest.approx(np.percentile(late, 50) * 1e3, abs=0.001)
    assert stats["lateness_ms_p99"] == pytest.approx(np.percentile(late, 99) * 1e3, abs=0.1)
    assert stats["lateness_ms_max"] == round(late.max() * 1e3, 4)
    period = np.diff(starts) * 1e3
    assert stats["period_ms_std"] == pytest.approx(period.std(), abs=1e-3)
    assert stats["period_ms_worst_late"] == pytest.approx(period.max() - 100.0, abs=1e-3)
