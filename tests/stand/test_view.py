"""The operator page's data, server and exports (no browser here; tests/stand/test_view_browser.py drives one)."""

from __future__ import annotations

import json
import math
import time
import urllib.error
import urllib.request

import numpy as np
import pytest

from sim.ephemeris import moon_position_gcrs, sun_position_gcrs
from sim.frames import dcm_itrs_gcrs
from sim.rotations import dcm
from sim.time import Epoch
from stand.cli import main
from stand.telemetry import load
from stand.view import export, server, state

from .view_scenario import write as write_scenario

ARCSEC = math.pi / 180 / 3600


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A 60 s run of the sun-sweep scenario (tracker valid, then the Sun in its field)."""
    base = tmp_path_factory.mktemp("view")
    out = base / "run"
    assert main(["run", write_scenario(base / "sweep.toml"), "--out", str(out), "--no-progress"]) == 0
    return out


def test_view_json_names_every_field_of_view(run_dir):
    meta = json.loads((run_dir / "view.json").read_text())
    devs = {d["name"]: d for d in meta["devices"]}
    assert devs["st1"]["fovs"][0]["shape"] == "rect" and devs["st1"]["fovs"][0]["fov_deg"] == [20.0, 15.0]
    assert devs["st1"]["exclusion_deg"] == {"sun": 40.0, "moon": 20.0, "earth": 20.0}
    assert devs["fss"]["fovs"][0] == {"shape": "cone", "axis_S": [0.0, 0.0, 1.0], "half_deg": 60.0, "label": "fss"}
    assert devs["mtq"]["fovs"] == []
    assert meta["earth_rotation"]["model"] == "iau2006"


def test_derived_sky_matches_direct_ephemerides(run_dir):
    meta = state.load_meta(run_dir)
    s = state.replay_samples(run_dir, meta)
    epoch = Epoch.from_iso(meta["epoch"])
    for i in (0, len(s["t_s"]) // 2, len(s["t_s"]) - 1):
        ep = epoch + float(s["t_s"][i])
        r = s["r_BN_N"][i]
        for body, fn in (("sun", sun_position_gcrs), ("moon", moon_position_gcrs)):
            d = fn(ep) - r
            err = math.acos(min(1.0, float(s[f"{body}_N"][i] @ (d / np.linalg.norm(d)))))
            assert err < 1.0 * ARCSEC, (body, err / ARCSEC)
        r_E = dcm_itrs_gcrs(ep) @ r
        assert s["lat_deg"][i] == pytest.approx(math.degrees(math.asin(r_E[2] / np.linalg.norm(r_E))), abs=1e-6)
        assert s["lon_deg"][i] == pytest.approx(math.degrees(math.atan2(r_E[1], r_E[0])), abs=1e-3)
        assert np.allclose(dcm(s["q_EN"][i]), dcm_itrs_gcrs(ep), atol=1e-8)
    assert np.all(s["sun_fraction"] == 1.0)  # sunlit over the first minute of this orbit


def test_decimation_keeps_the_ends_and_the_limit():
    t = np.arange(0.0, 5677.0, 0.1)
    idx = state.decimate(t, 1000)
    assert idx[0] == 0 and idx[-1] == len(t) - 1 and len(idx) <= 1001
    assert np.max(np.diff(t[idx])) < 2 * (t[-1] / 999)
    assert np.array_equal(state.decimate(t[:10], 1000), np.arange(10))


@pytest.mark.parametrize("kind", state.PROJECTIONS)
def test_projection_places_the_axes(kind):
    W, H = 1200, 600
    p = state.project(np.array([[1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0], [0, 0, 1.0]]), kind, W, H)
    assert p[0] == pytest.approx([600, 300])
    assert p[1][0] < 600 < p[2][0]  # seen from inside: +y on the left
    assert p[1][1] == pytest.approx(300) and p[2][1] == pytest.approx(300)
    assert p[3][1] == pytest.approx(0.0, abs=1e-9)  # +z at the top
    if kind == "equirectangular":
        assert p[1][0] == pytest.approx(300)
    else:  # Hammer-Aitoff of (90 deg, 0): x = 2 sqrt2 sin 45 / sqrt(1 + cos 45) of 2 sqrt2 at the edge
        hx = 2 * math.sqrt(2) * math.sin(math.pi / 4) / math.sqrt(1 + math.cos(math.pi / 4))
        assert p[1][0] == pytest.approx(600 - hx / (2 * math.sqrt(2)) * 600)


@pytest.mark.parametrize("kind", state.PROJECTIONS)
def test_inverse_projection_round_trips(kind):
    rng = np.random.default_rng(1)
    u = rng.normal(size=(500, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    p = state.project(u, kind, 1200, 600)
    back, ok = export.inverse(kind, p[:, 0], p[:, 1], 1200, 600)
    assert ok.all()
    assert np.max(np.linalg.norm(back - u, axis=1)) < 1e-9


def test_live_feed_decimates_and_the_source_controls(run_dir):
    meta = state.load_meta(run_dir)
    tel = load(run_dir)
    schema = json.loads((run_dir / "telemetry" / "schema.json").read_text())["columns"]
    flat = np.column_stack([np.asarray(tel[c["name"]]).reshape(len(tel["t_s"]), -1) for c in schema])
    assert flat.shape[1] == sum(c["width"] for c in schema)
    source = state.LiveSource(run_dir, meta)
    feed = state.LiveFeed(state.LocalLink(source), {**meta, "duration_s": 60.0}, max_samples=120)  # 0.5 s apart
    got = []
    source.listeners.append(got.append)
    for row in flat[:150]:
        feed.record(row[0], tuple(row))
    feed.push()
    for row in flat[150:301]:
        feed.record(row[0], tuple(row))
    feed.push()
    assert len(feed.rows) == 0 and feed.rows_taken == 301  # sent rows are let go (a run's rows are not kept)
    samples, events = source.snapshot()
    assert samples["t_s"][0] == 0.0 and samples["t_s"][-1] == pytest.approx(30.0)
    # every 0.5 s, plus the newest row of the first push (14.9 s) shown at once
    assert np.allclose(samples["t_s"], np.sort(np.append(np.arange(0.0, 30.01, 0.5), 14.9)))
    assert got[-1]["type"] == "samples" and got[-1]["samples"]["t_s"]["shape"] == [31, 1]
    assert events[0]["kind"] == "start"
    assert feed.poll_control() is None
    assert source.request("pause") == "paused"
    feed.push()
    assert feed.poll_control() == "pause"
    assert source.request("resume") == "running"
    feed.push()
    assert feed.poll_control() is None
    assert source.request("stop") == "stopping"
    feed.push()
    assert feed.poll_control() == "stop"
    assert source.request("resume") == "stopping"  # a stop is not taken back
    with pytest.raises(ValueError, match="not one of pause, resume, stop"):
        source.request("reboot")


class _Stopper:
    """An observer that pauses at the second poll, resumes at the fourth and stops at the sixth."""

    def __init__(self):
        self.rows = 0
        self.polls = 0

    def record(self, t_s, row):
        self.rows += 1

    def poll_control(self):
        self.polls += 1
        return {2: "pause", 3: "pause", 4: None, 6: "stop"}.get(self.polls)


def test_loop_observer_sees_rows_and_obeys_pause_and_stop(tmp_path):
    from stand.compose import build
    from stand.loop import run
    from stand.scenario import load as load_scenario

    sc = load_scenario(write_scenario(tmp_path / "s.toml"))
    now = [0.0]

    def clock():  # every call moves the wall clock by 0.1 s: the observer is polled every few ticks
        now[0] += 0.1
        return now[0]

    obs = _Stopper()
    with build(sc) as scene:
        result = run(scene, tmp_path / "out", clock=clock, sleep=lambda s: None, observer=obs)
    assert result.status == "stopped" and "operator page" in result.error
    assert obs.polls == 6
    assert obs.rows == len(load(tmp_path / "out")["t_s"])
    kinds = [json.loads(line)["kind"] for line in (tmp_path / "out" / "events.jsonl").read_text().splitlines()]
    assert kinds.index("paused") < kinds.index("resumed") < kinds.index("stopped")


def _get(url, data=None, headers=None):
    req = urllib.request.Request(url, data=data, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=10) as resp:
            return resp.status, resp.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


def test_replay_server_serves_the_page_and_its_data(run_dir):
    with server.ViewServer(server.ReplaySource(run_dir)) as view:
        status, body = _get(view.url)
        assert status == 200 and b"view.js" in body
        assert _get(view.url + "assets/view.js")[0] == 200
        assert _get(view.url + "assets/land-110m.json")[0] == 200
        meta = json.loads(_get(view.url + "api/meta")[1])
        assert meta["mode"] == "replay" and meta["scenario"] == "view_sun_sweep"
        data = json.loads(_get(view.url + "api/samples")[1])
        t = np.frombuffer(__import__("base64").b64decode(data["samples"]["t_s"]["data"]), "<f8")
        assert t[0] == 0.0 and t[-1] == 60.0 and len(t) == 601
        assert [e["kind"] for e in data["events"]][0] == "start"
        stars = json.loads(_get(view.url + "api/stars?mag=4")[1])
        assert 400 < stars["count"] < 1000 and stars["stars"]["shape"] == [stars["count"], 3]
        ctl = _get(view.url + "api/control", b'{"command": "stop"}', {"Content-Type": "application/json"})
        assert ctl[0] == 409  # nothing to control in a replay


def test_live_control_from_the_bound_host_only_or_with_the_token(run_dir):
    meta = state.load_meta(run_dir)
    js = {"Content-Type": "application/json"}
    feed = state.LiveSource(run_dir, meta)
    with server.ViewServer(feed) as view:
        assert _get(view.url + "api/control", b'{"command": "pause"}', js) == (200, b'{"status": "paused"}')
        evil = _get(view.url + "api/control", b'{"command": "stop"}', {**js, "Origin": "http://example.org"})
        assert evil[0] == 403 and b"Origin" in evil[1]
        assert _get(view.url + "api/control", b'{"command": "stop"}', {"Content-Type": "text/plain"})[0] == 403
    with pytest.raises(server.ViewError, match="without a token"):
        server.ViewServer(state.LiveSource(run_dir, meta), host="127.0.0.2")
    commands = []
    feed = state.LiveSource(run_dir, meta, control=commands.append)
    with server.ViewServer(feed, host="127.0.0.2", token="s3cret") as view:
        assert view.url.startswith("http://127.0.0.2:")
        assert _get(view.url + "api/control", b'{"command": "pause"}', js)[0] == 403
        assert _get(view.url + "api/control", b'{"command": "pause"}', {**js, "X-Stand-Token": "wrong"})[0] == 403
        assert _get(view.url + "api/control", b'{"command": "pause"}', {**js, "X-Stand-Token": "s3cret"})[0] == 200
        assert commands == ["pause"]


def test_run_view_elsewhere_needs_a_token(tmp_path, capsys):
    code = main(["run", "--view", "127.0.0.2:0", "--out", str(tmp_path / "o"), "--duration", "1"])
    assert code == 2 and "without a token" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    assert main(["run", "--view", "127.0.0.1:99999", "--out", str(tmp_path / "o"), "--duration", "1"]) == 2
    assert "0 (any free) to 65535" in capsys.readouterr().err


def test_export_draws_the_sun_where_the_truth_puts_it(run_dir, tmp_path):
    meta = state.load_meta(run_dir)
    s = state.replay_samples(run_dir, meta)
    i = 250
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(12, 6), dpi=100)
    ax = fig.add_axes((0, 0, 1, 1))
    where = export.draw_panorama(ax, s, meta, i)
    plt.close(fig)
    ep = Epoch.from_iso(meta["epoch"]) + float(s["t_s"][i])
    sun_B = dcm(s["q_BN"][i]) @ (sun_position_gcrs(ep) - s["r_BN_N"][i])
    assert np.allclose(where["sun"], state.project(sun_B, "equirectangular", 1200, 600), atol=0.05)
    paths = export.export(run_dir, tmp_path / "png", (10.0, 45.0), frame="gcrs", kind="hammer")
    assert [p.name for p in paths] == ["panorama_10s.png", "panorama_45s.png"]
    img = plt.imread(paths[0])
    assert img.shape[:2] == (780, 1200) and img[..., :3].std() > 0.05  # drawn, not blank
    with pytest.raises(ValueError, match="--times 99 is not allowed"):
        export.export(run_dir, tmp_path / "png", (99.0,))


def test_report_includes_the_panorama(run_dir):
    assert (run_dir / "panorama.png").is_file()
    assert "![panorama.png](panorama.png)" in (run_dir / "report.md").read_text()


def test_view_command_exports_and_refuses_bad_input(run_dir, tmp_path, capsys):
    assert main(["view", str(run_dir), "--export", str(tmp_path / "x"), "--times", "0,30"]) == 0
    assert sorted(p.name for p in (tmp_path / "x").iterdir()) == ["panorama_0s.png", "panorama_30s.png"]
    assert main(["view", str(run_dir), "--export", str(tmp_path / "x"), "--frame", "moon"]) == 2
    assert "--frame 'moon' is not allowed" in capsys.readouterr().err
    assert main(["view", str(tmp_path / "nothing")]) == 2
    assert "is not a run folder" in capsys.readouterr().err


def test_a_run_folder_without_view_json_is_described_from_its_scenario(tmp_path):
    out = tmp_path / "run"
    # not detumbled in 2 s
    assert main(["run", "--out", str(out), "--duration", "2", "--no-progress", "--no-plots"]) == 1
    written = json.loads((out / "view.json").read_text())
    (out / "view.json").unlink()
    assert state.load_meta(out) == written  # the summary names the shipped scenario
    summary = json.loads((out / "summary.json").read_text())
    (out / "summary.json").write_text(json.dumps({**summary, "source": str(tmp_path / "gone.toml")}))
    with pytest.raises(FileNotFoundError, match="neither a file on this machine nor a shipped scenario"):
        state.load_meta(out)


def test_run_view_on_a_busy_port_says_so_and_leaves_nothing(tmp_path, capsys):
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code = main(["run", "--view", f"127.0.0.1:{port}", "--out", str(tmp_path / "o"), "--duration", "1"])
    assert code == 2
    err = capsys.readouterr().err
    assert f"cannot listen on 127.0.0.1:{port}" in err
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------------------------------- issue 22, items 5, 13

def _strict(body):
    """json.loads that refuses NaN and infinities, as a browser's JSON.parse does."""
    def refuse(name):
        raise ValueError(f"{name} is not JSON")
    return json.loads(body, parse_constant=refuse)


