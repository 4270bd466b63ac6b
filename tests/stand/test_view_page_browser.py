"""Issue 25, item 2 in headless Chromium (the fixtures of test_view_browser.py: Debian's chromium and
chromium-driver through selenium, never a downloaded browser): the page of a finished `stand run --view` at the
default speed, the 3-D view, the pointing panel and the page at 1280 x 800."""

from __future__ import annotations

import math
import signal

import numpy as np
import pytest

from sim.rotations import dcm
from stand.cli import main
from stand.telemetry import load
from stand.view import server

from .test_view_browser import _canvas, _open, _seek, _severe, _wait, browser  # noqa: F401 - the fixture
from .test_view_operator import _end, _read_until, _start

ARCSEC = math.pi / 180 / 3600


@pytest.fixture(scope="module")
def pointing_run(tmp_path_factory):
    """A minute of the wheel-pointing scenario: the tracker acquires (its first solutions are not valid, with errors
    recorded all the same), the controller records its commanded attitude and estimate."""
    out = tmp_path_factory.mktemp("page") / "run"
    assert main(["run", "pointing_star_tracker", "--duration", "60", "--out", str(out), "--no-progress",
                 "--no-plots"]) in (0, 1)
    tel = load(out)
    invalid = tel["st.valid"] < 0.5
    assert invalid.any() and np.isfinite(tel["st.err_cross"][invalid]).any()  # what the panel must leave out
    return out


@pytest.fixture(scope="module")
def pointing_page(pointing_run):
    with server.ViewServer(server.ReplaySource(pointing_run)) as view:
        yield view


def _angle_arcsec(q_a, q_b):
    """The rotation angle between two attitudes, from their matrices (independently of stand.adcs.metrics)."""
    E = dcm(q_b) @ dcm(q_a).T
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(E) - 1) / 2)))) * 3600


def test_the_page_of_a_finished_default_run_stays_reachable(browser, tmp_path):  # noqa: F811
    """`stand run --view` at the default speed ends in about a second; the page opened after that still loads
    the whole run and its verdict, until the operator stops serving."""
    proc, master = _start(["--out", str(tmp_path / "run")], tmp_path, interactive=True)
    try:
        m, _ = _read_until(proc, r"its page stays at (http://127\.0\.0\.1:\d+/) until you press Ctrl-C")
        url = m.group(1)
        _open(browser, url)  # opened after the run's end
        assert browser.execute_script("return window.standView.status") == "finished"
        n = browser.execute_script("return window.standView.store.n")
        assert n > 1000
        assert browser.execute_script("return window.standView.store.t(window.standView.store.n - 1)") > 5600
        _wait(browser, "return document.getElementById('verdict').textContent.startsWith('PASS')")
        assert "detumbled" in browser.find_element("id", "verdict").text
        assert _severe(browser) == []
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0
    finally:
        _end(proc, master)


def test_the_3d_view_draws_the_spacecraft_where_its_orbit_puts_it(browser, pointing_page, pointing_run):  # noqa: F811
    _open(browser, pointing_page.url)
    for centre in ("earth", "sc"):
        browser.execute_script(f"const e = document.getElementById('v3-center'); e.value = '{centre}'; "
                               "e.dispatchEvent(new Event('change'))")
        t = _seek(browser, 30.0)
        info = browser.execute_script("return window.standView.view3d")
        cv = browser.execute_script("const c = document.getElementById('orbit3d'); return [c.width, c.height]")
        W, H = cv
        # The truth's position seen by the camera the page reports, computed here.
        tel = load(pointing_run)
        k = int(np.argmin(np.abs(tel["t_s"] - t)))
        r = tel["r_BN_N"][k] / 6378137.0
        cam = info["cam"]
        az, el, D = cam["az"], cam["el"], cam["dist"]
        back = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        right = np.array([-math.sin(az), math.cos(az), 0.0])
        up = np.cross(back, right)
        eye = (r if centre == "sc" else np.zeros(3)) + D * back
        f = H / 2 / math.tan(cam["fov"] / 2)
        d = r - eye
        z = -d @ back
        expected = (W / 2 + f * (d @ right) / z, H / 2 - f * (d @ up) / z)
        assert np.hypot(*(np.asarray(info["sc"]) - expected)) < 2.0, (info["sc"], expected)
        img = _canvas(browser, "orbit3d")
        if centre == "earth":  # the Earth's centre is drawn as the Earth (blue), not the black sky
            o = (W / 2 - f * (eye @ right) / (eye @ back), H / 2 - f * (eye @ up) / (eye @ back))
            px = img[int(o[1]), int(o[0])].astype(int)
            assert px[2] > 40 and px[2] > px[0], px
        # the body axes, the momentum and the tracker's field as a cone are drawn
        assert len(info["axes"]) == 3 and all(info["axes"])
        assert {v["col"] for v in info["vectors"]} >= {"h_total_B", "h_wheels_B", "torque_wheels_B"}
        assert info["cones"] == 1
        x_end = info["axes"][0]
        patch = img[int(x_end[1]) - 3:int(x_end[1]) + 4, int(x_end[0]) - 3:int(x_end[0]) + 4].astype(int)
        assert (np.abs(patch - (255, 85, 85)).max(axis=-1) <= 10).any()  # +X's arrow head, red
    assert _severe(browser) == []


