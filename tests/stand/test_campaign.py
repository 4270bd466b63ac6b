"""Campaigns: dispersion files, per-case seeds, the built scene, resumption, failures, executors, re-runs."""

import json
import math

import numpy as np
import pytest

from sim.rotations import dcm
from stand import campaign as cm
from stand.cli import main
from stand.compose import build
from stand.scenario import SCENARIO_DIR, parse

SHIPPED = SCENARIO_DIR / "detumble_dispersions.toml"
SHORT_S = 20.0


def spec_for(write_scenario, scenario_dict, dispersions: str, tmp_path, **kw):
    path = write_scenario(scenario_dict)
    dfile = tmp_path / "dispersions.toml"
    dfile.write_text(dispersions)
    return cm.make_spec(str(path), dfile, **kw)


# ------------------------------------------------------------------------------------ the dispersion file
@pytest.mark.parametrize("entry, needle", [
    ('field = "spacecraft.inertia_kg_m2"\ndistribution = "gauss"\nsigma = 0.1',
     "dispersions[0] (spacecraft.inertia_kg_m2).distribution = 'gauss' is not allowed: one of 'normal'"),
    ('field = "devices.nope.mag_noise_nT"\ndistribution = "uniform"\nmin = 0.0\nmax = 1.0',
     "devices has no entry named 'nope' (entries: mtq)"),
    ('field = "orbit.drag.cd"\ndistribution = "uniform"\nmin = 2.0\nmax = 2.4',
     "the scenario has no orbit.drag"),
    ('field = "spacecraft.omega_BN_B_deg_s"\ndistribution = "normal"\nsigma = [1.0, 2.0]',
     "sigma = [1.0, 2.0] is not allowed: a number or a list of shape [3] (one per axis)"),
    ('field = "spacecraft.omega_BN_B_deg_s"\ndistribution = "uniform"\nmin = 5.0\nmax = 1.0',
     ".max = 1.0 is not allowed: a bound above min"),
    ('field = "devices.mtq.mag_noise_nT"\ndistribution = "normal"\nsigma = -1.0',
     "sigma = -1.0 is not allowed: a number >= 0"),
    ('field = "spacecraft.mass_kg"\ndistribution = "rotation"\nsigma_deg = 1.0',
     "is not a unit quaternion [w, x, y, z]"),
    ('field = "spacecraft.mass_kg"\ndistribution = "normal"\nsigma = 0.1\nsigma_pct = 3',
     "sigma_pct = 3 is not allowed: a key a normal dispersion takes: mean, sigma, sigma_percent, min, max"),
    ('field = "scenario.epoch"\ndistribution = "normal"\nsigma = 1.0',
     "is not a number or a list of numbers; a normal dispersion draws numbers (use distribution = 'choice'"),
    ('field = "scenario.epoch"\ndistribution = "choice"\nvalues = []',
     "values = [] is not allowed: a non-empty list"),
    ('field = "scenario.seed"\ndistribution = "uniform"\nmin = 0\nmax = 9\ninteger = true',
     "scenario.seed and scenario.duration_s are set by the campaign"),
])
def test_a_bad_dispersion_is_refused_with_its_field_and_what_is_allowed(scenario_dict, entry, needle):
    with pytest.raises(cm.CampaignError) as e:
        cm.parse_dispersions("[[dispersions]]\n" + entry, scenario_dict, "d.toml")
    assert needle in str(e.value)


def test_a_value_the_scenario_refuses_stops_the_campaign_before_any_run(scenario_dict, write_scenario, tmp_path):
    # The file is well formed; the scenario's own validation refuses the drawn noise (it must be >= 0).
    spec = spec_for(write_scenario, scenario_dict, '[[dispersions]]\nfield = "devices.mtq.mag_noise_nT"\n'
                    'distribution = "uniform"\nmin = -50.0\nmax = -10.0\n', tmp_path, duration_s=SHORT_S)
    with pytest.raises(cm.CampaignError) as e:
        cm.run_campaign(spec, tmp_path / "out", 3, workers=0)
    text = str(e.value)
    assert text.startswith("case 0: dispersions[0] (devices.mtq.mag_noise_nT, uniform, in dispersions.toml) drew")
    assert "devices[0].mag_noise_nT" in text and ">= 0" in text
    assert not (tmp_path / "out").exists()


