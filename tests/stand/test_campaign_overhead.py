"""A campaign's cost per run beyond the loop (issue 26): what a worker keeps between cases, what travels back, what
is written, and the proof that a case in a warm worker is the case of a fresh process."""

import json
import os
import subprocess
import sys

import pytest

from stand import campaign as cm
from stand.campaign import spec as spec_mod
from stand.campaign.pool import _LocalPool
from stand.scenario import SCENARIO_DIR

SHORT_S = 20.0
#: What the campaign keeps of a run, and the record.
CASE_FILES = {*cm.RUN_FILES, "case.json"}


def part_dir(out, index: int):
    """Where the campaign writes case ``index`` before it counts."""
    final = cm.case_dir(out, index)
    return final.with_name(final.name + ".part")


def _files(folder) -> set[str]:
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()}


FRESH = """
import json, sys
from pathlib import Path
from stand import campaign as cm
spec = cm.Spec.from_json(json.loads(sys.argv[1]))
result = cm.run_case(spec.case(int(sys.argv[2])))
out = Path(sys.argv[3])
for name, data in result["files"].items():
    (out / name).parent.mkdir(parents=True, exist_ok=True)
    (out / name).write_bytes(data)
(out / "record.json").write_text(json.dumps(result["record"]))
"""


@pytest.mark.parametrize("scenario, dispersions, duration_s, runs", [
    ("detumble", "detumble_dispersions.toml", SHORT_S, 4),
    # Star tracker, gyro, wheels and a fault (the file's fault times need the scenario's 600 s).
    ("pointing_star_tracker", "fault_dispersions.toml", 600.0, 3),
])
def test_a_case_in_a_warm_worker_is_the_case_of_a_fresh_process(tmp_path, scenario, dispersions, duration_s, runs):
    """The pool's worker builds a scene to warm itself, then runs the cases one after another; the last one runs
    after the others. Run alone in a new interpreter, it gives the same telemetry, byte for byte, and the same
    summary."""
    spec = cm.make_spec(scenario, SCENARIO_DIR / dispersions, duration_s=duration_s)
    out = tmp_path / "camp"
    result = cm.run_campaign(spec, out, runs, workers=1, plots=False)
    assert result["finished"] == runs and result["errors"] == 0
    pids = {json.loads((cm.case_dir(out, k) / "case.json").read_text())["pid"] for k in range(runs)}
    assert len(pids) == 1, "the cases ran in one worker process"
    last = runs - 1
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    subprocess.run([sys.executable, "-c", FRESH, json.dumps(spec.to_json()), str(last), str(fresh)], check=True,
                   timeout=600)
    warm = cm.case_dir(out, last)
    for name in ("telemetry/rows.f64", "telemetry/schema.json"):
        assert (warm / name).read_bytes() == (fresh / name).read_bytes(), name
    assert (warm / "telemetry/rows.f64").stat().st_size > 0
    summary = {p: cm.comparable(json.loads((p / "summary.json").read_text())) for p in (warm, fresh)}
    assert summary[warm] == summary[fresh]
    record = json.loads((fresh / "record.json").read_text())
    assert record["digest"] == result["cases"][last]["digest"]


def test_a_local_worker_writes_the_run_once_where_the_campaign_keeps_it(tmp_path):
    """With a ``dest`` (a worker on the client's machine) the run and its record are written in the case's folder
    and only the record travels back; the folder ends with the files a case always had, nothing more."""
    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=SHORT_S)
    out = tmp_path / "camp"
    out.mkdir()
    task = {**spec.case(1), "dest": str(part_dir(out, 1))}
    result = cm.run_case(task)
    assert result["files"] == {} and result["dir"] == task["dest"] and result["written"]
    assert _files(part_dir(out, 1)) == CASE_FILES  # the run's own log and the like are not kept
    # The record on disk is the one sent back, less the CPU time of its own writing (measured after it).
    sent = json.loads(json.dumps(result["record"], default=float))
    assert sent["timing"].pop("record_write_cpu_s") >= 0.0
    assert json.loads((part_dir(out, 1) / "case.json").read_text()) == sent
    assert len(json.dumps(result["record"])) < 8192  # the record is what crosses the pipe
    alone = cm.run_case(spec.case(1))  # no dest: a temporary folder and the files sent back (Dask)
    assert set(alone["files"]) == set(cm.RUN_FILES)
    assert alone["record"]["digest"] == result["record"]["digest"]
    assert alone["files"]["telemetry/rows.f64"] == (part_dir(out, 1) / "telemetry/rows.f64").read_bytes()


