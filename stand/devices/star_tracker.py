"""Star trackers on a serial line (``drivers.star_tracker``, the ICD in ``fixtures/devices/star_tracker.toml``).

The stand hands the emulator a measurement source (``TrackerTruth`` at an exposure time: the tracker-frame
attitude, its rate, and the Sun, Moon and Earth seen from the spacecraft) and reads the solutions back through
the real protocol (SLIP frames, CRC). Each solution is compared with the truth at its mid-exposure time,
recovered from the device time stamp, so the summary reports what a flight computer would have received and
how wrong it was.

Two sources feed the emulator. ``truth``: the true attitude, to which the emulator adds its configured noise.
``image``: the star screen renders the tracker's detector image at the true attitude, camera noise is added and
``star_screen.tracking`` solves it (``ImageSolver``); the emulator is handed the solved attitude and the stars
matched, with its own noise at 0.

Links: ``emulated`` (emulator and host on an in-process serial line, ``port = "pipe"`` (default) or a kernel pty
pair with ``port = "pty"``, every exchange settled within the tick, so a
run is bit-for-bit repeatable), ``hardware`` (the host on a real port: the stand sets the device clock to sim
time at start, logs the offset it measures, and scores each solution against the truth at its time stamp),
``served`` (the emulator on a real port, fed by the truth, for a flight computer outside).
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.errors import DeviceTimeoutError
from drivers.serial_port import wait_readable
from sim.constants import R_EARTH
from sim.environment import R_SUN
from sim.rotations import hamilton_floats
from sim.truth import compose_floats, rotate_to_body
from stand.devices import (
    SERIAL_LINES,
    SETTLE_TIMEOUT_S,
    BuildContext,
    Device,
    DeviceCost,
    DeviceKind,
    DeviceSpec,
    SerialDevice,
    check_serial_url,
    frames_in,
)

ARCSEC = math.pi / 180.0 / 3600.0
R_MOON = 1.7374e6
#: The Earth's disk as a tracker sees it includes the bright atmosphere.
ATMOSPHERE_M = 100e3
FLAG_BITS = {"sun_in_field": 1, "moon_in_field": 2, "earth_in_field": 4, "rate_too_high": 8}
MODES = {"BOOT": 0, "LOST_IN_SPACE": 1, "TRACKING": 2}
#: The telemetry fragment before the first solution arrives (widths of the columns).
NO_SOLUTION = (math.nan,) * 10
#: Solutions in a row a tracker may miss before it is reported silent.
SILENT_SOLUTIONS = 5

#: Emulator settings a scenario may give that the ICD does not carry as a parameter: key -> (default, lo, hi).
TRACKER_SETTINGS = {
    "noise_cross_arcsec": (2.0, 0.0, 3600.0),
    "noise_roll_arcsec": (10.0, 0.0, 3600.0),
    "output_delay_s": (0.1, 0.0, 10.0),
    "clock_offset_s": (0.0, -1e6, 1e6),
    "clock_drift_ppm": (0.0, -1e3, 1e3),
    "boot_time_s": (1.0, 0.0, 600.0),
}
#: Scenario key suffix for an ICD parameter's wire unit, and the factor from the wire unit to the scenario's.
_UNIT_KEYS = {"ms": ("_s", 1e-3), "deg": ("_deg", 1.0), "deg/s": ("_deg_s", 1.0), "count": ("", 1.0)}
#: Settings of the truth source only: with source = "image" the image is the noise.
TRUTH_ONLY_SETTINGS = ("noise_cross_arcsec", "noise_roll_arcsec")
TRACKER_SOURCES = ("truth", "image")
#: Memory of an image-source tracker before its image buffers: star catalog and pattern database, bytes.
IMAGE_BASE_BYTES = 300 << 20
#: Image-source settings: key -> (default, lo, hi, integer). Pairs are [x, y] (image right, down).
TRACKER_IMAGE_SETTINGS = {
    "mag_limit": (8.0, 4.0, 9.0, False),  # stars drawn and used, Hipparcos Hp (the catalog fixture reaches 9)
    "psf_sigma_px": (1.0, 0.3, 5.0, False),  # Gaussian spot sigma on the detector
    "read_noise_e": (10.0, 0.0, 1000.0, False),  # rms per pixel
    "background_e": (20.0, 0.0, 1e6, False),  # sky, stray light and dark current per pixel and exposure
}
TRACKER_IMAGE_PAIRS = {
    "fov_deg": ((20.0, 15.0), 5.0, 60.0, False),  # full field along image x and y
    "resolution_px": ((1024, 768), 64, 4096, True),  # detector columns and rows
}


def icd_settings() -> dict[str, tuple[float, float, float, bool]]:
    """Scenario settings that are ICD parameters: key -> (default, lo, hi, integer) in the scenario's units,
    read from the ICD's parameter table so scenario limits are the device's own."""
    return dict(_icd_settings())


@functools.cache
def _icd_settings() -> dict[str, tuple[float, float, float, bool]]:
    from drivers.star_tracker.codec import load_icd

    out = {}
    for p in load_icd()["parameters"]:
        suffix, factor = _UNIT_KEYS[p["unit"]]
        integer = bool(p.get("integer", False))
        default = int(p["default"]) if integer else p["default"] * factor
        out[p["name"] + suffix] = (default, p["min"] * factor, p["max"] * factor, integer)
    return out


def attitude_error_arcsec(q_true, q_meas) -> tuple[float, float]:
    """(cross-boresight, roll) error of a measured tracker attitude, arcsec (boresight +z).

    The rotation from true to measured tracker axes, E = dcm(q_meas) dcm(q_true)^T, has the antisymmetric part
    vee(E - E^T) / 2 = sin(angle) axis = 2 w v for its quaternion (w, v) = q_true^-1 then q_meas: on floats."""
    tw, tx, ty, tz = q_true
    w, x, y, z = hamilton_floats((tw, -tx, -ty, -tz), tuple(q_meas))
    return math.hypot(2.0 * w * x, 2.0 * w * y) / ARCSEC, abs(2.0 * w * z) / ARCSEC


@dataclass(frozen=True)
class StarTrackerSpec(DeviceSpec):
    """A star tracker on a serial line, fed by truth plus noise (``source = "truth"``) or by image-based
    solutions (``source = "image"``)."""

    port: str = "pipe"  # emulated: "pipe" (in-process line) or "pty"; hardware/served: a pyserial URL or device path
    baudrate: int = 115200
    address: int | None = None
    source: str = "truth"
    emulator: dict = field(default_factory=dict)  # keyword arguments of the emulator's EmulatorConfig
    optics: Any = None  # star_screen.geometry.TrackerOptics for source = "image", else None
    camera: dict | None = None  # camera_noise keywords (read_noise_e, background_e) for source = "image"
    screen: dict | None = None  # a hardware tracker looking at the stand's star screen (star_screen_link)


class StarTrackerKind(DeviceKind):
    name = "star_tracker"
    senses = ("attitude", "star_sky", "time")
    column_meanings = {"t_exposure_s": "exposure time of the newest solution the host decoded, stand time",
                       "q_TN": "that solution: tracker frame relative to inertial, scalar first",
                       "valid": "1 when that solution is valid",
                       "mode": "the tracker's mode (0 boot, 1 lost in space, 2 tracking)",
                       "flags": "why it is not valid: bits 1 Sun, 2 Moon, 4 Earth in the field, 8 rate too high",
                       "err_cross": "that solution's error across the boresight against the truth",
                       "err_roll": "that solution's error about the boresight against the truth",
                       "clock_offset_s": "tracker clock minus stand clock, measured at start (hardware link)"}
    plot_files = {"tracker_{name}.png": "solution errors with their limits, validity, mode and flags"}
    view_layer_meanings = {"fovs": "the field of view", "exclusion_deg": "the Sun, Moon and Earth exclusion cones",
                           "rate_limit_deg_s": "the body rate above which it cannot solve"}
    view_state = {"missing": "no solution", "flags": True, "invalid": ["acquiring", "invalid: acquiring"]}
    view_error_columns = ("err_cross", "err_roll")
    #: Drawn with the stand's default optics when a tracker's scenario gives none (truth-source trackers).
    DEFAULT_FOV_DEG = (20.0, 15.0)

    def view_layers(self, spec) -> dict:
        optics = getattr(spec, "optics", None)
        fx, fy = optics.fov_deg if optics is not None else self.DEFAULT_FOV_DEG
        em = getattr(spec, "emulator", {}) or {}
        return {"fovs": [{"shape": "rect", "axis_S": [0.0, 0.0, 1.0], "fov_deg": [float(fx), float(fy)],
                          "label": spec.name}],
                "exclusion_deg": {b: float(em[f"{b}_exclusion_deg"]) for b in ("sun", "moon", "earth")
                                  if f"{b}_exclusion_deg" in em},
                "rate_limit_deg_s": float(em["rate_limit_deg_s"]) if "rate_limit_deg_s" in em else None}
    metrics = {
        "tracker_availability_after": "fraction of star-tracker solutions after time at_s that are valid",
        "tracker_error_cross_arcsec_p95": "95th percentile of the valid solutions' cross-boresight error (arcsec)",
        "tracker_error_roll_arcsec_p95": "95th percentile of the valid solutions' roll error (arcsec)",
    }
    metrics_at = ("tracker_availability_after",)

    def parse(self, t, base: DeviceSpec, step_s: float) -> StarTrackerSpec:
        source = t.choice("source", TRACKER_SOURCES, "truth")
        image_keys = (*TRACKER_IMAGE_PAIRS, *TRACKER_IMAGE_SETTINGS)
        if source == "image":
            for key in TRUTH_ONLY_SETTINGS:
                if t.has(key):
                    raise t.error(key, t.raw(key), "no such setting with source = 'image': the rendered image and "
                                  "its camera noise (read_noise_e, background_e) are the measurement noise")
        else:
            for key in image_keys:
                if t.has(key):
                    raise t.error(key, t.raw(key), f"a setting of image-source trackers only; this tracker has "
                                  f"source = {source!r} (set source = 'image' to render and solve its images)")
        settings = {}
        limits = {**{k: (*v, False) for k, v in TRACKER_SETTINGS.items()}, **icd_settings()}
        for key, (default, lo, hi, integer) in limits.items():
            if source == "image" and key in TRUTH_ONLY_SETTINGS:
                continue
            v = t.number(key, default, lo=lo, hi=hi, integer=integer)
            settings[key] = int(v) if integer else float(v)
        for key in ("output_interval_s", "boot_time_s"):
            _whole_steps(t, key, settings[key], step_s)
        address = t.raw("address", None)
        if address is not None and (isinstance(address, bool) or not isinstance(address, int)
                                    or not 0 <= address <= 255):
            raise t.error("address", address, "a whole number from 0 to 255")
        optics = camera = None
        if source == "image":
            optics, camera = _tracker_image(t, base.name)
            # The solution is the image's: no added noise, and the stars matched are the solver's own.
            settings.update(noise_cross_arcsec=0.0, noise_roll_arcsec=0.0, match_probability=1.0)
        if base.link == "emulated":
            port = t.choice("port", SERIAL_LINES, "pipe")
        else:
            port = check_serial_url(t, "port", t.text("port"))
        baud = int(t.number("baudrate", 115200, lo=1200, hi=4_000_000, integer=True))
        from stand.devices.star_screen_link import parse_screen

        spec = StarTrackerSpec(**base.__dict__, port=port, baudrate=baud, address=address, source=source,
                               emulator=settings, optics=optics, camera=camera, screen=parse_screen(t, base.link))
        t.check_unknown()
        return spec

    def needs(self, spec) -> dict[str, str]:
        if spec.link == "hardware":
            if spec.screen is None:
                return {}
            from stand.devices.star_screen_link import describe_screen

            return {"star_screen": f"the screen {spec.name} looks at: {describe_screen(spec.screen)}"}
        why = f"exclusion of {spec.name}"
        out = {"sun": why, "moon": why}
        if spec.source == "image":
            o, cam = spec.optics, spec.camera
            fx, fy = o.fov_deg
            out["star_screen"] = (
                f"renders the detector image of {spec.name} ({fx:g} x {fy:g} deg on {o.width} x {o.height} px, "
                f"stars to Hp {o.mag_limit:g}, PSF sigma {o.psf_sigma_px:g} px, aberration, rate smear), adds camera "
                f"noise (read {cam['read_noise_e']:g} e-, background {cam['background_e']:g} e-) and solves it "
                "(pattern database built at compose time)")
        return out

    def describe(self, spec) -> str:
        what = "solved from its rendered detector image" if spec.source == "image" else f"{spec.source} plus noise"
        every = f"a solution every {spec.emulator['output_interval_s']:g} s"
        if spec.screen is not None:
            from stand.devices.star_screen_link import describe_screen

            return (f"star tracker on serial {spec.port} at {spec.baudrate} Bd looking at the stand's star screen "
                    f"({describe_screen(spec.screen)}; the stand reads its solutions and sets its clock)")
        return {"emulated": f"star tracker emulated on an in-process serial {spec.port}, {what}, {every}",
                "hardware": f"star tracker on serial {spec.port} at {spec.baudrate} Bd (hardware: the stand reads "
                            "its solutions and sets its clock)",
                "served": f"star tracker served on serial {spec.port} for a flight computer outside, {what}, "
                          f"{every}"}[spec.link]

    def cost(self, spec: StarTrackerSpec) -> DeviceCost:
        # A solution crossing the serial pty (SLIP, CRC, both ends in this process) takes about 1.2 ms.
        rate_hz = 1.0 / spec.emulator["output_interval_s"]
        if spec.source != "image" or spec.link == "hardware":
            return DeviceCost(rate_hz=rate_hz, row_floats=10, publish_s=1.2e-3)
        # Measured: the catalog and pattern database take about 270 MB; the frame buffers about 14 bytes a
        # detector pixel (235 MB at 4096 x 4096); a frame (render, camera noise, detection, solve) 25 ms at
        # 1024 x 768 and Hp 8, 1.2 s at 4096 x 4096 with a 60 deg field and Hp 9.
        px = spec.optics.width * spec.optics.height
        return DeviceCost(rate_hz=rate_hz, row_floats=10, memory_bytes=IMAGE_BASE_BYTES + 16 * px,
                          publish_s=1.2e-3 + 5e-3 + 70e-9 * px)

    def build(self, spec: StarTrackerSpec, ctx: BuildContext) -> Device:
        if spec.screen is not None:
            from stand.devices.star_screen_link import ScreenTracker

            return ScreenTracker(spec, ctx)
        return {"emulated": EmulatedTracker, "hardware": HardwareTracker, "served": ServedTracker}[spec.link](spec, ctx)

    def metric(self, metric, at_s, tel, names):
        sol = _solutions(tel, names[0]) if names else None
        if sol is None:
            return math.nan
        if metric == "tracker_availability_after":
            sel = sol["t"] >= at_s - 1e-9
            return float(sol["valid"][sel].mean()) if np.any(sel) else math.nan
        err = sol["cross" if "cross" in metric else "roll"][sol["valid"] == 1.0]
        err = err[np.isfinite(err)]
        return float(np.percentile(err, 95)) if len(err) else math.nan


    def plots(self, tel, name, out_dir, criteria) -> list[str]:
        from stand.devices.star_tracker_plots import plot_tracker

        lim = {c["metric"]: c for c in criteria}

        def most(metric):
            return lim[metric]["limit"].get("max") if metric in lim else None

        avail = lim.get("tracker_availability_after")
        availability = (avail["limit"]["min"], avail.get("at_s", 0.0)) if avail and "min" in avail["limit"] else None
        return [plot_tracker(tel, out_dir, name, cross_limit_arcsec=most("tracker_error_cross_arcsec_p95"),
                             roll_limit_arcsec=most("tracker_error_roll_arcsec_p95"), availability=availability,
                             modes=MODES, flag_bits=FLAG_BITS)]


def _solutions(tel, n: str) -> dict | None:
    """A tracker's solutions, one per exposure (the telemetry repeats the newest)."""
    if f"{n}.t_exposure_s" not in tel:
        return None
    t = tel[f"{n}.t_exposure_s"]
    ok = np.isfinite(t)
    _, first = np.unique(t[ok], return_index=True)
    idx = np.flatnonzero(ok)[first]
    return {"t": t[idx], "valid": tel[f"{n}.valid"][idx], "cross": tel[f"{n}.err_cross"][idx],
            "roll": tel[f"{n}.err_roll"][idx]}


