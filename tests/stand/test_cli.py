"""The command line: exit codes and one-sentence errors (never a traceback on user input)."""

import json

import pytest

from stand.cli import main


def run_cli(argv, capsys):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def test_check_lists_built_and_left_out(capsys):
    code, out, _ = run_cli(["check", "detumble"], capsys)
    assert code == 0
    assert "magnetic_field.dipole" in out and "left out:" in out and "moon" in out
    code, out, _ = run_cli(["check", "detumble", "--json"], capsys)
    data = json.loads(out)
    assert {m["model"] for m in data["left_out"]} >= {"sun", "moon", "star_screen"}


@pytest.mark.parametrize("section, key, value, field", [
    ("spacecraft", "inertia_kg_m2", [0.0, 0.02, 0.01], "spacecraft.inertia_kg_m2"),
    ("orbit", "e", -0.5, "orbit.e"),
])
def test_bad_scenario_exits_2_with_one_line(scenario_dict, write_scenario, capsys, tmp_path, section, key, value,
                                            field):
    scenario_dict[section][key] = value
    code, out, err = run_cli(["run", str(write_scenario(scenario_dict)), "--out", str(tmp_path / "o")], capsys)
    assert code == 2
    assert err.startswith(f"stand: error: {field} = ") and err.count("\n") == 1
    assert "Traceback" not in err


def test_unknown_device_exits_2(scenario_dict, write_scenario, capsys, tmp_path):
    scenario_dict["devices"][0]["kind"] = "thruster"
    code, _, err = run_cli(["check", str(write_scenario(scenario_dict))], capsys)
    assert code == 2 and "devices[0].kind = 'thruster'" in err


def test_port_that_cannot_be_opened_exits_2(scenario_dict, write_scenario, capsys, tmp_path):
    scenario_dict["devices"][0]["interface"] = "no_such_interface"
    code, _, err = run_cli(["run", str(write_scenario(scenario_dict)), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "no_such_interface" in err and "Traceback" not in err


def test_run_passes_and_fails_by_criteria(scenario_dict, write_scenario, capsys, tmp_path):
    scenario_dict["scenario"]["duration_s"] = 5.0
    code, out, _ = run_cli(["run", str(write_scenario(scenario_dict)), "--no-plots", "--out", str(tmp_path / "a")],
                           capsys)
    assert code == 1 and "FAIL  detumbled" in out  # still spinning after 5 s
    scenario_dict["criteria"][0]["max"] = 100.0
    code, out, _ = run_cli(["run", str(write_scenario(scenario_dict, "b.toml")), "--no-plots", "--out",
                            str(tmp_path / "b")], capsys)
    assert code == 0
    summary = json.loads((tmp_path / "b" / "summary.json").read_text())
    for key in ("scenario", "sim_duration_s", "wall_time_s", "realtime_factor", "criteria", "pass", "models",
                "timing"):
        assert key in summary
    assert summary["pass"] is True and summary["sim_duration_s"] == pytest.approx(5.0)


@pytest.mark.parametrize("argv, text", [
    (["run", "--speed", "warp"], "--speed 'warp'"),
    (["run", "--seed", "-3"], "--seed"),
    (["bench", "nonsense"], "bench 'nonsense'"),
])
def test_usage_errors_exit_2(argv, text, capsys, tmp_path):
    code, _, err = run_cli(argv + ["--out", str(tmp_path / "x")] if argv[0] == "run" else argv, capsys)
    assert code == 2 and text in err


def test_out_dir_is_never_overwritten(capsys, tmp_path):
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "summary.json").write_text("{}")
    code, _, err = run_cli(["run", "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "--out" in err


def test_no_plots_writes_the_record_and_the_summary_but_no_drawing(scenario_dict, write_scenario, capsys, tmp_path):
    """``--no-plots``: the same verdict, summary and telemetry as a run with its plots, and no PNG nor report.md."""
    scenario_dict["scenario"]["duration_s"] = 5.0
    scenario_dict["criteria"][0]["max"] = 100.0
    path = write_scenario(scenario_dict)
    code_plots, _, _ = run_cli(["run", str(path), "--out", str(tmp_path / "plots")], capsys)
    code, out, err = run_cli(["run", str(path), "--no-plots", "--out", str(tmp_path / "bare")], capsys)
    assert code == code_plots == 0 and "PASS" in out and "Traceback" not in err
    drawn = {p.name for p in (tmp_path / "plots").iterdir()}
    bare = {p.name for p in (tmp_path / "bare").iterdir()}
    assert "report.md" in drawn and any(n.endswith(".png") for n in drawn)
    assert "report.md" not in bare and not any(n.endswith(".png") for n in bare)
    assert {"summary.json", "telemetry", "events.jsonl", "stand.log"} <= bare
    a = json.loads((tmp_path / "plots" / "summary.json").read_text())
    b = json.loads((tmp_path / "bare" / "summary.json").read_text())
    for key in ("pass", "status", "criteria", "checkpoints", "sim_duration_s"):
        assert a.get(key) == b.get(key), key
    for f in (tmp_path / "plots" / "telemetry").iterdir():
        assert f.read_bytes() == (tmp_path / "bare" / "telemetry" / f.name).read_bytes(), f.name
