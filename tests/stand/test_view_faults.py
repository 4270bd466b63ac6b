"""Live fault injection (issue 24, item 4): ``POST/GET /api/faults`` on the operator page's server, the command's
way through the feed and the loop to the run's fault schedule and back, and ``stand fault RUN_DIR ...``.

The schedule here is a stand-in with the interface of ``stand.faults.FaultSchedule`` (``inject(table) -> name``,
raising a ScenarioError for a bad table; ``clear(name)``, KeyError for an unknown one), so these tests judge the
transport only; tests/stand/test_view_faults_browser.py injects into the real schedule from the page.
"""

from __future__ import annotations

import json
import os
import stat
import threading
import urllib.error
import urllib.request

import pytest

from stand import loop
from stand.cli import main
from stand.errors import ScenarioError
from stand.view import server, state

from .view_scenario import write as write_scenario

JS = {"Content-Type": "application/json"}
TYPES = ("wheel_seized", "bias_step")


class FakeSchedule:
    """What the loop hands live commands to: records the tables, the thread that called, and the active names."""

    def __init__(self):
        self.tables: list[dict] = []
        self.cleared: list[str] = []
        self.active: dict[str, dict] = {}
        self.threads: set[int] = set()

    def inject(self, table: dict) -> str:
        self.threads.add(threading.get_ident())
        if table.get("type") not in TYPES:
            raise ScenarioError("faults[live].type", table.get("type"), "one of " + ", ".join(TYPES))
        name = table.get("name") or f"{table.get('device')}_{table['type']}"
        self.tables.append(table)
        self.active[name] = table
        return name

    def clear(self, name: str) -> None:
        self.threads.add(threading.get_ident())
        del self.active[name]
        self.cleared.append(name)