def test_the_shipped_dispersion_file_is_valid_and_not_a_scenario():
    from stand.scenario import loads, shipped

    data = loads((SCENARIO_DIR / "detumble.toml").read_text())
    disp = cm.parse_dispersions(SHIPPED.read_text(), data, SHIPPED.name)
    assert {d.field for d in disp.items} >= {"spacecraft.inertia_kg_m2", "spacecraft.omega_BN_B_deg_s",
                                              "devices.mtq.mag_noise_nT", "devices.mtq.mag_bias_nT",
                                              "devices.mtq.q_SB", "scenario.epoch"}
    assert "detumble_dispersions" not in shipped()


# ------------------------------------------------------------------------------------------ seeds, draws
def test_a_case_depends_on_the_campaign_seed_and_its_index_only():
    from stand.scenario import loads

    data = loads((SCENARIO_DIR / "detumble.toml").read_text())
    disp = cm.parse_dispersions(SHIPPED.read_text(), data, SHIPPED.name)
    a = [cm.case_values(disp, 7, k) for k in range(6)]
    assert cm.case_values(disp, 7, 4) == a[4]  # alone, after others: the same
    assert len({json.dumps(v) for v in a}) == 6
    assert cm.case_values(disp, 8, 4) != a[4]
    # A dispersion added at the end leaves the earlier ones' draws unchanged.
    more = cm.parse_dispersions(SHIPPED.read_text() + '[[dispersions]]\nfield = "spacecraft.mass_kg"\n'
                                'distribution = "uniform"\nmin = 3.0\nmax = 5.0\n', data, "more.toml")
    seed4, values4 = cm.case_values(more, 7, 4)
    assert seed4 == a[4][0] and all(values4[f] == v for f, v in a[4][1].items())


def test_draws_follow_their_distributions():
    data = {"x": {"v": 1.0, "w": [0.0, 0.0, 0.0], "q": [1.0, 0.0, 0.0, 0.0], "e": "a"}}
    text = """
[[dispersions]]
field = "x.v"
distribution = "normal"
sigma = 0.5
min = 0.5
[[dispersions]]
field = "x.w"
distribution = "uniform"
min = [-1.0, 0.0, 10.0]
max = [1.0, 2.0, 11.0]
[[dispersions]]
field = "x.q"
distribution = "rotation"
sigma_deg = [1.0, 2.0, 3.0]
[[dispersions]]
field = "x.e"
distribution = "choice"
values = ["a", "b"]
weights = [3.0, 1.0]
"""
    disp = cm.parse_dispersions(text, data)
    draws = [cm.case_values(disp, 1, k)[1] for k in range(4000)]
    v = np.array([d["x.v"] for d in draws])
    assert v.min() >= 0.5
    # Normal(1, 0.5) truncated below at 0.5 (a = -1): mean 1 + 0.5 * phi(-1) / (1 - Phi(-1)) = 1.1438.
    assert abs(v.mean() - 1.1438) < 0.02
    w = np.array([d["x.w"] for d in draws])
    assert np.all(w >= [-1.0, 0.0, 10.0]) and np.all(w <= [1.0, 2.0, 11.0])
    assert np.allclose(w.mean(axis=0), [0.0, 1.0, 10.5], atol=0.03)
    q = np.array([d["x.q"] for d in draws])
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    # Small rotation vector ~ N(0, diag(sigma^2)) per axis: recover each axis's sigma from the quaternion.
    rotvec_deg = np.degrees(2 * q[:, 1:])
    assert np.allclose(rotvec_deg.std(axis=0), [1.0, 2.0, 3.0], rtol=0.05)
    frac_b = np.mean([d["x.e"] == "b" for d in draws])
    assert abs(frac_b - 0.25) < 0.03


