"""``stand emulate star-tracker --source screen``: an emulated tracker that looks at the star screen.

The process is the display node and the tracker in front of it, as on a bench with a screen PC and
a real tracker behind a collimator:

* **screen**: a :class:`~stand.display.DisplayNode` bound to ``--screen-bind`` receives the
  stand's time-tagged state every tick and renders the screen (1920 x 1080, 8-bit drive codes) for
  the bench geometry it believes in: the nominal one (``--pre-distortion off``) or the one fitted by
  the ChArUco calibration (``star_screen.calibration``) of this bench's collimator
  (``--pre-distortion on``: the calibration pattern is shown, photographed through the physical
  collimator by the tracker's camera model, and fitted at start, before the ready line). A rendered
  frame lights ``--panel-latency-s`` after it was pushed (scan-out and panel response);
* **optics**: at each exposure the tracker takes the frame lit at its mid-exposure instant and maps
  screen pixels through the *physical* collimator to its detector
  (:func:`star_screen.collimated.screen_to_detector`: panel gamma and 8-bit steps, pixel pitch,
  collimator distortion ``--collimator-k1`` and axis offset ``--collimator-shift-px``, tracker
  defocus ``--defocus-sigma-px``);
* **camera and solver**: shot, background and read noise (``star_screen.tracking.noise``), then
  ``star_screen.tracking.StarTracker`` (lost in space, then tracking from its previous solutions);
* **serial**: the solution goes to the serial emulator (``drivers.star_tracker.emulator``) as its
  measurement, which adds no noise of its own and answers over the protocol with its own clock (set
  by the host's SET_TIME), exactly as a real tracker time-stamps its exposures.

The rate the tracker reports (for its rate flag) is the one in the state (the sky's turn on the
screen). When no frame is lit yet the screen is dark and the exposure matches no star.

At the end it prints one JSON line: serial counters, display-node counters (received, superseded,
refused), and the camera's figures: exposures, dark frames (none lit yet), stale frames (lit more
than a second before: the stand stopped), lost-in-space / tracking / failed solves, the age of the
lit frame at each exposure, render-to-display and the camera's work per
exposure (ms: median, p95, max), and the calibration residual.
"""

from __future__ import annotations

import dataclasses
import json
import math
import threading
import time
from collections import deque

import numpy as np

from stand.display import DisplayNode

#: Frames kept on the panel model: an exposure looks back at most a few frames.
_FRAMES_KEPT = 16
#: A lit frame older than this at an exposure means the stand stopped sending: counted as stale, not as latency.
STALE_NS = 1_000_000_000


class LitScreen:
    """The panel: frames pushed by the display node light ``panel_latency_ns`` later; keeps the last few so an
    exposure sees the frame lit at its own instant, whatever the moment it is processed."""

    def __init__(self, panel_latency_ns: int, clock=time.monotonic_ns):
        self.panel_latency_ns = int(panel_latency_ns)
        self.clock = clock
        self._frames: deque = deque(maxlen=_FRAMES_KEPT)
        self._lock = threading.Lock()

    def push(self, frame) -> None:
        lit = self.clock() + self.panel_latency_ns
        with self._lock:
            self._frames.append((lit, frame))

    def lit_at(self, t_ns: int):
        """``(lit_ns, frame)`` of the newest frame lit at ``t_ns``, or None (a dark screen)."""
        with self._lock:
            for lit, frame in reversed(self._frames):
                if lit <= t_ns:
                    return lit, frame
        return None


class _CameraNode(DisplayNode):
    """A display node whose frames keep the state they were rendered from (velocity and rate for the solver)."""

    def render_state(self, state):
        frame = super().render_state(state)
        frame.state = state
        return frame


def _ms(values) -> dict:
    v = np.asarray(values, float)
    if not len(v):
        return {}
    return {"median": round(float(np.median(v)), 3), "p95": round(float(np.percentile(v, 95)), 3),
            "max": round(float(v.max()), 3), "n": int(len(v))}


