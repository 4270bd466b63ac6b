"""Campaigns of faults (issue 24): fault tables drawn whole by a choice and their times by a uniform, validated before
the first run; the shipped fault dispersion file over the pointing scenario; a campaign of 100 cases on the local pool
and on Dask with identical cases, pass rates by fault type and device, and any case re-running alone bit for bit."""

import json
import tomllib

import pytest

from stand import campaign as cm
from stand.cli import main
from stand.compose import build
from stand.faults import FAULT_TYPES, LAYERS
from stand.faults.spec import taps_of
from stand.loop import run
from stand.report import write_summary
from stand.scenario import SCENARIO_DIR, loads, parse, shipped
from tests.stand.conftest import to_toml

SHIPPED = SCENARIO_DIR / "fault_dispersions.toml"
SCENARIO = "pointing_star_tracker"
#: Simulated seconds of a test case: 20 control periods.
SHORT_S = 2.0
RUNS = 100
#: Taps whose fault types land from the other branches of issue 24 (drivers/link_faults.py; the wheel, tracker,
#: clock and reboot attributes of the emulators). The campaign test runs every type of the shipped file whose tap is
#: not listed here; test_each_fault_type_of_the_shipped_file_runs_or_waits_for_its_tap fails as soon as a listed
#: tap works, so this set is emptied as they land and the campaign then covers all the file's types.
PENDING_TAPS = frozenset()


def shipped_file() -> dict:
    return tomllib.loads(SHIPPED.read_text())


def shipped_tables() -> list[dict]:
    (choice,) = [d for d in shipped_file()["dispersions"] if d["field"] == "faults.probe"]
    return choice["values"]


def short_overrides() -> list[str]:
    """The pointing scenario cut to SHORT_S: its criteria judged from 1 s instead of 200 s."""
    data = tomllib.loads((SCENARIO_DIR / f"{SCENARIO}.toml").read_text())
    return [f"criteria.{c['name']}.at_s=1.0" for c in data["criteria"] if "at_s" in c]


def short_dispersions(tmp_path, tables: list[dict]):
    """The shipped fault dispersion file over ``tables`` (its own, those that run today) with times within SHORT_S."""
    data = shipped_file()
    for d in data["dispersions"]:
        if d["field"] == "faults.probe":
            d["values"] = tables
        elif d["field"] == "faults.probe.at_s":
            d["min"], d["max"] = 0.0, SHORT_S - 0.5
    path = tmp_path / "fault_dispersions_short.toml"
    path.write_text(to_toml(data))
    return path


def short_run(table: dict, tmp_path, at_s: float = 0.5) -> dict:
    """One short run of the pointing scenario with ``table`` as its only fault: its summary."""
    data = loads((SCENARIO_DIR / f"{SCENARIO}.toml").read_text())
    for item in short_overrides():
        from stand.scenario import set_value

        set_value(data, item)
    data["scenario"]["duration_s"] = SHORT_S
    data["faults"] = [{"name": "probe", **table, "at_s": at_s}]
    sc = parse(data, "short")
    out = tmp_path / f"run-{table['type']}"
    with build(sc, None, SCENARIO_DIR) as scene:
        out.mkdir()
        result = run(scene, out, progress=False)
    return write_summary(scene, result, out, plots=False)


# ------------------------------------------------------------------------------------------- the shipped file
def test_the_shipped_fault_file_lists_every_fault_type_the_pointing_devices_take_at_three_layers():
    sc = parse(loads((SCENARIO_DIR / f"{SCENARIO}.toml").read_text()), SCENARIO)
    assert len(sc.devices) >= 4
    offered = {tap for d in sc.devices for tap in taps_of(d)}
    applicable = {name for name, ft in FAULT_TYPES.items() if ft.tap in offered}
    types = [t["type"] for t in shipped_tables()]
    assert len(types) == len(set(types)) and set(types) == applicable  # every one that applies, once each
    assert len(types) >= 20 and {FAULT_TYPES[t].layer for t in types} == set(LAYERS)
    # Every table is a fault the scenario accepts, on the nominal run (its own duration and criteria).
    spec = cm.make_spec(SCENARIO, SHIPPED)
    (task,) = cm.validate(spec, 1)
    assert task["faults"][0]["name"] == "probe" and 0.0 <= task["faults"][0]["at_s"] <= 590.0
    assert "fault_dispersions" not in shipped()