def _whole_steps(t, key: str, value: float, step_s: float) -> None:
    n = value / step_s
    if abs(n - round(n)) > 1e-9 * max(n, 1.0):
        raise t.error(key, value, f"a whole number of dynamics steps ({step_s:g} s), so exposures fall on ticks")


def _tracker_image(t, name: str) -> tuple[Any, dict]:
    """Optics (a star_screen TrackerOptics) and camera noise of an image-source tracker."""
    from stand.scenario import pair
    from star_screen.geometry import TrackerOptics

    pairs = {key: pair(t, key, *spec) for key, spec in TRACKER_IMAGE_PAIRS.items()}
    values = {key: t.number(key, d, lo=lo, hi=hi, integer=integer)
              for key, (d, lo, hi, integer) in TRACKER_IMAGE_SETTINGS.items()}
    (fx_deg, fy_deg), (width, height) = pairs["fov_deg"], pairs["resolution_px"]
    optics = TrackerOptics.from_fov(fx_deg, fy_deg, width, height, psf_sigma_px=float(values["psf_sigma_px"]),
                                    mag_limit=float(values["mag_limit"]), name=name)
    aspect = (width / height) / (math.tan(math.radians(fx_deg) / 2) / math.tan(math.radians(fy_deg) / 2))
    if not 0.5 <= aspect <= 2.0:
        raise t.error("fov_deg", list(pairs["fov_deg"]),
                      f"a field whose aspect matches resolution_px {list(pairs['resolution_px'])} within a factor "
                      f"of 2 (pixels {aspect:.2f} times as tall as wide here)")
    return optics, {"read_noise_e": float(values["read_noise_e"]), "background_e": float(values["background_e"])}