def _http(url, body=None, headers=None, method=None):
    data = body if body is None or isinstance(body, bytes) else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, headers=headers if headers is not None else JS, method=method)
    try:
        with urllib.request.urlopen(req, timeout=20) as resp:
            return resp.status, json.loads(resp.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    base = tmp_path_factory.mktemp("viewf")
    out = base / "run"
    assert main(["run", write_scenario(base / "sweep.toml", duration_s=5.0), "--out", str(out), "--no-progress",
                 "--no-plots"]) == 0
    return out


class _Loop:
    """The loop's side in one process: polls the feed as ``stand.loop._chores`` does and obeys through
    ``stand.loop._obey`` (the real routing), until stopped (bounded)."""

    def __init__(self, feed, faults):
        self.feed, self.faults = feed, faults
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.events = None

    def _run(self):
        for _ in range(20_000):  # 0.005 s each: at most 100 s
            if self.done.wait(0.005):
                return
            self.feed.push()
            command = self.feed.poll_control()
            if command is not None:
                loop._obey(command, self.feed, self.events, None, 0.0, lambda: 0.0, lambda s: None, self.faults)


@pytest.fixture
def live(run_dir):
    """A live page (server, source, feed joined in-process) whose run's loop hands faults to a FakeSchedule."""
    meta = state.load_meta(run_dir)
    source = state.LiveSource(run_dir, meta)
    feed = state.LiveFeed(state.LocalLink(source), meta)
    schedule = FakeSchedule()
    runner = _Loop(feed, schedule)
    with server.ViewServer(source) as view:
        runner.thread.start()
        try:
            yield view, schedule, runner
        finally:
            runner.done.set()
            runner.thread.join(timeout=10)


def test_inject_and_clear_reach_the_schedule_from_the_loop_thread(live):
    view, schedule, runner = live
    table = {"device": "rw2", "type": "wheel_seized", "duration_s": 5.0}
    assert _http(view.url + "api/faults", {"action": "inject", "fault": table}) == (
        200, {"action": "inject", "name": "rw2_wheel_seized"})
    assert schedule.tables == [table]
    assert schedule.threads == {runner.thread.ident}  # handed over by the loop, not by the server's threads
    named = {"device": "imu", "type": "bias_step", "bias_deg_s": [0.5, 0.0, 0.0], "name": "imu_jump"}
    assert _http(view.url + "api/faults", {"action": "inject", "fault": named}) == (
        200, {"action": "inject", "name": "imu_jump"})
    assert _http(view.url + "api/faults", {"action": "clear", "name": "rw2_wheel_seized"}) == (
        200, {"action": "clear", "name": "rw2_wheel_seized"})
    assert schedule.cleared == ["rw2_wheel_seized"] and list(schedule.active) == ["imu_jump"]


def test_the_schedules_refusal_comes_back_as_one_sentence(live):
    view, schedule, _ = live
    status, body = _http(view.url + "api/faults", {"action": "inject", "fault": {"device": "rw2", "type": "melt"}})
    assert status == 400
    assert body == {"error": "faults[live].type = 'melt' is not allowed: one of wheel_seized, bias_step."}
    status, body = _http(view.url + "api/faults", {"action": "clear", "name": "rw9.nothing"})
    assert (status, body) == (404, {"error": "no fault named 'rw9.nothing' was injected in this run"})
    assert schedule.tables == [] and schedule.cleared == []


@pytest.mark.parametrize("body, why", [
    (b"{not json", "Expecting property name"),
    (b"[1, 2]", "a fault command is a JSON object, not list"),
    (b'{"action": "reboot"}', 'action = "reboot" is not allowed: "inject" or "clear"'),
    (b'{"action": "inject"}', 'fault = null is not allowed: inject needs "fault", a non-empty object'),
    (b'{"action": "inject", "fault": {}}', 'fault = {} is not allowed'),
    (b'{"action": "inject", "fault": [1]}', 'fault = [1] is not allowed'),
    (b'{"action": "clear", "name": ""}', 'name = "" is not allowed: clear needs "name"'),
    (b'{"action": "clear", "name": 3}', 'name = 3 is not allowed'),
])
def test_malformed_commands_are_refused_before_the_run_sees_them(live, body, why):
    view, schedule, _ = live
    status, answer = _http(view.url + "api/faults", body)
    assert status == 400 and why in answer["error"], answer
    assert schedule.tables == [] and schedule.cleared == [] and schedule.threads == set()


def test_fault_commands_follow_the_control_rules(run_dir):
    meta = state.load_meta(run_dir)
    sent = []
    source = state.LiveSource(run_dir, meta, control=sent.append)
    inject = {"action": "inject", "fault": {"device": "rw2", "type": "wheel_seized"}}
    with server.ViewServer(source) as view:
        url = view.url + "api/faults"
        evil = _http(url, inject, {**JS, "Origin": "http://example.org"})
        assert evil[0] == 403 and "Origin" in evil[1]["error"]
        assert _http(url, json.dumps(inject).encode(), {"Content-Type": "text/plain"})[0] == 403
        rebound = _http(url, inject, {**JS, "Host": f"evil.example:{view.port}"})
        assert rebound[0] == 403 and "is not an address this view listens on" in rebound[1]["error"]
    with server.ViewServer(state.LiveSource(run_dir, meta, control=sent.append), host="127.0.0.2",
                           token="s3cret") as view:
        url = view.url + "api/faults"
        assert _http(url, inject)[0] == 403
        no = _http(url, inject, {**JS, "X-Stand-Token": "wrong"})
        assert no == (403, {"error": "this view needs its token (X-Stand-Token) to control the run (pause, resume, "
                                     "stop, faults)"})
    assert sent == []  # nothing refused reached the run
    with server.ViewServer(server.ReplaySource(run_dir)) as view:
        assert _http(view.url + "api/faults", inject) == (409, {"error": "a replay has no run to inject faults into"})


def test_a_run_without_a_schedule_or_that_does_not_answer(run_dir):
    meta = state.load_meta(run_dir)
    source = state.LiveSource(run_dir, meta)
    feed = state.LiveFeed(state.LocalLink(source), meta)
    inject = {"action": "inject", "fault": {"device": "rw2", "type": "wheel_seized"}}
    runner = _Loop(feed, None)  # a scene built without a fault schedule
    runner.thread.start()
    try:
        answer = source.fault(inject, timeout_s=10.0)
    finally:
        runner.done.set()
        runner.thread.join(timeout=10)
    assert answer == {"id": 1, "ok": False, "status": 409,
                      "error": "this run has no fault schedule: it was started without live injection"}
    # nobody polls: the wait is bounded, and says the command may still apply
    quiet = state.LiveSource(run_dir, meta)
    answer = quiet.fault(inject, timeout_s=0.2)
    assert answer["status"] == 504 and "did not answer within 0.2 s" in answer["error"]
    quiet.finished("completed")
    assert quiet.fault(inject) == {"ok": False, "status": 409, "error": "the run is finished: it takes no more faults"}
    # a command waiting when the run ends is told so at once
    ending = state.LiveSource(run_dir, meta)
    timer = threading.Timer(0.3, ending.finished, ("stopped",))
    timer.start()
    answer = ending.fault(inject, timeout_s=30.0)
    timer.join()
    assert answer == {"ok": False, "status": 409, "error": "the run ended before it took the fault command"}


def test_get_lists_the_faults_from_the_event_log(run_dir, tmp_path):
    import shutil

    out = tmp_path / "run"
    shutil.copytree(run_dir, out)
    with open(out / "events.jsonl", "a") as f:
        for ev in ({"kind": "fault_injected", "fault": "a", "type": "drop", "device": "st1", "t_s": 1.0,
                    "params": {"rate": 0.5}},
                   {"kind": "fault_injected", "fault": "b", "type": "bias_step", "device": "imu", "t_s": 2.0},
                   {"kind": "fault_cleared", "fault": "a", "t_s": 3.5},
                   {"kind": "fault_injected", "fault": "a", "type": "drop", "device": "st1", "t_s": 4.0,
                    "params": {"rate": 0.5}}):
            f.write(json.dumps({"message": "", **ev}) + "\n")
    expected = [
        {"name": "a", "type": "drop", "device": "st1", "params": {"rate": 0.5}, "injected_s": 1.0, "cleared_s": 3.5,
         "active": False},
        {"name": "b", "type": "bias_step", "device": "imu", "params": {}, "injected_s": 2.0, "cleared_s": None,
         "active": True},
        {"name": "a", "type": "drop", "device": "st1", "params": {"rate": 0.5}, "injected_s": 4.0, "cleared_s": None,
         "active": True}]
    meta = state.load_meta(out)
    for source in (server.ReplaySource(out), state.LiveSource(out, meta)):
        with server.ViewServer(source) as view:
            status, body = _http(view.url + "api/faults", headers={})
        assert status == 200 and body["faults"] == expected and body["live"] == (source.mode == "live")
        types = {t["name"]: t for t in body["types"]}
        assert types["bias_step"]["tap"] == "measurement" and types["bias_step"]["params"][0]["key"] == "bias_{unit}"
        assert len(types) >= 20


# ------------------------------------------------------------------------------------------------ stand fault

def test_view_url_file_is_private_and_points_at_the_page(tmp_path):
    path = server.write_view_url(tmp_path, "http://0.0.0.0:8123/", "0.0.0.0", "tok")
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    assert json.loads(path.read_text()) == {"url": "http://0.0.0.0:8123/", "connect": "http://127.0.0.1:8123/",
                                            "token": "tok", "pid": os.getpid()}
    path.chmod(0o644)  # left by an earlier run with other bits: written private again
    server.write_view_url(tmp_path, "http://[::]:8123/", "::", None)
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    assert json.loads(path.read_text())["connect"] == "http://[::1]:8123/"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["view_url.json"]  # no temporary file left


def test_stand_fault_injects_clears_and_lists(live, tmp_path, capsys):
    view, schedule, _ = live
    server.write_view_url(tmp_path, view.url, view.host, None)
    assert main(["fault", str(tmp_path), "inject", "--device", "imu", "--type", "bias_step", "--param",
                 "bias_deg_s=[0.5, 0, 0]", "--param", "axis=x", "--param", "on=true", "--duration-s", "2.5"]) == 0
    assert capsys.readouterr().out == "injected imu_bias_step\n"
    assert schedule.tables == [{"device": "imu", "type": "bias_step", "bias_deg_s": [0.5, 0, 0], "axis": "x",
                                "on": True, "duration_s": 2.5}]
    assert main(["fault", str(tmp_path), "inject", "--device", "st1", "--type", "wheel_seized", "--name", "n1"]) == 0
    assert schedule.tables[-1] == {"device": "st1", "type": "wheel_seized", "name": "n1"}
    assert main(["fault", str(tmp_path), "clear", "imu_bias_step"]) == 0
    assert capsys.readouterr().out == "injected n1\ncleared imu_bias_step\n"
    assert main(["fault", str(tmp_path), "clear", "imu_bias_step"]) == 2
    assert capsys.readouterr().err == ("stand: error: the run refused: no fault named 'imu_bias_step' was injected "
                                       "in this run (HTTP 404).\n")
    assert main(["fault", str(tmp_path), "inject", "--device", "imu", "--type", "melt"]) == 2
    assert "faults[live].type = 'melt' is not allowed: one of wheel_seized, bias_step." in capsys.readouterr().err
    assert main(["fault", str(tmp_path), "list", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["live"] is True


@pytest.mark.parametrize("argv, why", [
    (["inject", "--device", "imu", "--type", "bias_step", "--param", "nothing"],
     "--param 'nothing' is not allowed: KEY=VALUE, e.g. --param rate=0.5."),
    (["inject", "--device", "imu", "--type", "bias_step", "--param", "duration_s=3"],
     "--param 'duration_s=3' is not allowed: duration_s has its own option (--duration-s)."),
])
def test_stand_fault_refuses_bad_options(tmp_path, capsys, argv, why):
    assert main(["fault", str(tmp_path), *argv]) == 2
    assert capsys.readouterr().err == f"stand: error: {why}\n"


def test_stand_fault_without_a_live_page(tmp_path, capsys):
    assert main(["fault", str(tmp_path / "nope"), "list"]) == 2
    assert capsys.readouterr().err == f"stand: error: run folder {tmp_path / 'nope'} does not exist.\n"
    assert main(["fault", str(tmp_path), "list"]) == 2
    assert "has no live page (view_url.json is missing)" in capsys.readouterr().err
    (tmp_path / "view_url.json").write_text("{")
    assert main(["fault", str(tmp_path), "list"]) == 2
    assert "view_url.json cannot be used (JSONDecodeError" in capsys.readouterr().err
    import socket

    with socket.socket() as s:  # a port nobody listens on: the run ended without removing its file
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server.write_view_url(tmp_path, f"http://127.0.0.1:{port}/", "127.0.0.1", None)
    assert main(["fault", str(tmp_path), "list"]) == 3
    assert f"the run's page at http://127.0.0.1:{port} cannot be reached" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------ the real loop

def test_a_paced_run_takes_faults_through_the_view_process(tmp_path, capsys):
    """``stand run --view``'s two processes, the real loop and the real fault schedule: a fault injected over HTTP
    starts at the next tick and ``stand fault ... clear`` ends it, both logged; a bad table is refused with the
    schedule's sentence; view_url.json is there while the run goes, 0600, and removed at the end."""
    from stand.compose import build
    from stand.scenario import load as load_scenario

    sc = load_scenario(write_scenario(tmp_path / "s.toml", duration_s=600.0))
    out = tmp_path / "out"
    out.mkdir()
    live = server.LiveSession("127.0.0.1", 0, None)
    results = []
    with build(sc, live_faults=True) as scene:
        url = live.start(sc, out)
        try:
            assert stat.S_IMODE(os.stat(out / "view_url.json").st_mode) == 0o600
            runner = threading.Thread(target=lambda: results.append(
                loop.run(scene, out, speed=20.0, observer=live.observer)), daemon=True)
            runner.start()
            blind = {"action": "inject", "fault": {"device": "fss", "type": "bias_step", "bias_rad": [0.05, 0.0]}}
            assert _http(url + "api/faults", blind) == (200, {"action": "inject", "name": "fss_bias_step"})
            status, body = _http(url + "api/faults", {"action": "inject", "fault": {"device": "st1",
                                                                                     "type": "wheel_seized"}})
            assert status == 400 and body["error"].startswith("faults[1].type = 'wheel_seized' in live is not "
                                                              "allowed: a fault type device 'st1'"), body
            assert main(["fault", str(out), "clear", "fss_bias_step"]) == 0
            assert capsys.readouterr().out == "cleared fss_bias_step\n"
            for _ in range(200):  # the clearing is logged at the next tick
                if "fault_cleared" in (out / "events.jsonl").read_text():
                    break
                threading.Event().wait(0.05)
            assert main(["fault", str(out), "list"]) == 0
            listed = capsys.readouterr().out.splitlines()
            assert listed[0].startswith("fss_bias_step: bias_step on fss from t = ")
            assert ", cleared at t = " in listed[0]
            assert _http(url + "api/control", {"command": "stop"})[0] == 200
            runner.join(timeout=60.0)
            assert not runner.is_alive()
        finally:
            live.close(results[0].status if results else "aborted")
    assert results[0].status == "stopped"
    events = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]
    faults = [(e["kind"], e["fault"]) for e in events if e["kind"].startswith("fault_")]
    assert faults == [("fault_injected", "fss_bias_step"), ("fault_cleared", "fss_bias_step")]
    assert not (out / "view_url.json").exists()


def test_a_page_opening_mid_run_takes_no_event_from_the_pages_already_open(run_dir, tmp_path):
    """A snapshot (``/api/samples`` of a page that opens) must not take events from the log before the next push:
    the open pages would never get them (a fault injected then would be missing from their timeline)."""
    import shutil

    import numpy as np

    from stand.telemetry import load

    out = tmp_path / "run"
    shutil.copytree(run_dir, out)
    (out / "events.jsonl").write_text(json.dumps({"kind": "start", "message": "", "t_s": 0.0}) + "\n")
    tel = load(out)
    schema = json.loads((out / "telemetry" / "schema.json").read_text())["columns"]
    flat = np.column_stack([np.asarray(tel[c["name"]]).reshape(len(tel["t_s"]), -1) for c in schema])
    source = state.LiveSource(out, state.load_meta(out))
    pushed = []
    source.listeners.append(pushed.append)
    source.ingest(flat[:10])
    with open(out / "events.jsonl", "a") as f:
        f.write(json.dumps({"kind": "fault_injected", "message": "", "fault": "imu_bias_step", "t_s": 1.0}) + "\n")
    samples, events = source.snapshot()  # a second page opens
    assert [e["kind"] for e in events] == ["start"] and len(samples["t_s"]) == 10
    source.ingest(flat[10:20])
    assert [[e["kind"] for e in m.get("events", [])] for m in pushed] == [["start"], ["fault_injected"]]
    assert [e["kind"] for e in source.snapshot()[1]] == ["start", "fault_injected"]
    with open(out / "events.jsonl", "a") as f:
        f.write(json.dumps({"kind": "end", "message": "completed"}) + "\n")
    source.finished("completed")
    assert pushed[-1]["events"] == [{"kind": "end", "message": "completed"}]


def test_a_page_whose_address_cannot_be_written_does_not_start(tmp_path):
    """view_url.json cannot be written (here a folder holds its name): one sentence, the server process ended."""
    from stand.scenario import load as load_scenario

    sc = load_scenario(write_scenario(tmp_path / "s.toml", duration_s=5.0))
    out = tmp_path / "out"
    (out / "view_url.json" / "x").mkdir(parents=True)
    live = server.LiveSession("127.0.0.1", 0, None)
    with pytest.raises(server.ViewError, match=r"the live page's address cannot be written into .*view_url.json "
                       r"for `stand fault`: "):
        live.start(sc, out)
    assert not live.process.is_alive()
    assert sorted(p.name for p in out.iterdir()) == ["view.json", "view_url.json"]  # no temporary file left


def test_a_scenarios_own_faults_are_listed_with_what_happened(tmp_path, capsys):
    """A replay of a run with [[faults]]: GET /api/faults gives the scenario's faults and, from the events the real
    schedule logged, when each started and ended."""
    path = tmp_path / "s.toml"
    write_scenario(path, duration_s=5.0)
    path.write_text(path.read_text() + '\n[[faults]]\ndevice = "fss"\ntype = "bias_step"\nbias_rad = [0.05, 0.0]\n'
                    'at_s = 2.0\nduration_s = 1.0\n')
    out = tmp_path / "run"
    assert main(["run", str(path), "--out", str(out), "--no-progress", "--no-plots"]) == 0
    with server.ViewServer(server.ReplaySource(out)) as view:
        status, body = _http(view.url + "api/faults", headers={})
    assert status == 200 and body["live"] is False
    assert body["scheduled"] == [{"name": "fss_bias_step", "type": "bias_step", "device": "fss",
                                  "when": "fss_bias_step: bias_step on fss, at 2 s for 1 s"}]
    assert body["faults"] == [{"name": "fss_bias_step", "type": "bias_step", "device": "fss",
                               "params": {"bias_rad": [0.05, 0.0]}, "injected_s": 2.0, "cleared_s": 3.0,
                               "active": False}]
