"""The operator page in headless Chromium (Debian's chromium and chromium-driver, driven by selenium).

Skipped when Chromium or its driver is not installed (``.ci/run`` installs both). What is checked is what the
page draws: pixels of its canvas against the projection of the truth computed here, independently of the page.
"""

from __future__ import annotations

import base64
import contextlib
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from sim.ephemeris import sun_position_gcrs
from sim.rotations import dcm
from sim.time import Epoch
from stand.cli import main
from stand.view import server, state
from tests.oracles import require, unavailable

from .view_scenario import write as write_scenario

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver") or ("/usr/bin/chromedriver" if os.path.exists("/usr/bin/chromedriver") else None)
webdriver = require("selenium.webdriver")
if not (CHROMIUM and DRIVER):
    unavailable("Chromium and chromium-driver are not installed (apt-get install chromium chromium-driver, as .ci/run "
                "does)")

SUN_RGB = (255, 200, 0)
VALID_RGB = (60, 220, 90)
SUN_FLAG_RGB = (255, 60, 60)
W, H = 1200, 600  # the panorama canvas
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def browser():
    from selenium.webdriver.chrome.service import Service

    profile = tempfile.mkdtemp(prefix="stand-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={profile}",
                 "--window-size=1600,1400"):
        opts.add_argument(flag)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(DRIVER), options=opts)
    driver.set_page_load_timeout(30)
    driver.set_script_timeout(30)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    base = tmp_path_factory.mktemp("viewb")
    out = base / "run"
    assert main(["run", write_scenario(base / "sweep.toml"), "--out", str(out), "--no-progress", "--no-plots"]) == 0
    return out


@pytest.fixture(scope="module")
def replay(run_dir):
    with server.ViewServer(server.ReplaySource(run_dir)) as view:
        yield view


def _open(driver, url):
    driver.get(url)
    _wait(driver, "return !!(window.standView && (window.standView.loaded || window.standView.loadError))")
    assert driver.execute_script("return window.standView.loadError || null") is None