def test_clopper_pearson_matches_its_closed_forms():
    # k = 0: upper = 1 - (alpha/2)^(1/n); k = n: lower = (alpha/2)^(1/n).
    assert cm.clopper_pearson(0, 10) == (0.0, pytest.approx(1 - 0.025 ** 0.1, rel=1e-9))
    assert cm.clopper_pearson(10, 10) == (pytest.approx(0.025 ** 0.1, rel=1e-9), 1.0)
    lo, hi = cm.clopper_pearson(50, 100)
    assert lo == pytest.approx(0.3983, abs=1e-4) and hi == pytest.approx(0.6017, abs=1e-4)


# ----------------------------------------------------------------------- dispersed values reach the scene
def _scene_probe(field: str, scene):
    dev = scene.devices.get("mtq")
    return {
        "spacecraft.inertia_kg_m2": lambda: np.diag(scene.truth.body.inertia),
        "spacecraft.omega_BN_B_deg_s": lambda: np.degrees(scene.truth.w),
        "devices.mtq.mag_noise_nT": lambda: dev.emulator.config.mag_noise_T * 1e9,
        "devices.mtq.mag_bias_nT": lambda: np.asarray(dev.emulator.config.mag_bias_T) * 1e9,
        # What the emulated magnetometer measures: the truth field in its (misaligned) sensor frame.
        "devices.mtq.q_SB": lambda: np.asarray(dev.emulator.field_source(0.0)),
        "environment.era0_deg": lambda: np.asarray(scene.truth.b_B()),
        "scenario.epoch": lambda: np.asarray(scene.truth.b_B()),
    }[field]()


def _expected(field: str, value, scene):
    if field == "devices.mtq.q_SB":
        return dcm(np.asarray(value)) @ np.asarray(scene.truth.b_B())
    return value


@pytest.mark.parametrize("overrides", [[], ["environment.magnetic_field=igrf", "environment.earth_rotation=iau2006",
                                            "environment.eop=none"]], ids=["dipole", "igrf"])
def test_each_dispersed_field_changes_the_scene_that_runs(scenario_dict, write_scenario, tmp_path, overrides):
    text = SHIPPED.read_text()
    if overrides:  # era0_deg is unused under IAU 2006: the scenario refuses its dispersion there (last entry)
        text = text[:text.index('[[dispersions]]\nfield = "environment.era0_deg"')]
    spec = spec_for(write_scenario, scenario_dict, text, tmp_path, overrides=overrides, duration_s=SHORT_S)
    disp = spec.dispersions()
    nominal = parse(spec.scenario_dict(), "nominal")
    task = spec.case(3, disp)
    # In the comparison detumble (centred dipole, uniform Earth rotation from era0 at the epoch) the epoch moves
    # nothing the run uses and era0 turns the Earth; with IGRF and the IAU 2006 Earth it is the other way round.
    inert = "environment.era0_deg" if overrides else "scenario.epoch"
    fields = [d.field for d in disp.items if d.field != inert]
    assert len(fields) == 6
    with build(nominal) as base:
        for field in fields:
            # A case whose value differs from the scenario's (a choice may draw the scenario's own epoch).
            value = next(v for k in range(3, 40) if (v := spec.case(k, disp)["values"][field])
                         != cm.get_field(spec.scenario_dict(), field))
            alone = cm.apply(spec.scenario_dict(), {field: value}, task["seed"], SHORT_S)
            with build(parse(alone, "case")) as scene:
                got, before = _scene_probe(field, scene), _scene_probe(field, base)
                assert not np.allclose(got, before, rtol=1e-12, atol=0), field
                if field not in ("environment.era0_deg", "scenario.epoch"):
                    assert np.allclose(got, _expected(field, value, scene), rtol=1e-12), field
    # All together, as the worker runs it: the case's own seed too.
    sc = parse(task["data"], task["source"])
    assert sc.seed == task["seed"] != nominal.seed
    with build(sc) as scene:
        assert np.allclose(np.degrees(scene.truth.w), task["values"]["spacecraft.omega_BN_B_deg_s"])