def test_a_campaign_folder_holds_the_same_files_on_every_executor(tmp_path):
    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=SHORT_S)
    for workers in (0, 1):
        out = tmp_path / f"w{workers}"
        cm.run_campaign(spec, out, 2, workers=workers, plots=False)
        assert sorted(p.name for p in (out / "cases").iterdir()) == ["00000", "00001"]  # no .part left
        for k in range(2):
            assert _files(cm.case_dir(out, k)) == CASE_FILES


def test_a_failing_run_leaves_no_half_written_case(scenario_dict, write_scenario, tmp_path):
    """A run that raises in its worker: its folder is removed, and the client writes the error record alone."""
    scenario_dict["controller"] = {"kind": "plugin", "rate_hz": 5.0, "module": "no_such_module_anywhere:Nope"}
    scenario_dict["criteria"] = [{"name": "spin", "metric": "final_rate_deg_s", "max": 100.0}]
    path = write_scenario(scenario_dict)
    dfile = tmp_path / "d.toml"
    dfile.write_text('[[dispersions]]\nfield = "devices.mtq.mag_noise_nT"\ndistribution = "uniform"\nmin = 0.0\n'
                     'max = 1.0\n')
    spec = cm.make_spec(str(path), dfile, duration_s=SHORT_S)
    out = tmp_path / "camp"
    result = cm.run_campaign(spec, out, 1, workers=1, plots=False)
    assert result["errors"] == 1 and "no_such_module_anywhere" in result["failed_cases"][0]["error"]
    assert _files(cm.case_dir(out, 0)) == {"case.json"}
    assert not part_dir(out, 0).exists()


def test_a_worker_gets_its_next_case_before_the_client_writes_the_last_one():
    """The pool hands the next case to the worker that answered before it yields the answer to the writer, so the
    worker never waits for the client's disk."""
    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=SHORT_S)
    tasks = [spec.case(k) for k in range(3)]
    pool = _LocalPool(1)
    try:
        answers = pool.results(tasks)
        index, result, reason = next(answers)
        assert index == 0 and reason is None and result["record"]["status"] == "completed"
        assert pool.slots[0].task is not None and pool.slots[0].task["index"] == 1
        assert [i for i, _, _ in answers] == [1, 2]
    finally:
        pool.close(cancel=True)


def test_the_base_scenario_is_parsed_once_for_all_cases(monkeypatch):
    """Validating a campaign parses the scenario's TOML once, not once per case (it was half the validation)."""
    calls = []
    real = spec_mod.scenario_mod.loads
    monkeypatch.setattr(spec_mod.scenario_mod, "loads", lambda *a, **kw: calls.append(a) or real(*a, **kw))
    spec_mod._base_dict.cache_clear()
    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=SHORT_S)
    calls.clear()
    tasks = cm.validate(spec, 12)
    assert len(calls) <= 1 and len(tasks) == 12
    # Each case's dict is its own: changing one changes neither the next case nor the shared base.
    tasks[0]["data"]["spacecraft"]["mass_kg"] = -1.0
    assert spec.case(0)["data"]["spacecraft"]["mass_kg"] > 0 and spec.scenario_dict()["spacecraft"]["mass_kg"] > 0