def _wait(driver, script, *args, timeout_s=20.0):
    """Run ``script`` (with ``args``) until it returns something true, and return that: what is waited for and what
    is read of it come from one call, as a live page may change between two."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = driver.execute_script(script, *args)
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for: {script}")


def _seek(driver, t_s):
    """Move to time t_s and wait for the page to draw it; returns the sample time shown."""
    n = driver.execute_script("return window.standView.stats.draws")
    driver.execute_script(f"window.standView.seek({t_s})")
    _wait(driver, f"return window.standView.stats.draws > {n}")
    return driver.execute_script("return window.standView.t")


def _canvas(driver, cid="pano") -> np.ndarray:
    url = driver.execute_script(f"return document.getElementById('{cid}').toDataURL('image/png')")
    import cv2

    png = np.frombuffer(base64.b64decode(url.split(",", 1)[1]), np.uint8)
    bgr = cv2.imdecode(png, cv2.IMREAD_COLOR)
    return bgr[..., ::-1]


def _blob(img, rgb, tol=6):
    """Centre of the largest patch of exactly this colour (the Sun's disk, not its label's glyphs)."""
    import cv2

    mask = (np.abs(img.astype(int) - rgb).max(axis=-1) <= tol).astype(np.uint8)
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(mask)
    assert n > 1, f"no pixel of colour {rgb} on the canvas"
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    return centroids[k], stats[k, cv2.CC_STAT_AREA]


def _severe(driver):
    return [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]


def test_page_loads_without_console_errors(browser, replay):
    _open(browser, replay.url)
    assert _severe(browser) == []
    assert browser.execute_script("return window.standView.store.n") == 601
    assert browser.execute_script("return window.standView.stars.count") > 40000
    assert browser.find_element("id", "scenario").text == "view_sun_sweep"


def _truth(run_dir, t_s):
    from stand.telemetry import load

    tel = load(run_dir)
    i = int(np.argmin(np.abs(tel["t_s"] - t_s)))
    assert abs(tel["t_s"][i] - t_s) < 1e-6
    return {k: np.asarray(v)[i] for k, v in tel.items()}


@pytest.mark.parametrize("t_s, projection", [(12.0, "equirectangular"), (47.3, "hammer")])
def test_panorama_draws_the_sun_where_the_truth_puts_it(browser, replay, run_dir, t_s, projection):
    _open(browser, replay.url)
    browser.execute_script(f"document.getElementById('pano-proj').value = '{projection}'")
    t = _seek(browser, t_s)
    row = _truth(run_dir, t)
    meta = state.load_meta(run_dir)
    # The Sun from ERFA directly (not the page's interpolated track), in body axes by the recorded attitude.
    sun_B = dcm(row["q_BN"]) @ (sun_position_gcrs(Epoch.from_iso(meta["epoch"]) + float(t)) - row["r_BN_N"])
    expected = state.project(sun_B, projection, W, H)
    centre, area = _blob(_canvas(browser), SUN_RGB)
    assert area > 150  # the 9 px symbol, not a glyph
    assert np.hypot(*(centre - expected)) < 1.5, (centre, expected)


def _boresight_px(run_dir, t_s):
    row = _truth(run_dir, t_s)
    meta = state.load_meta(run_dir)
    st1 = next(d for d in meta["devices"] if d["name"] == "st1")
    bore_B = dcm(st1["q_SB"]).T @ np.array([0.0, 0.0, 1.0])
    return state.project(bore_B, "equirectangular", W, H), row  # body frame: fixed, whatever the attitude


def _colour_near(img, xy, rgb, r=2, tol=6):
    x, y = (int(round(v)) for v in xy)
    patch = img[y - r:y + r + 1, x - r:x + r + 1].astype(int)
    return bool((np.abs(patch - rgb).max(axis=-1) <= tol).any())


def test_tracker_field_turns_invalid_when_the_sun_enters_it(browser, replay, run_dir):
    from stand.telemetry import load

    tel = load(run_dir)
    valid = np.flatnonzero(tel["st1.valid"] == 1.0)
    sun = np.flatnonzero((np.nan_to_num(tel["st1.flags"]).astype(int) & 2) == 2)  # the ICD's bit 1: Sun in field
    assert len(valid) and len(sun) and tel["t_s"][valid[0]] < tel["t_s"][sun[0]]
    t_valid, t_sun = float(tel["t_s"][valid[len(valid) // 2]]), float(tel["t_s"][sun[len(sun) // 2]])
    _open(browser, replay.url)
    for t, colour, other, word in ((t_valid, VALID_RGB, SUN_FLAG_RGB, "valid"),
                                   (t_sun, SUN_FLAG_RGB, VALID_RGB, "Sun")):
        t = _seek(browser, t)
        xy, row = _boresight_px(run_dir, t)
        img = _canvas(browser)
        assert _colour_near(img, xy, colour), (t, xy)
        assert not _colour_near(img, xy, other)
        # The Sun's angle from the boresight says the same as the colour: inside the exclusion cone or not.
        sun_B = dcm(row["q_BN"]) @ (sun_position_gcrs(Epoch.from_iso(state.load_meta(run_dir)["epoch"]) + t)
                                     - row["r_BN_N"])
        angle = math.degrees(math.acos(sun_B[0] / np.linalg.norm(sun_B)))
        assert (angle < 40.3) == (word == "Sun"), angle
        state_text = browser.execute_script(
            "return window.standView.overlay.filter(o => o.name === 'st1').map(o => o.state)[0]")
        assert word in state_text
    # inside the sphere, looking along the tracker's boresight: its field is centred, in the same colour
    browser.execute_script("const e = document.getElementById('pano-proj'); e.value = 'inside'; "
                           "e.dispatchEvent(new Event('change'))")
    _wait(browser, "return window.standView.lookAxes && document.getElementById('look-at').value === 'dev:st1'")
    t = _seek(browser, t_sun + 0.5)
    img = _canvas(browser)
    assert _colour_near(img, (W / 2, H / 2), SUN_FLAG_RGB)
    # the 20 deg side of the field spans 2 tan(5 deg) / (2 tan(30 deg)) of the half width (stereographic, 120 deg)
    half_px = 2 * math.tan(math.radians(5)) / (2 * math.tan(math.radians(30))) * W / 2
    row = img[int(H / 2) + 2]
    edges = np.flatnonzero(np.abs(row.astype(int) - SUN_FLAG_RGB).max(axis=-1) <= 6)
    edges = edges[np.abs(edges - W / 2) < 1.5 * half_px]  # not the label's glyphs
    assert abs((edges.max() - edges.min()) / 2 - half_px) < 2.0, (edges.min(), edges.max(), half_px)


def test_slider_moves_time(browser, replay):
    _open(browser, replay.url)
    before = browser.find_element("id", "tsim").text
    n = browser.execute_script("return window.standView.stats.draws")
    browser.execute_script("const s = document.getElementById('slider'); s.value = 750; "
                           "s.dispatchEvent(new Event('input'))")
    _wait(browser, f"return window.standView.stats.draws > {n}")
    assert browser.execute_script("return window.standView.t") == pytest.approx(45.0, abs=0.1)
    after = browser.find_element("id", "tsim").text
    assert after != before and after.startswith("t = 45.0 s")
    assert "12:00:45" in browser.find_element("id", "utc").text
    # play advances time by itself
    browser.execute_script("window.standView.seek(0); document.getElementById('speed').value = '10'; "
                           "document.getElementById('play').click()")
    time.sleep(1.0)
    t = browser.execute_script("return window.standView.t")
    browser.find_element("id", "play").click()
    assert 3.0 < t < 20.0


@contextlib.contextmanager
def live_run(scenario, out: Path, speed: float):
    """``stand run SCENARIO --view`` in its own process: yields (the process, the page's URL it printed first); the
    process is killed if still running at the end, and its pipes closed."""
    cmd = [sys.executable, "-m", "stand.cli", "run", str(scenario), "--out", str(out), "--view",
           "--speed", f"{speed:g}", "--no-progress", "--no-plots"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        url = re.search(r"live view at (http://127\.0\.0\.1:\d+/)", line)
        assert url, line + (proc.stderr.read() if proc.poll() is not None else "")
        yield proc, url.group(1)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        proc.stdout.close()
        proc.stderr.close()


def test_a_live_run_updates_the_page_and_obeys_pause_and_stop(browser, tmp_path):
    scenario = write_scenario(tmp_path / "sweep.toml", duration_s=600.0)
    with live_run(scenario, tmp_path / "live", speed=10) as (proc, url):
        _open(browser, url)
        assert browser.find_element("id", "mode").text == "LIVE"
        n0 = browser.execute_script("return window.standView.store.n")
        t0 = browser.execute_script("return window.standView.t")
        _wait(browser, f"return window.standView.store.n > {n0} + 20 && window.standView.t > {t0} + 2")
        pushes = browser.execute_script("return window.standView.stats.pushes")
        assert pushes >= 2
        browser.execute_script("window.standView.control('pause')")
        _wait(browser, "return window.standView.status === 'paused'")
        # The page says paused when the server takes the request; rows already on their way (the sender thread,
        # the loop's control poll, the next push) still arrive. Held means: no new row for a whole second.
        _wait(browser, "const n = window.standView.store.n, h = window.testHeld || (window.testHeld = {}); "
                       "if (h.n !== n) { h.n = n; h.since = performance.now(); } "
                       "return performance.now() - h.since > 1000")
        n1 = browser.execute_script("return window.standView.store.n")
        time.sleep(1.0)
        assert browser.execute_script("return window.standView.store.n") <= n1 + 1  # held
        browser.execute_script("window.standView.control('resume')")
        _wait(browser, f"return window.standView.store.n > {n1} + 5")
        browser.execute_script("window.standView.control('stop')")
        assert proc.wait(timeout=30) == 130
        _wait(browser, "return ['finished', 'disconnected'].includes(window.standView.status)")
        assert _severe(browser) == []
    events = (tmp_path / "live" / "events.jsonl").read_text().splitlines()
    kinds = [json.loads(line)["kind"] for line in events]
    assert "paused" in kinds and "resumed" in kinds and kinds[-1] == "end"


@pytest.mark.parametrize("frame, seq", [("O", "321"), ("N", "312"), ("E", "313"), ("S", "123")])
def test_attitude_panel_matches_the_rotations_module(browser, replay, run_dir, frame, seq):
    from sim.frames import dcm_esd_gcrs, dcm_itrs_gcrs, dcm_lvlh_gcrs
    from sim.rotations import euler_from_quat, quat_from_dcm

    _open(browser, replay.url)
    browser.execute_script(f"document.getElementById('att-frame').value = '{frame}'; "
                           f"document.getElementById('euler-seq').value = '{seq}'")
    t = _seek(browser, 33.3)
    row = _truth(run_dir, t)
    ep = Epoch.from_iso(state.load_meta(run_dir)["epoch"]) + float(t)
    dcm_RN = {"O": lambda: dcm_lvlh_gcrs(row["r_BN_N"], row["v_BN_N"]), "N": lambda: np.eye(3),
              "E": lambda: dcm_itrs_gcrs(ep), "S": lambda: dcm_esd_gcrs(row["r_BN_N"], ep)}[frame]()
    C = dcm(row["q_BN"]) @ dcm_RN.T
    q = quat_from_dcm(C)
    page = browser.execute_script("return window.standView.attitude")
    assert page["frame"] == frame and page["seq"] == seq
    # the page works from float32 samples and the Earth's rotation without UT1 - UTC: 0.01 deg
    assert np.allclose(page["euler_deg"], np.degrees(euler_from_quat(q, seq)), atol=0.01)
    assert np.allclose(page["q"], q, atol=2e-4)
    assert np.allclose(page["dcm"], C, atol=2e-4)
    axis, angle = page["axis"], math.radians(page["angle_deg"])
    assert np.allclose(np.asarray(page["q"]), [math.cos(angle / 2), *(np.sin(angle / 2) * np.asarray(axis))], atol=1e-9)


# ------------------------------------------------------------------------------------------- issue 22, item 5

@pytest.fixture(scope="module")
def nan_run(tmp_path_factory):
    """detumble_star_tracker for 60 s: the tracker never solves in time, so three criteria have no value (null in
    summary.json, each with the stand's ``reason``) and the tracker's first rows are NaN. One criterion is given a
    bare NaN instead, as a summary written by an older stand holds it, which the page must take too."""
    out = tmp_path_factory.mktemp("viewnan") / "run"
    assert main(["run", "detumble_star_tracker", "--duration", "60", "--out", str(out), "--no-progress",
                 "--no-plots"]) == 1
    summary = json.loads((out / "summary.json").read_text())
    empty = [c for c in summary["criteria"] if c["value"] is None]
    assert len(empty) == 3 and all(c.get("reason") for c in empty), summary["criteria"]
    cross = next(c for c in summary["criteria"] if c["name"] == "tracker cross-boresight error p95")
    cross["value"] = math.nan
    cross.pop("reason")
    (out / "summary.json").write_text(json.dumps(summary))  # allow_nan: the NaN token on purpose
    with open(out / "events.jsonl", "a") as f:
        f.write(json.dumps({"kind": "odd", "message": "an event with a NaN time", "t_s": math.nan}) + "\n")
    return out


def test_page_works_with_nan_in_the_summary_and_the_telemetry(browser, nan_run):
    from stand.telemetry import load

    assert np.isnan(load(nan_run)["st1.err_roll"][:5]).all()
    with server.ViewServer(server.ReplaySource(nan_run)) as view:
        _open(browser, view.url)
        assert _severe(browser) == []
        assert browser.execute_script("return window.standView.store.n") == 601
        lines = [e.text for e in browser.find_elements("css selector", "#verdict > div")]
        assert lines[0].startswith("FAIL (completed)")
        by_name = {line.split(": ")[0][2:]: line for line in lines[1:]}
        assert by_name["tracker cross-boresight error p95"].endswith(": n/a (max 6)")
        reason = next(c["reason"] for c in json.loads((nan_run / "summary.json").read_text())["criteria"]
                      if c["name"] == "tracker roll error p95")
        assert by_name["tracker roll error p95"] == f"✗ tracker roll error p95: n/a (max 30)\n{reason}"
        assert by_name["no rejected frames"] == "✓ no rejected frames: 0 frames (max 0)"
        # the event with no time is listed without one; seeking into the NaN rows draws, and draws again after
        assert "odd an event with a NaN time" in browser.find_element("id", "events").text
        for t in (0.0, 0.5, 30.0):
            _seek(browser, t)
        assert browser.execute_script("return window.standView.loadError || null") is None
        assert _severe(browser) == []
        browser.save_screenshot(str(nan_run / "page_nan.png"))


def test_a_live_page_keeps_drawing_nan_rows(browser, run_dir, tmp_path):
    """Rows whose every value but the time is NaN (a run that diverged), and an event with a NaN time, pushed to
    an open page: it takes them and goes on drawing."""
    from stand.telemetry import load

    out = tmp_path / "live"
    shutil.copytree(run_dir, out)
    meta = state.load_meta(out)
    tel = load(out)
    schema = json.loads((out / "telemetry" / "schema.json").read_text())["columns"]
    flat = np.column_stack([np.asarray(tel[c["name"]]).reshape(len(tel["t_s"]), -1) for c in schema])
    source = state.LiveSource(out, meta)
    source.ingest(flat[:100])
    with server.ViewServer(source) as view:
        _open(browser, view.url)
        _wait(browser, "return window.standView.status === 'running' && !!window.standView.ws && "
                       "window.standView.ws.readyState === 1")
        with open(out / "events.jsonl", "a") as f:
            f.write(json.dumps({"kind": "odd", "message": "NaN time", "t_s": math.nan}) + "\n")
        bad = flat[100:150].copy()
        bad[:, 1:] = np.nan
        n = browser.execute_script("return window.standView.stats.draws")  # before the pushes: their redraw counts
        source.ingest(bad)
        source.ingest(flat[150:200])
        _wait(browser, "return window.standView.store.n === 200")
        _wait(browser, f"return window.standView.stats.draws > {n}")
        for t in (12.0, 16.0):  # inside the NaN rows, then after them
            _seek(browser, t)
        assert "NaN time" in browser.find_element("id", "events").text
        assert browser.execute_script("return window.standView.loadError || null") is None
        assert _severe(browser) == []
