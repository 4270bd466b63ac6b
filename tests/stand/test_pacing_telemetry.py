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
    clock.now += 0.35  # a stall of 3.5 ticks
    for k in range(1, 10):
        pacer.wait(k * 0.1)
        clock.now += 0.001
    stats = pacer.stats()
    assert stats["overruns"] == 2  # ticks 1 and 2 started more than one tick (0.1 s) late; tick 3 only 0.05 s
    assert clock.now == pytest.approx(100.9 + 0.001, abs=1e-3)  # back on the absolute schedule
    assert stats["lateness_ms_max"] == pytest.approx(250.0, abs=1.0)


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