def _nan_run(run_dir, tmp_path):
    """A copy of the sweep run whose summary has a criterion a tracker that never solved could not score (NaN, as
    the stand writes it) and whose event log has a NaN time and an infinite field."""
    import shutil

    out = tmp_path / "nan_run"
    shutil.copytree(run_dir, out)
    summary = json.loads((out / "summary.json").read_text())
    summary["criteria"].append({"name": "tracker roll error p95", "metric": "tracker_roll_err_p95", "value": math.nan,
                                "unit": "arcsec", "limit": {"max": 30.0}, "pass": False,
                                "reason": "the tracker gave no valid solution"})
    (out / "summary.json").write_text(json.dumps(summary))
    with open(out / "events.jsonl", "a") as f:
        f.write(json.dumps({"kind": "odd", "message": "a NaN time", "t_s": math.nan, "x": math.inf}) + "\n")
    assert "NaN" in (out / "summary.json").read_text() and "Infinity" in (out / "events.jsonl").read_text()
    return out


def test_every_endpoint_sends_strict_json(run_dir, tmp_path):
    out = _nan_run(run_dir, tmp_path)
    with server.ViewServer(server.ReplaySource(out)) as view:
        bodies = {path: _get(view.url + path) for path in ("api/meta", "api/samples", "api/events", "api/stars?mag=3",
                                                            "api/stars?mag=nan")}
        bodies["api/control"] = _get(view.url + "api/control", b'{"command": "stop"}',
                                     {"Content-Type": "application/json"})
        expected = {"api/meta": 200, "api/samples": 200, "api/events": 200, "api/stars?mag=3": 200,
                    "api/stars?mag=nan": 400, "api/control": 409}
        for path, (status, body) in bodies.items():
            assert status == expected[path], path
            _strict(body)  # raises on NaN / Infinity
        meta = _strict(bodies["api/meta"][1])
        roll = meta["summary"]["criteria"][-1]
        assert roll["value"] is None and roll["reason"] == "the tracker gave no valid solution"
        odd = _strict(bodies["api/events"][1])[-1]
        assert odd["kind"] == "odd" and odd["t_s"] is None and odd["x"] is None
        assert _strict(bodies["api/samples"][1])["events"][-1]["t_s"] is None