def test_the_pointing_panel_shows_the_controllers_error_and_no_invalid_solution(browser, pointing_page,  # noqa: F811
                                                                                pointing_run):
    _open(browser, pointing_page.url)
    series = dict(browser.execute_script(
        "const S = window.standView, p = S.plots.find((x) => x.opts.id === 'pointing'); "
        "return p.series.filter((s) => S.store.cols[s.col]).map((s) => "
        "[s.col, Array.from({length: S.store.n}, (_, k) => p.value(s, k))])"))
    tel = load(pointing_run)
    assert len(series["pointing_error_arcsec"]) == len(tel["t_s"])  # 601 rows: not decimated
    for k in range(0, len(tel["t_s"]), 25):
        want = _angle_arcsec(tel["q_BN"][k], tel["adcs_q_RN"][k])
        assert series["pointing_error_arcsec"][k] == pytest.approx(want, rel=1e-4, abs=0.5), k
        if np.all(np.isfinite(tel["adcs_q_BN_est"][k])):
            want = _angle_arcsec(tel["q_BN"][k], tel["adcs_q_BN_est"][k])
            assert series["knowledge_error_arcsec"][k] == pytest.approx(want, rel=1e-4, abs=0.5), k
    valid = tel["st.valid"] >= 0.5
    for col in ("st.err_cross.valid_only", "st.err_roll.valid_only"):
        drawn = np.array([math.nan if v is None else v for v in series[col]])
        assert np.all(np.isnan(drawn[~valid]))  # nothing of an invalid solution
        raw = tel[col.removesuffix(".valid_only")][valid]
        assert np.allclose(drawn[valid], raw, rtol=1e-6, equal_nan=True)
    assert not any(c in series for c in ("st.err_cross", "st.err_roll"))
    label = browser.execute_script("return window.standView.plots.find((x) => x.opts.id === 'pointing').title")
    assert label.startswith("pointing and knowledge error")


def test_the_page_fits_1280_by_800(browser, pointing_page, tmp_path):  # noqa: F811
    """No horizontal scrolling in a 1280 x 800 window; the wheels in one unit against their limits; the mode."""
    size = browser.get_window_size()
    try:
        browser.set_window_size(1280, 800)
        _open(browser, pointing_page.url)
        _seek(browser, 45.0)
        width = browser.execute_script("return window.innerWidth")
        assert 1260 <= width <= 1280
        scroll = browser.execute_script("return [document.documentElement.scrollWidth, document.body.scrollWidth]")
        assert max(scroll) <= width, scroll
        # nothing sticks out of its panel either (a panel's own scroll bar would hide it)
        wide = browser.execute_script(
            "return [...document.querySelectorAll('section')].filter((s) => s.scrollWidth > s.clientWidth + 1)"
            ".map((s) => s.className)")
        assert wide == []
        browser.save_screenshot(str(tmp_path / "page_1280.png"))
        wheels = browser.execute_script("const p = window.standView.plots.find((x) => x.opts.id === 'wheels'); "
                                        "return [p.title, p.series.map((s) => s.label), p.opts.limits]")
        assert wheels[0] == "wheel speeds (rpm)" and wheels[1] == ["rw0", "rw1", "rw2", "rw3"]
        assert [v for v, _ in wheels[2]] == [6000, -6000]  # the datasheet's 628.3 rad/s
        assert browser.find_element("id", "adcs-mode").text == "ADCS mode 2 fine pointing"
    finally:
        browser.set_window_size(size["width"], size["height"])