def test_warming_a_worker_with_a_case_loads_what_its_devices_need():
    """``warm(task)`` builds the case's devices once (no controller, nothing run): the drivers they import are
    loaded before the first case, in a process that had not imported them."""
    code = ("import sys, json\nfrom stand import campaign as cm\nfrom stand.scenario import SCENARIO_DIR\n"
            "spec = cm.make_spec('detumble', SCENARIO_DIR / 'detumble_dispersions.toml', duration_s=20.0)\n"
            "task = spec.case(0)\nname = 'drivers.magnetorquer.emulator'\nbefore = name in sys.modules\n"
            "cm.warm(task)\nprint(json.dumps([before, name in sys.modules]))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=300)
    assert json.loads(done.stdout.strip().splitlines()[-1]) == [False, True]


# ------------------------------------------------- a case the scenario refuses, found by its worker (issue 26)
#: The magnetometer's noise drawn from -100 to 100 nT: the scenario refuses a negative one.
SOMETIMES_REFUSED = ('[[dispersions]]\nfield = "devices.mtq.mag_noise_nT"\ndistribution = "uniform"\nmin = -100.0\n'
                     'max = 100.0\n')


def _sometimes_refused(scenario_dict, write_scenario, tmp_path, runs: int):
    """A spec whose case 0 draws a noise the scenario takes (the campaign checks case 0 before anything runs) and
    whose later cases draw both kinds, with the draws."""
    path = write_scenario(scenario_dict)
    (tmp_path / "d.toml").write_text(SOMETIMES_REFUSED)
    for seed in range(100):  # bounded: half the draws are negative, so a few seeds do
        spec = cm.make_spec(str(path), tmp_path / "d.toml", seed=seed, duration_s=5.0)
        draws = [cm.case_values(spec.dispersions(), seed, k)[1]["devices.mtq.mag_noise_nT"] for k in range(runs)]
        if draws[0] >= 0 and any(d < 0 for d in draws) and sum(d >= 0 for d in draws) >= 2:
            return spec, draws
    raise AssertionError("no seed below 100 draws a valid case 0 and a refused later case")


def _check_refused_cases(out, result, draws, client_pid: int) -> None:
    """Every case recorded; a refused one with the scenario's sentence naming the field, the value and what is
    allowed (as the campaign's error before the first run reads), validated in a worker process, not the client."""
    assert result["finished"] == len(draws) and result["status"] == "complete"
    assert result["errors"] == sum(d < 0 for d in draws)
    for k, d in enumerate(draws):
        rec = json.loads((cm.case_dir(out, k) / "case.json").read_text())
        assert rec["index"] == k and rec["values"]["devices.mtq.mag_noise_nT"] == d
        assert rec["pid"] != client_pid
        if d >= 0:
            assert rec["status"] == "completed" and rec["digest"]
            continue
        assert rec["status"] == "error" and not rec["passed"] and _files(cm.case_dir(out, k)) == {"case.json"}
        assert rec["error"].startswith(f"case {k}: dispersions[0] (devices.mtq.mag_noise_nT, uniform, in d.toml) "
                                       f"drew {d!r}, which the scenario refuses")
        assert f"devices[0].mag_noise_nT = {d!r} in " in rec["error"] and "a number >= 0" in rec["error"]
        assert {c["case"]: c["error"] for c in result["failed_cases"]}[k] == rec["error"]  # in campaign.json too


def test_a_case_the_scenario_refuses_is_that_case_s_error_found_by_its_local_worker(
        scenario_dict, write_scenario, tmp_path, monkeypatch):
    """The client checks the file, every choice and case 0 before anything runs, and no more: each case is drawn
    and validated by the worker that runs it (its parse). A refused case is recorded with the sentence the
    campaign gave when it validated every case itself, and the other cases run."""
    spec, draws = _sometimes_refused(scenario_dict, write_scenario, tmp_path, runs=4)
    parses = []
    real = spec_mod.scenario_mod.parse
    monkeypatch.setattr(spec_mod.scenario_mod, "parse", lambda *a, **kw: parses.append(a) or real(*a, **kw))
    cm.validate(spec, 1)
    up_front = len(parses)
    parses.clear()
    out = tmp_path / "camp"
    result = cm.run_campaign(spec, out, len(draws), workers=1, plots=False)
    assert len(parses) == up_front, "the client parsed the first case only"
    _check_refused_cases(out, result, draws, os.getpid())


@pytest.mark.slow
def test_a_case_the_scenario_refuses_is_that_case_s_error_found_by_its_dask_worker(
        scenario_dict, write_scenario, tmp_path):
    import distributed

    spec, draws = _sometimes_refused(scenario_dict, write_scenario, tmp_path, runs=4)
    out = tmp_path / "camp"
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=cm.DASK_HTTP_ADDRESS) as cluster:
        result = cm.run_campaign(spec, out, len(draws), scheduler=cluster.scheduler_address, plots=False)
    _check_refused_cases(out, result, draws, os.getpid())