def test_live_pushes_are_strict_json(run_dir, tmp_path):
    """The websocket's messages (samples with events) are strict JSON too."""
    import asyncio

    import aiohttp

    out = _nan_run(run_dir, tmp_path)
    meta = state.load_meta(out)
    tel = load(out)
    schema = json.loads((out / "telemetry" / "schema.json").read_text())["columns"]
    flat = np.column_stack([np.asarray(tel[c["name"]]).reshape(len(tel["t_s"]), -1) for c in schema])
    flat[5:, 1:] = np.nan  # every column but time
    source = state.LiveSource(out, meta)

    async def listen(url):
        got = []
        async with aiohttp.ClientSession() as session, session.ws_connect(url + "ws") as ws:
            got.append(_strict((await ws.receive(timeout=10)).data))
            source.ingest(flat[:10])
            got.append(_strict((await ws.receive(timeout=10)).data))
        return got

    with server.ViewServer(source) as view:
        status, samples = asyncio.run(listen(view.url))
        for _ in range(200):  # the server counts the page out when its handler ends, just after the close handshake
            if source.pages == 0:
                break
            time.sleep(0.05)
        assert source.pages == 0  # the page closed
    assert status == {"type": "status", "status": "running"}
    assert samples["type"] == "samples" and samples["samples"]["t_s"]["shape"] == [10, 1]
    assert samples["events"][-1]["t_s"] is None


