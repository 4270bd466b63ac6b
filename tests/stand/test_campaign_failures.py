"""Campaigns that meet bad cases and bad files: a case that exits, kills its worker or hangs is recorded as an
error and the others go on; a corrupt case.json or dispersion file is one sentence and exit 2."""

import json

import pytest

from stand import campaign as cm
from stand.cli import main

SHORT_S = 5.0

# A flight-code plug-in that misbehaves on demand; "hang" blocks its constructor (bounded: 600 s, far beyond the
# limits the tests set), where no per-call budget of the loop applies.
PLUGIN = """
import ctypes, os, signal, sys, threading


class Unruly(BaseException):
    pass


class Crashy:
    def __init__(self, devices, period_s, mode):
        self.mode = mode
        if mode == "hang":
            threading.Event().wait(600.0)

    def update(self, t_s):
        if self.mode == "exit":
            sys.exit(0)
        if self.mode == "base":
            raise Unruly("not an Exception")
        if self.mode == "os_exit":
            os._exit(0)
        if self.mode == "segv":
            ctypes.string_at(0)  # a crash in native code: no Python handler can stop it
        if self.mode == "kill":
            os.kill(os.getpid(), signal.SIGKILL)
"""


def _crashy_spec(scenario_dict, write_scenario, tmp_path, modes: list[str], seed: int | None = None):
    (tmp_path / "crashy.py").write_text(PLUGIN)
    scenario_dict["controller"] = {"kind": "plugin", "rate_hz": 5.0, "module": "crashy:Crashy",
                                   "path": str(tmp_path), "options": {"mode": "ok"}}
    (tmp_path / "d.toml").write_text('[[dispersions]]\nfield = "controller.options.mode"\ndistribution = "choice"\n'
                                     f"values = {json.dumps(modes)}\n")
    return cm.make_spec(str(write_scenario(scenario_dict)), tmp_path / "d.toml", seed=seed, duration_s=SHORT_S)


def _modes(spec, runs: int) -> list[str]:
    disp = spec.dispersions()
    return [cm.case_values(disp, spec.seed, k)[1]["controller.options.mode"] for k in range(runs)]


def _records(out, runs: int) -> list[dict]:
    return [json.loads((cm.case_dir(out, k) / "case.json").read_text()) for k in range(runs)]


# ------------------------------------------------------------------------------- item 3: sys.exit in a case
@pytest.mark.slow
def test_sys_exit_in_a_case_is_recorded_and_stand_campaign_says_so(scenario_dict, write_scenario, tmp_path, capsys):
    spec = _crashy_spec(scenario_dict, write_scenario, tmp_path, ["ok", "exit"])
    runs = 6
    modes = _modes(spec, runs)
    assert "ok" in modes and "exit" in modes
    out = tmp_path / "camp"
    rc = main(["campaign", f"{spec.scenario_base}/{spec.scenario_name}", "--runs", str(runs), "--dispersions",
               str(tmp_path / "d.toml"), "--out", str(out), "--workers", "1", "--duration", str(SHORT_S),
               "--no-progress"])
    printed = capsys.readouterr().out
    assert rc == 1  # cases failed: never 0
    data = json.loads((out / "campaign.json").read_text())
    assert data["status"] == "complete" and data["finished"] == runs
    assert f"{runs}/{runs} runs" in printed
    for rec, mode in zip(_records(out, runs), modes, strict=True):
        if mode == "exit":
            # The loop ends a run whose plug-in exits as aborted: recorded, failed, with the reason.
            assert rec["status"] == "aborted" and not rec["passed"] and "SystemExit" in rec["error"]
        else:
            assert rec["status"] == "completed" and rec["digest"]


