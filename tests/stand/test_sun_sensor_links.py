"""The sun sensor's links: emulated (the serial protocol in the loop, the same numbers as the model to within one
LSB), served (the stand's emulator read by a host in this process through a socat pty pair) and hardware (the
stand's host reading an emulator in another process)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from stand import scenario, telemetry
from stand.compose import build
from stand.loop import run
from tests.stand.processes import run_beside_device, run_stand_polling

from .conftest import to_toml

#: One LSB of the wire: 0.1 uA per head current, 1 urad per angle.
CURRENT_LSB_A = 1e-7
ANGLE_LSB_RAD = 1e-6

PLUGIN = """
import math

from drivers.sun_sensor.codec import CoarseSunSample, FineSunSample


class ReadsSun:
    def __init__(self, devices, period_s):
        self.css, self.fss = devices["css"], devices["fss"]
        self.last = (math.nan,) * 8
        self.shapes = set()

    def telemetry_columns(self):
        return [("fsw.css", 6, "A"), ("fsw.fss", 2, "rad")]

    def telemetry(self):
        return self.last

    def update(self, t_s):
        c, f = self.css.take_sun(), self.fss.take_sun()
        if c is not None:
            self.shapes.add(type(c).__name__)
            self.last = (*c.currents_A, *self.last[6:])
        if f is not None:
            self.shapes.add(type(f).__name__)
            self.last = (*self.last[:6], *f.angles_rad)