def _raw(port, path, headers, body=None, host_header=True):
    """A request with exactly these headers (Host too: what a DNS-rebinding page's browser sends)."""
    import http.client

    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.putrequest("POST" if body is not None else "GET", path, skip_host=True, skip_accept_encoding=True)
        for k, v in headers.items():
            conn.putheader(k, v)
        if body is not None:
            conn.putheader("Content-Length", str(len(body)))
        conn.endheaders(body)
        resp = conn.getresponse()
        return resp.status, resp.read()
    finally:
        conn.close()


def test_control_refuses_a_host_the_server_does_not_listen_on(run_dir):
    """DNS rebinding: evil.example re-pointed at 127.0.0.1 makes the browser send Host and Origin of evil.example."""
    commands = []
    source = state.LiveSource(run_dir, state.load_meta(run_dir), control=commands.append)
    js = {"Content-Type": "application/json"}
    pause = b'{"command": "pause"}'
    with server.ViewServer(source) as view:
        port = view.port
        for host in (f"evil.example:{port}", f"127.0.0.1.evil.example:{port}", f"127.0.0.1:{port + 1}",
                     "127.0.0.1", f"localhost.:{port}"):
            status, body = _raw(port, "/api/control", {**js, "Host": host, "Origin": f"http://{host}"}, pause)
            assert status == 403 and b"is not an address this view listens on" in body, (host, body)
            assert _raw(port, "/api/meta", {"Host": host})[0] == 403  # nor can such a page read the run
        # the right Host with another site's Origin, or no Host at all
        assert _raw(port, "/api/control", {**js, "Host": f"127.0.0.1:{port}", "Origin": f"http://evil.example:{port}"},
                    pause)[0] == 403
        assert _no_host(port, pause).startswith(b"HTTP/1.0 403")  # (HTTP/1.1 without Host aiohttp refuses itself)
        assert commands == [] and source.status == "running"
        # the page itself, by address or by name
        for host in (f"127.0.0.1:{port}", f"localhost:{port}", f"LocalHost:{port}"):
            status, body = _raw(port, "/api/control", {**js, "Host": host, "Origin": f"http://{host.lower()}"},
                                b'{"command": "pause"}' if source.status == "running" else b'{"command": "resume"}')
            assert status == 200, (host, body)
            assert _raw(port, "/api/meta", {"Host": host})[0] == 200
        assert commands == ["pause", None, "pause"]
    commands.clear()
    source = state.LiveSource(run_dir, state.load_meta(run_dir), control=commands.append)
    with server.ViewServer(source, host="127.0.0.2", token="s3cret") as view:
        port, tok = view.port, {**js, "X-Stand-Token": "s3cret"}
        assert _raw_to("127.0.0.2", port, {**tok, "Host": f"evil.example:{port}",
                                           "Origin": f"http://evil.example:{port}"}, pause)[0] == 403
        assert _raw_to("127.0.0.2", port, {**tok, "Host": f"127.0.0.2:{port}", "Origin": f"http://127.0.0.2:{port}"},
                       pause)[0] == 200
        assert commands == ["pause"]


