"""The star screen in the loop: the screen-to-detector optics, the stand's latency compensation, and the
scenario with a hardware tracker in another process looking at the screen the stand drives."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sim.time import Epoch
from stand import scenario
from stand.cli import main
from stand.errors import ScenarioError
from star_screen.attitude import q_SN_from_radec_roll
from star_screen.collimated import matched_gain, screen_to_detector
from star_screen.geometry import default_bench
from star_screen.render import Renderer
from star_screen.tracking.extract import extract_stars
from tests.oracles import require
from tests.stand.processes import stand_env

from .conftest import socat_pty_pair

EPOCH = Epoch.from_iso("2026-03-20T12:00:00Z")
ARCSEC = math.pi / 180 / 3600


@pytest.fixture(scope="module")
def frame():
    bench = default_bench()
    r = Renderer(bench, aberration=False)
    return bench, r, r.render(q_SN_from_radec_roll(80.0, 30.0, 10.0), EPOCH)


def _matched_offsets(image_a, image_b, sigma_px):
    a = extract_stars(image_a + 20.0, sigma_px, k_sigma=5.0).xy
    b = extract_stars(image_b + 20.0, sigma_px, k_sigma=5.0).xy
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)
    j = d.argmin(axis=1)
    near = d[np.arange(len(a)), j] < 3.0
    return a[near] - b[j[near]]


def test_the_screen_seen_through_the_nominal_collimator_puts_stars_where_the_ideal_detector_does(frame):
    bench, r, f = frame
    gain = matched_gain(r.flux_full, bench.tracker.flux_mag0_e, r.photometry)
    det = screen_to_detector(f.screen, bench, e_per_luminance_px=gain, defocus_sigma_px=0.8)
    off = _matched_offsets(det, f.detector, 1.0)
    assert len(off) > 100
    # Centroids agree to a few hundredths of a pixel (a pixel is 24.8 arcsec): the panel grid, its 8-bit steps and
    # gamma move them less than a tracker's own centroid noise.
    assert np.all(np.abs(np.median(off, axis=0)) < 0.02)
    assert np.percentile(np.linalg.norm(off, axis=1), 95) < 0.1
    # The radiometric match: unclipped stars keep the electrons of the ideal detector (quantisation aside).
    assert abs(det.sum() / f.detector.sum() - 1.0) < 0.02


def test_a_collimator_axis_off_nominal_moves_every_star_by_the_shift_over_the_magnification(frame):
    bench, r, f = frame
    shifted = dataclasses.replace(bench, sx0=bench.sx0 + 2.0, sy0=bench.sy0 - 1.5)
    gain = matched_gain(r.flux_full, bench.tracker.flux_mag0_e, r.photometry)
    det = screen_to_detector(f.screen, shifted, e_per_luminance_px=gain)
    ref = screen_to_detector(f.screen, bench, e_per_luminance_px=gain)
    off = _matched_offsets(det, ref, 1.0)
    # A screen point moved by (+2, -1.5) px on the axis appears moved the other way, scaled by fx / (f_c / pitch).
    want = -np.array([2.0, -1.5]) / bench.screen_px_per_tracker_px
    assert np.allclose(np.median(off, axis=0), want, atol=0.02)


def test_screen_to_detector_refuses_what_a_panel_cannot_show(frame):
    bench, _, f = frame
    with pytest.raises(ValueError, match="8-bit"):
        screen_to_detector(f.screen.astype(np.float32), bench, e_per_luminance_px=1.0)
    with pytest.raises(ValueError, match="does not match"):
        screen_to_detector(f.screen[:-1], bench, e_per_luminance_px=1.0)
    with pytest.raises(ValueError, match="defocus_sigma_px"):
        screen_to_detector(f.screen, bench, e_per_luminance_px=1.0, defocus_sigma_px=-1.0)
    assert not screen_to_detector(np.zeros_like(f.screen), bench, e_per_luminance_px=1.0).any()


def test_extrapolation_is_the_attitude_kinematics_with_the_rate_held():
    from sim.attitude import propagate
    from stand.devices.star_screen_link import extrapolate

    q0 = q_SN_from_radec_roll(33.0, -12.0, 40.0)
    w = np.radians([0.7, -1.9, 2.4])
    # A spherical body spins at a constant rate: the integrator's answer is the closed form's.
    _, q, _ = propagate(np.eye(3) * 0.01, q0, w, 0.05, 0.001)
    got = extrapolate(tuple(q0), tuple(w), 0.05)
    assert min(np.linalg.norm(np.array(got) - q[-1]), np.linalg.norm(np.array(got) + q[-1])) < 1e-10
    assert extrapolate(tuple(q0), (0.0, 0.0, 0.0), 1.0) == tuple(q0)


def _scenario(tmp_path, **changes):
    import tomllib

    from .conftest import to_toml

    data = tomllib.loads((scenario.SCENARIO_DIR / "detumble_star_tracker_screen.toml").read_text())
    data["devices"][1].update(changes)
    path = tmp_path / "s.toml"
    path.write_text(to_toml(data))
    return path


@pytest.mark.parametrize("changes, field", [
    ({"link": "emulated", "port": "pty"}, "screen"),
    ({"screen_port": "udp://8.8.8.8:5600"}, "screen_port"),
    ({"screen_port": "tcp://127.0.0.1:5600"}, "screen_port"),
    ({"screen": "pixels"}, "screen"),
    ({"screen": "window"}, "screen_port"),  # a window is drawn by the stand: no display node to send to
    ({"screen_latency_s": 2.0}, "screen_latency_s"),
])
def test_a_screen_the_stand_cannot_drive_is_refused_naming_the_key(tmp_path, changes, field):
    with pytest.raises(ScenarioError) as info:
        scenario.load(_scenario(tmp_path, **changes))
    assert info.value.field == f"devices[1].{field}"


def test_screen_settings_without_a_screen_are_refused(tmp_path):
    import tomllib

    from .conftest import to_toml

    data = tomllib.loads((scenario.SCENARIO_DIR / "detumble_star_tracker_screen.toml").read_text())
    del data["devices"][1]["screen"]
    path = tmp_path / "s.toml"
    path.write_text(to_toml(data))
    with pytest.raises(ScenarioError) as info:
        scenario.load(path)
    assert info.value.field.startswith("devices[1].screen_")


def test_a_bench_lan_display_node_is_accepted(tmp_path):
    sc = scenario.load(_scenario(tmp_path, screen_port="udp://192.168.10.20:5600"))
    st = next(d for d in sc.devices if d.name == "st1")
    assert st.screen == {"mode": "state", "host": "192.168.10.20", "port": 5600, "latency_s": 0.02}


DURATION_S = 20.0


def _start_tracker(tmp_path, tracker_end, pre_distortion: str) -> subprocess.Popen:
    """The hardware tracker in another process, looking at the screen it serves (its first line names the port)."""
    return subprocess.Popen(
        [sys.executable, "-m", "stand.cli", "emulate", "star-tracker", "--source", "screen", "--port", tracker_end,
         "--screen-bind", "127.0.0.1:0", "--interval-s", "0.5", "--collimator-k1", "0.05",
         "--collimator-shift-px", "2,-1.5", "--pre-distortion", pre_distortion, "--duration", "120"],
        env=stand_env(), cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _start_run(tmp_path, stand_end, emu: subprocess.Popen, pre_distortion: str) -> tuple[subprocess.Popen, Path]:
    """`stand run detumble_star_tracker_screen` in real time in another process, driving the tracker's screen."""
    ready = emu.stdout.readline()
    found = re.search(r"display node on 127\.0\.0\.1:(\d+) UDP", ready)
    assert found, ready
    out = tmp_path / f"run_{pre_distortion}"
    run = subprocess.Popen(
        [sys.executable, "-m", "stand.cli", "run", "detumble_star_tracker_screen",
         "--set", f"devices.st1.port={stand_end}", "--set", f"devices.st1.screen_port=udp://127.0.0.1:{found.group(1)}",
         "--speed", "1", "--duration", str(DURATION_S), "--out", str(out), "--no-progress", "--no-plots"],
        env=stand_env(), cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    return run, out


def _results(run: subprocess.Popen, out: Path, emu: subprocess.Popen) -> tuple[int, dict, dict]:
    """(the run's exit code, the tracker's summary in the stand, the tracker process's own JSON line)."""
    try:
        printed, _ = run.communicate(timeout=300)
    finally:
        emu.terminate()
        text, _ = emu.communicate(timeout=30)
    assert (out / "summary.json").exists(), printed
    summary = json.loads((out / "summary.json").read_text())
    line = [x for x in text.splitlines() if x.startswith("{")]
    assert line, text
    return run.returncode, summary["device_counters"]["st1"], json.loads(line[-1])


def _kill(proc: subprocess.Popen) -> None:
    """Whatever went wrong, no process of the test outlives it."""
    if proc.poll() is None:
        proc.kill()
        proc.communicate(timeout=30)


@pytest.mark.slow
def test_the_tracker_in_another_process_solves_the_screen_and_pre_distortion_removes_the_collimator_error(tmp_path):
    # The two cases (pre-distortion on and off) run side by side, each with its own pty pair, tracker process and
    # run: they share nothing, each is paced in wall time and mostly waits (together they use a fifth of a core), so
    # the test takes the wall time of one case instead of two.
    with contextlib.ExitStack() as stack:
        started = {}
        for name in ("on", "off"):
            stand_end, tracker_end = stack.enter_context(socat_pty_pair(tmp_path, f"{name}_"))
            emu = _start_tracker(tmp_path, tracker_end, name)
            stack.callback(_kill, emu)
            started[name] = stand_end, emu
        runs = {}
        for name, (stand_end, emu) in started.items():
            run, out = _start_run(tmp_path, stand_end, emu, name)
            stack.callback(_kill, run)
            runs[name] = run, out, emu
        (code_on, on, emu_on), (code_off, off, emu_off) = (_results(*runs[name]) for name in ("on", "off"))
    for name, st, emu in (("on", on, emu_on), ("off", off, emu_off)):
        scr = st["screen"]
        print(f"pre-distortion {name}: availability {st['availability']}, cross p95 {st['error_cross_arcsec']['p95']}"
              f" arcsec, roll p95 {st['error_roll_arcsec']['p95']} arcsec; frame-to-solution "
              f"{scr['frame_to_solution_s']}; exposure-to-solution {scr['exposure_to_solution_s']}; frames sent "
              f"{scr['frames_sent']}, dropped {scr['frames_dropped']}, late {scr['frames_late']}; latency used "
              f"{scr['latency_s']} s; render-to-display {emu['screen']['render_to_display_ms']} ms; calibration "
              f"{emu['screen'].get('calibration')}")
    # With the screen pre-distorted by the ChArUco calibration the scenario's criteria hold: the whole optical
    # chain within 15 arcsec across the boresight.
    assert code_on == 0, on
    assert on["valid"] >= 0.7 * DURATION_S / 0.5 and on["error_cross_arcsec"]["p95"] < 15.0
    assert emu_on["screen"]["calibration"]["rms_px"] < 0.5
    # Without it the collimator's axis offset (2.5 screen px, about 130 arcsec) and distortion stay in every
    # solution, and the criteria fail.
    assert code_off == 1
    assert off["error_cross_arcsec"]["median"] > 60.0
    assert off["error_cross_arcsec"]["median"] > 5 * on["error_cross_arcsec"]["median"]
    for st, emu in ((on, emu_on), (off, emu_off)):
        scr = st["screen"]
        ticks = round(DURATION_S / 0.1)
        assert scr["frames_dropped"] == 0 and ticks - 2 <= scr["frames_sent"] <= ticks + 1
        assert emu["screen"]["node"]["rendered"] >= 0.9 * scr["frames_sent"]
        assert emu["screen"]["camera"]["tracking"] >= 20
        # The chain's latency: the frame lit at the exposure was sent one panel latency plus its age before it,
        # the solution comes after the camera's work and the output delay (0.1 s).
        f2s, e2s = scr["frame_to_solution_s"], scr["exposure_to_solution_s"]
        assert 0.1 < e2s["median"] <= f2s["median"] < 1.0 and f2s["p95"] < 2.0


@pytest.mark.slow
def test_a_window_screen_is_rendered_by_the_stand_every_tick_time_tagged_for_when_it_is_lit(
        pty_pair, tmp_path, monkeypatch):
    monkeypatch.setenv("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    require("pygame", "the display extra (pygame-ce)")
    import tomllib

    from stand import telemetry

    from .conftest import to_toml

    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    stand_end, tracker_end = pty_pair
    data = tomllib.loads((scenario.SCENARIO_DIR / "detumble_star_tracker_screen.toml").read_text())
    st = data["devices"][1]
    del st["screen_port"]
    st.update(port=stand_end, screen="window", screen_fullscreen=False, screen_latency_s=0.03)
    data["devices"][0]["channel"] = f"screen-window-{tmp_path.name}"
    data["criteria"] = [c for c in data["criteria"] if c["metric"] == "frames_rejected"]
    path = tmp_path / "window.toml"
    path.write_text(to_toml(data))
    # The tracker here is the open-loop emulator (it does not look at the window): this is the screen's side.
    emu = subprocess.Popen([sys.executable, "-m", "stand.cli", "emulate", "star-tracker", "--port", tracker_end,
                            "--duration", "60", "--boot-time-s", "0.5"], env=stand_env(), cwd=tmp_path,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    out = tmp_path / "run"
    try:
        assert "star tracker at address" in emu.stdout.readline()
        code = main(["run", str(path), "--speed", "1", "--duration", "3", "--out", str(out), "--no-progress",
                     "--no-plots"])
    finally:
        emu.terminate()
        emu.communicate(timeout=20)
    assert code == 0
    scr = json.loads((out / "summary.json").read_text())["device_counters"]["st1"]["screen"]
    assert scr["mode"] == "window" and scr["to"].startswith("window on display 0 (1920 x 1080)")
    assert 30 <= scr["frames_sent"] <= 31 and scr["frames_dropped"] == 0  # one per tick, t = 0 to 3 s
    assert 0 < scr["render_to_display_ms"]["median"] < 100
    tel = telemetry.load(out)
    t, t_lit, lead = tel["t_s"], tel["st1.screen_t_lit_s"], tel["st1.screen_lead_s"]
    # Each frame is drawn for the middle of its time on the panel: lit 30 ms after its tick starts (plus the
    # tick's own lateness, which only ever adds), held one tick (0.1 s).
    assert np.all(np.diff(t_lit) > 0)
    assert np.all(lead >= 0.03 + 0.05 - 1e-6) and np.median(lead) < 0.03 + 0.05 + 0.05
    assert np.allclose(t_lit - t, lead)


@pytest.mark.parametrize("extra, needle", [
    (["--collimator-shift-px", "1"], "--collimator-shift-px"),
    (["--collimator-k1", "nan"], "--collimator-k1"),
    (["--panel-latency-s", "-0.1"], "--panel-latency-s"),
    (["--screen-bind", "nowhere"], "--screen-bind"),
    (["--collimator-k1", "0.6"], "--collimator-k1"),
])
def test_a_screen_tracker_with_impossible_optics_is_a_usage_error_naming_the_option(capsys, extra, needle):
    code = main(["emulate", "star-tracker", "--source", "screen", "--port", "/nonexistent-tty", *extra])
    assert code == 2 and needle in capsys.readouterr().err


def test_a_screen_tracker_on_a_port_that_cannot_be_opened_says_so(capsys):
    code = main(["emulate", "star-tracker", "--source", "screen", "--port", "/nonexistent-tty",
                 "--screen-bind", "127.0.0.1:0", "--pre-distortion", "off"])
    assert code == 2 and "/nonexistent-tty" in capsys.readouterr().err


def test_a_window_screen_is_pre_distorted_with_the_calibration_numbers_the_scenario_gives(tmp_path):
    import tomllib

    from stand.commands.screen_tracker import benches
    from stand.devices.star_screen_link import window_bench

    from .conftest import to_toml

    _, calibrated, _ = benches(0.05, (2.0, -1.5), pre_distortion=True)
    col = calibrated.collimator
    data = tomllib.loads((scenario.SCENARIO_DIR / "detumble_star_tracker_screen.toml").read_text())
    st = data["devices"][1]
    del st["screen_port"]
    # What an operator copies from calibrate_screen's result into the scenario.
    st.update(screen="window", screen_collimator_focal_m=float(col.focal_length_m),
              screen_collimator_distortion=[float(v) for v in col.distortion.as_opencv()],
              screen_axis_px=[float(calibrated.sx0), float(calibrated.sy0)])
    path = tmp_path / "w.toml"
    path.write_text(to_toml(data))
    spec = next(d for d in scenario.load(path).devices if d.name == "st1")
    bench = window_bench(spec.screen)
    t = bench.tracker
    d = t.unproject(np.random.default_rng(3).uniform([0, 0], [t.width, t.height], (500, 2)))
    assert np.abs(bench.direction_to_screen(d)[0] - calibrated.direction_to_screen(d)[0]).max() < 1e-9
    st["screen_collimator_distortion"] = [0.05, 0.0, 0.0, 0.0]
    path.write_text(to_toml(data))
    with pytest.raises(ScenarioError) as info:
        scenario.load(path)
    assert info.value.field == "devices[1].screen_collimator_distortion"


def test_a_display_node_draws_for_the_calibration_its_command_line_gives(tmp_path):
    import socket
    import threading

    from stand.display import StateSender

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = tmp_path / "frames"
    argv = ["display-node", "--bind", f"127.0.0.1:{port}", "--out", str(out), "--max-frames", "1", "--timeout", "10",
            "--collimator-focal-m", "1.105", "--collimator-distortion", "0.05,0.1,1e-4,-2e-4,0", "--axis-px",
            "962.5,537.25"]
    codes = []
    node = threading.Thread(target=lambda: codes.append(main(argv)))
    node.start()
    try:
        with StateSender("127.0.0.1", port, scenario_epoch=EPOCH) as sender:
            for _ in range(100):  # until the node is listening and has drawn one frame
                sender.send(q_SN_from_radec_roll(80.0, 30.0, 10.0), 0)
                node.join(0.1)
                if not node.is_alive():
                    break
    finally:
        node.join(20)
    assert codes == [0]
    truth = json.loads((out / "000000" / "truth.json").read_text())
    assert truth["collimator"] == {"focal_length_m": 1.105, "distortion": [0.05, 0.1, 1e-4, -2e-4, 0.0]}
    assert truth["screen_axis_px"] == [962.5, 537.25]


def test_a_display_node_calibration_that_is_not_five_numbers_is_a_usage_error(capsys):
    assert main(["display-node", "--bind", "127.0.0.1:0", "--collimator-distortion", "0.05,0.1"]) == 2
    assert "--collimator-distortion '0.05,0.1'" in capsys.readouterr().err


@pytest.mark.parametrize("argv, needle", [
    (["star-tracker", "--source", "screen", "--scenario", "detumble_star_tracker_screen"], "does not take --scenario"),
    (["magnetorquer", "--source", "screen"], "star tracker only"),
])
def test_source_screen_is_refused_where_it_has_no_meaning(capsys, argv, needle):
    assert main(["emulate", *argv, "--port", "/nonexistent-tty"]) == 2
    assert needle in capsys.readouterr().err