class TrackerDevice(SerialDevice):
    """What every link shares: scoring solutions against the truth, the telemetry columns and the summary."""

    def __init__(self, spec: StarTrackerSpec, ctx: BuildContext):
        self.name, self.spec = spec.name, spec
        self.q_SB = tuple(float(x) for x in spec.q_SB)
        self.truth_at: dict[int, tuple] = {}  # exposure time (us of sim time) -> q_TN
        self.solutions = self.valid = 0
        self.flags = dict.fromkeys(FLAG_BITS, 0)
        self.errors: list[tuple] = []  # (t_s, cross, roll) of valid solutions
        self.last = NO_SOLUTION  # the newest solution as a telemetry row fragment (see columns())
        self.last_solution = None  # the newest decoded SOLUTION message, as the host got it
        self.image = None  # the ImageSolver of an image-source tracker
        cfg = spec.emulator
        self.silent_after_s = cfg["boot_time_s"] + cfg["output_delay_s"] + SILENT_SOLUTIONS * cfg["output_interval_s"]
        self.emulator = None
        self._seen = 0

    def _new_solution(self):
        """The newest solution the host decoded since the last call, without taking it from the flight code
        (``take_solution`` stays theirs)."""
        self.host.poll()
        n = self.host.counters["solutions"]
        if n == self._seen:
            return None
        self._seen = n
        return self.host.latest_solution

    def _score(self, sol, t_exp: float) -> None:
        self.last_solution = sol
        self.solutions += 1
        for flag in FLAG_BITS:
            self.flags[flag] += bool(getattr(sol, flag))
        q_true = self.truth_at.pop(round(t_exp * 1e6), None)
        cross = roll = math.nan
        if q_true is not None:
            cross, roll = attitude_error_arcsec(q_true, sol.q_TN)
        if sol.valid:
            self.valid += 1
            self.errors.append((t_exp, cross, roll))
        bits = sum(b for f, b in FLAG_BITS.items() if getattr(sol, f))
        self.last = (t_exp, *sol.q_TN, float(sol.valid), float(MODES.get(sol.mode, -1)), float(bits), cross, roll)
        # Keep the truth log short: exposures older than a few seconds will never be reported.
        if len(self.truth_at) > 256:
            for k in sorted(self.truth_at)[:-64]:
                del self.truth_at[k]

    def columns(self) -> list[tuple[str, int, str]]:
        """Telemetry of the newest solution the host received (repeated until the next): exposure time in sim
        time, q_TN, valid, mode (0 boot, 1 lost in space, 2 tracking), flag bits (1 Sun, 2 Moon, 4 Earth,
        8 rate), and its error against the truth at that exposure."""
        n = self.name
        return [(f"{n}.t_exposure_s", 1, "s"), (f"{n}.q_TN", 4, "1"), (f"{n}.valid", 1, "1"),
                (f"{n}.mode", 1, "1"), (f"{n}.flags", 1, "1"), (f"{n}.err_cross", 1, "arcsec"),
                (f"{n}.err_roll", 1, "arcsec")]

    def row(self) -> tuple:
        return self.last

    def activity(self) -> int:
        return self.solutions

    def summary(self) -> dict:
        err = np.array([e[1:] for e in self.errors if math.isfinite(e[1])]).reshape(-1, 2)
        out = {"solutions": self.solutions, "valid": self.valid,
               "availability": round(self.valid / self.solutions, 4) if self.solutions else 0.0,
               "flags_fired": dict(self.flags)}
        out.update(self.driver_counters())
        if self.image is not None:
            out["image"] = self.image.summary()
        if len(err):
            for i, axis in enumerate(("cross", "roll")):
                out[f"error_{axis}_arcsec"] = {p: round(float(np.percentile(err[:, i], q)), 3)
                                               for p, q in (("median", 50), ("p95", 95), ("max", 100))}
        return out