def _no_host(port, body):
    """An HTTP/1.0 control request without a Host header; the raw answer."""
    import socket

    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(b"POST /api/control HTTP/1.0\r\nContent-Type: application/json\r\n"
                  b"Content-Length: %d\r\n\r\n%s" % (len(body), body))
        answer = b""
        for _ in range(100):  # bounded: the server closes an HTTP/1.0 connection after its answer
            chunk = s.recv(65536)
            if not chunk:
                break
            answer += chunk
    return answer


def _raw_to(address, port, headers, body):
    import http.client

    conn = http.client.HTTPConnection(address, port, timeout=10)
    try:
        conn.request("POST", "/api/control", body=body, headers=headers)
        resp = conn.getresponse()
        return resp.status, resp.read()
    finally:
        conn.close()


def test_star_magnitude_is_checked_and_the_cache_bounded(run_dir):
    with server.ViewServer(server.ReplaySource(run_dir)) as view:
        for bad in ("nan", "inf", "-inf", "9.5", "-3", "abc", "1e308"):
            status, body = _get(view.url + f"api/stars?mag={bad}")
            assert status == 400, bad
            assert _strict(body)["error"] == f"mag {bad!r} is not allowed: an Hp magnitude limit from -2 to 9."
        counts = []
        for mag in (1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 1.04):
            status, body = _get(view.url + f"api/stars?mag={mag}")
            assert status == 200
            counts.append(_strict(body)["count"])
            assert len(view._stars) <= server.STAR_CACHE_TABLES
        assert counts == sorted(counts[:-1]) + [counts[0]]  # fainter limits, more stars; 1.04 is served as 1.0
        assert list(view._stars) == [2.5, 3.0, 3.5, 4.0][-(server.STAR_CACHE_TABLES - 1):] + [1.0]


