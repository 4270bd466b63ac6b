"""The command line's promises: exit codes 0 / 1 / 2 / 3 / 130 (3 is in test_links.py: a plug-in that raises),
signals at any time leave a summary and an end event, scenarios are found by name, name.toml or path, and a full
disk ends a run "aborted" with what was written kept."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from stand import telemetry
from stand.cli import main
from tests.stand.processes import REPO, stand_env


def _events(out: Path) -> list[dict]:
    return [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_exit_0_when_the_criteria_hold_and_1_when_one_fails(tmp_path, capsys):
    # Without the plots (seconds of drawing on a whole orbit): the exit codes and the printed criteria are the point.
    assert main(["run", "--duration", "5677", "--out", str(tmp_path / "pass"), "--no-progress", "--no-plots"]) == 0
    out = capsys.readouterr().out
    # Criteria print with their units and readable limits.
    # The printed final rate is Basilisk's on the same case (fixtures/reference/basilisk/README.md) within 1e-3 deg/s,
    # plus half the last printed digit.
    printed = float(out.split("PASS  detumbled: ", 1)[1].split(" deg/s <= 0.5 deg/s", 1)[0])
    ref = json.loads((REPO / "fixtures/reference/basilisk/detumble_basilisk_stand_case.json").read_text())
    assert abs(printed - ref["final_omega_norm_deg_s"]) <= 1e-3 + 5e-5, (printed, ref["final_omega_norm_deg_s"])
    assert main(["run", "--duration", "60", "--out", str(tmp_path / "fail"), "--no-progress", "--no-plots"]) == 1
    out = capsys.readouterr().out
    assert "FAIL  detumbled:" in out and "FAIL: detumble" in out


@pytest.mark.parametrize("argv, needle", [
    (["run", "detumbel"], "did you mean 'detumble'"),
    (["check", "detumble_star_trackr"], "did you mean"),
    (["run", "--duration", "-5"], "--duration"),
])
def test_exit_2_for_usage_and_scenario_errors_with_one_sentence(tmp_path, capsys, argv, needle):
    argv = argv + (["--out", str(tmp_path / "x")] if argv[0] == "run" else [])
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and len(err.strip().splitlines()) == 1


def test_scenarios_are_found_by_name_by_name_with_toml_and_by_path_even_beside_a_folder_of_that_name(
        tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "detumble").mkdir()  # a folder named like the scenario must not hide it
    for arg in ("detumble", "detumble.toml", str(REPO / "fixtures" / "scenarios" / "detumble.toml")):
        assert main(["check", arg]) == 0, arg
        assert capsys.readouterr().out.startswith("detumble: valid")
    assert main(["scenarios"]) == 0
    out = capsys.readouterr().out
    assert "detumble_external" in out and "B-dot detumble from 10 deg/s" in out


def _start(args, tmp_path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "stand.cli", *args], cwd=tmp_path, env=stand_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_rows(out: Path, timeout_s: float = 60.0) -> None:
    rows = out / "telemetry" / "rows.f64"
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and (not rows.exists() or rows.stat().st_size == 0):
        time.sleep(0.05)
    assert rows.exists() and rows.stat().st_size > 0


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_mid_run_exits_130_with_a_summary_and_an_end_event(tmp_path, sig):
    out = tmp_path / "run"
    proc = _start(["run", "--speed", "20", "--out", str(out), "--no-progress"], tmp_path)
    try:
        _wait_for_rows(out)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:  # reaped with its pipes closed: nothing of it is left for a later test to trip on
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "stopped" and not summary["pass"]
    events = _events(out)
    assert events[-1]["kind"] == "end" and events[-1]["message"] == "stopped"
    assert (out / "report.md").exists() and len(telemetry.load(out)["t_s"]) > 0


def test_a_sigterm_that_lands_while_the_orbit_track_works_ahead_still_stops_the_run(tmp_path, monkeypatch, capsys):
    """A paced run spends its slack building the next orbit chunk (``OrbitTrack.work_ahead``, which takes any
    ``Exception`` there for a failure to report later). The SIGTERM handler raises wherever the main thread is: a
    signal that lands in that work must still stop the run (it once went on to the end, and the exit test above
    timed out under load in CI)."""
    from sim.truth import OrbitTrack

    real, signalled = OrbitTrack._extend, []

    def extend_then_signal(track, build, n):
        real(track, build, n)
        if not signalled and sys._getframe(1).f_code.co_name == "work_ahead":  # not the read of a chunk at once
            signalled.append(n)
            os.kill(os.getpid(), signal.SIGTERM)  # its handler runs here, inside work_ahead's try
            for _ in range(1000):  # the handler runs at the next bytecode boundaries of this thread
                pass

    monkeypatch.setattr(OrbitTrack, "_extend", extend_then_signal)
    before = signal.getsignal(signal.SIGTERM)
    out = tmp_path / "run"
    code = main(["run", "--speed", "50", "--duration", "60", "--out", str(out), "--no-progress", "--no-plots"])
    assert signalled, "the run never worked ahead: the test did not exercise the case"
    assert code == 130, capsys.readouterr()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "stopped" and summary["sim_duration_s"] < 60.0 and not summary["pass"]
    assert _events(out)[-1]["message"] == "stopped"
    assert signal.getsignal(signal.SIGTERM) == before  # the stand's handler is gone after the run


def test_a_signal_before_the_run_starts_exits_130_and_leaves_no_empty_folder(tmp_path):
    out = tmp_path / "early"
    # The image tracker's pattern database takes a second to build: the signal lands during composition.
    proc = _start(["run", "detumble_star_tracker_image", "--out", str(out), "--no-progress"], tmp_path)
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    # 130 once the stand's code runs; a signal that lands while the interpreter itself is still starting (a very
    # loaded machine) ends it the way Python ends any program there, killed by SIGINT, which leaves nothing behind.
    assert proc.returncode in (130, -signal.SIGINT), (proc.returncode, err)
    if proc.returncode == 130:
        assert "Traceback" not in err
    assert not out.exists() or (out / "summary.json").exists()


def test_a_full_disk_ends_the_run_aborted_and_keeps_a_whole_summary(tmp_path, monkeypatch):
    """The telemetry writer hits ENOSPC mid-run: the run ends "aborted" (exit 3), the rows written before stay
    readable, and summary.json is whole JSON."""
    import errno

    from stand import telemetry as tel_mod

    real_write = tel_mod.Recorder._writer
    calls = {"n": 0}

    class FullFile:
        def __init__(self, f):
            self.f = f

        def write(self, data):
            calls["n"] += 1
            if calls["n"] > 3:
                raise OSError(errno.ENOSPC, "No space left on device")
            return self.f.write(data)

        def __getattr__(self, name):
            return getattr(self.f, name)

    def writer(self):
        self._file = FullFile(self._file)
        real_write(self)

    monkeypatch.setattr(tel_mod.Recorder, "_writer", writer)
    monkeypatch.setattr(tel_mod, "BATCH_ROWS", 64)
    out = tmp_path / "full"
    assert main(["run", "--duration", "600", "--out", str(out), "--no-progress", "--no-plots"]) == 3
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "aborted" and "telemetry" in summary["error"] and not summary["pass"]
    rows = telemetry.load(out)["t_s"]
    assert 64 * 3 <= len(rows) < 6000
    assert any(e["kind"] == "aborted" for e in _events(out))


# --------------------------------------------------------------------------- issue 22: folders, --out, a full disk
SAME_SECOND = """
import sys, time
from pathlib import Path
time.strftime = lambda *a, **k: "20260101-000000"  # both runs start in the same second
go = Path(sys.argv[1])
Path(sys.argv[2]).touch()  # started: waiting at the line below
deadline = time.monotonic() + 60
while not go.exists() and time.monotonic() < deadline:
    time.sleep(0.005)
