"""What a scenario or a device may not do to the stand: connect out, escape the output folder, go silent unseen,
or take the summary down with a bus that fails to close."""

from __future__ import annotations

import json
import tomllib

import pytest

from stand import scenario
from stand.compose import build
from stand.errors import ScenarioError
from stand.loop import run
from stand.report import write_summary
from stand.scenario import SCENARIO_DIR

from .conftest import to_toml


def _default(tmp_path, **device_changes) -> dict:
    data = tomllib.loads((SCENARIO_DIR / "detumble.toml").read_text())
    data["devices"][0]["channel"] = f"hostile-{tmp_path.name}"
    data["devices"][0].update(device_changes)
    return data


def _load(tmp_path, data):
    path = tmp_path / "s.toml"
    path.write_text(to_toml(data))
    return scenario.load(path)


@pytest.mark.parametrize("changes, field", [
    ({"link": "served", "interface": "slcan", "channel": "socket://10.1.2.3:45999"}, "channel"),
    ({"link": "hardware", "interface": "serial", "channel": "rfc2217://example.org:1"}, "channel"),
    ({"interface": "udp_multicast", "channel": "239.0.0.1"}, "interface"),  # emulated stays in the process
    ({"link": "hardware", "interface": "some_vendor", "channel": "x"}, "interface"),
])
def test_a_scenario_cannot_make_the_stand_connect_out(tmp_path, changes, field):
    with pytest.raises(ScenarioError) as info:
        _load(tmp_path, _default(tmp_path, **changes))
    assert info.value.field == f"devices[0].{field}"


@pytest.mark.parametrize("name", ["/tmp/x/escaped", "../../x", "a/b", ".hidden", "nul\x00byte", "x" * 101])
def test_run_names_stay_inside_the_output_folder(tmp_path, name):
    data = _default(tmp_path)
    data["scenario"]["name"] = name
    with pytest.raises(ScenarioError) as info:
        scenario.parse(data, "s.toml")
    assert info.value.field == "scenario.name" and "\x00" not in str(info.value)


def test_a_silent_star_tracker_is_logged_and_heard_again(tmp_path):
    data = _default(tmp_path)
    data["scenario"]["duration_s"] = 40.0
    data["devices"].append({"name": "st1", "kind": "star_tracker", "boot_time_s": 0.2, "rate_limit_deg_s": 20.0})
    data["criteria"] = [c for c in data["criteria"] if c["metric"] == "frames_rejected"]
    sc = _load(tmp_path, data)
    out = tmp_path / "out"
    with build(sc) as scene:
        tracker = scene.devices["st1"]
        service = tracker.emulator.service
        # The device goes quiet from 5 s to 30 s (it reads, but sends nothing).
        tracker.emulator.service = lambda t: None if 5.0 <= t < 30.0 else service(t)
        result = run(scene, out)
    assert result.status == "completed" and result.counters["st1"]["silences"] == 1
    events = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
    silent = next(e for e in events if e["kind"] == "device_silent")
    assert silent["device"] == "st1" and 5.0 < silent["t_s"] <= 8.0
    back = next(e for e in events if e["kind"] == "device_recovered")
    assert back["device"] == "st1" and 30.0 <= back["t_s"] <= 32.0


def test_a_bus_that_raises_on_shutdown_does_not_take_the_summary_down(tmp_path):
    sc = _load(tmp_path, {**_default(tmp_path), "scenario": {**_default(tmp_path)["scenario"], "duration_s": 5.0}})
    out = tmp_path / "out"
    with build(sc) as scene:
        result = run(scene, out)
        bus = scene.devices["mtq"]._buses[0]
        real = bus.shutdown

        def broken():
            real()
            raise OSError("peer closed the connection")

        bus.shutdown = broken
    assert scene.closed and scene.close_errors and "peer closed" in scene.close_errors[0]
    summary = write_summary(scene, result, out, plots=False)
    assert json.loads((out / "summary.json").read_text())["status"] == summary["status"] == "completed"
