"""The magnetometer as a device kind of its own: registered, validated by its own table, served and emulated; the
shipped detumble with a standalone magnetometer passes; telemetry of the magnetorquer and the magnetometer observes
the bus beside the flight code, never through its drivers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stand import devices, telemetry
from stand.cli import main
from stand.scenario import DEFAULT_SCENARIO, SCENARIO_DIR

MAGNETOMETER = """
[[devices]]
name = "mag"
kind = "magnetometer"
interface = "stand_loopback"
channel = "stand-mtq"
"""


def _scenario(tmp_path, controller: str, extra: str = MAGNETOMETER) -> str:
    head, tail = DEFAULT_SCENARIO.read_text().split("\n[controller]\n", 1)
    tail = tail.split("\n[[criteria]]\n", 1)[1]
    path = tmp_path / "scenario.toml"
    path.write_text(f"{head}{extra}\n[controller]\n{controller}\n[[criteria]]\n{tail}")
    return str(path)


def test_magnetometer_is_a_shipped_kind():
    assert devices.get("magnetometer").name == "magnetometer"
    assert "magnetometer" in devices.kind_names() and devices.get("magnetometer").serving is not None


@pytest.mark.parametrize("names", [("mtq",), ("mtq", "mag")])
def test_telemetry_observes_the_bus_beside_a_flight_code_that_never_reads_its_drivers(tmp_path, names):
    out = tmp_path / "out"
    extra = MAGNETOMETER if "mag" in names else ""
    code = main(["run", _scenario(tmp_path, 'kind = "none"\n', extra), "--duration", "5", "--out", str(out),
                 "--no-progress", "--no-plots"])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed", code
    tel = telemetry.load(out)
    assert len(tel["t_s"]) == 51
    columns = {"mtq": ("mtq.mag_S", "mtq.mag_coil_active"), "mag": ("mag.mag_S", "mag.mag_valid")}
    for column in (c for n in names for c in columns[n]):
        assert np.all(np.isfinite(tel[column])), column  # a whole row from the first tick on
    # Noise-free, unit and board on body axes: what they sent is the true field, to half their step (5 nT, 1 nT).
    half_step = {"mtq": 2.5e-9, "mag": 0.5e-9}
    counters = summary["device_counters"]
    for name in names:
        assert np.max(np.abs(tel[f"{name}.mag_S"] - tel["b_true_B"])) <= half_step[name] * (1 + 1e-6), name
        # The flight code's driver was never read, by the flight code or by telemetry.
        assert counters[name]["received"] == 0 and counters[name]["samples"] == 0, name
        assert counters[name]["emulator"]["sent"] >= 50, name
        assert counters[name]["silences"] == 0, name  # the watch saw the samples too


def test_the_shipped_detumble_with_a_standalone_magnetometer_passes(tmp_path):
    out = tmp_path / "out"
    code = main(["run", "detumble_magnetometer", "--out", str(out), "--no-progress", "--no-plots"])
    summary = json.loads((out / "summary.json").read_text())
    assert code == 0 and all(c["pass"] for c in summary["criteria"]), summary["criteria"]
    counters = summary["device_counters"]
    # The B-dot read the standalone unit: every sample it sent reached the flight code, the board's were left alone.
    assert counters["mag"]["samples"] >= 10 * 5677 - 1  # 10 Hz for 5677 s, the last one after the last control tick
    assert counters["mtq"]["samples"] == 0 and counters["mtq"]["emulator"]["commands_accepted"] > 50_000


def test_bdot_reads_the_board_or_a_standalone_magnetometer():
    from stand.adcs import BDot

    class Sensor:
        def __init__(self, b_T):
            self.b_T, self.taken, self.commands = b_T, 0, []

        def take_sample(self):
            from drivers.magnetometer.codec import MagSample

            self.taken += 1
            self.b_T = tuple(x + 1e-6 for x in self.b_T)
            return MagSample(self.b_T, False, True, self.taken)

        def command_dipole(self, m, duration_s):
            self.commands.append(m)

    for standalone in (False, True):
        board, unit = Sensor((1e-5, 0.0, 0.0)), Sensor((0.0, 2e-5, 0.0))
        ctl = BDot(board, 0.1, 5e4, 0.2, sensor=unit if standalone else None)
        ctl.update(0.0)
        ctl.update(0.1)
        assert (unit.taken, board.taken) == ((2, 0) if standalone else (0, 2))
        assert board.commands == [pytest.approx((-0.2, -0.2, -0.2))] and unit.commands == []  # -k dB/dt, clipped


@pytest.mark.parametrize("value, message", [
    ("nope", "controller.magnetometer = 'nope'"),
    ("mtq", "controller.magnetometer = 'mtq'"),  # the board itself: leave the key out instead
])
def test_bdot_names_its_magnetometer_among_the_devices_that_sense_the_field(value, message):
    import tomllib

    from stand.errors import ScenarioError
    from stand.scenario import SCENARIO_DIR, parse

    data = tomllib.loads((SCENARIO_DIR / "detumble_magnetometer.toml").read_text())
    sc = parse(data, "detumble_magnetometer.toml")
    assert sc.controller.params["magnetometer"] == "mag"
    data["controller"]["magnetometer"] = value
    with pytest.raises(ScenarioError, match=message):
        parse(data, "x.toml")


@pytest.mark.parametrize("setting, message", [
    ("devices.mag.lsb_nT=1.5", "devices[1].lsb_nT = 1.5"),
    ("devices.mag.noise_nT=-1", "devices[1].noise_nT = -1"),
    ("devices.mag.sample_rate=3", "devices[1].sample_rate"),
])
def test_bad_magnetometer_values_are_one_sentence_and_exit_2(tmp_path, capsys, setting, message):
    code = main(["check", _scenario(tmp_path, 'kind = "none"\n'), "--set", setting])
    err = capsys.readouterr().err
    assert code == 2 and message in err and "Traceback" not in err, err


def test_the_example_scenario_ships():
    assert (SCENARIO_DIR / "detumble_magnetometer.toml").is_file()
