"""Issue 25, item 2: the image tracker's rendered frame, live on the operator page, without a browser (the page in
Chromium: tests/stand/test_view_image_browser.py). A frame is taken from the run only while a page is open, at most
``frames.FRAME_HZ`` a second, and ``GET /api/frame`` serves the newest and refuses what it should."""

from __future__ import annotations

import dataclasses
import json
import math
import time

import numpy as np
import pytest

from stand import scenario
from stand.compose import build
from stand.loop import run
from stand.telemetry import load
from stand.view import frames, server, state

from .test_view import _get, _raw

SCENARIO = "detumble_star_tracker_image"
DURATION_S = 12.0
#: Paced to last about a second of wall time, as a watched run does: unpaced the run can end (0.1 s) before the
#: sender's first push (every 0.1 s) has armed a frame.
SPEED = 12.0


def _live_run(out, pages: int):
    """The image scenario for DURATION_S in this process, its feed and the page's source joined by a LocalLink, as if
    ``pages`` pages were open. Returns (source, feed, wall seconds of the run)."""
    sc = dataclasses.replace(scenario.load(scenario.find(SCENARIO)), duration_s=DURATION_S)
    meta = state.describe(sc)
    source = state.LiveSource(out, meta)
    source.pages = pages
    feed = state.LiveFeed(state.LocalLink(source), meta)
    with build(sc, SPEED) as scene:
        out.mkdir()
        feed.start()
        t0 = time.monotonic()
        result = run(scene, out, speed=SPEED, observer=feed)
        wall_s = time.monotonic() - t0
        feed.finish()
        solver = scene.devices["st1"].image
        assert solver.on_frame is None or pages  # nobody asked: nothing was armed
    assert result.status == "completed"
    return source, feed, wall_s


@pytest.fixture(scope="module")
def watched(tmp_path_factory):
    return _live_run(tmp_path_factory.mktemp("img") / "run", pages=1)


def test_no_frame_is_copied_when_no_page_is_open(tmp_path):
    source, feed, _ = _live_run(tmp_path / "run", pages=0)
    assert [t.name for t in feed.taps] == ["st1"]  # the tracker is watchable ...
    assert feed.taps[0].taken == 0 and feed.frames_sent == 0 and source.frames == {}  # ... and was not watched
    assert feed.rows_taken == len(load(tmp_path / "run")["t_s"])  # the rows went as usual


def test_a_watched_run_sends_frames_at_a_bounded_rate(watched, tmp_path):
    source, feed, wall_s = watched
    tap = feed.taps[0]
    # one frame per arming, at most FRAME_HZ a second of wall time (the first at once), and every one sent
    assert 1 <= tap.taken <= math.floor(wall_s * frames.FRAME_HZ) + 2, (tap.taken, wall_s)
    assert feed.frames_sent == tap.taken
    info, png = source.frames["st1"]
    import cv2

    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.shape == (384, 512) and img.dtype == np.uint8  # 1024 x 768 shrunk twice each way
    assert info["size_px"] == [512, 384] and info["full_px"] == [1024, 768]
    assert 0 <= info["t_s"] <= DURATION_S  # an exposure
    # the stars the tracker extracted are in the picture: bright spots on a black sky
    assert info["stars_extracted"] > 20 and info["stars_matched"] > 0 and info["solved"]
    assert np.median(img) == 0 and (img > 50).sum() >= info["stars_extracted"] // 4


def test_the_frame_endpoint_serves_the_newest_frame_and_refuses_the_rest(watched, tmp_path):
    source, _, _ = watched
    info, png = source.frames["st1"]
    with server.ViewServer(source) as view:
        status, body = _get(view.url + "api/frame?device=st1")
        assert status == 200 and body == png
        port = view.port
        status, body = _raw(port, "/api/frame?device=st1", {"Host": f"127.0.0.1:{port}"})
        assert status == 200 and body[:8] == b"\x89PNG\r\n\x1a\n"
        # the frame a page was told of, by number, while it is among the last few
        assert _get(view.url + f"api/frame?device=st1&seq={info['seq']}") == (200, png)
        if info["seq"] > 1:
            older = source.frame_numbered("st1", info["seq"] - 1)
            assert older is not None and older[0]["t_s"] < info["t_s"]
            assert _get(view.url + f"api/frame?device=st1&seq={info['seq'] - 1}") == (200, older[1])
        for seq in (str(info["seq"] + 1), "0", "-1", "x"):
            status, body = _get(view.url + f"api/frame?device=st1&seq={seq}")
            assert status == 404 and "the number of one of the last 4 frames" in json.loads(body)["error"]
        # what it refuses, each with a sentence
        assert _get(view.url + "api/frame")[0] == 400
        status, body = _get(view.url + "api/frame?device=mtq")  # a device that renders nothing
        assert status == 404 and "not a device of this run that renders an image (st1)" in json.loads(body)["error"]
        assert _get(view.url + "api/frame?device=nope")[0] == 404
        status, body = _raw(port, "/api/frame?device=st1", {"Host": f"evil.example:{port}"})  # DNS rebinding
        assert status == 403 and b"is not an address this view listens on" in body
        assert _get(view.url + "api/frame?device=st1", data=b"{}")[0] == 405  # nothing to post
    # before the run's first frame
    empty = state.LiveSource(tmp_path, source.meta)
    with server.ViewServer(empty) as view:
        status, body = _get(view.url + "api/frame?device=st1")
        assert status == 404 and "has sent no frame yet" in json.loads(body)["error"]


