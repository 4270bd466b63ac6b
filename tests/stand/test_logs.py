"""Logging: loggers named by module, RUN/stand.log beside events.jsonl, -v/-q, no duplicate handlers across runs in
one process, the served device nobody talks to, and the verdict of a paced run with many overruns."""

from __future__ import annotations

import json
import logging

import pytest

from stand import logs
from stand.cli import main
from stand.telemetry import EventLog
from tests.stand.conftest import to_toml
from tests.stand.test_gyro_wheel_links import small_scenario

#: A criterion any short run passes, so that the verdict is a pass (an empty criteria table may not be one).
ALWAYS = {"name": "no rejected frames", "metric": "frames_rejected", "max": 0}


def _scenario(tmp_path, devices=(), duration_s=3.0) -> str:
    data = small_scenario(list(devices), duration_s)
    data["criteria"] = [ALWAYS]
    path = tmp_path / "sc.toml"
    path.write_text(to_toml(data))
    return str(path)


def _stand_handlers() -> int:
    return sum(len(logging.getLogger(name).handlers) for name in logs.PACKAGES)


def test_each_run_logs_to_its_own_stand_log_and_leaves_no_handler(tmp_path, capsys):
    before = _stand_handlers()
    for k in (1, 2, 3):  # three runs in one process, as a campaign's worker does
        assert main(["run", "detumble", "--duration", "2", "--out", str(tmp_path / f"r{k}"), "--no-progress",
                     "--no-plots"]) == 1
        assert _stand_handlers() == before
    for k in (1, 2, 3):
        lines = (tmp_path / f"r{k}" / "stand.log").read_text().splitlines()
        # one start and one end line each: no run wrote into another's file, none twice
        assert sum("stand.loop: scenario detumble for 2 s" in line for line in lines) == 1, lines
        assert sum(line.endswith("stand.loop: completed") for line in lines) == 1, lines
        assert (tmp_path / f"r{k}" / "events.jsonl").exists()


def test_events_are_records_of_the_module_that_logged_them(tmp_path, caplog):
    with caplog.at_level(logging.INFO):
        events = EventLog(tmp_path)
        events.log("device_silent", "st1: nothing received")
        events.log("start", "scenario x")
        events.close()
    assert [(r.name, r.levelno, r.stand_event) for r in caplog.records] == [
        (__name__, logging.WARNING, "device_silent"), (__name__, logging.INFO, "start")]
    # and still one JSON line each
    assert [json.loads(line)["kind"] for line in (tmp_path / "events.jsonl").read_text().splitlines()] == [
        "device_silent", "start"]


def test_verbose_and_quiet_set_the_console_and_leave_no_handler(tmp_path, capsys):
    def marked():
        return [h for h in logging.getLogger().handlers if getattr(h, logs._MARK, False)]

    def run(name, before=(), after=()):
        argv = [*before, "run", "detumble", "--duration", "1", "--out", str(tmp_path / name), "--no-progress",
                "--no-plots", *after]
        assert main(argv) == 1
        assert not marked()  # the console handler lives as long as the command
        return capsys.readouterr().err

    assert "INFO stand.loop: scenario detumble for 1 s" in run("a", after=["-v"])
    assert "INFO stand.loop: scenario detumble for 1 s" in run("b", before=["-v"])  # `stand -v run ...`
    assert "stand.loop" not in run("c")  # the default console: warnings and errors only
    assert "stand.loop" not in run("d", after=["-q"])
    assert "scenario detumble for 1 s" in (tmp_path / "d" / "stand.log").read_text()  # the file keeps INFO
    assert logging.getLogger("stand").level == logging.NOTSET  # put back


def test_the_console_shows_warnings_by_default_and_not_the_error_printed_at_the_end(capsys):
    console = logs.Console(0)
    try:
        logs.log_event("stand.loop", "device_silent", "st1: silent")
        logs.log_event("stand.loop", "start", "scenario x")
        logs.log_event("stand.loop", "device_exception", "at t = 1 s device st1 raised")
    finally:
        console.close()
    assert capsys.readouterr().err == "stand: WARNING stand.loop: st1: silent\n"