def test_a_dask_worker_writes_the_case_where_it_sees_the_campaign_folder_else_sends_the_files(tmp_path):
    """A Dask worker is told where the case goes and the session's token: reading the same token in the campaign
    folder (this machine, a shared file system), it writes the case in a folder of its own beside the case's
    ``.part`` (the scheduler may run a case twice at once) and leaves it whole as ``NNNNN.part.done``, which the
    client takes (the record from its case.json, the record's writing CPU time from the file beside it) and renames;
    a second run of the same case finds it there and leaves it: one case, not two, none lost. Elsewhere the worker
    runs in a temporary folder and sends the files, as before."""
    from stand.campaign import case, store

    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=SHORT_S)
    out = tmp_path / "camp"
    out.mkdir()
    token = store.write_token(out)
    part = str(part_dir(out, 2))
    task = {"index": 2, "spec": spec, "dest": part, "token": token}
    sent = cm.run_case({**task, "token": "0" * 32})  # a worker that does not see this folder
    assert set(sent["files"]) == set(cm.RUN_FILES) and "dir" not in sent and not (out / "cases").exists()
    assert case.take_done(part) is None  # nothing left there: the client fetches that answer through Dask
    wrote = cm.run_case(task)
    folder = wrote["dir"]
    assert wrote["files"] == {} and wrote["written"] and folder == part + ".done"
    assert _files(tmp_path / folder) == CASE_FILES | {case.DONE_TIMING}
    assert wrote["record"]["digest"] == sent["record"]["digest"]
    again = cm.run_case(task)  # the scheduler ran it a second time: the first whole folder stays, this one goes
    assert again["dir"] == folder and again["record"]["digest"] == wrote["record"]["digest"]
    assert sorted(p.name for p in (out / "cases").iterdir()) == ["00002.part.done"]
    taken = case.take_done(part)
    assert taken["record"] == wrote["record"] and taken["dir"] == folder and taken["written"]
    assert _files(tmp_path / folder) == CASE_FILES
    store._write_case(out, taken, taken["record"]["timing"]["worker_end"])
    assert sorted(p.name for p in (out / "cases").iterdir()) == ["00002"]
    assert _files(cm.case_dir(out, 2)) == CASE_FILES
    assert (cm.case_dir(out, 2) / "telemetry/rows.f64").read_bytes() == sent["files"]["telemetry/rows.f64"]