def _measure(spec: StarTrackerSpec, ctx: BuildContext, dev: TrackerDevice):
    """The emulator's measurement source: the truth (or the image solver's solution) at an exposure."""
    from drivers.star_tracker.emulator import TrackerTruth

    fields = _sky_truth(spec, ctx.truth, ctx.tracks, dev)
    if spec.source != "image":
        return lambda t_s: TrackerTruth(**fields(t_s))
    # The camera's own stream, spawned from the tracker's seed, so the emulator's draws are unchanged.
    dev.image = solver = ImageSolver(spec.optics, spec.camera, ctx.epoch, ctx.rng.spawn(1)[0])
    truth = ctx.truth

    def measure(t_s: float) -> TrackerTruth:
        out = fields(t_s)
        out.update(solver.solve(t_s, out["q_TN"], out["omega_TN_T"], truth.v_N))
        return TrackerTruth(**out)

    return measure


def _config(spec: StarTrackerSpec):
    from drivers.star_tracker.emulator import EmulatorConfig

    return EmulatorConfig(address=spec.address, **spec.emulator)


class EmulatedTracker(TrackerDevice):
    """Emulator and host on an in-process serial line (a pipe, or a pty pair: the kernel tty path a bench would
    use) without a second process; every exchange completes within the tick, so runs are repeatable."""

    def __init__(self, spec: StarTrackerSpec, ctx: BuildContext):
        from drivers.star_tracker.codec import Subscribe
        from drivers.star_tracker.emulator import StarTrackerEmulator
        from drivers.star_tracker.host import StarTrackerHost

        super().__init__(spec, ctx)
        measure = _measure(spec, ctx, self)
        self.open_emulated(spec.port,
                           lambda end: StarTrackerEmulator(end, measure, _config(spec), ctx.rng,
                                                           name=f"{spec.name} emulator"),
                           lambda end: StarTrackerHost(end, spec.address, name=spec.name))
        try:
            # Not the blocking subscribe(): nothing services the emulator while the host would wait.
            self.host.send_command(Subscribe(self.host.codec.solution_id, 0.0))
        except BaseException:
            self.close()
            raise

    def sim_time_of(self, time_us: int) -> float:
        """Invert the emulator's clock (offset and drift; no SET_TIME in an emulated run)."""
        cfg = self.emulator.config
        return (time_us * 1e-6 - cfg.clock_offset_s) / (1.0 + cfg.clock_drift_ppm * 1e-6)

    def _settle(self, done, port) -> None:
        """Wait (wall clock, bounded) until the other end has the frames written to it.

        A pty hands bytes over asynchronously: an as-fast-as-possible loop would otherwise see a frame one or
        many ticks late, a different number each run. Waiting for the exchange to complete makes every run take
        the same tick for every frame, as a paced bench would.
        """
        deadline = time.monotonic() + SETTLE_TIMEOUT_S
        while not done():
            left = deadline - time.monotonic()
            if left <= 0:
                raise DeviceTimeoutError(
                    f"{self.name}: a frame written to the serial line did not arrive within {SETTLE_TIMEOUT_S:g} s.",
                    device=self.name, awaited="frames written to the serial line", timeout_s=SETTLE_TIMEOUT_S)
            wait_readable(port, min(left, 0.01))
            if port is self.host.port:
                self.host.poll()
            else:
                return  # the emulator reads in service(); it only had to be readable

    def publish(self, t_s: float) -> None:
        emu, host = self.emulator, self.host
        if host.counters["sent"] > frames_in(emu.counters):
            self._settle(lambda: emu.port.in_waiting > 0, emu.port)
        emu.service(t_s)
        if emu.counters["sent"] > frames_in(host.counters):
            self._settle(lambda: frames_in(host.counters) >= emu.counters["sent"], host.port)
        sol = self._new_solution()
        if sol is not None:
            self._score(sol, self.sim_time_of(sol.time_us))