class _Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_a_served_device_nobody_talks_to_is_reported_once_after_the_wall_time(tmp_path, caplog):
    from stand.devices import UNHEARD_AFTER_S, Rejections

    clock, heard = _Clock(), [0]
    rej = Rejections("st1", lambda: 0, lambda: None, heard=lambda: heard[0], clock=clock)
    events = EventLog(tmp_path)
    rej.start(events)
    with caplog.at_level(logging.INFO, logger="stand"):
        for k in range(200):  # ticks 0.1 s of wall time apart: 20 s
            rej.check(k * 0.1)
            clock.t += 0.1
            if k == 150:
                heard[0] = 3  # a flight computer starts talking at 15 s
    events.close()
    kinds = [json.loads(line)["kind"] for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert kinds == ["device_unheard", "device_heard"]
    warn = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warn) == 1 and warn[0].name == "stand.devices" and "no flight computer talks" in warn[0].getMessage()
    t_warned = json.loads((tmp_path / "events.jsonl").read_text().splitlines()[0])["t_s"]
    assert UNHEARD_AFTER_S - 0.15 <= t_warned <= UNHEARD_AFTER_S + 0.15


def test_a_served_device_that_is_talked_to_says_nothing(tmp_path):
    from stand.devices import Rejections

    clock = _Clock()
    rej = Rejections("st1", lambda: 0, lambda: None, heard=lambda: 1, clock=clock)
    events = EventLog(tmp_path)
    rej.start(events)
    for k in range(100):
        rej.check(k * 0.1)
        clock.t += 0.1
    events.close()
    assert (tmp_path / "events.jsonl").read_text() == ""


def test_a_served_tracker_with_nothing_on_its_port_warns_on_the_console(pty_pair, tmp_path, capsys, monkeypatch):
    """End to end: a run serving a tracker on a pty nobody writes to says so on the console, once."""
    import stand.devices

    monkeypatch.setattr(stand.devices, "UNHEARD_AFTER_S", 0.5)  # the run is paced: half a second of wall time
    stand_end, _peer_end = pty_pair
    served = {"name": "st1", "kind": "star_tracker", "link": "served", "port": stand_end}
    path = _scenario(tmp_path, [served], duration_s=2.0)
    assert main(["run", path, "--speed", "1", "--out", str(tmp_path / "out"), "--no-progress", "--no-plots"]) == 0
    err = capsys.readouterr().err
    assert err.count("no flight computer talks to this served device") == 1, err
    assert "WARNING stand.devices: st1: nothing received from outside" in err
    assert "no flight computer talks" in (tmp_path / "out" / "stand.log").read_text()


def test_a_paced_run_with_many_overruns_is_not_a_plain_pass(tmp_path, capsys):
    """Paced far faster than a tick can be computed: nearly every tick starts a period late."""
    path = _scenario(tmp_path, duration_s=2.0)
    assert main(["run", path, "--speed", "1000000", "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    share = summary["timing"]["overruns"] / summary["timing"]["ticks"]
    assert summary["pass"] is True and share > 0.5
    assert summary["verdict"] == f"PASS, paced with {100 * share:.1f} % overruns"
    assert f"PASS, paced with {100 * share:.1f} % overruns: links" in out
    assert f"**PASS, paced with {100 * share:.1f} % overruns**" in (tmp_path / "out" / "report.md").read_text()
    events = [json.loads(line) for line in (tmp_path / "out" / "events.jsonl").read_text().splitlines()]
    assert [e["overruns"] for e in events if e["kind"] == "overruns"] == [summary["timing"]["overruns"]]


@pytest.mark.parametrize("timing, verdict", [
    ({"paced": False, "overruns": 0, "ticks": 100}, "PASS"),
    ({"paced": True, "overruns": 1, "ticks": 100}, "PASS"),  # 1 %: at the stated share, still a plain pass
    ({"paced": True, "overruns": 2, "ticks": 100}, "PASS, paced with 2.0 % overruns"),
    ({"paced": True, "overruns": 0, "ticks": 0}, "PASS")])
def test_the_verdict_states_the_overrun_share(timing, verdict):
    from stand.pacing import OVERRUN_SHARE_LIMIT
    from stand.report import verdict_text

    assert OVERRUN_SHARE_LIMIT == 0.01
    assert verdict_text(True, "completed", timing) == verdict
    assert verdict_text(False, "completed", timing) == "FAIL"
    assert verdict_text(False, "aborted", timing) == "ABORTED"


def test_a_run_log_that_cannot_be_written_costs_nothing_but_its_lines(tmp_path, capsys):
    """A full disk: the file's write fails; no traceback on the console, the handler still goes away."""
    before = _stand_handlers()
    (tmp_path / logs.RUN_LOG).symlink_to("/dev/full")  # every write fails with ENOSPC
    run_log = logs.RunLog(tmp_path)
    logs.log_event("stand.loop", "start", "scenario x")
    assert run_log.handler.lost == 1
    run_log.close()
    assert _stand_handlers() == before and "Traceback" not in capsys.readouterr().err
    logs.RunLog(tmp_path / "missing" / "deeper").close()  # a folder that is not there: no file, no error