@pytest.mark.slow
@pytest.mark.parametrize("per_message, messages", [(None, 1), (2, 2)])
def test_a_dask_campaign_sends_its_cases_to_the_scheduler_in_one_graph_update(tmp_path, monkeypatch, per_message,
                                                                              messages):
    """The client hands the scheduler every case in one message (and the spec in one before), not one per case:
    what the client and the scheduler do per case is the answer alone; a campaign bigger than CASES_PER_MESSAGE
    (here made 2) goes in messages of that many, each case in one. The scheduler sees each update_graph."""
    import distributed

    from stand.campaign import dask_executor

    if per_message is not None:
        monkeypatch.setattr(dask_executor, "CASES_PER_MESSAGE", per_message)
    from distributed.diagnostics.plugin import SchedulerPlugin

    class Updates(SchedulerPlugin):
        def __init__(self):
            self.keys: list[set] = []

        def update_graph(self, scheduler, *, keys, **kwargs):
            self.keys.append({str(k) for k in keys})

    runs = 4
    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=SHORT_S)
    updates = Updates()
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=cm.DASK_HTTP_ADDRESS) as cluster:
        cluster.scheduler.add_plugin(updates, name="stand-test-updates")
        result = cm.run_campaign(spec, tmp_path / "camp", runs, scheduler=cluster.scheduler_address, plots=False)
    assert result["status"] == "complete" and result["runs"] == runs
    cases = [k for k in updates.keys if any(key.startswith("stand-case-") for key in k)]
    assert len(cases) == messages, f"the cases came in {len(cases)} graph updates"
    keys = [key for update in cases for key in update if key.startswith("stand-case-")]
    assert sorted(keys) == sorted(f"stand-case-{spec.key}-{k}" for k in range(runs))


@pytest.mark.slow
def test_the_campaign_bench_runs_its_dask_cluster_in_a_process_of_its_own():
    """The bench's LocalCluster runs apart from the client, as a cluster met with ``--scheduler ADDRESS`` does, so
    the client's CPU time per run is the client's alone: its scheduler answers on 127.0.0.1 from another process,
    whose CPU time the bench reads, and the process ends when the bench closes it."""
    import distributed

    from stand.benches.campaign import _ClusterProcess

    with _ClusterProcess(workers=1) as cluster:
        assert cluster.address.startswith("tcp://127.0.0.1:")
        with distributed.Client(cluster.address, timeout=30, set_as_default=False) as client:
            assert client.run_on_scheduler(os.getpid) not in (os.getpid(), None)
            assert len(client.scheduler_info()["workers"]) == 1
        cpu0 = cluster.cpu_s()
        assert cluster.idle_cpu_ms_per_s(wait_s=0.2) >= 0.0 and cluster.cpu_s() >= cpu0 > 0.0
        proc = cluster.proc
    assert not proc.is_alive() and proc.exitcode == 0


def _count_reads_of(monkeypatch, name: str) -> list[str]:
    """Every read of a file called ``name`` from now on: opened by Python (open, pathlib) or by numpy.fromfile."""
    import builtins
    import io

    import numpy as np

    reads: list[str] = []
    real_open, real_fromfile = io.open, np.fromfile

    def counted_open(file, mode="r", *a, **kw):
        if str(file).endswith(name) and "r" in mode:
            reads.append(f"open {file}")
        return real_open(file, mode, *a, **kw)

    def counted_fromfile(file, *a, **kw):
        if str(file).endswith(name):
            reads.append(f"fromfile {file}")
        return real_fromfile(file, *a, **kw)

    monkeypatch.setattr(io, "open", counted_open)
    monkeypatch.setattr(builtins, "open", counted_open)
    monkeypatch.setattr(np, "fromfile", counted_fromfile)
    return reads


def test_a_case_reads_its_telemetry_once_for_its_summary_and_its_digest(tmp_path, monkeypatch):
    """The summary judges the columns and the digest hashes the bytes of one read of rows.f64 (two reads were a
    copy of the whole telemetry per case); the digest is still that of the file's bytes."""
    import hashlib

    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=SHORT_S)
    dest = tmp_path / "case.part"
    reads = _count_reads_of(monkeypatch, "rows.f64")
    result = cm.run_case({**spec.case(2), "dest": str(dest)})
    assert result["record"]["status"] == "completed"
    assert len(reads) == 1, reads
    monkeypatch.undo()
    summary = json.loads((dest / "summary.json").read_text())
    h = hashlib.sha256(json.dumps(cm.comparable(summary), sort_keys=True, default=float).encode())
    h.update((dest / "telemetry" / "rows.f64").read_bytes())
    assert result["record"]["digest"] == h.hexdigest()


