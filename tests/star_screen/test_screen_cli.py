"""`stand screen` end to end: files, truth content, errors, and the bench rows' shape."""

import json

import numpy as np
import pytest

from stand.cli import main as cli_main
from star_screen.attitude import q_SN_from_radec_roll
from tests.oracles import require


def test_screen_writes_png_and_truth(tmp_path):
    cv2 = require("cv2", "the base install (opencv-contrib-python-headless)")
    out = tmp_path / "frame"
    rc = cli_main(["screen", "--ra", "83.8", "--dec", "-5.4", "--roll", "15", "--out", str(out)])
    assert rc == 0
    scr = cv2.imread(str(out / "screen.png"), cv2.IMREAD_UNCHANGED)
    det = cv2.imread(str(out / "detector_raw.png"), cv2.IMREAD_UNCHANGED)
    view = cv2.imread(str(out / "detector.png"), cv2.IMREAD_UNCHANGED)
    assert scr.shape == (1080, 1920) and scr.dtype == np.uint8 and scr.max() > 200
    assert det.shape == (768, 1024) and det.dtype == np.uint16
    # the viewing copy: 8-bit, a grey sky, and the same stars bright where the raw counts peak
    assert view.shape == det.shape and view.dtype == np.uint8
    assert 15 <= np.median(view) <= 60 and view[det > np.percentile(det, 99.9)].min() > 2 * np.median(view)
    truth = json.loads((out / "truth.json").read_text())
    assert np.allclose(truth["q_SN"], q_SN_from_radec_roll(83.8, -5.4, 15.0))
    assert truth["tracker"]["width"] == 1024 and np.allclose(truth["tracker"]["fov_deg"], [20, 15])
    assert truth["aberration"] is True and truth["time_tag_ns"] == 0
    stars = truth["stars"]
    assert len(stars) == truth["n_stars"] > 100
    s0 = stars[0]
    assert {"hip", "mag", "detector_xy"} <= set(s0)
    # Rigel (HIP 24436) is in this field; its detector pixel is in the image
    rigel = [s for s in stars if s["hip"] == 24436][0]
    x, y = rigel["detector_xy"]
    assert det[int(y), int(x)] == det[int(y) - 2 : int(y) + 3, int(x) - 2 : int(x) + 3].max()


def test_aberration_off_moves_stars_by_arcseconds(tmp_path):
    a, b = tmp_path / "on", tmp_path / "off"
    args = ["screen", "--ra", "200", "--dec", "-30", "--out"]
    assert cli_main(args + [str(a)]) == 0
    assert cli_main(args + [str(b), "--aberration", "off"]) == 0
    ta = {s["hip"]: s["detector_xy"] for s in json.loads((a / "truth.json").read_text())["stars"]}
    tb = {s["hip"]: s["detector_xy"] for s in json.loads((b / "truth.json").read_text())["stars"]}
    common = sorted(set(ta) & set(tb))
    d = np.array([np.hypot(*np.subtract(ta[h], tb[h])) for h in common]) * 70.3  # arcsec
    assert 3.0 < np.median(d) < 25.0


@pytest.mark.parametrize(
    "argv, word",
    [
        (["--ra", "0", "--dec", "95"], "dec"),
        (["--ra", "0", "--dec", "0", "--scenario", "x.toml"], "--scenario 'x.toml'"),
        (["--ra", "0", "--dec", "0", "--tracker", "st1"], "needs --scenario"),
        (["--ra", "0", "--dec", "0", "--screen", "big"], "--screen"),
        (["--ra", "0", "--dec", "0", "--epoch", "yesterday"], "ISO 8601"),
    ],
)
def test_usage_errors_exit_2_with_a_message(tmp_path, capsys, argv, word):
    rc = cli_main(["screen", *argv, "--out", str(tmp_path / "x")])
    assert rc == 2
    assert word in capsys.readouterr().err


def _image_scenario(tmp_path, fov="[16.0, 12.0]", resolution="[640, 480]"):
    """The image-source fixture scenario with other optics, so the output shows whose optics were used."""
    from stand.scenario import SCENARIO_DIR

    text = (SCENARIO_DIR / "detumble_star_tracker_image.toml").read_text()
    text = text.replace("fov_deg = [20.0, 15.0]", f"fov_deg = {fov}")
    text = text.replace("resolution_px = [1024, 768]", f"resolution_px = {resolution}")
    path = tmp_path / "image.toml"
    path.write_text(text)
    return path


def test_screen_uses_the_scenario_tracker_optics_and_epoch(tmp_path):
    cv2 = require("cv2", "the base install (opencv-contrib-python-headless)")
    out = tmp_path / "frame"
    sc = _image_scenario(tmp_path)
    rc = cli_main(["screen", "--scenario", str(sc), "--tracker", "st1", "--ra", "83.8", "--dec", "-5.4",
                              "--out", str(out)])
    assert rc == 0
    det = cv2.imread(str(out / "detector_raw.png"), cv2.IMREAD_UNCHANGED)
    assert det.shape == (480, 640) and det.max() > 0
    truth = json.loads((out / "truth.json").read_text())
    assert truth["tracker"]["name"] == "st1" and (truth["tracker"]["width"], truth["tracker"]["height"]) == (640, 480)
    assert np.allclose(truth["tracker"]["fov_deg"], [16, 12])
    assert truth["epoch_utc"].startswith("2026-03-20T12:00:00")
    assert all(0 <= s["detector_xy"][0] < 640 + 4 for s in truth["stars"])


@pytest.mark.parametrize(
    "scenario, tracker, words",
    [
        ("image", "st9", ["--tracker 'st9' is not a star tracker", "available: st1 (source = 'image')"]),
        ("detumble_star_tracker", "st1", ["--tracker 'st1' has source = 'truth'", "no optics", "source = 'image'"]),
        ("detumble", None, ["--tracker is required", "no image-source star trackers"]),
    ],
)
def test_scenario_tracker_errors_name_the_tracker(tmp_path, capsys, scenario, tracker, words):
    sc = str(_image_scenario(tmp_path)) if scenario == "image" else scenario
    argv = ["screen", "--ra", "0", "--dec", "0", "--out", str(tmp_path / "x"), "--scenario", sc]
    rc = cli_main(argv + (["--tracker", tracker] if tracker else []))
    assert rc == 2
    err = capsys.readouterr().err
    assert all(w in err for w in words), err
    assert not (tmp_path / "x").exists()


def test_bench_rows_have_the_agreed_keys(monkeypatch):
    from stand.benches import render as bench_render

    geo_rows, speed_rows = bench_render.geometry_rows, bench_render.speed_rows
    monkeypatch.setattr(bench_render, "geometry_rows", lambda n: geo_rows(2))
    monkeypatch.setattr(bench_render, "speed_rows", lambda n: speed_rows(3))
    rows = bench_render.bench_render(quick=True)
    assert rows and all({"name", "value", "unit"} <= set(r) for r in rows)
    geo = {r["name"]: r for r in rows}
    assert geo["detector truth vs reference max"]["pass"]