"""


def sun_scenario(devices: list[dict], *, duration_s: float = 400.0, controller: dict | None = None) -> dict:
    """A tumbling spacecraft that enters the Earth's shadow after about 200 s (the equinox orbit holds the Sun in
    its plane; argument of latitude 100 deg at t = 0, umbra from about 112 deg)."""
    return {
        "scenario": {"name": "sun_links", "epoch": "2026-03-20T12:00:00Z", "duration_s": duration_s, "seed": 3},
        "dynamics": {"step_s": 0.1, "integrator": "rk4", "torques": []},
        "orbit": {"altitude_km": 500.0, "i_deg": 97.4, "nu_deg": 100.0},
        "spacecraft": {"mass_kg": 4.0, "inertia_kg_m2": [0.02, 0.02, 0.01], "q_BN": [1.0, 0.0, 0.0, 0.0],
                       "omega_BN_B_deg_s": [1.0, 2.0, 3.0]},
        "devices": devices,
        "controller": controller or {"kind": "none"},
        "recording": {"rate_hz": 10.0},
    }


def both_sensors(link: str) -> list[dict]:
    return [{"name": "css", "kind": "sun_sensor", "type": "coarse", "link": link, "rate_hz": 10.0, "noise_mA": 0.005},
            {"name": "fss", "kind": "sun_sensor", "type": "fine", "link": link, "rate_hz": 5.0, "noise_deg": 0.05}]


def _run(tmp_path: Path, name: str, data: dict):
    path = tmp_path / f"{name}.toml"
    path.write_text(to_toml(data))
    with build(scenario.load(path), base=tmp_path) as scene:
        result = run(scene, tmp_path / name)
        controller = scene.controller
    assert result.status == "completed"
    return telemetry.load(tmp_path / name), result.counters, controller


def test_emulated_is_the_default_link_and_the_model_link_stays():
    from stand.devices import get

    kind = get("sun_sensor")
    assert kind.default_link == "emulated" and set(kind.links) == {"emulated", "hardware", "served", "model"}


def test_emulated_link_carries_the_models_readings_to_within_one_lsb_and_is_invalid_in_umbra(tmp_path):
    (tmp_path / "fsw.py").write_text(PLUGIN)
    plugin = {"kind": "plugin", "rate_hz": 10.0, "module": "fsw:ReadsSun", "path": str(tmp_path)}
    model, _, _ = _run(tmp_path, "model", sun_scenario(both_sensors("model"), controller=plugin))
    emu, counters, fsw = _run(tmp_path, "emulated", sun_scenario(both_sensors("emulated"), controller=plugin))
    again, _, _ = _run(tmp_path, "again", sun_scenario(both_sensors("emulated"), controller=plugin))

    assert fsw.shapes == {"CoarseSunSample", "FineSunSample"}
    # The truth is the same (nothing acts on it), so each sample is the model's reading through the wire.
    assert np.array_equal(model["css.sun_fraction"], emu["css.sun_fraction"])
    nu = emu["css.sun_fraction"]
    umbra, lit = nu == 0.0, nu == 1.0
    assert umbra.sum() > 500 and lit.sum() > 500
    assert np.array_equal(model["css.valid"], emu["css.valid"]) and np.all(emu["css.valid"][umbra] == 0.0)
    assert np.max(np.abs(model["css.currents"] - emu["css.currents"])) <= 0.5 * CURRENT_LSB_A * (1 + 1e-6)
    # Currents are whole LSBs: the host recorded what it decoded, not the model's value.
    assert np.allclose(emu["css.currents"] / CURRENT_LSB_A, np.round(emu["css.currents"] / CURRENT_LSB_A),
                       rtol=0, atol=1e-6)
    assert not np.array_equal(model["css.currents"], emu["css.currents"])

    assert np.array_equal(model["fss.valid"], emu["fss.valid"])
    fss_umbra = emu["fss.sun_fraction"] == 0.0
    assert fss_umbra.sum() > 500 and np.all(emu["fss.valid"][fss_umbra] == 0.0)
    ok = emu["fss.valid"] == 1.0
    assert ok.sum() > 100
    assert np.max(np.abs(model["fss.angles"][ok] - emu["fss.angles"][ok])) <= 0.5 * ANGLE_LSB_RAD * (1 + 1e-6)
    # What the flight code read is what the stand recorded from its host (the controller does not run at the
    # final tick).
    row_ok = np.isfinite(emu["fsw.fss"][:, 0]) & ok
    row_ok[-1] = False
    assert np.array_equal(emu["fsw.fss"][row_ok], emu["fss.angles"][row_ok])
    read = np.isfinite(emu["fsw.css"][:, 0])
    read[-1] = False
    assert read.sum() > 3000 and np.array_equal(emu["fsw.css"][read], emu["css.currents"][read])

    for name, rate_hz in (("css", 10.0), ("fss", 5.0)):
        c = counters[name]
        assert c["host_counters"]["samples"] == c["emulator_counters"]["sent"] == 400 * rate_hz + 1
        assert c["host_counters"]["samples_lost"] == 0 and c["host_counters"]["rejected_crc"] == 0
    # Settled within every tick: a second run is the same bit for bit.
    for column in ("css.currents", "fss.angles", "fss.valid", "fsw.fss"):
        assert np.array_equal(emu[column], again[column], equal_nan=True)


@pytest.mark.slow
def test_served_link_streams_to_a_host_in_another_process(pty_pair, tmp_path):
    from drivers.sun_sensor.host import SunSensorHost

    stand_end, peer_end = pty_pair
    served = {"name": "css", "kind": "sun_sensor", "type": "coarse", "link": "served", "port": stand_end,
              "rate_hz": 5.0}
    path = tmp_path / "served.toml"
    path.write_text(to_toml(sun_scenario([served], duration_s=20.0)))
    out = tmp_path / "out"
    samples, answered = [], []
    with SunSensorHost(peer_end, name="fc sun sensor") as host:

        def take():
            s = host.take_sun()
            if s is not None:
                samples.append(s)
            if not answered and len(samples) >= 10:
                answered.append(host.request_sun(timeout_s=5.0))
                samples.append(answered[0])

        code, log = run_stand_polling(["run", str(path), "--speed", "4", "--out", str(out), "--no-progress",
                                       "--no-plots"], tmp_path, take)
        host.poll()
        counters = dict(host.counters)
    assert code == 0, log
    summary = json.loads((out / "summary.json").read_text())
    emu = summary["device_counters"]["css"]["emulator_counters"]
    assert emu["requests"] == 1 and counters["rejected_crc"] == counters["rejected_other"] == 0
    assert len(samples) >= 40 and counters["samples"] == emu["sent"]
    seqs = [s.seq for s in samples]
    assert seqs == sorted(seqs) and counters["samples_lost"] == 0
    assert all(type(s).__name__ == "CoarseSunSample" and s.valid for s in samples)
    # Samples are measured on the ticks (the streamed ones on the 0.2 s grid, the requested one at its tick);
    # each one carries the currents the stand recorded at that tick.
    streamed = [s for s in samples if not any(s is a for a in answered)]
    assert all(s.time_us % 100_000 == 0 for s in samples)
    assert sum(s.time_us % 200_000 != 0 for s in streamed) <= 1
    tel = telemetry.load(out)
    recorded = {round(t * 1e6): tuple(c) for t, c in zip(tel["t_s"], tel["css.currents"], strict=True)}
    matched = [s for s in streamed if s.time_us in recorded]
    assert len(matched) >= 40 and all(recorded[s.time_us] == s.currents_A for s in matched)


EMULATOR = """
import json, sys
from drivers.sun_sensor.emulator import SunEmulatorConfig, SunSensorEmulator

