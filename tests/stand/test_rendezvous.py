"""The [rendezvous] section and `stand shadow`: validation, intervals, outputs, camera."""

import json
import tomllib

import numpy as np
import pytest

from stand import scenario
from stand.cli import main
from stand.errors import ScenarioError
from stand.rendezvous import Approach, compute, find_intervals, render_camera, sample_times

SHIPPED = scenario.SCENARIO_DIR / "rendezvous_shadow.toml"


@pytest.fixture(scope="module")
def approach():
    return Approach(scenario.load(SHIPPED))


@pytest.fixture(scope="module")
def reference(approach):
    """Interval ends at a 0.5 s step, bisected to 10 us."""
    return compute(approach, step_s=0.5, refine=True, tol_s=1e-5, per_occluder=False)


@pytest.fixture
def rdv_dict():
    return tomllib.loads(SHIPPED.read_text())


def _ends(res, which):
    return np.array([getattr(iv, which) for iv in res.intervals if not getattr(iv, which.replace("_s", "_open"))])


def test_shipped_scenario_parses_and_others_have_no_rendezvous():
    sc = scenario.load(SHIPPED)
    r = sc.rendezvous
    assert r.trajectory == "line" and r.plate.marks_m.shape == (8, 2)
    assert [o.name for o in r.target_bodies] == ["target front cone", "target antenna box"]
    assert len(r.chaser_bodies) == 4 and r.camera.resolution_px == (480, 360)
    assert scenario.load(scenario.DEFAULT_SCENARIO).rendezvous is None


def test_check_lists_the_rendezvous(capsys):
    assert main(["check", "rendezvous_shadow"]) == 0
    out = capsys.readouterr().out
    assert "valid" in out and "rendezvous.shadow" in out and "stand shadow" in out


@pytest.mark.parametrize("path, value, field, allowed", [
    (("chaser", "trajectory"), "spiral", "rendezvous.chaser.trajectory", "'line', 'cw', 'kepler'"),
    (("step_s",), 0.0, "rendezvous.step_s", ">= 0.001"),
    (("sun",), "lamp", "rendezvous.sun", "'disk', 'point'"),
    (("target", "plate", "mark_radius_m"), 2.0, "rendezvous.target.plate.mark_radius_m", "<= 0.6"),
    (("target", "plate", "marks_m"), [[0.59, 0.0]], "rendezvous.target.plate.marks_m", "lie on the plate"),
    (("target", "plate", "marks_m"), [[0.1]], "rendezvous.target.plate.marks_m", "mark centres [x, y]"),
    (("target", "q_TL"), [1.0, 1.0, 0.0, 0.0], "rendezvous.target.q_TL", "unit quaternion"),
    (("chaser", "v0_m_s"), [1.0, 0.0, 0.0], "rendezvous.chaser.v0_m_s", "in front of the plate"),
    (("chaser", "r0_m"), [-3.0, 0.0, 0.0], "rendezvous.chaser.r0_m", "in front of the plate"),
    (("camera", "times_s"), [700.0], "rendezvous.camera.times_s", "in [0, 600] s"),
    (("target", "bodies", 0, "kind"), "sphere", "rendezvous.target.bodies[0].kind", "'frustum', 'cone'"),
    (("target", "bodies", 0, "axis"), [0.0, 0.0, 0.0], "rendezvous.target.bodies[0].axis", "non-zero"),
    (("chaser", "bodies", 2, "edge_v_m"), [0.0, 2.0, 0.0], "rendezvous.chaser.bodies[2].edge_v_m",
     "not parallel"),
    (("chaser", "bodies", 0, "lenght_m"), 3.0, "rendezvous.chaser.bodies[0].lenght_m", "not known here"),
    (("colour",), "red", "rendezvous.colour", "not known here"),
])
def test_bad_rendezvous_values_are_named(rdv_dict, write_scenario, path, value, field, allowed):
    node = rdv_dict["rendezvous"]
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    with pytest.raises(ScenarioError) as info:
        scenario.load(write_scenario(rdv_dict))
    assert info.value.field == field
    assert allowed in str(info.value)


