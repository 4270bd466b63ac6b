"""The tracker bench's same-sitting tetra3rs anchor, without tetra3rs: the centroid file, the conversion the
script makes of it, the rows from a canned run, and the rows when the anchor was not run. Nothing here is timed."""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest

from sim.rotations import dcm, quat_from_axis_angle
from stand.benches import _judged
from stand.benches import tracker as bench
from star_screen.geometry import TrackerOptics
from star_screen.tracking.extract import ExtractedStars


def _script():
    spec = importlib.util.spec_from_file_location("tetra3rs_solve", bench.TETRA3RS_SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _stars(xy, flux):
    return ExtractedStars(np.asarray(xy, float), np.asarray(flux, float), np.ones(len(flux)), 20.0, 10.0)


def test_centroid_file_round_trip_and_tetra3rs_convention(tmp_path):
    optics = TrackerOptics()
    frames = [_stars([[512.0, 384.0], [0.5, 0.5], [1023.5, 767.5]], [900.0, 500.0, 100.0]),
              _stars(np.zeros((0, 2)), []),
              _stars([[612.0, 284.0]], [42.0])]
    path = tmp_path / "c.npz"
    bench.export_centroids(path, frames, optics)
    script = _script()
    data = script.load_centroids(path)
    assert data["offsets"].tolist() == [0, 3, 3, 4]
    assert data["xy_px"].tolist() == [[512.0, 384.0], [0.5, 0.5], [1023.5, 767.5], [612.0, 284.0]]
    assert (int(data["width"]), int(data["height"])) == (1024, 768)
    conv = script.to_tetra3rs(data)
    assert [len(c) for c in conv] == [3, 0, 1]
    # The stand's principal point (512, 384), its image centre, is tetra3rs's origin; y is scaled to fx's focal
    # length: the same direction through a pinhole of focal length fx.
    k = optics.fx / optics.fy
    assert conv[0][0].tolist() == [0.0, 0.0, 900.0]
    assert conv[0][1].tolist() == pytest.approx([-511.5, -383.5 * k, 500.0], abs=1e-12)
    assert conv[2][0].tolist() == pytest.approx([100.0, -100.0 * k, 42.0], abs=1e-12)
    d = optics.unproject(np.array([[612.0, 284.0]]))[0]
    assert conv[2][0][0] / optics.fx == pytest.approx(d[0] / d[2], rel=1e-12)
    assert conv[2][0][1] / optics.fx == pytest.approx(d[1] / d[2], rel=1e-12)


def test_centroid_file_of_another_format_is_refused(tmp_path):
    path = tmp_path / "c.npz"
    np.savez(path, format=99, xy_px=np.zeros((0, 2)), flux=np.zeros(0), offsets=np.zeros(1, np.int64))
    with pytest.raises(ValueError, match="centroid format 99"):
        _script().load_centroids(path)


def _truth(n):
    rng = np.random.default_rng(3)
    q = rng.normal(size=(n, 4))
    return dcm(q / np.linalg.norm(q, axis=1, keepdims=True))


def _canned_run(C, warm_ms, cold_ms, off_arcsec):
    """A tetra3rs JSON as the script writes it: frame 0 solved 30 arcsec off by a matrix orthonormal to 2e-7
    only (as tetra3rs's are), frame 1 solved ``off_arcsec`` off, frame 2 not solved."""
    def turn(arcsec):
        return dcm(quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), math.radians(arcsec / 3600.0)))

    rot = [((1.0 - 2e-7) * turn(30.0) @ C[0]).tolist(), (turn(off_arcsec) @ C[1]).tolist(), None]
    p = {"solved": [True, True, False], "R_camera_icrs": rot, "status": ["match_found", "match_found", "no_match"]}
    return {"tetra3rs_version": "0.14.0", "mag_limit_G": 8.0,
            "warm": dict(p, cpu_s=[t * 1e-3 for t in warm_ms]), "cold": dict(p, cpu_s=[t * 1e-3 for t in cold_ms])}


def test_rows_from_a_canned_run_compare_like_with_like():
    C = _truth(3)
    own = {"warm": [[0.2e-3, 0.3e-3, 0.4e-3], [0.3e-3, 0.3e-3, 0.3e-3]],
           "cold": [[0.5e-3, 0.6e-3, 0.7e-3], [0.6e-3, 0.6e-3, 0.6e-3]]}
    runs = [_canned_run(C, [0.15, 0.15, 0.15], [0.9, 0.9, 0.9], 120.0),
            _canned_run(C, [0.15, 0.15, 0.15], [0.9, 0.9, 0.9], 120.0)]
    rows = {r["name"]: r for r in bench.anchor_rows(own, runs, C)}
    assert rows["tracker.lis.warm_median"]["value"] == 0.3
    assert rows["tracker.lis.tetra3rs_warm_median"]["value"] == 0.15
    assert rows["tracker.lis.cold_median"]["value"] == 0.6
    assert rows["tracker.lis.tetra3rs_cold_median"]["value"] == 0.9
    # warm against warm: tetra3rs twice as fast fails the goal; cold against cold passes it.
    assert rows["tracker.lis.vs_tetra3rs"]["value"] == 0.5 and rows["tracker.lis.vs_tetra3rs"]["pass"] is False
    assert rows["tracker.lis.vs_tetra3rs_cold"]["value"] == 1.5
    assert rows["tracker.lis.vs_tetra3rs_cold"]["pass"] is True
    # Speeds: --quick (one round of 100 frames) shows them without judging them.
    quick = _judged(dict(rows["tracker.lis.vs_tetra3rs_cold"]), quick=True)
    assert "pass" not in quick and quick["limit"] == ">= 1.0 (judged on the full run only)"
    # Frame 0 is a success (the trace of its matrix alone would put it 2.7 arcmin off); frame 1 is 2 arcmin off:
    # a false solve, not a success; frame 2 a failure.
    ok = rows["tracker.lis.tetra3rs_success_rate"]
    assert ok["value"] == pytest.approx(100.0 / 3, abs=0.01)
    assert "false solves 1" in ok["note"] and "1 no_match" in ok["note"]


def test_rows_without_the_anchor_say_it_was_not_run():
    own = {"warm": [[0.2e-3, 0.3e-3, 0.4e-3]], "cold": []}
    rows = {r["name"]: r for r in bench.anchor_rows(own, [], _truth(3))}
    assert rows["tracker.lis.warm_median"]["value"] == 0.3
    for name in ("tracker.lis.vs_tetra3rs", "tracker.lis.vs_tetra3rs_cold", "tracker.lis.tetra3rs_warm_median",
                 "tracker.lis.tetra3rs_cold_median", "tracker.lis.tetra3rs_success_rate"):
        assert math.isnan(rows[name]["value"])
        assert "pass" not in rows[name]
        assert rows[name]["note"].startswith("not run: set STAND_TETRA3RS_PYTHON")


def test_a_run_of_other_frames_is_refused():
    C = _truth(3)
    run = _canned_run(C, [0.1] * 3, [0.1] * 3, 0.0)
    own = {"warm": [[1e-3] * 3], "cold": [[1e-3] * 3]}
    with pytest.raises(RuntimeError, match="solved 3 frames; the bench gave it 4"):
        bench.anchor_rows(own, [run], _truth(4))


def test_image_workload_is_the_one_both_sides_run():
    script = _script()
    assert bench._image_workload().__code__.co_code == script.image_workload.__code__.co_code
    # It returns the count of pixels above its threshold, so its work cannot be dropped as unused.
    n = script.image_workload(np.random.default_rng(0), 64, 48)
    assert isinstance(n, int) and 0 <= n <= 64 * 48
