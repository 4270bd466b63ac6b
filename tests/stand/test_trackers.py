"""Star trackers with ``source = "image"``: scenario keys, composition, and a short closed-loop run in
which the solutions of rendered, noisy detector images cross the serial protocol."""

import copy
import itertools
import math
import tomllib

import numpy as np
import pytest

from stand import scenario, telemetry
from stand.compose import build, plan
from stand.devices.star_tracker_source import ARCSEC as ARCSEC_RAD
from stand.errors import ScenarioError
from stand.loop import run
from stand.report import write_summary
from stand.scenario import SCENARIO_DIR

IMAGE_SCENARIO = SCENARIO_DIR / "detumble_star_tracker_image.toml"
_channels = itertools.count()


@pytest.fixture
def image_dict():
    """The image-source scenario as a dict, on a CAN channel of its own."""
    data = tomllib.loads(IMAGE_SCENARIO.read_text())
    for d in data["devices"]:
        if d["kind"] == "magnetorquer":
            d["channel"] = f"test-trk-{d['name']}-{next(_channels)}"
    return data


def _tracker(data):
    return next(d for d in data["devices"] if d["kind"] == "star_tracker")


def test_image_scenario_loads_optics_and_zeroes_the_emulator_noise():
    sc = scenario.load(IMAGE_SCENARIO)
    st = sc.device("star_tracker")
    assert st.source == "image" and st.name == "st1"
    o = st.optics
    assert (o.width, o.height) == (1024, 768) and o.mag_limit == 8.0 and o.psf_sigma_px == 1.0
    assert o.fov_deg == pytest.approx((20.0, 15.0))
    assert st.camera == {"read_noise_e": 10.0, "background_e": 20.0}
    assert st.emulator["noise_cross_arcsec"] == st.emulator["noise_roll_arcsec"] == 0.0
    assert st.emulator["match_probability"] == 1.0
    # The truth-source scenario is unchanged: no optics, the emulator's noise.
    truth = scenario.load(SCENARIO_DIR / "detumble_star_tracker.toml").device("star_tracker")
    assert truth.optics is None and truth.camera is None and truth.emulator["noise_cross_arcsec"] == 2.0


def test_plan_lists_the_star_screen_only_for_image_trackers():
    image = {c.model: c for c in plan(scenario.load(IMAGE_SCENARIO))}
    assert image["star_screen"].built
    assert image["star_screen"].reason.startswith("renders the detector image of st1 (20 x 15 deg on 1024 x 768 px")
    assert "solved from its rendered detector image" in image["device.st1"].reason
    truth = {c.model: c for c in plan(scenario.load(SCENARIO_DIR / "detumble_star_tracker.toml"))}
    assert not truth["star_screen"].built and "image-source star tracker" in truth["star_screen"].reason


@pytest.mark.parametrize("key, value, allowed", [
    ("fov_deg", [20.0], "a list of 2 numbers"),
    ("fov_deg", [20.0, 100.0], "from 5 to 60"),
    ("fov_deg", [40.0, 6.0], "aspect"),
    ("resolution_px", [1024.5, 768], "whole numbers"),
    ("resolution_px", [1024, 10], "from 64 to 4096"),
    ("mag_limit", 12.0, "<= 9"),
    ("psf_sigma_px", 0.0, ">= 0.3"),
    ("read_noise_e", -1.0, ">= 0"),
    ("background_e", "dark", "a number"),
    ("noise_cross_arcsec", 2.0, "the rendered image and its camera noise"),
    ("source", "camera", "one of 'truth', 'image'"),
    ("exposure_ms", 100.0, "not known here"),
])
def test_bad_image_settings_are_named(image_dict, write_scenario, key, value, allowed):
    _tracker(image_dict)[key] = value
    with pytest.raises(ScenarioError) as info:
        scenario.load(write_scenario(image_dict))
    err = info.value
    assert err.field == f"devices[1].{key}" and err.value == value
    assert allowed in str(err) and f"devices[1].{key} = {value!r}" in str(err)


def test_optics_keys_are_refused_on_a_truth_source_tracker(image_dict, write_scenario):
    _tracker(image_dict)["source"] = "truth"
    with pytest.raises(ScenarioError, match=r"devices\[1\]\.fov_deg = \[20\.0, 15\.0\].*source = 'truth'"):
        scenario.load(write_scenario(image_dict))