def test_cw_is_refused_for_an_eccentric_target(rdv_dict, write_scenario):
    rdv_dict["rendezvous"]["chaser"]["trajectory"] = "cw"
    del rdv_dict["orbit"]["altitude_km"]
    rdv_dict["orbit"].update(a_km=7000.0, e=0.02)
    with pytest.raises(ScenarioError, match="'kepler'") as info:
        scenario.load(write_scenario(rdv_dict))
    assert info.value.field == "rendezvous.chaser.trajectory"


def test_find_intervals_unrefined_and_bisected():
    true = [(3.3, 7.05), (12.6, 12.9), (17.2, 25.0)]

    def fn(t):
        t = np.asarray(t)
        return np.any([(t >= a) & (t < b) for a, b in true], axis=0)

    t = sample_times(20.0, 0.5)
    raw = find_intervals(t, fn(t))
    # Each end at the first sample past it; the 0.3 s interval between two samples is not seen.
    assert raw == [(3.5, 7.5, False, False), (17.5, 20.0, False, True)]
    fine = find_intervals(t, fn(t), fn, 1e-6)
    assert len(fine) == 2
    assert fine[0][:2] == pytest.approx(true[0], abs=1e-6)
    assert fine[1][0] == pytest.approx(17.2, abs=1e-6) and fine[1][1] == 20.0 and fine[1][3]


def test_interval_ends_are_within_one_step_and_converge(approach, reference):
    starts_ref, ends_ref = _ends(reference, "start_s"), _ends(reference, "end_s")
    assert len(starts_ref) + len(ends_ref) >= 4
    worst = {}
    for h in (8.0, 4.0, 2.0):
        res = compute(approach, step_s=h, refine=False, per_occluder=False)
        s, e = _ends(res, "start_s"), _ends(res, "end_s")
        assert len(s) == len(starts_ref) and len(e) == len(ends_ref)
        # Unrefined: each end is the first sample past the change, so late by less than one step.
        late = np.concatenate((s - starts_ref, e - ends_ref))
        assert np.all(late >= -1e-4) and np.all(late < h + 1e-4)
        worst[h] = late.max()
        fine = compute(approach, step_s=h, refine=True, tol_s=1e-3, per_occluder=False)
        err = np.concatenate((_ends(fine, "start_s") - starts_ref, _ends(fine, "end_s") - ends_ref))
        assert np.max(np.abs(err)) <= 5e-4 + 1e-5
    assert worst[2.0] <= worst[8.0] and worst[2.0] < 2.0


def test_obscuration_causes_and_earth_shadow(approach):
    res = compute(approach, step_s=4.0, refine=False)
    causes = {c for iv in res.intervals for c in iv.causes}
    assert "target front cone" in causes and any(c.startswith("chaser panel") for c in causes)
    st = res.samples
    peak = int(np.argmax(st["obscured_percent"]))
    assert st["obscured_percent"][peak] == pytest.approx(100.0)
    # Each body's share alone never exceeds the total, and the total never exceeds their sum.
    share = st["occluder_percent"]
    assert np.all(share <= st["obscured_percent"] + 1e-9)
    assert np.all(st["obscured_percent"] <= share.sum(axis=0) + 1e-9)
    assert len(res.eclipses) == 1 and res.eclipses[0].end_open and 500.0 < res.eclipses[0].start_s < 580.0


