"""Live fault injection from the operator page in headless Chromium (issue 24's acceptance): a paced
``stand run --view`` with an ideal gyro; a gyro bias step injected and then cleared from the page's fault panel
appears in ``events.jsonl``, on the page's timeline and as markers on its time plots, and shows in the telemetry.

Skipped as tests/stand/test_view_browser.py is (whose browser fixture and helpers this reuses) when Chromium or its
driver is not installed.
"""

from __future__ import annotations

import base64
import json
import os
from pathlib import Path

import numpy as np

from stand.telemetry import load
from stand.view import server

from .test_view_browser import ROOT, _open, _severe, _wait, browser, live_run  # noqa: F401 - browser is a fixture
from .view_scenario import write as write_scenario

FAULT_RGB = (255, 120, 0)
CLEARED_RGB = (0, 200, 200)
BIAS_RAD_S = 0.02
#: An ideal gyro reports the true rate; its newest sample is up to one output period (0.1 s) old while gravity
#: gradient changes the rate by well under 1e-7 rad/s in that time, and the codec carries float32 (2e-9 rad/s at
#: 0.02): 1e-6 rad/s bounds both with room.
RATE_TOL = 1e-6


def _scenario(path: Path) -> str:
    write_scenario(path, duration_s=600.0)
    path.write_text(path.read_text().replace("[controller]", """[[devices]]
name = "imu"
kind = "gyro"
ideal = true
output_rate_hz = 10.0

[controller]"""))
    return str(path)


def _png(driver, script) -> tuple[np.ndarray, list]:
    """The picture of the data URL ``script`` returns first, and the rest of what it returns: read in one call, as a
    live plot's axis moves with every new sample."""
    import cv2

    url, *rest = driver.execute_script(script)
    png = np.frombuffer(base64.b64decode(url.split(",", 1)[1]), np.uint8)
    return cv2.imdecode(png, cv2.IMREAD_COLOR)[..., ::-1], rest


def _column_has(img, x, rgb, tol=8) -> int:
    """Pixels of colour ``rgb`` in the columns x - 1 .. x + 1."""
    x = int(round(x))
    cols = img[:, max(0, x - 1):x + 2].astype(int)
    return int((np.abs(cols - rgb).max(axis=-1) <= tol).sum())


