"""`stand screen` end to end: files, truth content, errors, and the bench rows' shape."""

import json

import numpy as np
import pytest

from stand import screen_command
from star_screen.attitude import q_SN_from_radec_roll


def test_screen_writes_png_and_truth(tmp_path):
    cv2 = pytest.importorskip("cv2")
    out = tmp_path / "frame"
    rc = screen_command.main(["screen", "--ra", "83.8", "--dec", "-5.4", "--roll", "15", "--out", str(out)])
    assert rc == 0
    scr = cv2.imread(str(out / "screen.png"), cv2.IMREAD_UNCHANGED)
    det = cv2.imread(str(out / "detector.png"), cv2.IMREAD_UNCHANGED)
    assert scr.shape == (1080, 1920) and scr.dtype == np.uint8 and scr.max() > 200
    assert det.shape == (768, 1024) and det.dtype == np.uint16
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
    assert screen_command.main(args + [str(a)]) == 0
    assert screen_command.main(args + [str(b), "--aberration", "off"]) == 0
    ta = {s["hip"]: s["detector_xy"] for s in json.loads((a / "truth.json").read_text())["stars"]}
    tb = {s["hip"]: s["detector_xy"] for s in json.loads((b / "truth.json").read_text())["stars"]}
    common = sorted(set(ta) & set(tb))
    d = np.array([np.hypot(*np.subtract(ta[h], tb[h])) for h in common]) * 70.3  # arcsec
    assert 3.0 < np.median(d) < 25.0


@pytest.mark.parametrize(
    "argv, word",
    [
        (["--ra", "0", "--dec", "95"], "dec"),
        (["--ra", "0", "--dec", "0", "--scenario", "x.toml"], "not yet supported"),
        (["--ra", "0", "--dec", "0", "--screen", "big"], "--screen"),
        (["--ra", "0", "--dec", "0", "--epoch", "yesterday"], "ISO 8601"),
    ],
)
def test_usage_errors_exit_2_with_a_message(tmp_path, capsys, argv, word):
    rc = screen_command.main(["screen", *argv, "--out", str(tmp_path / "x")])
    assert rc == 2
    assert word in capsys.readouterr().err


def test_bench_rows_have_the_agreed_keys(monkeypatch):
    from stand import bench_render

    geo_rows, speed_rows = bench_render.geometry_rows, bench_render.speed_rows
    monkeypatch.setattr(bench_render, "geometry_rows", lambda n: geo_rows(2))
    monkeypatch.setattr(bench_render, "speed_rows", lambda n: speed_rows(3))
    rows = bench_render.bench_render(quick=True)
    assert rows and all({"name", "value", "unit"} <= set(r) for r in rows)
    geo = {r["name"]: r for r in rows}
    assert geo["detector truth vs reference max"]["pass"]