def test_the_epoch_changes_nothing_the_comparison_detumble_uses(scenario_dict, write_scenario, tmp_path):
    """Said in the dispersion file and docs: era0_deg, not the epoch, turns the Earth in that scene."""
    spec = spec_for(write_scenario, scenario_dict, SHIPPED.read_text(), tmp_path, duration_s=SHORT_S)
    a = cm.apply(spec.scenario_dict(), {"scenario.epoch": "2026-03-20T12:00:00Z"}, 1, SHORT_S)
    b = cm.apply(spec.scenario_dict(), {"scenario.epoch": "2026-09-22T18:00:00Z"}, 1, SHORT_S)
    with build(parse(a)) as sa, build(parse(b)) as sb:
        assert np.array_equal(sa.truth.b_B(), sb.truth.b_B())


# ------------------------------------------------------------------------------------ running campaigns
FAST = """
[[dispersions]]
field = "spacecraft.omega_BN_B_deg_s"
distribution = "uniform"
min = [-12.0, -12.0, -12.0]
max = [12.0, 12.0, 12.0]
[[dispersions]]
field = "devices.mtq.mag_noise_nT"
distribution = "uniform"
min = 0.0
max = 300.0
"""


def _fast_spec(scenario_dict, write_scenario, tmp_path, extra: str = ""):
    # A rate limit some cases meet and some do not after 20 s.
    scenario_dict["criteria"][0]["max"] = 12.0
    return spec_for(write_scenario, scenario_dict, FAST + extra, tmp_path, duration_s=SHORT_S)


def test_a_campaign_writes_its_cases_aggregates_and_resumes(scenario_dict, write_scenario, tmp_path):
    spec = _fast_spec(scenario_dict, write_scenario, tmp_path)
    out = tmp_path / "camp"
    first = cm.run_campaign(spec, out, 3, workers=0, plots=False)
    assert first["finished"] == 3 and first["execution"]["runs_this_session"] == 3
    for k in range(3):
        d = cm.case_dir(out, k)
        rec = json.loads((d / "case.json").read_text())
        summary = json.loads((d / "summary.json").read_text())
        assert rec["index"] == k and (d / "telemetry" / "rows.f64").stat().st_size > 0
        assert summary["sim_duration_s"] == pytest.approx(SHORT_S)
        # The recorded initial rate is the dispersed one.
        from stand.telemetry import load

        w0 = np.degrees(load(d)["omega_BN_B"][0])
        assert np.allclose(w0, rec["values"]["spacecraft.omega_BN_B_deg_s"], rtol=1e-12)
    stamps = {k: (cm.case_dir(out, k) / "case.json").stat().st_mtime_ns for k in range(3)}
    more = cm.run_campaign(spec, out, 5, workers=0)
    assert more["execution"]["runs_this_session"] == 2 and more["execution"]["resumed"] == 3
    assert {k: (cm.case_dir(out, k) / "case.json").stat().st_mtime_ns for k in range(3)} == stamps
    assert more["finished"] == 5 and [c["case"] for c in more["cases"]] == list(range(5))
    values = [c["criteria"]["detumbled"] for c in more["cases"]]
    passed = sum(v <= 12.0 for v in values)
    assert more["criteria"]["detumbled"]["passed"] == passed
    assert 0 < passed < 5, "the fixture should give a mixed campaign"
    lo, hi = more["criteria"]["detumbled"]["ci95"]
    assert lo <= passed / 5 <= hi
    assert more["worst_cases"][0]["case"] == int(np.argmax(values))
    assert more["metrics"]["detumbled"]["max"] == max(values)
    report = (out / "report.md").read_text()
    assert "Pass rate" in report and (out / "metrics.png").is_file() and (out / "scatter_0.png").is_file()
    # Another campaign may not write into this folder.
    other = cm.make_spec(spec.scenario_base + "/" + spec.scenario_name, tmp_path / "dispersions.toml", seed=99,
                         duration_s=SHORT_S)
    with pytest.raises(cm.CampaignError, match="holds another campaign"):
        cm.run_campaign(other, out, 3, workers=0)