def test_a_fault_injected_from_the_page(browser, tmp_path):  # noqa: F811 - the fixture
    out = tmp_path / "live"
    with live_run(_scenario(tmp_path / "gyro.toml"), out, speed=4) as (proc, url):
        assert oct(os.stat(out / "view_url.json").st_mode & 0o777) == "0o600"
        _open(browser, url)
        _wait(browser, "return window.standView.store.n > 5 && window.standView.status === 'running'")
        assert not browser.find_element("id", "faults-panel").get_attribute("hidden")
        # The panel offers the gyro's faults: its measurement faults with the unit filled in, not a wheel's.
        browser.execute_script("const d = document.getElementById('fault-device'); d.value = 'imu'; "
                               "d.dispatchEvent(new Event('change'))")
        offered = browser.execute_script("return [...document.getElementById('fault-type').options].map(o => o.value)")
        assert "bias_step" in offered and "clock_jump" in offered and "wheel_seized" not in offered
        browser.execute_script("document.getElementById('fault-type').value = 'bias_step'; "
                               "document.getElementById('fault-type').dispatchEvent(new Event('change'))")
        assert browser.find_element("id", "fault-params").get_attribute("placeholder") == "bias_rad_s=…"
        browser.find_element("id", "fault-params").send_keys(f"bias_rad_s=[{BIAS_RAD_S}, 0, 0]")
        browser.find_element("id", "fault-inject").click()
        _wait(browser, "return window.standView.faultAnswers.length > 0")
        answer = browser.execute_script("return window.standView.faultAnswers[0]")
        assert answer == {"status": 200, "action": "inject", "name": "imu_bias_step"}, answer
        assert browser.find_element("id", "fault-msg").text == "injected imu_bias_step (from the run's next tick)"
        # The event reaches the page; the fault is drawn once samples after it arrived.
        _wait(browser, "return window.standView.faults.length === 1 && window.standView.faults[0].active")
        t_in = browser.execute_script("return window.standView.faults[0].injected_s")
        _wait(browser, f"return window.standView.store.t(window.standView.store.n - 1) > {t_in} + 3")
        # A bad table from the page: the schedule's sentence, shown; nothing else injected.
        browser.find_element("id", "fault-params").clear()
        browser.find_element("id", "fault-params").send_keys("bias_rad_s=[1, 2]")
        browser.find_element("id", "fault-inject").click()
        _wait(browser, "return window.standView.faultAnswers.length > 1")
        bad = browser.execute_script("return window.standView.faultAnswers[1]")
        assert bad["status"] == 400 and "bias_rad_s" in bad["error"], bad
        assert browser.find_element("id", "fault-msg").text == bad["error"]
        # Clear it from the panel's list.
        browser.find_element("css selector", "#fault-list button[data-fault='imu_bias_step']").click()
        _wait(browser, "return window.standView.faults.length === 1 && !window.standView.faults[0].active")
        t_out = browser.execute_script("return window.standView.faults[0].cleared_s")
        _wait(browser, f"return window.standView.store.t(window.standView.store.n - 1) > {t_out} + 1")
        n = browser.execute_script("return window.standView.stats.draws")
        _wait(browser, f"return window.standView.stats.draws > {n}")
        # On the timeline: a mark at each time, in the two colours.
        timeline, (x_in, x_out) = _png(browser, "const x = window.standView.timeline.x; return [document."
                                       f"getElementById('timeline').toDataURL('image/png'), x({t_in}), x({t_out})]")
        assert _column_has(timeline, x_in, FAULT_RGB) >= 20  # the 30 px high mark
        assert _column_has(timeline, x_out, CLEARED_RGB) >= 20
        assert _column_has(timeline, (x_in + x_out) / 2, FAULT_RGB) == 0  # marks, not a wash of colour
        # On the gyro's plot (and every other): dashed markers at the same times.
        k = browser.execute_script("return window.standView.plots.findIndex(p => p.title.startsWith('gyro rate'))")
        assert k >= 0
        plot, (px_in, px_out) = _png(browser, f"const p = window.standView.plots[{k}]; "
                                     f"return [p.canvas.toDataURL('image/png'), p.X({t_in}), p.X({t_out})]")
        assert _column_has(plot, px_in, FAULT_RGB) >= 40 and _column_has(plot, px_out, CLEARED_RGB) >= 40
        events_text = browser.find_element("id", "events").text
        assert "fault_injected imu_bias_step: bias_step on imu" in events_text and "fault_cleared" in events_text
        # The refused table's 400 is the one network error the browser logs.
        severe = _severe(browser)
        assert len(severe) == 1 and "/api/faults - " in severe[0]["message"] and "of 400" in severe[0]["message"]
        browser.set_window_size(1600, 1900)
        browser.execute_script("window.scrollTo(0, 0)")
        browser.save_screenshot(str(tmp_path / "view_faults.png"))
        browser.set_window_size(1600, 1400)
        browser.execute_script("window.standView.control('stop')")
        assert proc.wait(timeout=30) == 130
    assert not (out / "view_url.json").exists()
    events = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
    faults = [e for e in events if e["kind"].startswith("fault_")]
    assert [(e["kind"], e["fault"], e["t_s"]) for e in faults] == [("fault_injected", "imu_bias_step", t_in),
                                                                    ("fault_cleared", "imu_bias_step", t_out)]
    assert faults[0]["params"] == {"bias_rad_s": [BIAS_RAD_S, 0, 0]}
    # In the telemetry: the gyro's x rate is the truth's until the injection, the truth's plus the bias while the
    # fault lasts (from the first sample taken after it), and the truth's again once cleared.
    tel = load(out)
    t, meas, true = tel["t_s"], tel["imu.omega_S"][:, 0], tel["omega_BN_B"][:, 0]
    err = meas - true
    before, during, after = t < t_in, (t >= t_in + 0.15) & (t < t_out), t >= t_out + 0.15
    assert before.sum() > 10 and during.sum() > 10 and after.sum() > 5
    assert np.abs(err[before]).max() < RATE_TOL
    assert np.abs(err[during] - BIAS_RAD_S).max() < RATE_TOL
    assert np.abs(err[after]).max() < RATE_TOL
    # A replay of the run draws the same from its event log: the list (no form) and the marks.
    with server.ViewServer(server.ReplaySource(out)) as view:
        _open(browser, view.url)
        assert not browser.find_element("id", "faults-panel").get_attribute("hidden")
        assert browser.find_element("id", "fault-form").get_attribute("hidden")
        assert browser.find_element("id", "fault-list").text.replace("\n", " ") == (
            f"imu_bias_step bias_step on imu, t = {t_in:.1f}–{t_out:.1f} s (bias_rad_s=[0.02,0,0])")
        assert browser.find_elements("css selector", "#fault-list button") == []
        timeline, (x_in, x_out) = _png(browser, "const x = window.standView.timeline.x; return [document."
                                       f"getElementById('timeline').toDataURL('image/png'), x({t_in}), x({t_out})]")
        assert _column_has(timeline, x_in, FAULT_RGB) >= 20 and _column_has(timeline, x_out, CLEARED_RGB) >= 20
        assert _severe(browser) == []