class HardwareTracker(TrackerDevice):
    """The host driver on a real port. At start the device clock is set to sim time 0 (SET_TIME) and the
    offset the device then reports is logged; solutions are scored against the truth at their time stamps."""

    def __init__(self, spec: StarTrackerSpec, ctx: BuildContext):
        from drivers.star_tracker.host import StarTrackerHost

        super().__init__(spec, ctx)
        self._truth = ctx.truth
        self._step_us = round(ctx.step_s * 1e6)
        self._speed = ctx.speed or 1.0
        self.host = StarTrackerHost(spec.port, spec.address, name=spec.name, baudrate=spec.baudrate)
        self.clock_offset_s = math.nan

    def start(self, events) -> None:
        host = self.host
        t_set = time.monotonic()
        host.set_time(0)
        status = host.request_status()
        # Device time runs in wall time; sim time runs `speed` times faster from the start of the run.
        self.clock_offset_s = status.time_us * 1e-6 - (time.monotonic() - t_set)
        host.subscribe("SOLUTION", 0.0)
        events.log("device_clock", f"{self.name}: device clock set to 0 at start; it then read "
                   f"{self.clock_offset_s * 1e3:+.3f} ms against the stand's clock", device=self.name,
                   offset_s=self.clock_offset_s)

    def publish(self, t_s: float) -> None:
        # The truth of every tick, to score solutions whose exposures fall on (or near) it.
        self.truth_at[round(t_s * 1e6)] = compose_floats(self.q_SB, self._truth.q)
        sol = self._new_solution()
        if sol is not None:
            t_exp = sol.time_us * 1e-6 * self._speed
            t_tick = round(t_exp * 1e6 / self._step_us) * self._step_us * 1e-6
            self._score(sol, t_tick)

    def columns(self):
        return [*super().columns(), (f"{self.name}.clock_offset_s", 1, "s")]

    def row(self):
        return (*self.last, self.clock_offset_s)

    def summary(self):
        return {**super().summary(), "clock_offset_s": self.clock_offset_s}


