"""Small things a new user tripped on (issue 25, point 6): each one sentence or verdict that says what happened."""

from __future__ import annotations

import json

import pytest

from stand.cli import main


def test_a_scenario_without_criteria_is_not_judged_and_never_a_pass(tmp_path, capsys):
    # rendezvous_shadow names no [[criteria]]: a run of it simulated 600 s and judged nothing, so "PASS" (with an
    # empty table) would be a success the stand cannot vouch for.
    out = tmp_path / "run"
    assert main(["run", "rendezvous_shadow", "--out", str(out), "--no-progress"]) == 1
    printed = capsys.readouterr().out
    assert "PASS" not in printed and printed.startswith("NOT JUDGED (the scenario has no [[criteria]]): ")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["criteria"] == [] and summary["pass"] is False
    assert summary["verdict"].startswith("NOT JUDGED")
    assert "**NOT JUDGED" in (out / "report.md").read_text()


@pytest.mark.parametrize("argv", [
    ["shadow", "rendezvous_shadow"],
    ["campaign", "detumble", "--runs", "1", "--dispersions", "fixtures/scenarios/detumble_dispersions.toml"],
])
def test_an_out_folder_that_cannot_be_made_is_one_sentence_naming_out(argv, capsys, monkeypatch):
    from tests.stand.processes import REPO

    monkeypatch.chdir(REPO)
    assert main([*argv, "--out", "/proc/nope"]) == 2
    err = capsys.readouterr().err
    assert err == ("stand: error: --out = '/proc/nope' is not allowed: a folder the stand can create and write in "
                   "(No such file or directory).\n")


def _fault_scenario(tmp_path, extra: str):
    from tests.stand.processes import REPO

    text = (REPO / "fixtures/scenarios/fault_wheel_seizure.toml").read_text()
    assert "\nat_s = 30.0 " in text
    path = tmp_path / "s.toml"
    path.write_text(text.replace("\nat_s = 30.0 ", f"\nat_s = 30.0\n{extra}\n# ", 1))
    return path


@pytest.mark.parametrize("extra", ["duration = 2.0", "duration = 2.0\ncolour = 1", "colour = 1\nduration = 2.0"])
def test_an_optional_key_missing_its_unit_suffix_is_named_with_the_key_it_meant(tmp_path, extra):
    # duration_s of a fault is optional (read only when given): the error must still name `duration` and offer
    # `duration_s`, even beside another unknown key, not "a typo?" with a list of keys that lacks duration_s.
    from stand import scenario
    from stand.errors import ScenarioError

    with pytest.raises(ScenarioError) as err:
        scenario.load(_fault_scenario(tmp_path, extra))
    text = str(err.value)
    assert text.startswith("faults[0].duration = 2.0 in ") and "did you mean 'duration_s'?" in text, text
    assert ("also unknown: colour;" in text) == ("colour" in extra)
    assert "duration_s" in text.split("known keys: ", 1)[1]