@pytest.mark.slow
def test_each_fault_type_of_the_shipped_file_runs_or_waits_for_its_tap(tmp_path):
    """A type whose tap is here runs in the short scenario, its fault starting when drawn; a type whose tap is pending
    fails only because the tap is not there yet (and once it works, PENDING_TAPS must drop it)."""
    works: dict[str, list[bool]] = {}
    for table in shipped_tables():
        tap = FAULT_TYPES[table["type"]].tap
        s = short_run(table, tmp_path)
        ok = s["status"] == "completed" and s["faults"]["probe"]["occurrences"][0][0] == pytest.approx(0.5)
        if tap not in PENDING_TAPS:
            assert ok, f"{table}: {s['status']} {s['error']}"
        else:
            assert ok or "the fault schedule raised" in (s["error"] or ""), f"{table}: {s['error']}"
        works.setdefault(tap, []).append(ok)
    landed = sorted(tap for tap in PENDING_TAPS if tap in works and all(works[tap]))
    assert not landed, f"the {landed} taps work now: remove them from PENDING_TAPS so the campaign test runs them"


# ------------------------------------------------------------------------------ whole fault tables, validated
@pytest.fixture
def pointing():
    return loads((SCENARIO_DIR / f"{SCENARIO}.toml").read_text())


PROBE = '[[faults]]\nname = "probe"\ntype = "stuck"\ndevice = "imu"\nat_s = 5.0\nduration_s = 2.0\n'


def test_a_drawn_fault_table_replaces_the_entry_but_its_name_and_its_trigger(pointing):
    disp = cm.parse_dispersions(PROBE + '[[dispersions]]\nfield = "faults.probe"\ndistribution = "choice"\n'
                                'values = [{type = "bias_step", device = "imu", bias_rad_s = 1e-4}]\n',
                                pointing, "d.toml")
    assert disp.faults == ({"name": "probe", "type": "stuck", "device": "imu", "at_s": 5.0, "duration_s": 2.0},)
    data = cm.apply(pointing, {"faults.probe": {"type": "bias_step", "device": "imu", "bias_rad_s": 1e-4}}, 1, None,
                    disp.faults)
    assert data["faults"] == [{"name": "probe", "at_s": 5.0, "type": "bias_step", "device": "imu",
                               "bias_rad_s": 1e-4}]  # its duration went with the table it replaced
    # A table with a trigger of its own brings it: the entry's at_s goes.
    data = cm.apply(pointing, {"faults.probe": {"type": "reboot", "device": "st", "period_s": 50.0}}, 1, None,
                    disp.faults)
    assert data["faults"] == [{"name": "probe", "type": "reboot", "device": "st", "period_s": 50.0}]
    # delay_s alone is no trigger (tracker_slow's parameter): the entry's at_s stays.
    data = cm.apply(pointing, {"faults.probe": {"type": "tracker_slow", "device": "st", "delay_s": 0.3}}, 1, None,
                    disp.faults)
    assert data["faults"][0]["at_s"] == 5.0 and data["faults"][0]["delay_s"] == 0.3
    # A time dispersed on its own wins over the table drawn for its entry, whatever their order.
    for values in ({"faults.probe.at_s": 7.5, "faults.probe": {"type": "stuck", "device": "imu"}},
                   {"faults.probe": {"type": "stuck", "device": "imu"}, "faults.probe.at_s": 7.5}):
        assert cm.apply(pointing, values, 1, None, disp.faults)["faults"][0]["at_s"] == 7.5
    assert cm.get_field(cm.with_faults(pointing, disp.faults), "faults.probe")["type"] == "stuck"
    assert "faults" not in pointing  # the scenario dict itself is untouched