def test_any_base_exception_in_a_case_is_recorded_in_process_too(scenario_dict, write_scenario, tmp_path):
    spec = _crashy_spec(scenario_dict, write_scenario, tmp_path, ["ok", "exit", "base", "os_exit"])
    runs = 12
    modes = _modes(spec, runs)
    assert {"ok", "exit", "base", "os_exit"} <= set(modes)
    result = cm.run_campaign(spec, tmp_path / "camp", runs, workers=0, plots=False)
    assert result["status"] == "complete" and result["finished"] == runs
    for rec, mode in zip(_records(tmp_path / "camp", runs), modes, strict=True):
        if mode == "ok":
            assert rec["status"] == "completed" and rec["digest"]
        else:  # the loop ends such a run as aborted (os._exit is guarded while a run is on)
            assert rec["status"] == "aborted" and not rec["passed"]
            assert {"base": "Unruly", "exit": "SystemExit", "os_exit": "called os._exit(0)"}[mode] in rec["error"]


def test_campaign_json_is_not_left_running_when_a_campaign_is_stopped(scenario_dict, write_scenario, tmp_path,
                                                                       monkeypatch):
    spec = _crashy_spec(scenario_dict, write_scenario, tmp_path, ["ok"])
    real = cm.run_case
    calls = []

    def stop_at_the_second(task, **kw):
        calls.append(task["index"])
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(task, **kw)

    monkeypatch.setattr(cm.pool, "run_case", stop_at_the_second)  # where the inline executor looks it up
    with pytest.raises(KeyboardInterrupt):
        cm.run_campaign(spec, tmp_path / "camp", 3, workers=0, plots=False)
    data = json.loads((tmp_path / "camp" / "campaign.json").read_text())
    assert data["status"] == "incomplete" and data["finished"] == 1 and data["execution"]["stopped"]


# ------------------------------------------------------------------------ item 15: dead workers, hung cases
@pytest.mark.slow
def test_a_case_that_kills_its_worker_is_an_error_and_no_other_case_is_lost(scenario_dict, write_scenario, tmp_path):
    spec = _crashy_spec(scenario_dict, write_scenario, tmp_path, ["ok", "ok", "segv", "kill"])
    runs = 8
    modes = _modes(spec, runs)
    assert {"segv", "kill"} <= set(modes) and modes.count("ok") >= 3
    result = cm.run_campaign(spec, tmp_path / "camp", runs, workers=2, plots=False)  # a case may end 2 workers
    assert result["status"] == "complete" and result["finished"] == runs and not result["execution"]["lost"]
    recs = _records(tmp_path / "camp", runs)
    for rec, mode in zip(recs, modes, strict=True):
        if mode == "ok":
            assert rec["status"] == "completed" and rec["digest"]
        else:
            assert rec["status"] == "error" and "died 2 times" in rec["error"]
            assert ("SIGKILL" if mode == "kill" else "SIGSEGV") in rec["error"]
    # The cases that ran next to the crashes are the same as alone, in this process.
    k = modes.index("ok")
    assert cm.run_case(spec.case(k), interruptible=True)["record"]["digest"] == recs[k]["digest"]


@pytest.mark.slow
def test_a_case_that_hangs_is_ended_at_the_limit_and_the_campaign_completes(scenario_dict, write_scenario, tmp_path):
    spec = _crashy_spec(scenario_dict, write_scenario, tmp_path, ["ok", "hang"])
    runs = 4
    modes = _modes(spec, runs)
    assert {"ok", "hang"} <= set(modes)
    # 10 s: a 5 s detumble takes well under a second of wall time; the hung case would wait 600 s.
    result = cm.run_campaign(spec, tmp_path / "camp", runs, workers=2, plots=False, case_timeout_s=10.0)
    assert result["status"] == "complete" and result["finished"] == runs
    for rec, mode in zip(_records(tmp_path / "camp", runs), modes, strict=True):
        if mode == "hang":
            assert rec["status"] == "error" and "per-case limit of 10 s" in rec["error"]
        else:
            assert rec["status"] == "completed"


@pytest.mark.parametrize("value", [-1.0, float("nan"), 1e12])
def test_a_bad_case_timeout_is_refused(scenario_dict, write_scenario, tmp_path, value):
    spec = _crashy_spec(scenario_dict, write_scenario, tmp_path, ["ok"])
    with pytest.raises(cm.CampaignError, match="--case-timeout = .* is not allowed: seconds of wall time per case"):
        cm.run_campaign(spec, tmp_path / "camp", 1, workers=0, case_timeout_s=value)


