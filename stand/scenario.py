"""Scenario files: TOML with units in the key names, validated before t = 0.

Every value is checked here, before anything is built, so an impossible run is refused at once
with one sentence naming the field, the value and what is allowed (``ScenarioError``), not at
minute nine. Units are converted to SI on the way in; nothing past this module sees degrees or km.

Layout (see ``fixtures/scenarios/detumble.toml`` for a complete, commented example)::

    [scenario]     name, description, epoch (UTC ISO 8601), duration_s, seed
    [dynamics]     step_s, integrator = "rk4" | "rkmk4" | "implicit_midpoint", torques
    [orbit]        altitude_km | a_km | p_km, e, i_deg, raan_deg, argp_deg, nu_deg | mean_anomaly_deg,
                   gravity = "point" | "j2" | "jgm3", gravity_degree, third_bodies, [orbit.drag], [orbit.srp],
                   step_s
    [spacecraft]   mass_kg, inertia_kg_m2 (3 principal moments or 3x3), q_BN, omega_BN_B_deg_s
    [environment]  magnetic_field = "igrf" | "dipole", igrf_degree, earth_rotation = "iau2006" | "uniform",
                   era0_deg, eop = "iers" | "none"
    [[devices]]    name, kind = "magnetorquer" | "star_tracker" | "sun_sensor", q_SB, and per kind:
                   magnetorquer: interface, channel, sample_rate_hz, max_dipole_A_m2, mag_noise_nT, ...
                   star_tracker: port, source = "truth" | "image", noise_cross_arcsec, fov_deg, ...
                   sun_sensor: type = "coarse" | "fine", rate_hz, noise_mA | noise_deg, fov_half_deg
    [controller]   kind = "bdot" | "none" | "plugin", rate_hz, ...
    [[criteria]]   name, metric, max | min, at_s
    [recording]    rate_hz
    [rendezvous]   shadows on a docking target during an approach (``stand shadow``; see stand.rendezvous)
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sim.attitude import check_inertia
from sim.constants import R_EARTH
from sim.time import Epoch

from .errors import MISSING, ScenarioError

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
SCENARIO_DIR = FIXTURES / "scenarios"
DEFAULT_SCENARIO = SCENARIO_DIR / "detumble.toml"

TORQUES = ("magnetic", "gravity_gradient")
DEVICE_KINDS = ("magnetorquer", "star_tracker", "sun_sensor")
CONTROLLER_KINDS = ("bdot", "none", "plugin")
METRICS = {
    "final_rate_deg_s": "body rate |omega| at the end of the run (deg/s)",
    "rate_deg_s_at": "body rate |omega| at time at_s (deg/s)",
    "max_rate_deg_s_after": "largest body rate |omega| after time at_s (deg/s)",
    "frames_rejected": "device frames rejected by any codec (count)",
    "overruns": "ticks that ran past their real-time deadline (count, paced runs only)",
    "tracker_availability_after": "fraction of star-tracker solutions after time at_s that are valid",
    "tracker_error_cross_arcsec_p95": "95th percentile of the valid solutions' cross-boresight error (arcsec)",
    "tracker_error_roll_arcsec_p95": "95th percentile of the valid solutions' roll error (arcsec)",
}


class _Table:
    """A TOML table that remembers its dotted path, hands out validated values and notices typos."""

    def __init__(self, data: Any, path: str, source: str | None):
        if not isinstance(data, dict):
            raise ScenarioError(path, data, "a table of key = value pairs is expected", source)
        self.data = data
        self.path = path
        self.source = source
        self.used: set[str] = set()

    def _name(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def error(self, key: str, value, allowed: str) -> ScenarioError:
        return ScenarioError(self._name(key), value, allowed, self.source)

    def raw(self, key: str, default=MISSING):
        self.used.add(key)
        return self.data.get(key, default)

    def has(self, key: str) -> bool:
        return key in self.data

    def number(self, key: str, default=MISSING, *, lo=None, hi=None, lo_open=False, hi_open=False,
               integer=False) -> float:
        value = self.raw(key, default)
        rng = _range_text(lo, hi, lo_open, hi_open)
        kind = "a whole number" if integer else "a number"
        if value is MISSING:
            raise self.error(key, value, f"{kind}{rng} is required")
        if isinstance(value, bool) or not isinstance(value, int | float) or (integer and not isinstance(value, int)):
            raise self.error(key, value, f"{kind}{rng} is expected")
        if not math.isfinite(value):
            raise self.error(key, value, f"a finite number{rng} is expected")
        if (lo is not None and (value < lo or (lo_open and value == lo))) or (
            hi is not None and (value > hi or (hi_open and value == hi))
        ):
            raise self.error(key, value, f"{kind}{rng} is expected")
        return value

    def choice(self, key: str, options, default=MISSING) -> str:
        value = self.raw(key, default)
        if value not in options:
            raise self.error(key, MISSING if value is MISSING else value,
                             "one of " + ", ".join(repr(o) for o in options))
        return value

    def text(self, key: str, default=MISSING) -> str:
        value = self.raw(key, default)
        if not isinstance(value, str) or not value:
            raise self.error(key, value, "a non-empty string is expected")
        return value

    def vector(self, key: str, n: int, default=MISSING) -> np.ndarray:
        value = self.raw(key, default)
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            arr = None
        if value is MISSING or arr is None or arr.shape != (n,) or not np.all(np.isfinite(arr)):
            raise self.error(key, value, f"a list of {n} finite numbers is expected")
        return arr

    def table(self, key: str, required: bool = True) -> _Table:
        value = self.raw(key, MISSING)
        if value is MISSING:
            if required:
                raise ScenarioError(self._name(key), value, "this table is required", self.source)
            value = {}
        return _Table(value, self._name(key), self.source)

    def check_unknown(self, allowed_extra: tuple[str, ...] = ()) -> None:
        unknown = sorted(set(self.data) - self.used - set(allowed_extra))
        if unknown:
            key = unknown[0]
            raise self.error(key, self.data[key], "this key is not known here (a typo?); known keys: "
                             + ", ".join(sorted(self.used | set(allowed_extra))))


def _range_text(lo, hi, lo_open, hi_open) -> str:
    if lo is None and hi is None:
        return ""
    parts = []
    if lo is not None:
        parts.append(f"{'>' if lo_open else '>='} {lo:g}")
    if hi is not None:
        parts.append(f"{'<' if hi_open else '<='} {hi:g}")
    return " " + " and ".join(parts)


@dataclass(frozen=True)
class OrbitSpec:
    e: float
    i_rad: float
    raan_rad: float
    argp_rad: float
    a_m: float | None
    p_m: float | None
    nu_rad: float | None
    mean_anomaly_rad: float | None
    gravity: str
    step_s: float
    gravity_degree: int = 20
    third_bodies: tuple[str, ...] = ()
    drag: dict | None = None
    srp: dict | None = None


@dataclass(frozen=True)
class SpacecraftSpec:
    mass_kg: float
    inertia_kg_m2: np.ndarray
    q_BN: np.ndarray
    omega_BN_B: np.ndarray


@dataclass(frozen=True)
class EnvironmentSpec:
    magnetic_field: str
    earth_rotation: str
    era0_rad: float
    igrf_degree: int = 13
    eop: str = "iers"


@dataclass(frozen=True)
class MagnetorquerSpec:
    """A magnetorquer board with an on-board magnetometer on a CAN bus."""

    name: str
    link: str
    interface: str
    channel: str
    q_SB: np.ndarray
    sample_rate_hz: float
    max_dipole_A_m2: float
    dipole_lsb_A_m2: float
    mag_noise_T: float
    mag_bias_T: np.ndarray
    coil_coupling_T_per_A_m2: np.ndarray
    kind: str = "magnetorquer"


@dataclass(frozen=True)
class StarTrackerSpec:
    """A star tracker on a serial line (drivers.star_tracker), fed either by truth plus noise
    (``source = "truth"``) or by image-based solutions (``source = "image"``: the star screen renders
    its detector image, camera noise is added and ``star_screen.tracking`` solves it)."""

    name: str
    link: str
    port: str  # "pty": an in-process pty pair
    address: int | None
    q_SB: np.ndarray  # tracker frame (boresight +z) relative to body
    source: str
    emulator: dict  # keyword arguments of drivers.star_tracker.emulator.EmulatorConfig
    kind: str = "star_tracker"
    optics: Any = None  # star_screen.geometry.TrackerOptics for source = "image", else None
    camera: dict | None = None  # camera_noise keywords (read_noise_e, background_e) for source = "image"


@dataclass(frozen=True)
class SunSensorSpec:
    """Coarse (cosine heads) or fine (two-axis) sun sensor, sampled by the stand from the truth
    through ``sim.sensors`` (no bus: ``link = "model"``); eclipse-aware through the shadow model."""

    name: str
    type: str  # "coarse" | "fine"
    q_SB: np.ndarray
    rate_hz: float
    noise: float  # coarse: head current noise (A); fine: angle noise (rad)
    fov_half_deg: float
    link: str = "model"
    kind: str = "sun_sensor"


@dataclass(frozen=True)
class ControllerSpec:
    kind: str
    rate_hz: float
    params: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Criterion:
    name: str
    metric: str
    max: float | None
    min: float | None
    at_s: float | None


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    source: str
    epoch: Epoch
    duration_s: float
    seed: int
    step_s: float
    integrator: str
    torques: tuple[str, ...]
    orbit: OrbitSpec
    spacecraft: SpacecraftSpec
    environment: EnvironmentSpec
    devices: tuple[MagnetorquerSpec | StarTrackerSpec | SunSensorSpec, ...]
    controller: ControllerSpec
    criteria: tuple[Criterion, ...]
    record_rate_hz: float
    rendezvous: Any = None  # stand.rendezvous.RendezvousSpec when the scenario has a [rendezvous] section

    def device(self, kind: str) -> MagnetorquerSpec | StarTrackerSpec | None:
        return next((d for d in self.devices if d.kind == kind), None)


def load(path: str | Path) -> Scenario:
    """Read and validate a scenario file; raises ``ScenarioError`` naming the first bad field."""
    path = Path(path)
    if not path.exists() and not path.suffix:
        candidate = SCENARIO_DIR / f"{path}.toml"
        if candidate.exists():
            path = candidate
    try:
        text = path.read_text()
    except OSError as exc:
        raise ScenarioError("SCENARIO", str(path), f"a readable TOML file is required ({exc.strerror})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError("SCENARIO", str(path), f"valid TOML is required ({exc})") from None
    return parse(data, source=path.name)


def parse(data: dict, source: str | None = None) -> Scenario:
    root = _Table(data, "", source)
    sc = root.table("scenario")
    name = sc.text("name")
    description = sc.raw("description", "")
    epoch_text = sc.text("epoch")
    try:
        epoch = Epoch.from_iso(epoch_text)
    except ValueError as exc:
        raise sc.error("epoch", epoch_text, str(exc).rstrip(".")) from None
    duration_s = sc.number("duration_s", lo=0, lo_open=True, hi=30 * 86400)
    seed = int(sc.number("seed", 0, lo=0, integer=True))
    sc.check_unknown()

    dyn = root.table("dynamics")
    step_s = dyn.number("step_s", lo=1e-6, hi=10.0)
    # Fixed-step methods only: an adaptive one restarting at every control step is what the issue
    # criticises in Basilisk; DOP853 stays an offline reference (stand bench accuracy).
    integrator = dyn.choice("integrator", ("rk4", "rkmk4", "implicit_midpoint"), "rk4")
    torques = dyn.raw("torques", ["magnetic", "gravity_gradient"])
    if not isinstance(torques, list) or any(t not in TORQUES for t in torques):
        raise dyn.error("torques", torques, "a list drawn from " + ", ".join(repr(t) for t in TORQUES))
    dyn.check_unknown()

    orbit = _orbit(root.table("orbit"))
    spacecraft = _spacecraft(root.table("spacecraft"), step_s, integrator)
    environment = _environment(root.table("environment", required=False), epoch)

    devices_raw = root.raw("devices", [])
    if not isinstance(devices_raw, list):
        raise root.error("devices", devices_raw, "an array of [[devices]] tables is expected")
    devices = tuple(_device(_Table(d, f"devices[{k}]", source), step_s) for k, d in enumerate(devices_raw))
    names = [d.name for d in devices]
    if len(set(names)) != len(names):
        raise root.error("devices", names, "device names must be unique")

    controller = _controller(root.table("controller", required=False), step_s, devices)
    crit_raw = root.raw("criteria", [])
    if not isinstance(crit_raw, list):
        raise root.error("criteria", crit_raw, "an array of [[criteria]] tables is expected")
    criteria = tuple(_criterion(_Table(c, f"criteria[{k}]", source), duration_s) for k, c in enumerate(crit_raw))

    rec = root.table("recording", required=False)
    record_rate_hz = _rate(rec, "rate_hz", step_s, default=1.0 / step_s)
    rec.check_unknown()
    rendezvous = None
    if root.has("rendezvous"):
        from .rendezvous import parse_rendezvous

        rendezvous = parse_rendezvous(root.table("rendezvous"), duration_s, orbit, source)
    root.check_unknown()
    return Scenario(name, description, source or "<string>", epoch, duration_s, seed, step_s, integrator,
                    tuple(torques), orbit, spacecraft, environment, devices, controller, criteria,
                    record_rate_hz, rendezvous)


def _rate(t: _Table, key: str, step_s: float, default=MISSING) -> float:
    """A rate in Hz whose period is a whole number of dynamics steps (rates are exact ratios)."""
    hz = t.number(key, default, lo=0, lo_open=True, hi=1.0 / step_s)
    ratio = 1.0 / (hz * step_s)
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise t.error(key, hz, f"a rate whose period is a whole number of dynamics steps ({step_s:g} s), "
                      f"e.g. {1.0 / step_s:g}, {0.5 / step_s:g} or {0.1 / step_s:g} Hz")
    return hz


def _orbit(t: _Table) -> OrbitSpec:
    e = t.number("e", 0.0, lo=0.0)
    sizes = [k for k in ("altitude_km", "a_km", "p_km") if t.has(k)]
    if len(sizes) != 1:
        raise t.error("altitude_km", sizes or MISSING, "exactly one of altitude_km (circular), a_km or p_km")
    a_m = p_m = None
    if sizes[0] == "altitude_km":
        alt = t.number("altitude_km", lo=100.0, hi=100000.0)
        if e != 0.0:
            raise t.error("e", e, "0 when the orbit is given by altitude_km (a circular orbit); use a_km or p_km")
        a_m = R_EARTH + alt * 1e3
    elif sizes[0] == "a_km":
        a_m = t.number("a_km") * 1e3
        if e < 1.0 and a_m <= 0:
            raise t.error("a_km", a_m / 1e3, "a positive semi-major axis for an elliptic orbit (e < 1)")
        if e > 1.0 and a_m >= 0:
            raise t.error("a_km", a_m / 1e3, "a negative semi-major axis for a hyperbolic orbit (e > 1)")
        if e == 1.0:
            raise t.error("a_km", a_m / 1e3, "p_km instead: a parabola (e = 1) has no finite semi-major axis")
    else:
        p_m = t.number("p_km", lo=0.0, lo_open=True) * 1e3
    peri = a_m * (1.0 - e) if a_m is not None else p_m / (1.0 + e)
    if peri < R_EARTH:
        raise t.error(sizes[0], (a_m or p_m) / 1e3,
                      f"an orbit whose perigee radius ({peri / 1e3:.1f} km) is above the Earth's surface "
                      f"({R_EARTH / 1e3:.1f} km)")
    anomalies = [k for k in ("nu_deg", "mean_anomaly_deg") if t.has(k)]
    if len(anomalies) > 1:
        raise t.error("nu_deg", anomalies, "only one of nu_deg or mean_anomaly_deg")
    nu = math.radians(t.number("nu_deg", 0.0)) if "mean_anomaly_deg" not in anomalies else None
    mean = math.radians(t.number("mean_anomaly_deg")) if "mean_anomaly_deg" in anomalies else None
    spec = OrbitSpec(
        e=e,
        i_rad=math.radians(t.number("i_deg", lo=0.0, hi=180.0)),
        raan_rad=math.radians(t.number("raan_deg", 0.0, lo=-360.0, hi=360.0)),
        argp_rad=math.radians(t.number("argp_deg", 0.0, lo=-360.0, hi=360.0)),
        a_m=a_m, p_m=p_m, nu_rad=nu, mean_anomaly_rad=mean,
        gravity=t.choice("gravity", ("point", "j2", "jgm3"), "j2"),
        step_s=t.number("step_s", 10.0, lo=1e-3, hi=60.0),
        gravity_degree=int(t.number("gravity_degree", 20, lo=2, hi=20, integer=True)),
        third_bodies=tuple(_subset(t, "third_bodies", ("sun", "moon"))),
        drag=_coefficients(t, "drag", {"cd": (2.2, 0.5, 5.0), "area_m2": (None, 1e-6, 100.0)}),
        srp=_coefficients(t, "srp", {"cr": (1.5, 0.0, 2.0), "area_m2": (None, 1e-6, 100.0)}),
    )
    t.check_unknown()
    return spec


def _subset(t: _Table, key: str, options) -> list:
    value = t.raw(key, [])
    if not isinstance(value, list) or any(v not in options for v in value) or len(set(value)) != len(value):
        raise t.error(key, value, "a list drawn from " + ", ".join(repr(o) for o in options) + " without repeats")
    return value


def _coefficients(t: _Table, key: str, spec: dict) -> dict | None:
    """An optional table of named numbers: ``{name: (default or None if required, lo, hi)}``."""
    if not t.has(key):
        t.raw(key)
        return None
    sub = t.table(key)
    out = {name: sub.number(name, MISSING if d is None else d, lo=lo, hi=hi) for name, (d, lo, hi) in spec.items()}
    sub.check_unknown()
    return out


def _spacecraft(t: _Table, step_s: float, integrator: str) -> SpacecraftSpec:
    from sim.attitude import check_step
    from sim.integrators import max_angle_rad
    from sim.rotations import check_unit

    mass = t.number("mass_kg", lo=0.0, lo_open=True)
    raw_I = t.raw("inertia_kg_m2")
    try:
        inertia = check_inertia(raw_I, "spacecraft.inertia_kg_m2")
    except (ValueError, TypeError) as exc:
        raise t.error("inertia_kg_m2", raw_I, str(exc).rstrip(".")) from None
    q = t.vector("q_BN", 4, [1.0, 0.0, 0.0, 0.0])
    try:
        check_unit(q, "spacecraft.q_BN")
    except ValueError:
        raise t.error("q_BN", q.tolist(),
                      f"a unit quaternion [w, x, y, z] (its norm is {np.linalg.norm(q):.9g})") from None
    omega = np.radians(t.vector("omega_BN_B_deg_s", 3, [0.0, 0.0, 0.0]))
    try:
        check_step(inertia, omega, step_s, "dynamics.step_s", max_angle_rad(integrator), integrator)
    except ValueError as exc:
        raise ScenarioError("dynamics.step_s", step_s, str(exc).rstrip("."), t.source) from None
    t.check_unknown()
    return SpacecraftSpec(mass, inertia, q, omega)


def _environment(t: _Table, epoch: Epoch) -> EnvironmentSpec:
    spec = EnvironmentSpec(
        # IGRF-14 unless the scenario asks for the centred dipole (comparison cases).
        magnetic_field=t.choice("magnetic_field", ("igrf", "dipole"), "igrf"),
        earth_rotation=t.choice("earth_rotation", ("iau2006", "uniform"), "iau2006"),
        era0_rad=math.radians(t.number("era0_deg", 0.0, lo=-360.0, hi=360.0)),
        igrf_degree=int(t.number("igrf_degree", 13, lo=1, hi=13, integer=True)),
        eop=t.choice("eop", ("iers", "none"), "iers"),
    )
    if spec.magnetic_field == "igrf" and not 1900.0 <= epoch.decimal_year <= 2030.0:
        raise t.error("magnetic_field", "igrf", "a scenario epoch within IGRF-14's validity, 1900.0 to 2030.0, "
                      "or magnetic_field = 'dipole'")
    t.check_unknown()
    return spec


#: Star-tracker emulator settings a scenario may give: key -> (default, lo, hi, integer). Units are
#: in the names; the defaults are those of drivers.star_tracker.emulator.EmulatorConfig.
TRACKER_SETTINGS = {
    "noise_cross_arcsec": (2.0, 0.0, 3600.0, False),
    "noise_roll_arcsec": (10.0, 0.0, 3600.0, False),
    "output_interval_s": (0.2, 0.01, 60.0, False),
    "output_delay_s": (0.1, 0.0, 10.0, False),
    "clock_offset_s": (0.0, -1e6, 1e6, False),
    "clock_drift_ppm": (0.0, -1e3, 1e3, False),
    "sun_exclusion_deg": (40.0, 0.0, 90.0, False),
    "moon_exclusion_deg": (40.0, 0.0, 90.0, False),
    "earth_exclusion_deg": (30.0, 0.0, 90.0, False),
    "rate_limit_deg_s": (1.0, 0.01, 90.0, False),
    "boot_time_s": (1.0, 0.0, 600.0, False),
    "min_stars_matched": (6, 3, 100, True),
    "stable_count": (5, 1, 1000, True),
    "track_loss_count": (3, 1, 1000, True),
}
#: Settings of the truth source only: with source = "image" the image is the noise.
TRUTH_ONLY_SETTINGS = ("noise_cross_arcsec", "noise_roll_arcsec")
TRACKER_SOURCES = ("truth", "image")
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


def _whole_steps(t: _Table, key: str, value: float, step_s: float) -> None:
    n = value / step_s
    if abs(n - round(n)) > 1e-9 * max(n, 1.0):
        raise t.error(key, value, f"a whole number of dynamics steps ({step_s:g} s), so exposures fall on ticks")


def _pair(t: _Table, key: str, default, lo, hi, integer: bool) -> tuple:
    value = t.raw(key, list(default))
    kind = "whole numbers" if integer else "numbers"
    ok = isinstance(value, list) and len(value) == 2 and all(
        not isinstance(v, bool) and isinstance(v, int if integer else int | float)
        and math.isfinite(v) and lo <= v <= hi for v in value)
    if not ok:
        raise t.error(key, value, f"a list of 2 {kind} [x, y], each from {lo:g} to {hi:g}")
    return tuple(int(v) if integer else float(v) for v in value)


def _tracker_image(t: _Table, name: str) -> tuple[Any, dict]:
    """Optics (a star_screen TrackerOptics) and camera noise of an image-source tracker."""
    from star_screen.geometry import TrackerOptics

    pairs = {key: _pair(t, key, *spec) for key, spec in TRACKER_IMAGE_PAIRS.items()}
    values = {key: t.number(key, d, lo=lo, hi=hi, integer=integer)
              for key, (d, lo, hi, integer) in TRACKER_IMAGE_SETTINGS.items()}
    (fx_deg, fy_deg), (width, height) = pairs["fov_deg"], pairs["resolution_px"]
    try:
        optics = TrackerOptics.from_fov(fx_deg, fy_deg, width, height, psf_sigma_px=float(values["psf_sigma_px"]),
                                        mag_limit=float(values["mag_limit"]), name=name)
    except ValueError as exc:  # pragma: no cover - the ranges above keep the optics valid
        raise t.error("fov_deg", list(pairs["fov_deg"]), str(exc).rstrip(".")) from None
    aspect = (width / height) / (math.tan(math.radians(fx_deg) / 2) / math.tan(math.radians(fy_deg) / 2))
    if not 0.5 <= aspect <= 2.0:
        raise t.error("fov_deg", list(pairs["fov_deg"]),
                      f"a field whose aspect matches resolution_px {list(pairs['resolution_px'])} within a factor "
                      f"of 2 (pixels {aspect:.2f} times as tall as wide here)")
    return optics, {"read_noise_e": float(values["read_noise_e"]), "background_e": float(values["background_e"])}


def _star_tracker(t: _Table, name: str, link: str, q_SB: np.ndarray, step_s: float) -> StarTrackerSpec:
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
    for key, (default, lo, hi, integer) in TRACKER_SETTINGS.items():
        if source == "image" and key in TRUTH_ONLY_SETTINGS:
            continue
        v = t.number(key, default, lo=lo, hi=hi, integer=integer)
        settings[key] = int(v) if integer else float(v)
    for key in ("output_interval_s", "boot_time_s"):
        _whole_steps(t, key, settings[key], step_s)
    address = t.raw("address", None)
    if address is not None and (isinstance(address, bool) or not isinstance(address, int) or not 0 <= address <= 255):
        raise t.error("address", address, "a whole number from 0 to 255")
    optics = camera = None
    if source == "image":
        optics, camera = _tracker_image(t, name)
        # The solution is the image's: no added noise, and the stars matched are the solver's own.
        settings.update(noise_cross_arcsec=0.0, noise_roll_arcsec=0.0, match_probability=1.0)
    # In a run the flight-software side is in process; `stand emulate star-tracker --port URL` serves
    # a real flight computer instead.
    spec = StarTrackerSpec(name=name, link=link, port=t.choice("port", ("pty",), "pty"), address=address, q_SB=q_SB,
                           source=source, emulator=settings, optics=optics, camera=camera)
    t.check_unknown()
    return spec


def _sun_sensor(t: _Table, name: str, q_SB: np.ndarray, step_s: float) -> SunSensorSpec:
    kind = t.choice("type", ("coarse", "fine"))
    if kind == "coarse":
        noise = t.number("noise_mA", 0.0, lo=0.0, hi=10.0) * 1e-3
    else:
        noise = math.radians(t.number("noise_deg", 0.0, lo=0.0, hi=10.0))
    # Coarse heads default to the bare cosine law (a 90 deg half-field); a fine sensor to 60 deg.
    fov = t.number("fov_half_deg", 90.0, lo=1.0, hi=90.0) if kind == "coarse" else \
        t.number("fov_half_deg", 60.0, lo=1.0, hi=89.0)
    spec = SunSensorSpec(name=name, type=kind, q_SB=q_SB, rate_hz=_rate(t, "rate_hz", step_s, 1.0 / step_s),
                         noise=noise, fov_half_deg=fov)
    t.check_unknown()
    return spec


def _device(t: _Table, step_s: float) -> MagnetorquerSpec | StarTrackerSpec | SunSensorSpec:
    kind = t.choice("kind", DEVICE_KINDS)
    name = t.text("name")
    # A sun sensor is a model the stand samples (no device protocol yet); the others are emulated.
    link = t.choice("link", ("model",) if kind == "sun_sensor" else ("emulated",),
                    "model" if kind == "sun_sensor" else "emulated")
    q_SB = t.vector("q_SB", 4, [1.0, 0.0, 0.0, 0.0])
    if abs(np.linalg.norm(q_SB) - 1.0) > 1e-6:
        raise t.error("q_SB", q_SB.tolist(), "a unit quaternion [w, x, y, z] (sensor frame relative to body)")
    if kind == "sun_sensor":
        return _sun_sensor(t, name, q_SB, step_s)
    if kind == "star_tracker":
        return _star_tracker(t, name, link, q_SB, step_s)
    max_dipole = t.number("max_dipole_A_m2", 0.2, lo=0.0, lo_open=True, hi=100.0)
    spec = MagnetorquerSpec(
        kind=kind,
        name=name,
        link=link,
        interface=t.text("interface", "virtual"),
        channel=t.text("channel", f"stand-{name}"),
        q_SB=q_SB,
        sample_rate_hz=_rate(t, "sample_rate_hz", step_s, 10.0),
        max_dipole_A_m2=max_dipole,
        dipole_lsb_A_m2=t.number("dipole_lsb_A_m2", 1e-5, lo=0.0, hi=max_dipole),
        mag_noise_T=t.number("mag_noise_nT", 0.0, lo=0.0, hi=1e5) * 1e-9,
        mag_bias_T=t.vector("mag_bias_nT", 3, [0.0, 0.0, 0.0]) * 1e-9,
        coil_coupling_T_per_A_m2=np.asarray(
            t.vector("coil_coupling_nT_per_A_m2", 3, [0.0, 0.0, 0.0]), dtype=float) * 1e-9,
    )
    t.check_unknown()
    return spec


def _controller(t: _Table, step_s: float, devices) -> ControllerSpec:
    kind = t.choice("kind", CONTROLLER_KINDS, "none")
    if kind == "none":
        t.check_unknown()
        return ControllerSpec("none", 1.0 / step_s)
    rate = _rate(t, "rate_hz", step_s)
    params: dict = {}
    if kind == "bdot":
        if not any(d.kind == "magnetorquer" for d in devices):
            raise t.error("kind", kind, "a controller that has its devices: B-dot needs a [[devices]] entry "
                          "of kind 'magnetorquer'")
        params["gain_A_m2_s_per_T"] = t.number("gain_A_m2_s_per_T", lo=0.0, lo_open=True)
        params["max_dipole_A_m2"] = t.number("max_dipole_A_m2", lo=0.0, lo_open=True)
        params["skip_coil_active"] = bool(t.raw("skip_coil_active", True))
        # Coils on for this fraction of the control period; the on-time must be whole dynamics steps
        # so the zero-order hold switches exactly on a step boundary.
        duty = t.number("duty_cycle", 1.0, lo=0.0, lo_open=True, hi=1.0)
        on_steps = duty / (rate * step_s)
        if abs(on_steps - round(on_steps)) > 1e-9 * on_steps:
            raise t.error("duty_cycle", duty, f"a fraction whose on-time is whole dynamics steps of {step_s:g} s "
                          f"(the control period is {1.0 / rate:g} s)")
        params["duty_cycle"] = duty
    else:
        params["module"] = t.text("module")
        params["options"] = t.raw("options", {})
    t.check_unknown()
    return ControllerSpec(kind, rate, params)


def _criterion(t: _Table, duration_s: float) -> Criterion:
    metric = t.choice("metric", tuple(METRICS))
    c = Criterion(
        name=t.text("name", metric),
        metric=metric,
        max=t.number("max") if t.has("max") else None,
        min=t.number("min") if t.has("min") else None,
        at_s=t.number("at_s", lo=0.0, hi=duration_s) if t.has("at_s") else None,
    )
    if c.max is None and c.min is None:
        raise t.error("max", MISSING, "a max or a min limit for the criterion")
    if metric in ("rate_deg_s_at", "max_rate_deg_s_after", "tracker_availability_after") and c.at_s is None:
        raise t.error("at_s", MISSING, f"a time in [0, {duration_s:g}] s for metric {metric!r}")
    t.check_unknown()
    return c