def test_live_feed_and_history_are_bounded(run_dir):
    meta = state.load_meta(run_dir)

    class Nowhere:  # a server that never takes anything (gone, or too slow)
        def send(self, message):
            raise AssertionError("not sent in this test")

        def receive(self):
            return []

    feed = state.LiveFeed(Nowhere(), meta, max_pending=1000)
    for k in range(5000):
        feed.record(k / 10, (k / 10, float(k)))
    assert len(feed.rows) == 1000 and feed.rows[-1] == (499.9, 4999.0) and feed.rows[0] == (400.0, 4000.0)
    # the server's history: at most max_samples, the newest recent_samples exactly as they came
    tel = load(run_dir)
    schema = json.loads((run_dir / "telemetry" / "schema.json").read_text())["columns"]
    flat = np.column_stack([np.asarray(tel[c["name"]]).reshape(len(tel["t_s"]), -1) for c in schema])
    source = state.LiveSource(run_dir, meta, max_samples=200, recent_samples=80)
    got = []
    source.listeners.append(got.append)
    for k in range(0, len(flat), 20):
        source.ingest(flat[k:k + 20])
        assert len(source.snapshot()[0]["t_s"]) <= 200
    samples = source.snapshot()[0]
    assert np.array_equal(samples["t_s"][-80:], flat[-80:, 0])
    assert samples["t_s"][0] == 0.0 and np.all(np.diff(samples["t_s"]) > 0)
    assert sum(m["samples"]["t_s"]["shape"][0] for m in got) == len(flat)  # the open pages got every row pushed


def _paused_feed(tmp_path, link, clock, **kw):
    meta = {"duration_s": 60.0, "record_rate_hz": 10.0}
    events = tmp_path / "events.jsonl"
    feed = state.LiveFeed(link, meta, events_path=events, clock=clock, **kw)
    return feed, events


def test_a_pause_with_no_page_open_is_released_after_its_limit(run_dir, tmp_path):
    now = [100.0]
    source = state.LiveSource(run_dir, state.load_meta(run_dir))
    feed, events = _paused_feed(tmp_path, state.LocalLink(source), lambda: now[0], unattended_pause_s=600.0)
    source.pages = 1
    source.request("pause")
    feed.push()
    assert feed.poll_control() == "pause"
    source.pages = 0  # the operator closed the page
    now[0] += 300.0
    feed.push()
    assert feed.poll_control() == "pause"
    now[0] += 299.0
    feed.push()
    assert feed.poll_control() == "pause"  # 599 s with no page since the last one was seen
    now[0] += 2.0
    feed.push()
    assert feed.poll_control() is None
    feed.push()  # tells the server
    assert source.status == "running"
    logged = [json.loads(line) for line in events.read_text().splitlines()]
    assert [e["kind"] for e in logged] == ["pause_unattended"]
    assert "no operator page open for 601 s (limit 600 s); the run resumes" in logged[0]["message"]