@pytest.mark.slow
def test_a_failing_run_is_recorded_and_the_others_go_on(scenario_dict, write_scenario, tmp_path):
    (tmp_path / "fragile.py").write_text(
        "class Fragile:\n"
        "    def __init__(self, devices, period_s, explode):\n"
        "        if explode:\n"
        "            raise RuntimeError('the flight code refused to start')\n"
        "    def update(self, t_s):\n"
        "        pass\n")
    scenario_dict["controller"] = {"kind": "plugin", "rate_hz": 5.0, "module": "fragile:Fragile",
                                   "path": str(tmp_path), "options": {"explode": False}}
    spec = _fast_spec(scenario_dict, write_scenario, tmp_path, '[[dispersions]]\nfield = "controller.options.explode"'
                      '\ndistribution = "choice"\nvalues = [false, true]\n')
    disp = spec.dispersions()
    explode = [cm.case_values(disp, spec.seed, k)[1]["controller.options.explode"] for k in range(4)]
    assert any(explode) and not all(explode)
    result = cm.run_campaign(spec, tmp_path / "camp", 4, workers=2, plots=False)
    assert result["finished"] == 4
    for c in result["cases"]:
        assert (c["status"] == "error") == explode[c["case"]]
    errors = [f for f in result["failed_cases"] if f["status"] == "error"]
    assert len(errors) == sum(explode) == result["errors"]
    assert all("the flight code refused to start" in f["error"] for f in errors)


@pytest.fixture
def port_8787_held():
    """Port 8787 (Dask's default dashboard port) taken, as on a machine where a notebook or another cluster runs:
    bound here on 127.0.0.1, or already held by another program, which serves as well."""
    import errno
    import socket

    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        sock.bind(("127.0.0.1", 8787))
        sock.listen(1)
    except OSError as exc:
        if exc.errno != errno.EADDRINUSE:
            raise
    probe = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    with pytest.raises(OSError):
        probe.bind(("127.0.0.1", 8787))
    probe.close()
    yield
    sock.close()


@pytest.mark.slow
def test_local_pool_and_dask_local_cluster_give_identical_cases(scenario_dict, write_scenario, tmp_path,
                                                                port_8787_held):
    import distributed  # an extra the test install carries ('.[test]'): missing, the test fails, not skips

    spec = _fast_spec(scenario_dict, write_scenario, tmp_path)
    inline = cm.run_campaign(spec, tmp_path / "inline", 3, workers=0, plots=False)
    pool = cm.run_campaign(spec, tmp_path / "pool", 3, workers=2, plots=False)
    # dashboard_address=None still starts the scheduler's HTTP server on 8787 (and warns when it is taken); port 0
    # on loopback never collides, and without bokeh it serves no dashboard.
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=cm.DASK_HTTP_ADDRESS) as cluster:
        dask = cm.run_campaign(spec, tmp_path / "dask", 3, scheduler=cluster.scheduler_address, plots=False)
    assert dask["execution"]["executor"] == "dask" and dask["execution"]["scheduler"].startswith("tcp://127.0.0.1:")
    digests = [[c["digest"] for c in r["cases"]] for r in (inline, pool, dask)]
    assert digests[0] == digests[1] == digests[2] and len(set(digests[0])) == 3
    pids = {json.loads((cm.case_dir(tmp_path / "dask", k) / "case.json").read_text())["pid"] for k in range(3)}
    assert pids and not pids & {__import__("os").getpid()}


