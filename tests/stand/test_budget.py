"""What a run costs is known before t = 0: the orbit track stays bounded whatever the dynamics step, and the
estimate (ticks, telemetry, peak memory, computation) is listed by `stand check` and refuses what the machine
cannot hold."""

import tracemalloc

import numpy as np
import pytest

from sim import truth as truth_mod
from sim.constants import MU_EARTH, R_EARTH
from stand import compose, scenario
from stand.cli import main
from stand.errors import ScenarioError
from stand.loop import columns


def track(half_step_ns):
    r0 = np.array([R_EARTH + 500e3, 0.0, 0.0])
    v0 = np.array([0.0, np.sqrt(MU_EARTH / r0[0]) * 0.6, np.sqrt(MU_EARTH / r0[0]) * 0.8])
    return truth_mod.OrbitTrack(r0, v0, gravity="j2", orbit_step_s=10.0, half_step_ns=half_step_ns, field_N=None)


def test_orbit_track_memory_does_not_grow_with_a_smaller_step():
    # At 1e-6 s steps a 200 s chunk used to be 4e8 grid points (23.7 GB before the run was killed).
    fine = track(500)
    tracemalloc.start()
    try:
        p_fine = fine.position(200_000)  # t = 0.1 s on the 5e-7 s half-step grid
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert fine._chunk_len <= truth_mod.CHUNK_POINTS + 1
    assert peak < 50e6
    coarse = track(50_000_000)
    p_coarse = coarse.position(2)  # t = 0.1 s on the 0.05 s grid: the same Hermite interpolant
    assert np.allclose(p_fine, p_coarse, rtol=0, atol=1e-6)


def test_short_chunks_reuse_the_orbit_nodes():
    # Many chunks fit in one 10 s orbit step: they share one propagation instead of repeating it.
    t = track(500)
    t.position(0)
    nodes = t._nodes
    t.position(5 * truth_mod.CHUNK_POINTS)
    assert t._nodes is nodes and t._chunk_start_idx == 5 * truth_mod.CHUNK_POINTS
    t.position(int(12.0 / 5e-7))  # past the first orbit node: a new propagation
    assert t._nodes is not nodes


def test_estimate_of_the_default_run_matches_what_it_builds():
    sc = scenario.load(scenario.DEFAULT_SCENARIO)
    b = compose.budget(sc)
    assert b.ticks == 56770 and b.rows == 56771
    with compose.build(sc) as scene:
        assert b.row_floats == sum(w for _, w, _ in columns(scene))
    assert b.telemetry_bytes == b.rows * b.row_floats * 8
    assert b.memory_bytes == sum(b.parts.values()) and b.compute_s > 0
    assert compose.budget(sc, 600.0).ticks == 6000


def test_check_lists_the_estimate(capsys):
    assert main(["check", "detumble"]) == 0
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.strip().startswith("estimate"))
    assert "56,770 ticks" in line and "peak memory" in line and "computation" in line


def test_a_run_beyond_the_machine_s_memory_is_refused(scenario_dict, write_scenario):
    sc = scenario.load(write_scenario(scenario_dict))
    b = compose.budget(sc)
    with pytest.raises(ScenarioError) as info:
        compose.check_budget(sc, memory_bytes=int(b.memory_bytes))  # half of it is available
    text = str(info.value)
    assert "peak memory" in text and "scenario.toml" in text and "dynamics.step_s = 0.1" in text
    compose.check_budget(sc, memory_bytes=int(4 * b.memory_bytes))


def test_a_step_a_million_times_too_small_is_refused_before_t0(scenario_dict, write_scenario):
    scenario_dict["scenario"]["duration_s"] = 30 * 86400.0
    scenario_dict["dynamics"]["step_s"] = 1e-6
    scenario_dict["recording"]["rate_hz"] = 0.1
    scenario_dict["devices"][0]["sample_rate_hz"] = 10.0
    sc = scenario.load(write_scenario(scenario_dict))
    with pytest.raises(ScenarioError) as info:
        compose.plan(sc)
    assert info.value.field == "dynamics.step_s" and "days of computation" in str(info.value)


def test_telemetry_larger_than_the_free_disk_is_refused(scenario_dict, write_scenario, tmp_path, monkeypatch):
    sc = scenario.load(write_scenario(scenario_dict))
    b = compose.budget(sc)
    monkeypatch.setattr(compose, "free_disk_bytes", lambda folder: (tmp_path, b.telemetry_bytes - 1))
    with pytest.raises(ScenarioError) as info:
        compose.check_budget(sc, out_dir=tmp_path / "run")
    assert info.value.field == "recording.rate_hz" and "free" in str(info.value)


def test_run_refuses_before_writing_anything(scenario_dict, write_scenario, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(compose, "MEMORY_FRACTION", 1e-9)
    out = tmp_path / "out"
    assert main(["run", str(write_scenario(scenario_dict)), "--out", str(out), "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "peak memory" in err
    assert not out.exists()


def test_free_disk_is_taken_from_the_nearest_existing_folder(tmp_path):
    folder, free = compose.free_disk_bytes(tmp_path / "a" / "b")
    assert folder == tmp_path and free > 0


def test_run_checks_the_disk_of_its_own_output_folder(scenario_dict, write_scenario, tmp_path, monkeypatch, capsys):
    real = compose.free_disk_bytes

    def free(folder):
        where, n = real(folder)
        return (where, 1000) if "tight" in str(folder) else (where, n)

    monkeypatch.setattr(compose, "free_disk_bytes", free)
    path = str(write_scenario(scenario_dict))
    assert main(["run", path, "--out", str(tmp_path / "tight" / "run"), "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert "recording.rate_hz" in err and "free" in err and err.count("\n") == 1
    # the --duration is what is estimated: one second of telemetry is 11 rows
    assert compose.budget(scenario.load(path), 1.0).rows == 11