@pytest.mark.parametrize("text, needle", [
    (PROBE + '[[dispersions]]\nfield = "faults.probe"\ndistribution = "choice"\nvalues = ["stuck"]\n',
     "dispersions[0] (faults.probe).values[0] = 'stuck' is not allowed: a table of the keys of entry faults.probe"),
    (PROBE + '[[dispersions]]\nfield = "faults.probe"\ndistribution = "choice"\n'
     'values = [{name = "other", type = "stuck", device = "imu"}]\n',
     "values[0].name = 'other' is not allowed: no name: the drawn table keeps the entry's own name ('probe')"),
    ('[[faults]]\ntype = "stuck"\ndevice = "imu"\nat_s = 1.0\n'
     '[[dispersions]]\nfield = "faults.imu.at_s"\ndistribution = "uniform"\nmin = 0.0\nmax = 9.0\n',
     "faults has no entry named 'imu' (entries: none; 1 entries without a name, which a path cannot address"),
    ('faults = [1, 2]\n[[dispersions]]\nfield = "scenario.epoch"\ndistribution = "choice"\nvalues = ["x"]\n',
     "faults = [1, 2] in d.toml is not allowed: [[faults]] tables"),
])
def test_a_bad_fault_dispersion_is_one_sentence(pointing, text, needle):
    with pytest.raises(cm.CampaignError) as e:
        cm.parse_dispersions(text, pointing, "d.toml")
    assert needle in str(e.value)


def test_every_fault_table_of_a_choice_is_validated_before_the_first_run_even_one_never_drawn(tmp_path):
    # The wheel fault on the gyro has weight 0: no case can draw it, and it is still refused at once.
    (tmp_path / "d.toml").write_text(
        PROBE + '[[dispersions]]\nfield = "faults.probe"\ndistribution = "choice"\n'
        'values = [{type = "stuck", device = "imu"}, {type = "wheel_seized", device = "imu"}]\nweights = [1.0, 0.0]\n')
    spec = cm.make_spec(SCENARIO, tmp_path / "d.toml")
    with pytest.raises(cm.CampaignError) as e:
        cm.run_campaign(spec, tmp_path / "out", 2, workers=0)
    text = str(e.value)
    assert text.startswith("dispersions[0] (faults.probe, choice, in d.toml): values[1] = {'type': 'wheel_seized', "
                           "'device': 'imu'} is refused by the scenario, so no case may draw it: faults[0].type = "
                           "'wheel_seized'")
    assert "a fault type device 'imu'" in text and "needs its wheel tap" in text and "\n" not in text
    assert not (tmp_path / "out").exists()
    # The file's own [[faults]] are checked on the nominal scenario first.
    (tmp_path / "e.toml").write_text(PROBE.replace('"stuck"', '"stuk"') + '[[dispersions]]\nfield = '
                                     '"faults.probe.at_s"\ndistribution = "uniform"\nmin = 0.0\nmax = 9.0\n')
    with pytest.raises(cm.CampaignError, match=r"^e.toml: its \[\[faults\]\] are refused by the scenario: "
                                               r"faults\[0\].type = 'stuk'"):
        cm.run_campaign(cm.make_spec(SCENARIO, tmp_path / "e.toml"), tmp_path / "out", 2, workers=0)