def test_stand_run_re_runs_one_case_bit_for_bit(scenario_dict, write_scenario, tmp_path, capsys):
    spec = _fast_spec(scenario_dict, write_scenario, tmp_path)
    camp = tmp_path / "camp"
    cm.run_campaign(spec, camp, 3, workers=0, plots=False)
    rc = main(["run", "--campaign", str(camp), "--case", "2", "--out", str(tmp_path / "again"), "--no-progress",
               "--no-plots"])
    out = capsys.readouterr().out
    rec = json.loads((cm.case_dir(camp, 2) / "case.json").read_text())
    assert rc == (0 if rec["passed"] else 1)
    assert "reproduces campaign case 2 bit for bit" in out
    mine = json.loads((tmp_path / "again" / "summary.json").read_text())
    theirs = json.loads((cm.case_dir(camp, 2) / "summary.json").read_text())
    assert cm.comparable(mine) == cm.comparable(theirs)
    assert (tmp_path / "again" / "telemetry" / "rows.f64").read_bytes() == \
        (cm.case_dir(camp, 2) / "telemetry" / "rows.f64").read_bytes()
    # A record that does not match is reported as different.
    rec["digest"] = "0" * 64
    (cm.case_dir(camp, 2) / "case.json").write_text(json.dumps(rec))
    main(["run", "--campaign", str(camp), "--case", "2", "--out", str(tmp_path / "third"), "--no-progress",
          "--no-plots"])
    assert "DIFFERS from campaign case 2" in capsys.readouterr().err


def test_the_campaign_command_runs_and_explains_its_errors(scenario_dict, write_scenario, tmp_path, capsys):
    spec = _fast_spec(scenario_dict, write_scenario, tmp_path)
    scen = f"{spec.scenario_base}/{spec.scenario_name}"
    rc = main(["campaign", scen, "--runs", "2", "--dispersions", str(tmp_path / "dispersions.toml"), "--out",
               str(tmp_path / "c"), "--workers", "0", "--duration", str(SHORT_S), "--no-progress"])
    out = capsys.readouterr().out
    data = json.loads((tmp_path / "c" / "campaign.json").read_text())
    assert rc == (0 if data["passed"] == 2 else 1)
    assert f"2/2 runs: {data['passed']} passed" in out
    bad = tmp_path / "bad.toml"
    bad.write_text('[[dispersions]]\nfield = "spacecraft.inertia_kg_m2"\ndistribution = "normal"\n')
    rc = main(["campaign", scen, "--runs", "2", "--dispersions", str(bad), "--out", str(tmp_path / "d")])
    err = capsys.readouterr().err
    assert rc == 2 and "exactly one of sigma" in err and "spacecraft.inertia_kg_m2" in err
    rc = main(["run", "--campaign", str(tmp_path / "nowhere"), "--case", "0"])
    assert rc == 2 and "a campaign folder" in capsys.readouterr().err
    assert math.isfinite(data["execution"]["overhead_per_run_s"])


def test_a_scenario_with_wall_time_devices_is_refused():
    with pytest.raises(cm.CampaignError, match="hardware or served links"):
        cm.make_spec("star_tracker_hardware", SHIPPED)


def test_the_progress_line_counts_runs_passed_and_failed():
    import io

    stream = io.StringIO()
    bar = cm.CampaignProgress(4, True, stream)
    bar.add({"passed": True, "status": "completed"}, resumed=True)
    bar.add({"passed": False, "status": "completed"})
    bar.add({"passed": False, "status": "error"})
    bar.show()
    line = stream.getvalue().rsplit("\r", 1)[-1]
    assert "3/4 runs  passed 1  failed 2 (1 errors)" in line
    quiet = io.StringIO()
    cm.CampaignProgress(4, False, quiet).show()
    assert quiet.getvalue() == ""