class ServedTracker(TrackerDevice):
    """The emulator on a real port, fed by the truth, for a flight computer outside (no host in the stand)."""

    def __init__(self, spec: StarTrackerSpec, ctx: BuildContext):
        from drivers.star_tracker.emulator import StarTrackerEmulator

        super().__init__(spec, ctx)
        self.serve(StarTrackerEmulator(spec.port, _measure(spec, ctx, self), _config(spec), ctx.rng,
                                       name=f"{spec.name} emulator", baudrate=spec.baudrate))

    def publish(self, t_s: float) -> None:
        self.emulator.service(t_s)
        self.rejections.check(t_s)

    def activity(self) -> int:
        # Silence here means the flight computer stopped talking to the tracker.
        return self.emulator.counters["frames_received"]

    def row(self) -> tuple:
        return self.last


class ImageSolver:
    """The image source of one tracker: render its detector image, add camera noise, solve it.

    Built once at compose time (renderer, catalog places, pattern database), so the first exposure
    costs what every other does. ``solve`` renders at the TRUE tracker attitude with orbital and
    annual aberration (``v_N``: the spacecraft's velocity) and the rate smear of the exposure, adds
    shot, background and read noise from its own seeded Generator, and solves the image against
    apparent places: tracking from the previous exposure's solution (propagated by the rotation
    between the two solutions before it, as a tracker's own rate estimate) when that one was valid,
    lost in space otherwise (and when tracking finds no match).
    """

    def __init__(self, optics, camera: dict, epoch, rng: np.random.Generator):
        from star_screen.geometry import default_bench
        from star_screen.render import Renderer
        from star_screen.tracking import StarTracker

        self.optics = optics
        self.camera = dict(camera)
        self.epoch = epoch
        self.rng = rng
        self.renderer = Renderer(default_bench(tracker=optics), aberration=True)
        self.tracker = StarTracker(catalog=self.renderer.catalog, mag_limit=optics.mag_limit, epoch=epoch)
        self.tracker.database(optics)  # the pattern database (about 1 s), now rather than on the first tick
        self.tracker.places(epoch, parallax=True)  # apparent places at the scenario epoch, cached
        self.exposure = self.tracker.sparse_exposure(optics, **self.camera)  # noise drawn where extraction looks
        self._last: tuple[float, np.ndarray] | None = None  # (t_s, q) of the previous exposure if valid
        self._before: tuple[float, np.ndarray] | None = None  # the valid one before it
        self.counts = {"frames": 0, "lis": 0, "tracking": 0, "failed": 0}
        self.frame_ms: list[float] = []

    def _prior(self, t_s: float):
        if self._last is None:
            return None
        t1, q1 = self._last
        if self._before is None:
            return np.array(q1)
        t0, q0 = self._before
        # The rotation of the tracker axes from t0 to t1 (w >= 0), its angle scaled to t_s - t1, then after q1.
        w0, x0, y0, z0 = q0
        w, x, y, z = hamilton_floats((w0, -x0, -y0, -z0), q1)
        if w < 0.0:
            w, x, y, z = -w, -x, -y, -z
        s = math.sqrt(x * x + y * y + z * z)
        if s == 0.0:
            return np.array(q1)
        half = math.atan2(s, w) * (t_s - t1) / (t1 - t0)
        k = math.sin(half) / s
        q = hamilton_floats(q1, (math.cos(half), k * x, k * y, k * z))
        return np.array(q if q[0] >= 0.0 else tuple(-c for c in q))

    def solve(self, t_s: float, q_TN, omega_TN_T, v_N) -> dict:
        """TrackerTruth fields measured from the exposure at ``t_s``: the solved q_TN, stars centroided
        and matched, 1-sigma errors (rad); an identity attitude and 0 stars matched when the solve fails."""
        from star_screen.render import SmearTooLong

        w0 = time.perf_counter()
        epoch = self.epoch + t_s
        v = np.asarray(v_N, dtype=float)
        try:
            _, lit, signal_e = self.renderer.detector_signal(q_TN, epoch, v_sc_gcrs_m_s=v, omega_SN_S=omega_TN_T)
        except SmearTooLong:  # stars trailed past the renderer's cap: no tracker solves such an image
            self.counts["frames"] += 1
            self.counts["failed"] += 1
            self.frame_ms.append((time.perf_counter() - w0) * 1e3)
            self._last = self._before = None
            return {"q_TN": (1.0, 0.0, 0.0, 0.0), "stars_matched": 0, "stars_in_field": 0}
        sol = self.tracker.solve_stars(self.exposure.stars(lit, signal_e, self.rng), self.optics, self._prior(t_s),
                                       observer_velocity_m_s=self.renderer.observer_velocity(epoch, v))
        self.counts["frames"] += 1
        self.frame_ms.append((time.perf_counter() - w0) * 1e3)
        seen = {"stars_in_field": int(sol.stars_centroided)}
        if not sol.valid:
            self.counts["failed"] += 1
            self._last = self._before = None
            return {"q_TN": (1.0, 0.0, 0.0, 0.0), "stars_matched": 0, **seen}
        self.counts[sol.mode] += 1
        self._before, self._last = self._last, (t_s, tuple(sol.q_SN.tolist()))
        return {"q_TN": tuple(float(x) for x in sol.q_SN), "stars_matched": int(sol.stars_matched),
                "sigma_cross_rad": float(sol.sigma_cross_arcsec) * ARCSEC,
                "sigma_roll_rad": float(sol.sigma_roll_arcsec) * ARCSEC, **seen}

    def summary(self) -> dict:
        ms = np.asarray(self.frame_ms)
        out = dict(self.counts)
        if len(ms):
            out["frame_ms"] = {"median": round(float(np.median(ms)), 2), "p95": round(float(np.percentile(ms, 95)), 2),
                               "max": round(float(ms.max()), 2)}
        return out