# ------------------------------------------------------------------------------------- corrupt case.json
@pytest.mark.parametrize("content, needle", [
    (b"\xff\xfe garbage", "a case record (UTF-8 JSON)"),
    (b"[1, 2]", "the record = [1, 2] in"),
    (b'{"index": "2"}', "index = '2' in"),
    (b'{"index": 2, "digest": 5}', "digest = 5 in"),
])
def test_a_corrupt_case_json_is_one_sentence_and_exit_2(scenario_dict, write_scenario, tmp_path, capsys, content,
                                                        needle):
    spec = _crashy_spec(scenario_dict, write_scenario, tmp_path, ["ok"])
    camp = tmp_path / "camp"
    cm.run_campaign(spec, camp, 3, workers=0, plots=False)
    path = cm.case_dir(camp, 2) / "case.json"
    path.write_bytes(content)
    capsys.readouterr()
    rc = main(["run", "--campaign", str(camp), "--case", "2", "--out", str(tmp_path / "again"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and needle in err and str(path) in err and "Traceback" not in err
    assert err.count("\n") == 1 and err.startswith("stand: error: ")
    # A resume treats that case as unfinished and runs it again; the others are kept.
    again = cm.run_campaign(spec, camp, 3, workers=0, plots=False)
    assert again["execution"]["runs_this_session"] == 1 and again["finished"] == 3


# ------------------------------------------------------------------------------ malformed dispersion files
BAD_FILES = [
    ('field = "spacecraft.omega_BN_B_deg_s"\ndistribution = "uniform"\nmin = -1e308\nmax = 1e308',
     "dispersions[0] (spacecraft.omega_BN_B_deg_s).max = 1e+308 is not allowed: a bound whose distance to min"),
    ('field = "spacecraft.mass_kg"\ndistribution = "uniform"\nmin = 1\nmax = 1e300\ninteger = true',
     ".max = 1e+300 is not allowed: whole numbers from -2**53 to 2**53"),
    ('field = "devices.mtq.q_SB"\ndistribution = "rotation"\nsigma_deg = 1e308',
     "sigma_deg = 1e+308 is not allowed: a number or a list of shape [3] (one per axis), each <= 180"),
    ('field = "spacecraft.mass_kg"\ndistribution = "normal"\nsigma_percent = 1e308',
     "sigma_percent = 1e+308 is not allowed: a percentage whose sigma (of the mean 4.0) is a finite number"),
    ('field = "spacecraft.mass_kg"\ndistribution = "normal"\nsigma = 0.1\n[dispersions.min]\nx = 1',
     "dispersions[0] (spacecraft.mass_kg).min = {'x': 1} is not allowed: one number, finite"),
    # A percentage of zero is zero: every case would draw the nominal, silently.
    ('field = "environment.era0_deg"\ndistribution = "normal"\nmean = 0.0\nsigma_percent = 10.0',
     "era0_deg).sigma_percent = 10.0 is not allowed: a percentage of a mean that is not zero (the mean is 0.0"),
    ('field = "spacecraft.omega_BN_B_deg_s"\ndistribution = "normal"\nmean = [0.0, 0.0, 0.0]\nsigma_percent = 5.0',
     "omega_BN_B_deg_s).sigma_percent = 5.0 is not allowed: a percentage of a mean that is not zero"),
    ('field = "devices.mtq.mag_bias_nT"\ndistribution = "normal"\nmean = [0.0, 50.0, 0.0]\nsigma_percent = 10.0',
     "use sigma in the field's unit"),
]


@pytest.mark.parametrize("entry, needle", BAD_FILES)
def test_a_malformed_dispersion_file_is_one_sentence_naming_it_and_exit_2(scenario_dict, write_scenario, tmp_path,
                                                                         capsys, entry, needle):
    scen = write_scenario(scenario_dict)
    (tmp_path / "bad.toml").write_text("[[dispersions]]\n" + entry + "\n")
    rc = main(["campaign", str(scen), "--runs", "2", "--dispersions", str(tmp_path / "bad.toml"), "--out",
               str(tmp_path / "c"), "--workers", "0", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("stand: error: bad.toml: ") and needle in err, err
    assert err.count("\n") == 1 and not (tmp_path / "c").exists()


def test_weights_too_large_to_add_up_still_choose_by_their_ratio(scenario_dict):
    disp = cm.parse_dispersions('[[dispersions]]\nfield = "scenario.epoch"\ndistribution = "choice"\n'
                                'values = ["2026-03-20T12:00:00Z", "2026-06-21T06:00:00Z"]\n'
                                "weights = [1e308, 1e308]\n", scenario_dict, "w.toml")
    draws = [cm.case_values(disp, 3, k)[1]["scenario.epoch"] for k in range(400)]
    assert 150 < draws.count("2026-03-20T12:00:00Z") < 250  # 1:1, binomial sd 10


# -------------------------------------------- item 4: a dispersion the scenario refuses (or would not apply)
def test_a_dispersion_the_scenario_refuses_is_named_before_any_case_runs(scenario_dict, write_scenario, tmp_path):
    """The scenario refuses a key its other settings leave unused (era0_deg under the IAU 2006 Earth) as it
    refuses an unknown one: a campaign names the [[dispersions]] entry and runs nothing."""
    (tmp_path / "d.toml").write_text('[[dispersions]]\nfield = "spacecraft.mass_kg"\ndistribution = "uniform"\n'
                                     'min = 3.0\nmax = 5.0\n'
                                     '[[dispersions]]\nfield = "environment.era0_degrees"\ndistribution = "uniform"\n'
                                     "min = 0.0\nmax = 360.0\n")
    spec = cm.make_spec(str(write_scenario(scenario_dict)), tmp_path / "d.toml", duration_s=SHORT_S)
    with pytest.raises(cm.CampaignError) as e:
        cm.run_campaign(spec, tmp_path / "camp", 3, workers=0)
    text = str(e.value)
    assert text.startswith("case 0: dispersions[1] (environment.era0_degrees, uniform, in d.toml) drew ")
    assert "which the scenario refuses" in text and "environment.era0_degrees = " in text
    assert not (tmp_path / "camp").exists()


# ------------------------------------------------------------------------------------ the same on Dask
@pytest.mark.slow
def test_on_dask_an_exiting_or_hung_case_is_an_error_and_the_campaign_completes(
        scenario_dict, write_scenario, tmp_path):
    import dask
    import distributed

    # Seed 41 draws ok, exit, hang for cases 0, 1, 2: the hung case comes last, so the worker processes its limit
    # ends run nothing else (Dask blames a worker's death on every task it holds). A case that ends its worker by
    # itself (os._exit) takes the same path (KilledWorker) as one the limit ends.
    spec = _crashy_spec(scenario_dict, write_scenario, tmp_path, ["ok", "exit", "hang"], seed=41)
    runs = 3
    modes = _modes(spec, runs)
    assert modes == ["ok", "exit", "hang"]
    # One retry on another worker process instead of the default three, to keep the test short; one task per
    # worker at a time, so that a worker's death is blamed on its own case only (docs/campaigns.md).
    config = {"distributed.scheduler.allowed-failures": 1, "distributed.scheduler.worker-saturation": 1.0}
    with dask.config.set(config), \
            distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                     dashboard_address=cm.DASK_HTTP_ADDRESS) as cluster:
        result = cm.run_campaign(spec, tmp_path / "camp", runs, scheduler=cluster.scheduler_address, plots=False,
                                 case_timeout_s=5.0)
    assert result["status"] == "complete" and result["finished"] == runs and not result["execution"]["lost"]
    for rec, mode in zip(_records(tmp_path / "camp", runs), modes, strict=True):
        if mode == "ok":
            assert rec["status"] == "completed" and rec["digest"]
        elif mode == "exit":
            assert rec["status"] in ("error", "aborted") and "SystemExit" in rec["error"]
        else:  # the per-case limit ended its worker each time: the scheduler gave up, the case is an error
            assert rec["status"] == "error" and "KilledWorker" in rec["error"] and "limit of 5 s" in rec["error"]
