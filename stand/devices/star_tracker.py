"""Star trackers on a serial line (``drivers.star_tracker``, the ICD in ``fixtures/devices/star_tracker.toml``).

The stand hands the emulator a measurement source (``TrackerTruth`` at an exposure time: the tracker-frame
attitude, its rate, and the Sun, Moon and Earth seen from the spacecraft) and reads the solutions back through
the real protocol (SLIP frames, CRC). Each solution is compared with the truth at its mid-exposure time,
recovered from the device time stamp, so the summary reports what a flight computer would have received and
how wrong it was.

Two sources feed the emulator. ``truth``: the true attitude, to which the emulator adds its configured noise.
``image``: the star screen renders the tracker's detector image at the true attitude, camera noise is added and
``star_screen.tracking`` solves it (``ImageSolver``, in ``star_tracker_source``); the emulator is handed the
solved attitude and the stars matched, with its own noise at 0.

Links: ``emulated`` (emulator and host on an in-process serial line, ``port = "pipe"`` (default) or a kernel pty
pair with ``port = "pty"``, every exchange settled within the tick, so a
run is bit-for-bit repeatable), ``hardware`` (the host on a real port: the stand sets the device clock to sim
time at start, logs the offset it measures, and scores each solution against the truth at its time stamp),
``served`` (the emulator on a real port, fed by the truth, for a flight computer outside).
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from stand.checks import pair
from stand.devices import (
    SERIAL_LINES,
    BuildContext,
    Device,
    DeviceCost,
    DeviceKind,
    DeviceSpec,
    check_serial_url,
    fault_taps,
)
from stand.devices.star_screen_link import ScreenTracker, describe_screen, parse_screen
from stand.devices.star_tracker_devices import (
    FLAG_BITS,
    ICD_FLAG_BITS,
    MODES,
    EmulatedTracker,
    HardwareTracker,
    ServedTracker,
    StarTrackerSpec,
)
from stand.devices.star_tracker_serving import serving

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


class StarTrackerKind(DeviceKind):
    name = "star_tracker"
    senses = ("attitude", "star_sky", "time")
    column_meanings = {"t_exposure_s": "exposure time of the newest solution the host decoded, stand time",
                       "q_TN": "that solution: tracker frame relative to inertial, scalar first",
                       "valid": "1 when that solution is valid",
                       "mode": "the tracker's mode (0 boot, 1 lost in space, 2 tracking)",
                       "flags": "that solution's flags byte as the ICD sends it (bits below)",
                       "err_cross": "that solution's error across the boresight against the truth",
                       "err_roll": "that solution's error about the boresight against the truth",
                       "clock_offset_s": "tracker clock minus stand clock, measured at start (hardware link)",
                       "screen_t_lit_s": "time tag of the newest star-screen frame sent: the middle of the tick it "
                                         "is lit (hardware tracker looking at the screen)",
                       "screen_lead_s": "that time tag minus the tick's time (hardware tracker looking at the screen)"}
    column_bits = {"flags": tuple(ICD_FLAG_BITS)}
    plot_files = {"tracker_{name}.png": "solution errors with their limits, validity, mode and flags"}
    view_layer_meanings = {"fovs": "the field of view", "exclusion_deg": "the Sun, Moon and Earth exclusion cones",
                           "rate_limit_deg_s": "the body rate above which it cannot solve",
                           "image": "its detector image, shown live when it renders one (source = image)"}
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
                "rate_limit_deg_s": float(em["rate_limit_deg_s"]) if "rate_limit_deg_s" in em else None,
                "image": _image_layer(spec, optics, em)}
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
        spec = StarTrackerSpec(**base.__dict__, port=port, baudrate=baud, address=address, source=source,
                               emulator=settings, optics=optics, camera=camera, screen=parse_screen(t, base.link))
        t.check_unknown()
        return spec

    def needs(self, spec) -> dict[str, str]:
        if spec.link == "hardware":
            if spec.screen is None:
                return {}
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

    def datasheet(self, spec: StarTrackerSpec) -> dict:
        # Timing and exclusion angles (the ICD's parameters); its noise is the simulated unit's.
        e = spec.emulator
        out = {"output_interval_s": e.get("output_interval_s"), "output_delay_s": e.get("output_delay_s"),
               "rate_limit_rad_s": math.radians(e["rate_limit_deg_s"]) if "rate_limit_deg_s" in e else None,
               **{f"{b}_exclusion_rad": math.radians(e[f"{b}_exclusion_deg"]) if f"{b}_exclusion_deg" in e else None
                  for b in ("sun", "moon", "earth")}}
        if spec.optics is not None:
            out["fov_rad"] = tuple(math.radians(x) for x in spec.optics.fov_deg)
        return {k: v for k, v in out.items() if v is not None}

    def describe(self, spec) -> str:
        what = "solved from its rendered detector image" if spec.source == "image" else f"{spec.source} plus noise"
        every = f"a solution every {spec.emulator['output_interval_s']:g} s"
        if spec.screen is not None:
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

    def fault_taps(self, spec: StarTrackerSpec) -> dict:
        if spec.screen is not None:  # a real tracker before the star screen: its line, and the sky the screen shows
            return {"link": {}, "stimulus": {}}
        return fault_taps(spec.link, "tracker")

    def build(self, spec: StarTrackerSpec, ctx: BuildContext) -> Device:
        if spec.screen is not None:
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
        # lazy: the figures load matplotlib, which only drawing a report needs
        from stand.devices.star_tracker_plots import plot_tracker

        lim = {c["metric"]: c for c in criteria}

        def most(metric):
            return lim[metric]["limit"].get("max") if metric in lim else None

        avail = lim.get("tracker_availability_after")
        availability = (avail["limit"]["min"], avail.get("at_s", 0.0)) if avail and "min" in avail["limit"] else None
        return [plot_tracker(tel, out_dir, name, cross_limit_arcsec=most("tracker_error_cross_arcsec_p95"),
                             roll_limit_arcsec=most("tracker_error_roll_arcsec_p95"), availability=availability,
                             modes=MODES, flag_bits=FLAG_BITS)]


def _image_layer(spec, optics, em: dict) -> dict:
    """The live page's image panel: whether the tracker renders (source = image), its detector size and the delay
    from an exposure to its solution (the telemetry sample whose validity and flags belong to a shown frame)."""
    if getattr(spec, "source", "truth") != "image" or optics is None:
        return {"renders": False, "why": f"source = {getattr(spec, 'source', 'truth')!r}: this tracker does not "
                "render"}
    return {"renders": True, "size_px": [int(optics.width), int(optics.height)],
            "delay_s": float(em.get("output_delay_s", 0.1))}


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




KIND = StarTrackerKind()


# How `stand emulate star-tracker` serves it (its options are many: they live beside this module).
KIND.serving = serving()