def _sky_truth(spec, truth, tracks: dict, link: TrackerDevice):
    """``fields(t_s)``: the TrackerTruth fields at an exposure (true q_TN, rate, Sun, Moon and Earth in
    tracker axes), logging the true attitude in ``link.truth_at``; shared by every source."""
    q_SB = link.q_SB
    bodies: dict[int, dict] = {}  # Sun and Moon per whole second: from LEO they move < 5 arcsec/s

    def fields(t_s: float) -> dict:
        if abs(t_s - truth.t_s) > 1e-6:
            raise ValueError(f"{spec.name}: exposure at t = {t_s:.6f} s but the truth is at {truth.t_s:.6f} s; "
                             "the output interval and boot time must be whole dynamics steps.")
        q_TN = compose_floats(q_SB, truth.q)
        link.truth_at[round(t_s * 1e6)] = q_TN
        rx, ry, rz = truth.r_N
        rn = math.sqrt(rx * rx + ry * ry + rz * rz)
        out = {"q_TN": q_TN, "omega_TN_T": rotate_to_body(q_SB, truth.w),
               "earth_T": rotate_to_body(q_TN, (-rx, -ry, -rz)),
               "earth_radius_rad": math.asin(min(1.0, (R_EARTH + ATMOSPHERE_M) / rn))}
        second = int(t_s)
        if second not in bodies:
            bodies.clear()
            bodies[second] = {b: tracks[b].position_gcrs(float(second)) for b in ("sun", "moon") if b in tracks}
        for body, radius in (("sun", R_SUN), ("moon", R_MOON)):
            if body in bodies[second]:
                bx, by, bz = bodies[second][body]
                d = (bx - rx, by - ry, bz - rz)
                out[f"{body}_T"] = rotate_to_body(q_TN, d)
                out[f"{body}_radius_rad"] = math.asin(radius / math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2))
        return out

    return fields


KIND = StarTrackerKind()



# How `stand emulate star-tracker` serves it (its options are many: they live beside this module).
from stand.devices.star_tracker_serving import serving  # noqa: E402

KIND.serving = serving()