class ScreenCamera:
    """Display node, panel, collimator, camera and solver of an emulated tracker looking at the screen.

    ``physical``: the bench as it is (collimator distortion and axis); ``render_bench``: the bench the
    renderer draws for (nominal, or calibrated = pre-distorted). ``measure(t_e)`` is the serial
    emulator's measurement source; ``base_ns`` (monotonic ns of the emulator's time 0) must be set
    before the first exposure. Call :meth:`start` to serve the screen and :meth:`close` at the end.
    """

    def __init__(self, bind, physical, render_bench, *, camera: dict, defocus_sigma_px: float,
                 panel_latency_s: float, rng: np.random.Generator, calibration: dict | None = None):
        from star_screen.collimated import matched_gain
        from star_screen.render import Renderer
        from star_screen.tracking import StarTracker

        self.physical = physical
        self.optics = physical.tracker
        self.camera = dict(camera)
        self.defocus_sigma_px = float(defocus_sigma_px)
        self.rng = rng
        self.calibration = calibration
        self.renderer = Renderer(render_bench, aberration=True)
        self.gain = matched_gain(self.renderer.flux_full, self.optics.flux_mag0_e, self.renderer.photometry)
        self.screen = LitScreen(round(panel_latency_s * 1e9))
        self.node = _CameraNode(bind, self.renderer, self.screen, copy=True)
        self.tracker = StarTracker(catalog=self.renderer.catalog, mag_limit=self.optics.mag_limit)
        self.tracker.database(self.optics)  # about a second, before the ready line rather than at the first exposure
        self.base_ns: int | None = None
        self.epoch0 = None
        self._last = self._before = None  # (t_s, q_SN) of the last two valid solutions
        self.counts = {"exposures": 0, "dark": 0, "stale": 0, "lis": 0, "tracking": 0, "failed": 0}
        self.frame_age_ms: list[float] = []
        self.camera_ms: list[float] = []
        self.errors: list[str] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def address(self):
        return self.node.address

    def start(self) -> None:
        self._thread = threading.Thread(target=self._serve, name="screen display node", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                self.node.serve(max_frames=1, timeout_s=0.1)
            except OSError as exc:  # the socket closed under us at shutdown
                if not self._stop.is_set():
                    self.errors.append(f"display node stopped: {exc}")
                return

    def _prior(self, t_s: float):
        from sim.rotations import axis_angle, compose, conjugate, quat_from_axis_angle

        if self._last is None:
            return None
        t1, q1 = self._last
        if self._before is None:
            return q1
        t0, q0 = self._before
        axis, angle = axis_angle(compose(q1, conjugate(q0)))  # the tracker's own rate estimate
        return compose(quat_from_axis_angle(axis, float(angle) * (t_s - t1) / (t1 - t0)), q1)

    def measure(self, t_e: float):
        from drivers.star_tracker.emulator import TrackerTruth
        from star_screen.collimated import screen_to_detector
        from star_screen.tracking.noise import camera_noise

        self.counts["exposures"] += 1
        t_ns = self.base_ns + round(t_e * 1e9)
        lit = self.screen.lit_at(t_ns)
        dark = TrackerTruth(q_TN=(1.0, 0.0, 0.0, 0.0), stars_in_field=0, stars_matched=0)
        if lit is None:
            self.counts["dark"] += 1
            self._last = self._before = None
            return dark
        w0 = time.perf_counter()
        lit_ns, frame = lit
        if t_ns - lit_ns > STALE_NS:  # the stand stopped driving the screen; the tracker still sees the last frame
            self.counts["stale"] += 1
        else:
            self.frame_age_ms.append((t_ns - lit_ns) * 1e-6)
        state = frame.state
        omega = state.omega_SN_S if state.omega_SN_S is not None else (0.0, 0.0, 0.0)
        if self.epoch0 is None:
            self.epoch0 = frame.epoch  # one catalog epoch per run: proper motion moves stars < 1 mas a day
        image = screen_to_detector(frame.screen, self.physical, e_per_luminance_px=self.gain,
                                   defocus_sigma_px=self.defocus_sigma_px)
        image = camera_noise(image, self.rng, **self.camera)
        v_obs = self.renderer.observer_velocity(frame.epoch, state.v_sc_gcrs_m_s)
        sol = self.tracker.solve(image, self.optics, self._prior(t_e), epoch=self.epoch0, observer_velocity_m_s=v_obs)
        self.camera_ms.append((time.perf_counter() - w0) * 1e3)
        if not sol.valid:
            self.counts["failed"] += 1
            self._last = self._before = None
            return dataclasses.replace(dark, omega_TN_T=omega, stars_in_field=int(sol.stars_centroided))
        self.counts[sol.mode] += 1
        self._before, self._last = self._last, (t_e, sol.q_SN)
        arcsec = math.pi / 180.0 / 3600.0
        return TrackerTruth(q_TN=tuple(float(x) for x in sol.q_SN), omega_TN_T=tuple(float(x) for x in omega),
                            stars_in_field=int(sol.stars_centroided), stars_matched=int(sol.stars_matched),
                            sigma_cross_rad=float(sol.sigma_cross_arcsec) * arcsec,
                            sigma_roll_rad=float(sol.sigma_roll_arcsec) * arcsec)

    def summary(self) -> dict:
        st = self.node.stats
        log = list(self.node.log)
        out = {"node": {"received": st.received, "rendered": st.rendered, "superseded": st.superseded,
                        "duplicate": st.duplicate, "out_of_order": st.out_of_order, "refused": dict(st.errors)},
               "camera": dict(self.counts), "frame_age_at_exposure_ms": _ms(self.frame_age_ms),
               "render_to_display_ms": _ms([(f.pushed_ns - f.received_ns) * 1e-6 for f in log]),
               "camera_ms": _ms(self.camera_ms)}
        if self.calibration is not None:
            out["calibration"] = self.calibration
        if self.errors:
            out["errors"] = self.errors[-3:]
        return out

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self.node.close()


def benches(k1: float, shift_px, pre_distortion: bool):
    """``(physical, render_bench, calibration)`` of the default bench whose collimator has radial distortion
    ``k1`` and an axis ``shift_px`` (screen px) off nominal; the render bench is the ChArUco fit of the physical
    one (``pre_distortion``) or the nominal bench."""
    from star_screen.geometry import BrownConrady, Collimator, default_bench

    nominal = default_bench()
    physical = dataclasses.replace(nominal, collimator=Collimator(nominal.collimator.focal_length_m,
                                                                  BrownConrady(k1=k1)),
                                   sx0=nominal.sx0 + shift_px[0], sy0=nominal.sy0 + shift_px[1])
    problems = physical.check_fits()
    if problems:
        raise ValueError(f"--collimator-k1 {k1:g} / --collimator-shift-px {shift_px[0]:g},{shift_px[1]:g}: the "
                         "tracker field no longer fits the screen: " + "; ".join(problems))
    if not pre_distortion:
        return physical, nominal, None
    from star_screen.calibration import calibrate_screen, charuco_screen_image, simulate_camera_view

    image, pattern = charuco_screen_image(nominal, 30, 22, 40)
    cal = calibrate_screen([simulate_camera_view(image, physical)], pattern, nominal)
    return physical, cal.bench, {"points": cal.n_points, "rms_px": round(cal.rms_px, 4),
                                 "max_px": round(cal.max_px, 4)}


def run_screen(args, fail) -> int:
    """The ``--source screen`` tracker of ``stand emulate star-tracker`` (see the module docstring)."""
    from drivers.errors import DriverError
    from drivers.star_tracker.emulator import EmulatorConfig, StarTrackerEmulator
    from stand.display import parse_hostport

    try:
        bind = parse_hostport(args.screen_bind, "--screen-bind")
        shift = tuple(float(x) for x in args.collimator_shift_px.split(","))
        if len(shift) != 2 or not all(math.isfinite(x) and abs(x) <= 50 for x in shift):
            raise ValueError(f"--collimator-shift-px {args.collimator_shift_px!r} is not allowed; give DX,DY in "
                             "screen pixels, each within 50.")
        if not (math.isfinite(args.collimator_k1) and abs(args.collimator_k1) <= 0.5):
            raise ValueError(f"--collimator-k1 {args.collimator_k1!r} is not allowed; give a number from -0.5 to 0.5.")
        if not (math.isfinite(args.panel_latency_s) and 0.0 <= args.panel_latency_s <= 1.0):
            raise ValueError(f"--panel-latency-s {args.panel_latency_s!r} is not allowed; give 0 to 1 s.")
        for name in ("read_noise_e", "background_e"):
            v = getattr(args, name)
            if not (math.isfinite(v) and 0.0 <= v <= 1e6):
                raise ValueError(f"--{name.replace('_', '-')} {v!r} is not allowed; give 0 to 1e6 electrons.")
        physical, render_bench, calibration = benches(args.collimator_k1, shift, args.pre_distortion == "on")
        overrides = {"boot_time_s": args.boot_time_s, "output_interval_s": args.interval_s,
                     "output_delay_s": args.delay_s, "address": args.address}
        # The solution is the image's: no added noise, the stars matched are the solver's own.
        config = EmulatorConfig(noise_cross_arcsec=0.0, noise_roll_arcsec=0.0, match_probability=1.0,
                                **{k: v for k, v in overrides.items() if v is not None})
        rng = np.random.default_rng(args.seed)
        cam = ScreenCamera(bind, physical, render_bench,
                           camera={"read_noise_e": args.read_noise_e, "background_e": args.background_e},
                           defocus_sigma_px=args.defocus_sigma_px, panel_latency_s=args.panel_latency_s,
                           rng=rng.spawn(1)[0], calibration=calibration)
    except ValueError as exc:
        return fail(str(exc))
    try:
        emu = StarTrackerEmulator(args.port, cam.measure, config, rng=rng, baudrate=args.baud)
    except (ValueError, DriverError) as exc:
        cam.close()
        return fail(str(exc))
    from stand.devices.serving import serve_until_stopped

    with emu:
        cam.start()
        where = f"{cam.address[0]}:{cam.address[1]}"
        print(f"stand emulate: star tracker at address 0x{emu.address:02X} on {args.port} looking at the screen "
              f"(display node on {where} UDP, pre-distortion {args.pre_distortion})"
              + (f" for {args.duration:g} s" if args.duration else " until Ctrl-C"), flush=True)

        def time_zero():
            cam.base_ns = time.monotonic_ns()  # the emulator's time 0: its run() starts now

        try:
            status = serve_until_stopped(emu, args.duration, start=time_zero)
        finally:
            cam.close()
        print(json.dumps({"device": args.device, "port": args.port, "source": "screen", "mode": emu.mode,
                          "counters": emu.counters, "screen": cam.summary()}), flush=True)
    return status
