"""Small things a new user tripped on (issue 25, point 6): each one sentence or verdict that says what happened."""

from __future__ import annotations

import json

import pytest

from stand.cli import main


def test_a_scenario_without_criteria_is_not_judged_and_never_a_pass(tmp_path, capsys):
    # rendezvous_shadow names no [[criteria]]: a run of it simulated 600 s and judged nothing, so "PASS" (with an
    # empty table) would be a success the stand cannot vouch for.
    out = tmp_path / "run"
    # Exit 0: nothing failed (a script running a study is not broken by it); the words and the summary say it was
    # not judged.
    assert main(["run", "rendezvous_shadow", "--out", str(out), "--no-progress"]) == 0
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


def _speed_bench(quick: bool = False) -> list[dict]:
    # A speed measured over a sub-second --quick run misses its full-run limit; a correctness check does not.
    return [{"name": "fake.realtime_factor", "value": 55.0, "unit": "x", "limit": ">= 150", "pass": False,
             "full_only": True},
            {"name": "fake.rate", "value": 0.1, "unit": "deg/s", "limit": "<= 0.5", "pass": True}]


def _wrong_bench(quick: bool = False) -> list[dict]:
    return [{"name": "fake.rate", "value": 0.9, "unit": "deg/s", "limit": "<= 0.5", "pass": False}]


def test_bench_quick_does_not_judge_full_run_limits_but_still_fails_a_wrong_result(monkeypatch, capsys):
    from stand import benches

    monkeypatch.setitem(benches.BENCHES, "fake-speed", f"{__name__}:_speed_bench")
    monkeypatch.setitem(benches.BENCHES, "fake-wrong", f"{__name__}:_wrong_bench")
    assert main(["bench", "fake-speed", "--quick"]) == 0
    out = capsys.readouterr().out
    assert "limit >= 150 (judged on the full run only)" in out and "FAIL" not in out
    assert main(["bench", "fake-speed"]) == 1  # the full run is judged
    assert "limit >= 150; FAIL" in capsys.readouterr().out
    assert main(["bench", "fake-wrong", "--quick"]) == 1


def test_the_real_benches_mark_their_speed_limits_full_run_only():
    # The rows that made `stand bench loop --quick` and `stand bench view --quick` exit 1 on this machine.
    import inspect

    from stand.benches import _image_tracker_rows
    from stand.benches import view as view_bench

    assert '"full_only": True' in inspect.getsource(_image_tracker_rows)
    source = inspect.getsource(view_bench)
    for limit in ('"pass": slow <= LIMIT_PERCENT, "full_only": True', '"pass": cpu_slow <= LIMIT_PERCENT, '
                  '"full_only": True', '"pass": share <= LIMIT_PERCENT, "full_only": True'):
        assert limit in source, limit


def test_bench_view_names_selenium_when_selenium_is_missing(monkeypatch):
    import sys

    from stand.benches.view import Browser

    monkeypatch.setitem(sys.modules, "selenium", None)  # import selenium raises ImportError
    assert Browser.missing().startswith("no selenium") and "Chromium" not in Browser.missing()
    assert Browser.open() is None