def test_image_source_solutions_cross_the_serial_line_within_the_image_accuracy(image_dict, write_scenario,
                                                                                   tmp_path):
    image_dict["scenario"]["duration_s"] = 25.0
    image_dict["devices"] = [_tracker(image_dict)]  # the tracker alone: no CAN board, no B-dot
    image_dict["controller"] = {"kind": "none"}
    image_dict["criteria"] = [c for c in image_dict["criteria"] if c["metric"].startswith("tracker_error")]
    sc = scenario.load(write_scenario(image_dict))
    with build(sc) as scene:
        link = scene.devices["st1"]
        # The pattern database and the apparent places exist before the first tick.
        assert link.image is not None and link.image.tracker._dbs and link.image.counts["frames"] == 0
        result = run(scene, tmp_path / "out")
        summary = write_summary(scene, result, tmp_path / "out", plots=False)
        host = link.host.counters
        last = link.last_solution
    assert result.status == "completed"
    # The solver's own measurement reaches the flight computer: its sigmas and star counts.
    assert 0.0 < last.sigma_cross_rad < 3.0 * ARCSEC_RAD and last.sigma_roll_rad > last.sigma_cross_rad
    assert last.stars_centroided >= last.stars_matched >= 8
    st = result.counters["st1"]
    # One exposure a second from t = 1 s (boot), each rendered and solved, each published as a
    # SOLUTION frame that the host decoded; no frame was rejected on either side.
    assert st["image"]["frames"] == st["emulator_counters"]["solutions"] == 25
    assert st["image"]["failed"] == 0 and st["image"]["lis"] >= 1 and st["image"]["tracking"] >= 20
    assert host["solutions"] == st["solutions"] >= 24 and host["frames_received"] >= 24
    assert not any(v for k, v in {**host, **st["emulator_counters"]}.items() if k.startswith("rejected"))
    # Lost in space until 5 stable exposures, then valid (no Sun, Moon or Earth in this field).
    tel = telemetry.load(tmp_path / "out")
    t, valid = tel["st1.t_exposure_s"], tel["st1.valid"]
    ok = np.isfinite(t)
    _, first = np.unique(t[ok], return_index=True)
    rows = np.flatnonzero(ok)[first]
    assert np.all(valid[rows][t[rows] >= 5.0 - 1e-9] == 1.0) and np.all(valid[rows][t[rows] < 5.0 - 1e-9] == 0.0)
    # the ICD's flags byte: bit 0 (valid) as the valid column says, no Sun, Moon, Earth or rate bit
    flags = tel["st1.flags"][rows].astype(int)
    assert np.all((flags & 1) == valid[rows]) and np.all(flags & 0b11110 == 0)
    assert st["valid"] >= 19
    # Scored against the truth at each exposure: image accuracy, and not the truth itself.
    cross, roll = tel["st1.err_cross"][rows], tel["st1.err_roll"][rows]
    assert np.all(np.isfinite(cross)) and np.max(cross) < 4.0 and np.max(roll) < 30.0
    assert np.median(cross) > 0.01 and np.median(roll) > 0.05
    assert st["error_cross_arcsec"]["p95"] <= 3.0 and st["error_roll_arcsec"]["p95"] <= 15.0
    assert summary["pass"], summary["criteria"]


def _per_exposure(tel) -> dict:
    """Exposure time -> reported q_TN (telemetry repeats the newest solution until the next)."""
    t, q = tel["st1.t_exposure_s"], tel["st1.q_TN"]
    return {float(t[i]): tuple(q[i]) for i in np.flatnonzero(np.isfinite(t))}


def test_image_source_is_reproducible_and_its_camera_is_seeded(image_dict, write_scenario, tmp_path):
    image_dict["scenario"]["duration_s"] = 4.0
    image_dict["devices"] = [_tracker(image_dict)]
    image_dict["controller"] = {"kind": "none"}
    image_dict["criteria"] = []
    runs = []
    for k, seed in enumerate((1, 1, 2)):
        data = copy.deepcopy(image_dict)
        data["scenario"]["seed"] = seed
        with build(scenario.load(write_scenario(data, f"s{k}.toml"))) as scene:
            run(scene, tmp_path / f"o{k}")
        runs.append(_per_exposure(telemetry.load(tmp_path / f"o{k}")))
    # Per exposure, not per telemetry row: which tick a frame crosses the pty is up to the kernel.
    a, b, c = runs
    assert len(a) >= 2 and a == b
    common = sorted(set(a) & set(c))
    assert common and all(a[t] != c[t] for t in common)  # another seed, other camera noise
    assert math.isclose(np.linalg.norm(a[common[-1]]), 1.0, rel_tol=1e-6)  # as quantised on the wire


def test_truth_source_still_adds_the_emulator_noise(image_dict, write_scenario, tmp_path):
    """The shared Sun/Moon/Earth path with source = "truth": no image, the emulator's noise."""
    st = _tracker(image_dict)
    for key in ("source", "fov_deg", "resolution_px", "mag_limit", "psf_sigma_px", "read_noise_e", "background_e"):
        del st[key]
    st.update(output_interval_s=0.2, noise_cross_arcsec=2.0, noise_roll_arcsec=10.0)
    image_dict["scenario"]["duration_s"] = 30.0
    image_dict["devices"] = [st]
    image_dict["controller"] = {"kind": "none"}
    image_dict["criteria"] = []
    sc = scenario.load(write_scenario(image_dict))
    assert not {c.model: c for c in plan(sc)}["star_screen"].built
    with build(sc) as scene:
        assert scene.devices["st1"].image is None
        result = run(scene, tmp_path / "out")
    s = result.counters["st1"]
    # Unpaced, the loop outruns the pty's delivery now and then, so not every solution is read.
    assert result.counters["st1"]["emulator_counters"]["solutions"] == 146
    assert "image" not in s and s["valid"] >= 30 and not any(s["flags_fired"].values())
    assert 0.5 < s["error_cross_arcsec"]["median"] < 5.0 and 2.0 < s["error_roll_arcsec"]["median"] < 15.0


def test_serial_tracker_runs_are_bit_identical_and_lose_no_solution(tmp_path):
    """The pty hands bytes over asynchronously; the loop waits for each exchange, so an as-fast-as-
    possible run sees every frame on the same tick every time."""
    import dataclasses

    import numpy as np

    from stand import scenario, telemetry
    from stand.compose import build
    from stand.loop import run

    sc = dataclasses.replace(scenario.load("detumble_star_tracker"), duration_s=20.0)
    logs = []
    for k in range(2):
        with build(sc) as scene:
            run(scene, tmp_path / f"r{k}")
            link = scene.devices["st1"]
            assert link.solutions == link.emulator.counters["published"] > 90
        logs.append(telemetry.load(tmp_path / f"r{k}"))
    for name in logs[0]:
        assert np.array_equal(logs[0][name], logs[1][name], equal_nan=True), name