def test_pass_rates_group_the_cases_by_fault_type_and_by_device():
    def case(index, passed, *faults, status="completed"):
        return {"index": index, "passed": passed, "status": status,
                "faults": [{"name": f"f{i}", "type": t, "device": d, "layer": FAULT_TYPES[t].layer}
                           for i, (t, d) in enumerate(faults)]}

    records = [case(0, True, ("stuck", "imu")), case(1, False, ("stuck", "imu")),
               case(2, False, ("reboot", "st"), ("stuck", "imu")),  # two faults: counted in both groups
               case(3, False, ("clock_drift", "st"), status="error"), case(4, True, ("stuck", "mag"), ("stuck", "imu")),
               {"index": 5, "passed": True, "status": "completed", "faults": []}]  # no fault: in no group
    by_type = cm.fault_groups.group(records, "type", cm.clopper_pearson)
    assert list(by_type) == ["stuck", "reboot", "clock_drift"]  # physics, protocol, time
    assert by_type["stuck"] == {"layer": "physics", "devices": ["imu", "mag"], "runs": 4, "passed": 2, "rate": 0.5,
                                "ci95": list(cm.clopper_pearson(2, 4)), "failed_cases": [1, 2]}
    assert (by_type["reboot"]["runs"], by_type["clock_drift"]["failed_cases"]) == (1, [3])
    by_device = cm.fault_groups.group(records, "device", cm.clopper_pearson)
    assert {k: (g["runs"], g["passed"], g["types"]) for k, g in by_device.items()} == {
        "imu": (4, 2, ["stuck"]), "mag": (1, 1, ["stuck"]), "st": (2, 0, ["clock_drift", "reboot"])}
    lines = cm.fault_lines({"by_fault_type": by_type, "by_fault_device": by_device})
    assert lines[0] == "fault stuck (physics): 2/4 passed (50.0 %, 95 % interval 6.8 to 93.2 %); failed: case 1, 2"
    assert cm.fault_lines({}) == []
    # report.md's tables: a header, its rule and one row per group, every line with the header's cells.
    md = cm.fault_groups.report_lines({"by_fault_type": by_type, "by_fault_device": by_device})
    tables = [[line for line in md[k + 2:] if line.startswith("|")][:2 + n] for k, n in
              ((md.index("## Pass rate by fault type"), 3), (md.index("## Pass rate by device"), 3))]
    for table in tables:
        assert table[1] == "|---" * (table[0].count("|") - 1) + "|"
        assert {line.count("|") for line in table} == {table[0].count("|")} and len(table) == 5
    assert tables[0][2] == "| stuck | physics | imu, mag | 2/4 | 50.0 % | 6.8 to 93.2 % | 1, 2 |"
    assert cm.fault_groups.report_lines({}) == []


def test_a_fault_s_device_is_dispersed_and_each_device_of_the_choice_is_checked(tmp_path, pointing):
    text = PROBE + '[[dispersions]]\nfield = "faults.probe.device"\ndistribution = "choice"\nvalues = ["imu", "st"]\n'
    (tmp_path / "d.toml").write_text(text)
    with pytest.raises(cm.CampaignError, match=r"^dispersions\[0\] \(faults.probe.device, choice, in d.toml\): "
                                               r"values\[1\] = 'st' is refused by the scenario, .*: faults\[0\].type = "
                                               r"'stuck' .* a fault type device 'st' \(star_tracker"):
        cm.validate(cm.make_spec(SCENARIO, tmp_path / "d.toml"), 1)
    # A type both take: each case runs it on the device it drew.
    (tmp_path / "d.toml").write_text(text.replace('"stuck"', '"silence"').replace('"st"]', '"st", "rw3"]'))
    spec = cm.make_spec(SCENARIO, tmp_path / "d.toml")
    tasks = cm.validate(spec, 12)
    assert {t["faults"][0]["device"] for t in tasks} == {"imu", "st", "rw3"}
    assert all(t["faults"][0]["device"] == t["values"]["faults.probe.device"] == t["data"]["faults"][0]["device"]
               for t in tasks)


# ---------------------------------------------------------------------------------------------- the campaign
def _rerun_alone(camp, index: int, tmp_path) -> tuple[bytes, bool]:
    sc, base, rec = cm.load_case(camp, index)
    out = tmp_path / f"alone-{index}"
    with build(sc, None, base) as scene:
        out.mkdir()
        result = run(scene, out, progress=False)
    write_summary(scene, result, out, plots=False)
    same, _text = cm.compare_case(rec, out)
    return (out / "telemetry" / "rows.f64").read_bytes(), same