def test_load_with_bytes_gives_load_s_columns_and_the_file_s_bytes(tmp_path):
    """The same columns, value for value, as ``load``; a trailing partial row (a run killed mid-write) is left out
    of the columns as ``load`` leaves it out, and the bytes are the file's, whole."""
    import numpy as np

    from stand import telemetry

    with telemetry.Recorder(tmp_path, [("t_s", 1, "s"), ("omega_BN_B", 3, "rad/s")]) as rec:
        for k in range(7):
            rec.record((0.1 * k, 1.0 + k, -2.0 * k, 3.5))
    path = tmp_path / "telemetry" / "rows.f64"
    with open(path, "ab") as f:
        f.write(np.float64(9.0).tobytes() + b"\x01\x02\x03")  # a row cut after one float and three bytes
    tel, data = telemetry.load_with_bytes(tmp_path)
    assert data == path.read_bytes()
    want = telemetry.load(tmp_path)
    assert tel.keys() == want.keys() and len(tel["t_s"]) == 7
    for name in want:
        assert np.array_equal(tel[name], want[name]) and tel[name].shape == want[name].shape
        assert not tel[name].flags.writeable  # the fingerprinted bytes cannot change under the digest


def test_a_summary_computes_the_body_rate_of_the_telemetry_once(tmp_path, monkeypatch):
    """The rate checkpoints and the rate criteria read one body-rate array (each computed its own over every row),
    and the criterion's value is that array's last row."""
    import numpy as np

    from stand import report

    calls = []
    real = report._rate_deg_s
    monkeypatch.setattr(report, "_rate_deg_s", lambda tel: calls.append(1) or real(tel))
    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=SHORT_S)
    dest = tmp_path / "case.part"
    result = cm.run_case({**spec.case(3), "dest": str(dest)})
    assert result["record"]["status"] == "completed"
    assert len(calls) == 1
    from stand import telemetry

    omega = telemetry.load(dest)["omega_BN_B"]
    final = [c for c in result["record"]["criteria"] if c["metric"] == "final_rate_deg_s"]
    assert final and final[0]["value"] == float(np.degrees(np.linalg.norm(omega, axis=1))[-1])


@pytest.mark.parametrize("workers, out", [(0, "camp"), (1, "camp"), (1, "../up/./camp")])
def test_a_campaign_in_a_relative_folder_keeps_each_run_s_files(tmp_path, monkeypatch, workers, out):
    """``--out camp`` (relative to the working directory): the worker writes the run in the case's folder named from
    the absolute path, and the client renames that folder as it is (it took the two names for two folders, removed
    the run's files and kept the record alone)."""
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=SHORT_S)
    result = cm.run_campaign(spec, out, 2, workers=workers, plots=False)
    assert result["finished"] == 2 and result["errors"] == 0
    folder = (here / out).resolve()
    for k in range(2):
        assert _files(cm.case_dir(folder, k)) == CASE_FILES
    assert sorted(p.name for p in (folder / "cases").iterdir()) == ["00000", "00001"]


def test_a_case_folder_keeps_the_run_files_and_nothing_else(tmp_path):
    """What a run leaves beyond RUN_FILES goes: its log, a temporary file beside a kept one, a folder of its own."""
    from stand.campaign.case import _keep_only_run_files

    for name in (*cm.RUN_FILES, "stand.log", "summary.json.tmp", "telemetry/rows.f64.tmp", "plots/deep/a.png"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(name)
    _keep_only_run_files(tmp_path)
    assert _files(tmp_path) == set(cm.RUN_FILES)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["events.jsonl", "summary.json", "telemetry"]
    assert all((tmp_path / name).read_text() == name for name in cm.RUN_FILES)


def test_a_case_s_estimate_checks_the_disk_its_telemetry_goes_to(tmp_path, monkeypatch):
    """The free space a case's telemetry needs is looked for where the case is written, not in ./runs (which a
    campaign does not write, and which may be on another disk or not exist)."""
    from stand import compose

    asked = []
    real = compose.free_disk_bytes
    monkeypatch.setattr(compose, "free_disk_bytes", lambda folder: asked.append(folder) or real(folder))
    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=SHORT_S)
    dest = tmp_path / "camp" / "cases" / "00001.part"
    result = cm.run_case({**spec.case(1), "dest": str(dest)})
    assert result["record"]["status"] == "completed"
    assert asked == [dest]


