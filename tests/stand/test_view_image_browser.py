"""Issue 25, item 2 in headless Chromium (the fixtures of test_view_browser.py: Debian's chromium and
chromium-driver through selenium, never a downloaded browser): the tracker's rendered image, live on the page of an
image-tracker run, and the "no image" line of a tracker that does not render."""

from __future__ import annotations

import base64
import re

import numpy as np

from stand.cli import main
from stand.view import server

from .test_view_browser import _open, _severe, _wait, browser  # noqa: F401 - the fixture
from .test_view_operator import _read_until, _start

FIGURE = "#trackimg figure[data-device='st1']"


def _image_pixels(driver) -> np.ndarray:
    """The frame as the page decoded it (drawn on a canvas of its natural size), grey levels."""
    import cv2

    url = _wait(  # a frame loading into the <img> has no picture yet: wait for a loaded one
        driver, f"const img = document.querySelector(\"{FIGURE} img\"), c = document.createElement('canvas'); "
        "if (!img.complete || !img.naturalWidth) return null; "
        "c.width = img.naturalWidth; c.height = img.naturalHeight; c.getContext('2d').drawImage(img, 0, 0); "
        "return c.toDataURL('image/png')")
    png = np.frombuffer(base64.b64decode(url.split(",", 1)[1]), np.uint8)
    return cv2.imdecode(png, cv2.IMREAD_GRAYSCALE)


def test_the_live_page_shows_the_trackers_newest_frame(browser, tmp_path):  # noqa: F811
    """A live run of the image tracker at 5 x real time: the panel shows decoded frames whose sim time advances,
    with the stars extracted and the solution's validity; the page still fits 1280 pixels."""
    out = tmp_path / "run"
    proc, master = _start(["detumble_star_tracker_image", "--duration", "120", "--speed", "5", "--out", str(out),
                           "--no-plots"], tmp_path, interactive=False)
    size = browser.get_window_size()
    try:
        m, _ = _read_until(proc, r"live view at (http://127\.0\.0\.1:\d+/)")
        browser.set_window_size(1280, 800)
        _open(browser, m.group(1))
        assert not browser.find_element("id", "trackimg").get_attribute("hidden")
        _wait(browser, "const f = window.standView.frames.st1; return f.loaded >= 1", timeout_s=60)
        first = browser.execute_script("return window.standView.frames.st1.shown")
        _wait(browser, f"return window.standView.frames.st1.shown.t_s > {first['t_s']}", timeout_s=60)
        shown = browser.execute_script("return window.standView.frames.st1.shown")
        assert shown["seq"] > first["seq"]
        img = browser.find_element("css selector", f"{FIGURE} img")
        # A new frame arrives twice a second and loads into the same <img>: wait for one loaded, read in that call.
        natural = _wait(browser, "const i = arguments[0]; return i.complete && i.naturalWidth ? [i.naturalWidth, "
                                 "i.naturalHeight, i.clientWidth] : null", img)
        assert natural[:2] == [512, 384] and natural[2] > 200, natural
        pixels = _image_pixels(browser)
        assert pixels.shape == (384, 512)
        assert np.median(pixels) == 0 and (pixels > 50).sum() > 20  # stars on a black sky
        # The caption: the frame's time and stars; once the samples reach its solution, that solution's state.
        # Read in the same call as the wait: a newer frame may arrive between two calls, with its solution pending.
        caption = _wait(browser, "const t = document.querySelector(\"" + FIGURE + " figcaption\").textContent.trim(); "
                                 "return t.includes('pending') ? null : t", timeout_s=30)
        m = re.fullmatch(r"st1 at t = ([\d.]+) s: (\d+) stars extracted, (\d+) matched; solution (.+)", caption)
        assert m, caption
        assert int(m.group(2)) > 20 and m.group(4).startswith(("valid, flags 0x", "invalid: acquiring")), caption
        # 1280 x 800: no horizontal scrolling, nothing sticking out of a panel
        width = browser.execute_script("return window.innerWidth")
        scroll = browser.execute_script("return [document.documentElement.scrollWidth, document.body.scrollWidth]")
        assert max(scroll) <= width <= 1280, scroll
        wide = browser.execute_script(
            "return [...document.querySelectorAll('section')].filter((s) => s.scrollWidth > s.clientWidth + 1)"
            ".map((s) => s.className)")
        assert wide == []
        browser.execute_script("document.getElementById('trackimg').scrollIntoView({block: 'end'})")
        browser.save_screenshot(str(tmp_path / "view_tracker_image.png"))
        assert _severe(browser) == []
        browser.execute_script("window.standView.control('stop')")
        assert proc.wait(timeout=60) == 130
    finally:
        browser.set_window_size(size["width"], size["height"])
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        proc.stdout.close()
        proc.stderr.close()


def test_a_truth_tracker_shows_no_image(browser, tmp_path):  # noqa: F811
    out = tmp_path / "run"
    assert main(["run", "detumble_star_tracker", "--duration", "5", "--out", str(out), "--no-progress",
                 "--no-plots"]) in (0, 1)
    with server.ViewServer(server.ReplaySource(out)) as view:
        _open(browser, view.url)
        assert not browser.find_element("id", "trackimg").get_attribute("hidden")
        caption = browser.find_element("css selector", "#trackimg figure[data-device='st1'] figcaption").text
        assert caption == "st1: no image: source = 'truth': this tracker does not render"
        assert browser.find_elements("css selector", "#trackimg img") == []
        assert _severe(browser) == []


def test_a_run_without_a_tracker_has_no_image_panel(browser, tmp_path):  # noqa: F811
    out = tmp_path / "run"
    assert main(["run", "detumble_igrf", "--duration", "2", "--out", str(out), "--no-progress", "--no-plots"]) in (0, 1)
    with server.ViewServer(server.ReplaySource(out)) as view:
        _open(browser, view.url)
        assert browser.find_element("id", "trackimg").get_attribute("hidden")