port, duration = sys.argv[1], float(sys.argv[2])
emu = SunSensorEmulator(port, lambda t: ((0.1234567, -0.2), True, 0.8), SunEmulatorConfig(kind="fine"))
with emu:
    print("ready", flush=True)
    emu.run(duration)
    print(json.dumps({"period_s": emu.period_s, "counters": emu.counters}), flush=True)
"""


def test_hardware_link_reads_an_emulator_in_another_process(pty_pair, tmp_path):
    stand_end, device_end = pty_pair
    hardware = {"name": "fss", "kind": "sun_sensor", "type": "fine", "link": "hardware", "port": stand_end,
                "rate_hz": 5.0}
    path = tmp_path / "hw.toml"
    path.write_text(to_toml(sun_scenario([hardware], duration_s=12.0)))
    out = tmp_path / "hw"
    code, emu_out = run_beside_device(EMULATOR, device_end, path, out, tmp_path)
    assert code == 0, emu_out
    report = json.loads(emu_out.strip().splitlines()[-1])
    # The stand set the sensor's output period to the scenario's rate at start.
    assert report["period_s"] == pytest.approx(0.2) and report["counters"]["commands_applied"] == 1
    summary = json.loads((out / "summary.json").read_text())
    host = summary["device_counters"]["fss"]["host_counters"]
    assert host["samples"] >= 10 and host["rejected_crc"] == host["rejected_other"] == 0
    tel = telemetry.load(out)
    got = np.isfinite(tel["fss.angles"][:, 0])
    assert got.sum() >= 30
    # The source's 0.1234567 rad crossed the wire as 123457 urad.
    assert np.allclose(tel["fss.angles"][got], [0.123457, -0.2], rtol=0, atol=1e-12)
    assert np.all(tel["fss.valid"][got] == 1.0)
    assert np.all(np.isnan(tel["fss.sun_fraction"]))  # nothing simulated for a hardware sensor


def test_link_settings_are_checked(tmp_path):
    from stand.errors import ScenarioError

    def load(device):
        path = tmp_path / "s.toml"
        path.write_text(to_toml(sun_scenario([{"name": "s", "kind": "sun_sensor", "type": "fine", **device}])))
        return scenario.load(path)

    with pytest.raises(ScenarioError, match="port"):
        load({"link": "hardware"})
    with pytest.raises(ScenarioError, match="socket://"):
        load({"link": "served", "port": "socket://10.0.0.1:5000"})
    with pytest.raises(ScenarioError, match="pty"):
        load({"link": "emulated", "port": "/dev/ttyUSB1"})
    with pytest.raises(ScenarioError, match="SET_OUTPUT_PERIOD"):
        load({"link": "hardware", "port": "/dev/ttyUSB1", "rate_hz": 0.01})
    assert load({"link": "model", "rate_hz": 0.01}).devices[0].link == "model"
    spec = load({"link": "hardware", "port": "/dev/ttyUSB1", "baudrate": 9600}).devices[0]
    assert (spec.port, spec.baudrate) == ("/dev/ttyUSB1", 9600)


def test_a_sun_sensor_that_stops_sending_is_logged_silent_and_heard_again(tmp_path):
    fss = {"name": "fss", "kind": "sun_sensor", "type": "fine", "rate_hz": 5.0}
    path = tmp_path / "s.toml"
    path.write_text(to_toml(sun_scenario([fss], duration_s=40.0)))
    out = tmp_path / "out"
    with build(scenario.load(path)) as scene:
        device = scene.devices["fss"]
        assert device.silent_after_s == pytest.approx(2.0)  # ten sample periods
        emulator = device.emulator
        service = emulator.service

        def quiet_from_5_to_30_s(t_s):
            # The sensor keeps sampling but sends nothing.
            emulator.silent = 5.0 <= t_s < 30.0
            service(t_s)

        emulator.service = quiet_from_5_to_30_s
        result = run(scene, out)
    assert result.status == "completed" and result.counters["fss"]["silences"] == 1
    events = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
    silent = next(e for e in events if e["kind"] == "device_silent")
    assert silent["device"] == "fss" and 5.0 + 2.0 <= silent["t_s"] <= 5.0 + 3.0
    back = next(e for e in events if e["kind"] == "device_recovered")
    assert back["device"] == "fss" and 30.0 <= back["t_s"] <= 31.0