def test_a_replay_has_no_frames_and_says_so(tmp_path):
    out = tmp_path / "run"
    from stand.cli import main

    assert main(["run", SCENARIO, "--duration", "3", "--out", str(out), "--no-progress", "--no-plots"]) in (0, 1)
    meta = state.load_meta(out)
    layer = {d["name"]: d.get("image") for d in meta["devices"]}
    assert layer["st1"] == {"renders": True, "size_px": [1024, 768], "delay_s": 0.1}
    assert layer["mtq"] is None  # a magnetorquer has no image panel at all
    with server.ViewServer(server.ReplaySource(out)) as view:
        status, body = _get(view.url + "api/frame?device=st1")
        assert status == 404 and "a replay has no frames" in json.loads(body)["error"]


def test_a_truth_tracker_says_it_does_not_render():
    meta = state.describe(scenario.load(scenario.find("detumble_star_tracker")))
    st = next(d for d in meta["devices"] if d["kind"] == "star_tracker")
    assert st["image"] == {"renders": False, "why": "source = 'truth': this tracker does not render"}


def test_shrink_keeps_a_one_pixel_star_and_blackens_the_sky():
    background_e, sigma_e = 20.0, 11.0
    rng = np.random.default_rng(3)
    image = (background_e + sigma_e * rng.standard_normal((768, 1024))).clip(0).astype(np.float32)
    faint = background_e + 8 * sigma_e  # a faint star's only lit pixel
    image[301, 601] = faint
    image[10, 20] = background_e + frames.BLACK_SIGMA * sigma_e + frames.WHITE_E  # white
    small = frames.shrink(image, background_e, sigma_e)
    assert small.shape == (384, 512) and small.dtype == np.uint8
    assert small[150, 300] > 40  # the 2 x 2 block holding the faint star keeps it (an average: about 12)
    assert small[5, 10] == 255
    # the noise of the sky: below the black level in most blocks, dim elsewhere
    sky = np.delete(small.ravel(), [150 * 512 + 300, 5 * 512 + 10])
    assert np.median(sky) < 20 and sky.max() < small[150, 300]


def test_a_broken_frame_costs_the_page_its_frame_not_the_run(tmp_path, caplog):
    """A copy that fails in the tracker's thread never reaches the tracker; a corrupt frame on the pipe is left out of
    the page, which goes on with the next good one."""

    class Solver:
        on_frame = None
        exposure = None  # no image to copy

    solver = Solver()
    tap = frames.FrameTap("st1", solver)
    assert tap.arm() and solver.on_frame == tap.take
    tap.take(3.0, {"stars_in_field": 5})  # raises nothing
    assert solver.on_frame is None and tap.taken == 0 and "no frame for the page: AttributeError" in tap.error
    assert tap.collect() is None
    meta = state.describe(scenario.load(scenario.find(SCENARIO)))
    source = state.LiveSource(tmp_path, meta)
    header = {"device": "st1", "t_s": 1.0, "size_px": [512, 384]}
    with caplog.at_level("WARNING", logger="stand.view.server"):
        server._frame(source, json.dumps(header).encode() + b"\n" + b"\x00" * 100)  # 100 bytes, not 512 x 384
        server._frame(source, b"{not json\n" + b"\x00" * 10)
    assert source.frames == {} and len([r for r in caplog.records if "left out of the page" in r.message]) == 2
    server._frame(source, json.dumps(header).encode() + b"\n" + bytes(512 * 384))
    assert source.frames["st1"][0]["seq"] == 1 and source.frames["st1"][1][:4] == b"\x89PNG"
