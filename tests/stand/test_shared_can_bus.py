"""The default scenario's magnetorquer with four idle reaction wheels on its CAN bus, as the wheel ICD allows: no
device counts the others' frames as rejected, so "no rejected frames" holds and the board still takes every
command of the B-dot controller."""

from __future__ import annotations

import json

from stand.cli import main
from stand.scenario import DEFAULT_SCENARIO

WHEELS = 4
RUN_S = 5


def _with_wheels_on_the_mtq_bus(text: str) -> str:
    head, controller = text.split("\n[controller]\n", 1)
    assert 'channel = "stand-mtq"' in head and 'interface = "stand_loopback"' in head
    wheels = "".join(
        f'\n[[devices]]\nname = "rw{n}"\nkind = "reaction_wheel"\nwheel = {n}\ninterface = "stand_loopback"\n'
        f'channel = "stand-mtq"\nspin_axis_B = [{float(n == 0)}, {float(n == 1)}, {float(n >= 2)}]\n'
        for n in range(WHEELS))
    return f"{head}{wheels}\n[controller]\n{controller}"


def test_idle_wheels_on_the_magnetorquer_bus_reject_nothing_and_are_not_rejected(tmp_path):
    path = tmp_path / "shared.toml"
    path.write_text(_with_wheels_on_the_mtq_bus(DEFAULT_SCENARIO.read_text()))
    out = tmp_path / "out"
    code = main(["run", str(path), "--duration", str(RUN_S), "--out", str(out), "--no-progress", "--no-plots"])
    summary = json.loads((out / "summary.json").read_text())
    assert code == 1 and summary["status"] == "completed"  # completed; 5 s cannot detumble
    (check,) = [c for c in summary["criteria"] if c["name"] == "no rejected frames"]
    assert check["pass"] and check["value"] == 0
    counters = summary["device_counters"]
    mtq = counters["mtq"]
    assert mtq["rejected_unknown_id"] == mtq["rejected_length"] == mtq["rejected_other"] == 0
    assert mtq["foreign"] > 0  # the wheels' telemetry reached the board's host and was left alone
    board = mtq["emulator"]
    assert board["rejected_unknown_id"] == board["rejected_length"] == board["rejected_other"] == 0
    assert board["commands_accepted"] == mtq["sent"] > 0  # every B-dot command applied
    for n in range(WHEELS):
        wheel = counters[f"rw{n}"]["emulator_counters"]
        assert wheel["rejected_unknown_id"] == wheel["rejected_length"] == wheel["rejected_other"] == 0, n
        assert wheel["foreign"] > 0, n  # the B-dot commands to the board and the other wheels' frames