def test_a_pause_is_released_when_the_server_falls_silent(tmp_path):
    now = [0.0]

    class Once:  # a server that sends "pause" and is never heard from again
        def __init__(self):
            self.sent = ["pause"]

        def send(self, message):
            pass

        def receive(self):
            out, self.sent = self.sent, []
            return out

    feed, events = _paused_feed(tmp_path, Once(), lambda: now[0], server_silent_s=15.0)
    feed.push()
    now[0] += 14.0
    assert feed.poll_control() == "pause"
    now[0] += 2.0
    assert feed.poll_control() is None
    assert "has not answered for 16 s (limit 15 s); the run paused from it resumes" in events.read_text()


def test_a_run_paused_from_the_page_resumes_when_the_page_server_dies(tmp_path):
    """``stand run --view``'s two processes: pause from the page, kill the page's server; the run must end."""
    import threading

    from stand.compose import build
    from stand.loop import run
    from stand.scenario import load as load_scenario

    sc = load_scenario(write_scenario(tmp_path / "s.toml", duration_s=20.0))
    out = tmp_path / "out"
    out.mkdir()
    live = server.LiveSession("127.0.0.1", 0, None)
    results = []
    with build(sc) as scene:
        url = live.start(sc, out)
        try:
            status, body = _get(url + "api/control", b'{"command": "pause"}', {"Content-Type": "application/json"})
            assert (status, body) == (200, b'{"status": "paused"}')
            for _ in range(200):  # the feed hears it within a tenth of a second
                if live.feed.poll_control() == "pause":
                    break
                threading.Event().wait(0.05)
            assert live.feed.poll_control() == "pause"
            runner = threading.Thread(target=lambda: results.append(run(scene, out, observer=live.observer)),
                                      daemon=True)  # a run that hangs must not keep pytest from ending
            runner.start()
            for _ in range(200):
                if (out / "events.jsonl").is_file() and '"paused"' in (out / "events.jsonl").read_text():
                    break
                threading.Event().wait(0.05)
            live.process.kill()
            runner.join(timeout=60.0)
            assert not runner.is_alive(), "the run stayed paused after its page's server died"
        finally:
            live.close("completed")
    assert results[0].status == "completed"
    kinds = [json.loads(line)["kind"] for line in (out / "events.jsonl").read_text().splitlines()]
    assert kinds.index("paused") < kinds.index("view_lost") < kinds.index("resumed") < kinds.index("end")
    assert len(load(out)["t_s"]) == 201


@pytest.mark.parametrize("text, why", [
    ("{not json", "is not valid JSON (Expecting property name enclosed in double quotes at line 1, column 2)"),
    ("[1, 2]", "it holds a JSON list, not an object"),
    ('{"duration_s": 60}', "its epoch None is not an ISO 8601 UTC time"),
    ('{"epoch": "2026-03-20T12:00:00Z", "duration_s": NaN, "devices": []}', "its duration_s nan is not a positive"),
    ('{"epoch": "2026-03-20T12:00:00Z", "duration_s": 60, "devices": [{"name": "st1"}]}',
     "its device 1 ('st1') lacks a name, a kind, a q_SB of 4 numbers"),
    ('{"epoch": "2026-03-20T12:00:00Z", "duration_s": 60, "devices": [], "earth_rotation": {"model": "flat"}}',
     "its earth_rotation"),
])
def test_view_of_a_corrupt_view_json_says_which_file_and_what(run_dir, tmp_path, capsys, monkeypatch, text, why):
    import shutil
    import threading

    class Interrupted(threading.Event):  # a view that does serve is stopped at once, as by Ctrl-C
        def wait(self, timeout=None):
            raise KeyboardInterrupt

    monkeypatch.setattr("stand.commands.view.threading.Event", Interrupted)
    out = tmp_path / "run"
    shutil.copytree(run_dir, out)
    (out / "view.json").write_text(text)
    assert main(["view", str(out), "--bind", "127.0.0.1:0"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"stand: error: {out / 'view.json'} ") and why in err and err.count("\n") == 1, err
    assert main(["view", str(out), "--export", str(tmp_path / "png")]) == 2
    assert why in capsys.readouterr().err