def test_camera_sees_the_plate_on_its_axis_and_the_shadow_darkens_it(approach):
    far = render_camera(approach, 0.0)
    h, w = far.shape
    assert (h, w) == (360, 480)
    assert far[h // 2 - 2:h // 2 + 2, w // 2 - 2:w // 2 + 2].min() > 0.05  # the target is on the boresight
    assert far[:20, :20].max() == 0.0 and far[-20:, -20:].max() == 0.0  # black sky in the corners
    lit, dark = render_camera(approach, 300.0), render_camera(approach, 235.0)
    st = approach.evaluate([235.0, 300.0])
    assert st["obscured_percent"][0] == pytest.approx(100.0) and st["obscured_percent"][1] < 1.0
    seen = lit > 0
    assert dark[seen].mean() < 0.3 * lit[seen].mean()


def test_stand_shadow_writes_every_output(tmp_path, capsys):
    out = tmp_path / "shadow"
    code = main(["shadow", "rendezvous_shadow", "--out", str(out), "--step", "4", "--refine", "off",
                 "--camera-times", "10,300"])
    assert code == 0
    text = capsys.readouterr().out
    assert "obscured 1:" in text and "Earth shadow" in text
    summary = json.loads((out / "summary.json").read_text())
    for name in summary["outputs"]:
        assert (out / name).stat().st_size > 0
    assert {"camera_000010.0s.png", "camera_000300.0s.png", "tracks.png", "obscured.png"} <= set(summary["outputs"])
    rows = (out / "obscuration.csv").read_text().splitlines()
    header = rows[0].split(",")
    assert len(rows) == 1 + 151 and header[:2] == ["t_s", "obscured_percent"]
    pct = np.array([float(r.split(",")[1]) for r in rows[1:]])
    assert pct.max() == pytest.approx(summary["max_obscured_percent"], abs=1e-5)
    assert "| 1 |" in (out / "report.md").read_text()
    assert main(["shadow", "rendezvous_shadow", "--out", str(out)]) == 2  # never overwrites


@pytest.mark.parametrize("argv, text", [
    (["shadow", "detumble"], "rendezvous"),
    (["shadow", "rendezvous_shadow", "--step", "0"], "--step"),
    (["shadow", "rendezvous_shadow", "--camera-times", "5,x"], "--camera-times"),
])
def test_shadow_usage_errors_exit_2(argv, text, capsys, tmp_path):
    assert main([*argv, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert text in err and err.count("\n") == 1


def test_bench_shadow_quick_rows():
    from stand.benches import run_bench

    rows = run_bench("shadow", quick=True)
    names = [r["name"] for r in rows]
    assert "shadow.unrefined.step_8s.max_end_error" in names and "shadow.refined.step_2s.max_end_error" in names
    assert all(r["pass"] for r in rows if "pass" in r)


def test_cw_and_kepler_approaches_agree_and_the_chaser_points_at_the_plate(rdv_dict, write_scenario):
    from sim.relative_motion import cw_state, mean_motion

    t = np.linspace(0.0, 600.0, 61)
    paths = {}
    for kind in ("cw", "kepler"):
        rdv_dict["rendezvous"]["chaser"]["trajectory"] = kind
        sc = scenario.load(write_scenario(rdv_dict, f"{kind}.toml"))
        st = Approach(sc).states(t)
        paths[kind] = st["r_CL_L"]
        to_plate = np.array([-5.0, 0.0, 0.0]) - st["r_CL_L"]
        np.testing.assert_allclose(st["dcm_CL"][:, 0], to_plate / np.linalg.norm(to_plate, axis=1, keepdims=True),
                                   atol=1e-12)
    r0, v0 = np.array([-65.0, 0.0, 0.0]), np.array([0.09, 0.0, 0.0])
    np.testing.assert_allclose(paths["cw"], cw_state(r0, v0, t, mean_motion(sc.orbit.a_m))[0])
    # 60 m from the target the linearisation is good to well under a centimetre in ten minutes.
    assert np.max(np.linalg.norm(paths["cw"] - paths["kepler"], axis=1)) < 0.01
    assert np.max(np.abs(paths["cw"][:, 2])) > 10.0  # free flight: not the straight V-bar line