from stand.cli import main
sys.exit(main(["run", "--duration", "2", "--no-progress", "--no-plots"]))
"""


@pytest.mark.slow
def test_two_runs_started_in_the_same_second_get_a_folder_each(tmp_path):
    go = tmp_path / "go"
    ready = [tmp_path / f"ready{k}" for k in range(2)]
    procs = [subprocess.Popen([sys.executable, "-c", SAME_SECOND, str(go), str(r)], cwd=tmp_path, env=stand_env(),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for r in ready]
    try:
        # Both wait at the same line (each says so by its file; was a fixed 3 s sleep): released together.
        deadline = time.monotonic() + 60
        while not all(r.exists() for r in ready) and time.monotonic() < deadline:
            time.sleep(0.005)
        go.touch()
        outputs = [p.communicate(timeout=120) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate()
    assert [p.returncode for p in procs] == [1, 1], outputs  # 2 s do not detumble: both ran to the end
    folders = sorted(d.name for d in (tmp_path / "runs").iterdir())
    assert folders == ["detumble-20260101-000000", "detumble-20260101-000000-2"], folders
    for name in folders:
        out = tmp_path / "runs" / name
        assert json.loads((out / "summary.json").read_text())["status"] == "completed"
        assert len(telemetry.load(out)["t_s"]) == 21  # one run's rows, not two runs' interleaved
        assert sum(e["kind"] == "start" for e in _events(out)) == 1
    said = sorted(o[0].strip().splitlines()[-1].rsplit("results in ", 1)[1] for o in outputs)
    assert said == [f"runs/{n}" for n in folders]


@pytest.mark.parametrize("where", ["/proc/nope", "/proc/self/nope/run"])
def test_an_output_folder_that_cannot_be_made_is_one_sentence_naming_out(tmp_path, capsys, where):
    assert main(["run", "--duration", "1", "--out", where, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"stand: error: --out = '{where}' is not allowed") and len(err.strip().splitlines()) == 1


def test_a_full_disk_at_the_end_still_leaves_a_whole_summary(tmp_path, monkeypatch):
    """Nothing can be created any more when the run ends (the temporary file for the rename fails): the summary
    is written over the space reserved for it before t = 0, as strict JSON."""
    import errno

    from stand import report

    def full(path, text):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(report, "write_text_atomic", full)
    out = tmp_path / "full"
    assert main(["run", "--duration", "5", "--out", str(out), "--no-progress"]) == 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["sim_duration_s"] == 5.0 and not summary["pass"]
    assert [c["name"] for c in summary["criteria"]] == ["detumbled", "no rejected frames"]


FILL_THE_DISK = """
import json, os, subprocess, sys, time
from pathlib import Path
mnt = Path(sys.argv[1]); keep = Path(sys.argv[2])
subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(mnt)], check=True)
out = mnt / "run"
stand = subprocess.Popen([sys.executable, "-m", "stand.cli", "run", "--duration", "600", "--speed", "20", "--out",
                          str(out), "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
rows = out / "telemetry" / "rows.f64"
deadline = time.monotonic() + 60
while time.monotonic() < deadline and (not rows.exists() or rows.stat().st_size == 0):
    time.sleep(0.05)
with open(mnt / "filler", "wb") as f:  # another program fills the disk mid-run
    try:
        while True:
            f.write(b"\\0" * 65536)
            f.flush()
    except OSError:
        pass
try:
    _, err = stand.communicate(timeout=120)
finally:
    if stand.poll() is None:
        stand.kill()
keep.mkdir()
for name in ("summary.json", "events.jsonl"):
    if (out / name).exists():
        (keep / name).write_bytes((out / name).read_bytes())
(keep / "result.json").write_text(json.dumps({"code": stand.returncode, "err": err,
                                              "rows": rows.stat().st_size}))
"""


def _mount_namespace_ok() -> bool:
    try:
        return subprocess.run(["unshare", "-rm", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt"],
                              capture_output=True, timeout=30).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


@pytest.mark.skipif(not _mount_namespace_ok(), reason="needs `unshare -rm` and a tmpfs mount in a user namespace "
                    "(a real full disk; test_a_full_disk_at_the_end_still_leaves_a_whole_summary covers the logic)")
def test_a_disk_that_fills_mid_run_leaves_a_whole_summary(tmp_path):
    """A real full disk: a 4 MB tmpfs that another program fills while the run goes (in a private mount namespace).
    The run ends aborted (exit 3) and summary.json, reserved before t = 0, is whole JSON saying why."""
    mnt, keep = tmp_path / "mnt", tmp_path / "keep"
    mnt.mkdir()
    done = subprocess.run(["unshare", "-rm", sys.executable, "-c", FILL_THE_DISK, str(mnt), str(keep)],
                          env=stand_env(), cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    result = json.loads((keep / "result.json").read_text())
    assert result["code"] == 3, result["err"]
    summary = json.loads((keep / "summary.json").read_text())
    assert summary["status"] == "aborted" and not summary["pass"] and "telemetry" in summary["error"]
    assert "No space left on device" in summary["error"] and "report_error" in summary
    assert result["rows"] > 0 and "Traceback" not in result["err"]


def test_no_exit_0_without_the_summary_on_disk(tmp_path, monkeypatch, capsys):
    """The criteria hold, but summary.json is gone when the verdict is given (a disk that lost it, another program):
    `stand run` reads it back and does not exit 0."""
    from stand import report

    real = report.write_summary

    def lose_it(scene, result, out, *a, **k):
        summary = real(scene, result, out, *a, **k)
        (out / "summary.json").unlink()
        return summary

    monkeypatch.setattr(report, "write_summary", lose_it)
    out = tmp_path / "lost"
    lenient = ["--set", "criteria.detumbled.max=100"]
    assert main(["run", "--duration", "30", "--out", str(out), "--no-progress", "--no-plots", *lenient]) == 3
    captured = capsys.readouterr()
    assert "PASS: detumble" not in captured.out and "does not hold this run's summary" in captured.err