@pytest.mark.slow
def test_a_fault_campaign_runs_alike_on_the_local_pool_and_on_dask_and_any_case_re_runs_alone(tmp_path, capsys):
    import distributed  # an extra the test install carries ('.[test]'): missing, the test fails, not skips

    tables = [t for t in shipped_tables() if FAULT_TYPES[t["type"]].tap not in PENDING_TAPS]
    types = {t["type"] for t in tables}
    assert len(types) >= 7 and (PENDING_TAPS or len(types) >= 20)
    dfile = short_dispersions(tmp_path, tables)
    spec = cm.make_spec(SCENARIO, dfile, overrides=short_overrides(), duration_s=SHORT_S)
    pool = cm.run_campaign(spec, tmp_path / "pool", RUNS, workers=2, plots=False)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=cm.DASK_HTTP_ADDRESS) as cluster:
        dask = cm.run_campaign(spec, tmp_path / "dask", RUNS, scheduler=cluster.scheduler_address, plots=False)
    assert pool["status"] == dask["status"] == "complete" and dask["execution"]["executor"] == "dask"
    digests = [[c["digest"] for c in r["cases"]] for r in (pool, dask)]
    assert digests[0] == digests[1] and len(set(digests[0])) == RUNS
    assert pool["by_fault_type"] == dask["by_fault_type"] and pool["by_fault_device"] == dask["by_fault_device"]

    # Each case records the fault it drew, started when drawn (at the first tick from its time).
    records = [json.loads((cm.case_dir(tmp_path / "pool", k) / "case.json").read_text()) for k in range(RUNS)]
    for r in records:
        drawn, at_s = r["values"]["faults.probe"], r["values"]["faults.probe.at_s"]
        (f,) = r["faults"]
        assert (f["type"], f["device"], f["at_s"]) == (drawn["type"], drawn["device"], at_s)
        assert f["layer"] == FAULT_TYPES[drawn["type"]].layer and r["status"] == "completed"
        assert at_s - 1e-9 <= f["started_s"] < at_s + 0.1 + 1e-9  # the 0.1 s step
    drawn = {r["values"]["faults.probe"]["type"] for r in records}
    assert drawn <= types and len(drawn) >= min(20, len(types))
    # Pass rates by fault type and device: the cases of each, counted from the records.
    by_type = pool["by_fault_type"]
    assert set(by_type) == drawn and sum(g["runs"] for g in by_type.values()) == RUNS
    for name, g in by_type.items():
        mine = [r for r in records if r["faults"][0]["type"] == name]
        assert (g["runs"], g["passed"]) == (len(mine), sum(r["passed"] for r in mine))
        assert g["failed_cases"] == [r["index"] for r in mine if not r["passed"]]
        assert g["layer"] == FAULT_TYPES[name].layer and 0.0 <= g["ci95"][0] <= g["rate"] <= g["ci95"][1] <= 1.0
    assert set(pool["by_fault_device"]) == {r["faults"][0]["device"] for r in records}

    # Any case re-runs alone bit for bit: one of each fault type drawn.
    first = {}
    for r in records:
        first.setdefault(r["faults"][0]["type"], r["index"])
    for k in first.values():
        rows, same = _rerun_alone(tmp_path / "pool", k, tmp_path)
        assert same is True and rows == (cm.case_dir(tmp_path / "dask", k) / "telemetry" / "rows.f64").read_bytes()

    # The command prints the groups (resuming the finished campaign runs nothing) and report.md has their tables.
    rc = main(["campaign", SCENARIO, "--runs", str(RUNS), "--dispersions", str(dfile), "--out", str(tmp_path / "pool"),
               "--duration", str(SHORT_S), "--no-progress", *[a for o in short_overrides() for a in ("--set", o)]])
    out = capsys.readouterr().out
    assert rc == (0 if pool["passed"] == RUNS else 1)
    assert json.loads((tmp_path / "pool" / "campaign.json").read_text())["execution"]["resumed"] == RUNS
    for name, g in by_type.items():
        assert f"fault {name} ({g['layer']}): {g['passed']}/{g['runs']} passed" in out
    report = (tmp_path / "pool" / "report.md").read_text()
    assert "## Pass rate by fault type" in report and "## Pass rate by device" in report
    assert all(f"| {name} | {g['layer']} |" in report for name, g in by_type.items())