def test_the_client_reads_an_answer_without_polling_its_pipe_again(monkeypatch):
    """The wait that woke the client says which pipes have an answer: it reads them without a poll of each (a poll
    is a wait of its own, which the client paid once per answer); every case still comes back, in order."""
    from multiprocessing.connection import Connection

    polls = []
    real = Connection.poll
    monkeypatch.setattr(Connection, "poll", lambda self, *a: polls.append(1) or real(self, *a))
    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=SHORT_S)
    pool = _LocalPool(1)
    try:
        answers = list(pool.results([spec.case(k) for k in range(3)]))
    finally:
        pool.close(cancel=True)
    assert [i for i, _, _ in answers] == [0, 1, 2]
    assert all(reason is None and result["record"]["status"] == "completed" for _, result, reason in answers)
    assert polls == []


@pytest.mark.slow
def test_a_dask_campaign_takes_the_cases_its_workers_left_whole_without_fetching_them(tmp_path, monkeypatch):
    """Workers that see the campaign folder leave each case whole there (``NNNNN.part.done``): the client takes it
    from there as soon as the scheduler says the case's task ended, and fetches no answer through the scheduler (it
    fetched every case's record before); every case is there once, as the local pool writes it, and the record's
    writing CPU time is still counted."""
    import distributed
    from distributed.client import Client

    fetched: list[int] = []
    real_gather = Client._gather

    async def counted(self, futures, *args, **kwargs):
        fetched.append(len(futures))
        return await real_gather(self, futures, *args, **kwargs)

    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=SHORT_S)
    runs = 4
    local = cm.run_campaign(spec, tmp_path / "local", runs, workers=0, plots=False)
    monkeypatch.setattr(Client, "_gather", counted)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=cm.DASK_HTTP_ADDRESS) as cluster:
        result = cm.run_campaign(spec, tmp_path / "dask", runs, scheduler=cluster.scheduler_address, plots=False)
    assert fetched == []
    assert result["status"] == "complete" and result["finished"] == runs and not result["execution"]["lost"]
    assert [c["digest"] for c in result["cases"]] == [c["digest"] for c in local["cases"]]
    assert sorted(p.name for p in (tmp_path / "dask" / "cases").iterdir()) == [f"{k:05d}" for k in range(runs)]
    for k in range(runs):
        assert _files(cm.case_dir(tmp_path / "dask", k)) == CASE_FILES
    assert result["execution"]["worker_record_write_cpu_s"] > 0.0


def test_a_dask_worker_that_cannot_leave_its_case_as_done_keeps_it_in_its_own_folder_for_the_client(
        tmp_path, monkeypatch):
    """The rename to ``NNNNN.part.done`` refused (and no other run of the case there): the case stays whole in the
    worker's own folder without the timing file, as before this pass, and the client, which then fetches the record
    through the scheduler, makes it count."""
    from pathlib import Path

    from stand.campaign import case, store

    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=SHORT_S)
    out = tmp_path / "camp"
    out.mkdir()
    task = {"index": 1, "spec": spec, "dest": str(part_dir(out, 1)), "token": store.write_token(out)}

    def refused(src, dst):
        raise OSError(18, "Invalid cross-device link")

    monkeypatch.setattr(os, "rename", refused)
    kept = cm.run_case(task)
    assert kept["written"] and kept["dir"].startswith(task["dest"] + ".") and kept["dir"] != task["dest"] + ".done"
    assert _files(Path(kept["dir"])) == CASE_FILES
    assert case.take_done(task["dest"]) is None
    monkeypatch.undo()
    store._write_case(out, kept, kept["record"]["timing"]["worker_end"])
    assert sorted(p.name for p in (out / "cases").iterdir()) == ["00001"]
    assert _files(cm.case_dir(out, 1)) == CASE_FILES
