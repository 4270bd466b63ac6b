"""``stand bench screen-loop``: the star screen in the closed loop, timed piece by piece.

* **render to display**: the stand's state for each frame sent over loopback UDP at the tick rate
  (10 Hz) to a display node serving in its own thread, as in ``stand emulate star-tracker --source
  screen``: send -> received -> rendered (1920 x 1080, copied out) -> pushed to the panel, median,
  p95 and max, on one clock. Adding the panel's own latency (one 60 Hz frame, the emulator's
  default) gives send -> lit, which is what a scenario's ``screen_latency_s`` should be set to; the
  row ``latency_mismatch`` is the median send -> lit minus the 20 ms of
  ``detumble_star_tracker_screen``, and ``timing_error_arcsec`` what that mismatch costs at the
  scenario's rate (0.017 deg/s);
* **window**: ``screen = "window"``, the stand rendering and flipping each frame itself (render +
  show, median and p95; SDL's dummy driver unless a display is set);
* **camera per exposure**: screen pixels through the collimator to the detector
  (``star_screen.collimated.screen_to_detector``), camera noise, and the tracking solve, median and
  p95, on the frames the node rendered.

Frame-to-solution latency of the whole chain (serial, emulator output delay included) is a scenario
figure: ``stand run detumble_star_tracker_screen`` reports it in the tracker's ``screen`` summary.
"""

from __future__ import annotations

import math
import time

import numpy as np

TICK_S = 0.1
PANEL_LATENCY_S = 0.016
SCENARIO_LATENCY_S = 0.02
SCENARIO_RATE_DEG_S = 0.01 * math.sqrt(3.0)


def _row(name, value, unit, **kw) -> dict:
    return {"name": f"screen_loop.{name}", "value": round(float(value), 3), "unit": unit, **kw}


def bench_screen_loop(quick: bool = False) -> list[dict]:
    from sim.time import Epoch
    from stand.commands.screen_tracker import ScreenCamera, benches
    from stand.devices.star_screen_link import extrapolate
    from stand.display import StateSender
    from star_screen.attitude import q_SN_from_radec_roll

    n = 30 if quick else 300
    epoch = Epoch.from_iso("2026-03-20T12:00:00Z")
    physical, render_bench, _ = benches(0.05, (2.0, -1.5), pre_distortion=False)
    cam = ScreenCamera(("127.0.0.1", 0), physical, render_bench, camera={"read_noise_e": 10.0, "background_e": 20.0},
                       defocus_sigma_px=0.8, panel_latency_s=PANEL_LATENCY_S, rng=np.random.default_rng(0))
    sent_ns: dict[int, int] = {}
    q0 = q_SN_from_radec_roll(80.0, 30.0, 10.0)
    w = tuple(np.radians([0.01, 0.01, 0.01]))
    exposures = []
    try:
        cam.start()
        cam.base_ns = time.monotonic_ns()
        with StateSender(*cam.address, scenario_epoch=epoch) as sender:
            t0 = time.monotonic()
            for k in range(n):
                deadline = t0 + k * TICK_S
                time.sleep(max(0.0, deadline - time.monotonic()))
                q = extrapolate(tuple(q0), w, k * TICK_S)
                now = time.monotonic_ns()
                state = sender.send(q, round(k * TICK_S * 1e9), v_sc_gcrs_m_s=(0.0, 7600.0, 0.0), omega_SN_S=w)
                sent_ns[state.sequence] = now
                if k % 5 == 4:  # an exposure every half second, between frames, in this thread as the emulator does
                    exposures.append(cam.measure((time.monotonic_ns() - cam.base_ns) * 1e-9))
            time.sleep(0.3)
    finally:
        cam.close()
    log = [f for f in cam.node.log if f.sequence in sent_ns]
    recv = np.array([(f.received_ns - sent_ns[f.sequence]) * 1e-6 for f in log])
    push = np.array([(f.pushed_ns - sent_ns[f.sequence]) * 1e-6 for f in log])
    render = np.array([(f.pushed_ns - f.received_ns) * 1e-6 for f in log])
    lit = push + PANEL_LATENCY_S * 1e3
    mismatch = float(np.median(lit)) - SCENARIO_LATENCY_S * 1e3
    note = f"{len(log)} of {n} frames rendered at {1 / TICK_S:g} Hz, node in its own thread"
    rows = [
        _row("send_to_received_median", np.median(recv), "ms", note="loopback UDP and the node's wake-up"),
        _row("render_to_display_median", np.median(render), "ms", note=note),
        _row("render_to_display_p95", np.percentile(render, 95), "ms"),
        _row("render_to_display_max", render.max(), "ms"),
        _row("send_to_display_median", np.median(push), "ms"),
        _row("send_to_display_p95", np.percentile(push, 95), "ms"),
        _row("send_to_lit_median", np.median(lit), "ms", note=f"with the panel's {PANEL_LATENCY_S * 1e3:g} ms"),
        _row("latency_mismatch", mismatch, "ms",
             note=f"against screen_latency_s = {SCENARIO_LATENCY_S:g} s of detumble_star_tracker_screen"),
        _row("timing_error_arcsec", abs(mismatch) * 1e-3 * SCENARIO_RATE_DEG_S * 3600.0, "arcsec",
             note=f"at the scenario's {SCENARIO_RATE_DEG_S:.3f} deg/s"),
    ]
    ms = np.asarray(cam.camera_ms)
    if len(ms):
        solved = sum(1 for e in exposures if e.stars_matched)
        rows += [_row("camera_per_exposure_median", np.median(ms), "ms",
                      note=f"screen -> collimator -> detector, noise, solve; {solved} of {len(exposures)} solved"),
                 _row("camera_per_exposure_p95", np.percentile(ms, 95), "ms")]
    rows += _window_rows(30 if quick else 300, epoch, q0, w)
    if len(log) < 0.9 * n:
        rows.append(_row("frames_rendered", len(log), "frames", limit=f">= {0.9 * n:g}", **{"pass": False}))
    return rows


def _window_rows(n: int, epoch, q0, w) -> list[dict]:
    """``screen = "window"``: the stand renders and flips each frame itself (SDL's dummy driver unless a display
    is set, so this times the render and the copy to the window surface, not a real panel's scan-out)."""
    import os

    from stand.devices.star_screen_link import extrapolate
    from star_screen.geometry import default_bench
    from star_screen.render import Renderer

    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    try:
        from star_screen.window import ScreenWindow

        window = ScreenWindow((1920, 1080), fullscreen=False, clock=time.monotonic_ns)
    except (RuntimeError, ValueError) as exc:
        return [_row("window_render_to_display_median", math.nan, "ms", note=f"skipped: {exc}")]
    renderer = Renderer(default_bench(), aberration=True)
    ms = []
    try:
        for k in range(n):
            t_ns = round(k * TICK_S * 1e9)
            w0 = time.monotonic_ns()
            frame = renderer.render(extrapolate(tuple(q0), w, k * TICK_S), epoch.add_ns(t_ns),
                                    v_sc_gcrs_m_s=(0.0, 7600.0, 0.0), omega_SN_S=w, time_tag_ns=t_ns, detector=False,
                                    copy=False)
            ms.append((window.show(frame).clock - w0) * 1e-6)
    finally:
        window.close()
    driver = os.environ.get("SDL_VIDEODRIVER", "")
    return [_row("window_render_to_display_median", np.median(ms), "ms",
                 note=f"render 1920x1080 + show, SDL driver {driver or 'default'}, vsync {window.vsync_note}"),
            _row("window_render_to_display_p95", np.percentile(ms, 95), "ms")]
