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
    [[devices]]    name, kind = "magnetorquer" | "star_tracker" | "sun_sensor" | "cage" | "gyro" | "reaction_wheel",
                   q_SB, and per kind:
                   magnetorquer: interface, channel, sample_rate_hz, max_dipole_A_m2, mag_noise_nT, ...
                   star_tracker: port, source = "truth" | "image", noise_cross_arcsec, fov_deg, ...
                   sun_sensor: type = "coarse" | "fine", port, rate_hz, noise_mA | noise_deg, fov_half_deg, ...
                   gyro: port, output_rate_hz, ideal, arw_deg_sqrt_h, bias_instability_deg_h, delay_s, ...
                   reaction_wheel: interface, channel, wheel, spin_axis_B, inertia_kg_m2, max_torque_Nm, ...
    [controller]   kind = "bdot" | "none" | "plugin" | "external" | "pointing", rate_hz, budget_s, ...
                   (pointing: [controller.options] of stand.adcs.pointing.PointingController, devices by name;
                   [controller.datasheet.NAME] of its star tracker and gyro, datasheet_margin: what its filter is
                   tuned from, never the simulated devices' own noise)
    [[criteria]]   name, metric, max | min, at_s (metrics that take a time only)
    [recording]    rate_hz
    [rendezvous]   shadows on a docking target during an approach (``stand shadow``; see stand.rendezvous)

A key the run would ignore is refused, not accepted: one another setting leaves unused (``era0_deg`` under
``earth_rotation = "iau2006"``, ``eop`` under ``"uniform"``, ``igrf_degree`` under a dipole, ``gravity_degree``
without ``"jgm3"``, an ``[environment]`` setting of a model nothing in the scene evaluates, ``at_s`` of a metric
without a time, a controller key of another kind), because a campaign dispersing it would record different
inputs for identical runs. A required key given without its unit (``duration = 10``) is named as the mistake,
with the key it probably meant. Numbers are finite and of normal size (a subnormal rate has an infinite period).
"""

from __future__ import annotations

import difflib
import math
import re
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import fixtures
from sim.attitude import check_inertia
from sim.constants import MU_EARTH, R_EARTH
from sim.time import Epoch

from .adcs.metrics import METRICS as POINTING_METRICS
from .devices import DeviceSpec
from .errors import MISSING, ScenarioError, shown

FIXTURES = fixtures.ROOT
SCENARIO_DIR = FIXTURES / "scenarios"
DEFAULT_SCENARIO = SCENARIO_DIR / "detumble.toml"

TORQUES = ("magnetic", "gravity_gradient")
CONTROLLER_KINDS = ("bdot", "none", "plugin", "external", "pointing")
#: ``controller.budget_s`` when not given: wall-clock seconds one call into the flight code may take.
DEFAULT_BUDGET_S = 1.0
#: Devices the reference pointing ADCS (``controller.kind = "pointing"``) takes by name: option -> device kind.
POINTING_DEVICES = {"star_tracker": "star_tracker", "gyro": "gyro", "magnetorquer": "magnetorquer",
                    "sun_sensor": "sun_sensor"}
#: The Earth's Hill sphere radius, km: the largest orbit the Earth alone governs.
HILL_KM = 1.5e6
#: Largest principal moment of inertia a scenario may give (a space station is about 1e8 kg m^2).
MAX_INERTIA_KG_M2 = 1e10
#: Longest period of a rate, in dynamics steps: whole numbers of steps stay exact in a float below 2**53, and a
#: period of 30 days at the smallest step (1e-6 s) is 2.6e12 steps.
MAX_STEPS_PER_PERIOD = 1e13
#: Strongest geomagnetic field at the Earth's surface, T (IGRF: about 66 uT south of Australia; the centred
#: dipole's pole field is 61 uT); it falls with the cube of the distance.
MAX_FIELD_T = 6.7e-5
#: A scenario file larger than this is refused before it is parsed (the shipped ones are under 5 KiB).
MAX_FILE_BYTES = 1 << 20
#: Run names become folder names under the output folder: a plain name, no path.
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,99}")
#: Keys printed as they are in an error; any other key is quoted and cut.
KEY_PATTERN = re.compile(r"[A-Za-z0-9_-]{1,100}")
#: Control characters (C0 but tab, DEL, C1): refused in text that reaches a console or a report.
CONTROL = re.compile("[\x00-\x08\x0a-\x1f\x7f-\x9f]")
#: Metrics of the run itself; device kinds add theirs (stand.devices.DeviceKind.metrics).
METRICS = {
    "final_rate_deg_s": "body rate |omega| at the end of the run (deg/s)",
    "rate_deg_s_at": "body rate |omega| at time at_s (deg/s)",
    "max_rate_deg_s_after": "largest body rate |omega| after time at_s (deg/s)",
    "frames_rejected": "device frames rejected by any codec (count)",
    "overruns": "ticks that ran past their real-time deadline (count, paced runs only)",
}
# Metrics on the controller's estimate and reference, read from its telemetry columns by convention
# (stand.adcs.metrics): they all take at_s, the settle time.
METRICS.update(POINTING_METRICS)
#: Units of the metrics, for the console and the report.
METRIC_UNITS = {"final_rate_deg_s": "deg/s", "rate_deg_s_at": "deg/s", "max_rate_deg_s_after": "deg/s",
                "frames_rejected": "frames", "overruns": "ticks", "tracker_availability_after": "",
                "tracker_error_cross_arcsec_p95": "arcsec", "tracker_error_roll_arcsec_p95": "arcsec",
                "pointing_error_arcsec_p95_after": "arcsec", "knowledge_error_arcsec_p95_after": "arcsec",
                "knowledge_within_3sigma_fraction": ""}


def all_metrics() -> dict[str, str]:
    """The run's metrics and those of every device kind."""
    from stand import devices

    out = dict(METRICS)
    for name in devices.kind_names():
        out.update(devices.get(name).metrics)
    return out


class Table:
    """A TOML table that remembers its dotted path, hands out validated values and notices typos."""

    def __init__(self, data: Any, path: str, source: str | None):
        if not isinstance(data, dict):
            raise ScenarioError(path, data, "a table of key = value pairs is expected", source)
        self.data = data
        self.path = path
        self.source = source
        self.used: set[str] = set()

    def _name(self, key: str) -> str:
        # A key is any string in TOML: one with a line break or a megabyte of text is quoted and cut, so the
        # error stays one short line.
        if not KEY_PATTERN.fullmatch(key):
            key = shown(key)
        return f"{self.path}.{key}" if self.path else key

    def error(self, key: str, value, allowed: str) -> ScenarioError:
        if value is MISSING and key not in self.data:
            # A required key is missing: when the table has it under another spelling (``duration = 10`` for
            # ``duration_s``), that key is the mistake to name, not the missing one.
            meant = [k for k in self.data if k not in self.used and key in _likely_meant(k, (key,))]
            if meant:
                return self.error(meant[0], self.data[meant[0]], f"this key is not known here; did you mean "
                                  f"{key!r} (units are part of the key's name)?")
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
        if 0 < abs(value) < sys.float_info.min:
            # A subnormal has lost its precision and its inverse (a period, a rate) overflows to infinity.
            raise self.error(key, value, f"a number of normal size{rng}, not a subnormal (below "
                             f"{sys.float_info.min:.4g}, whose inverse overflows to infinity)")
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
        if not isinstance(value, str) or not value or CONTROL.search(value):
            # Names, ports and paths reach file systems, buses and consoles: a NUL or an escape has no place there.
            raise self.error(key, value, "a non-empty string without control characters is expected")
        return value

    def vector(self, key: str, n: int, default=MISSING, *, lo=None, hi=None) -> np.ndarray:
        value = self.raw(key, default)
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError, OverflowError):
            arr = None
        rng = _range_text(lo, hi, False, False)
        if (value is MISSING or arr is None or arr.shape != (n,) or not np.all(np.isfinite(arr))
                or any(isinstance(v, bool) for v in value)):
            raise self.error(key, value, f"a list of {n} finite numbers{rng} is expected")
        if (lo is not None and np.any(arr < lo)) or (hi is not None and np.any(arr > hi)):
            raise self.error(key, value, f"a list of {n} numbers, each{rng}")
        return arr

    def flag(self, key: str, default=MISSING) -> bool:
        value = self.raw(key, default)
        if not isinstance(value, bool):
            raise self.error(key, value, "true or false")
        return value

    def table(self, key: str, required: bool = True) -> Table:
        value = self.raw(key, MISSING)
        if value is MISSING:
            if required:
                raise ScenarioError(self._name(key), value, "this table is required", self.source)
            value = {}
        return Table(value, self._name(key), self.source)

    def check_unknown(self, allowed_extra: tuple[str, ...] = ()) -> None:
        unknown = sorted(set(self.data) - self.used - set(allowed_extra))
        if unknown:
            key = unknown[0]
            known = sorted(self.used | set(allowed_extra))
            meant = _likely_meant(key, known)
            hint = f"did you mean {' or '.join(repr(m) for m in meant)}?" if meant else "a typo?"
            raise self.error(key, self.data[key], f"this key is not known here ({hint}); known keys: "
                             + ", ".join(known))

    def refuse_unused(self, key: str, setting: str, what_to_do: str) -> None:
        """Refuse a key the scenario gives but whose value the run would ignore under ``setting``: a campaign that
        dispersed it would record different inputs for identical runs."""
        if key in self.data:
            raise self.error(key, self.data[key], f"{setting} leaves this key unused (its value, or a campaign's "
                             f"dispersion of it, would change nothing); {what_to_do}")


def _likely_meant(key: str, known) -> list[str]:
    """Known keys a given key probably meant: the same name with a unit suffix (``duration`` for ``duration_s``),
    another unit (``duration_min``), or a close spelling."""
    if not isinstance(key, str):
        return []
    stem = key.rsplit("_", 1)[0]
    out = [k for k in known if k != key and (k.startswith(key + "_") or (k.rsplit("_", 1)[0] == stem and "_" in k
                                                                          and "_" in key))]
    return out or difflib.get_close_matches(key, [k for k in known if k != key], n=2, cutoff=0.8)


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
    devices: tuple[DeviceSpec, ...]
    controller: ControllerSpec
    criteria: tuple[Criterion, ...]
    record_rate_hz: float
    rendezvous: Any = None  # stand.rendezvous.RendezvousSpec when the scenario has a [rendezvous] section

    def device(self, kind: str) -> DeviceSpec | None:
        return next((d for d in self.devices if d.kind == kind), None)

    @property
    def wall_time_links(self) -> list[str]:
        """Devices whose other end runs in wall time (hardware and served links): the run must be paced."""
        from stand.devices import WALL_TIME_LINKS

        return [d.name for d in self.devices if d.link in WALL_TIME_LINKS]


def shipped() -> dict[str, str]:
    """The scenarios shipped in ``fixtures/scenarios``: name -> one-line description."""
    out = {}
    for f in sorted(SCENARIO_DIR.glob("*.toml")):
        try:
            data = tomllib.loads(f.read_text(encoding="utf-8"))
        except (tomllib.TOMLDecodeError, OSError):
            data = {"scenario": {"description": "(unreadable)"}}
        if "scenario" in data:  # a campaign's dispersion file lives beside its scenario but is none
            out[f.stem] = data["scenario"].get("description", "")
    return out


def find(arg: str | Path) -> Path:
    """A scenario by path, by shipped name, or by shipped name with ``.toml``; ScenarioError with the closest
    shipped names otherwise. A file wins over a shipped name; a folder never counts as a scenario."""
    path = Path(arg)
    if path.is_file():
        return path
    stem = path.name[:-5] if path.name.endswith(".toml") else path.name
    if path.parent == Path(".") and (SCENARIO_DIR / f"{stem}.toml").is_file():
        return SCENARIO_DIR / f"{stem}.toml"
    names = list(shipped())
    close = difflib.get_close_matches(stem, names, n=3, cutoff=0.5)
    hint = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
    what = "a folder, not a scenario file; " if path.is_dir() else ""
    raise ScenarioError("SCENARIO", str(arg), f"{what}a scenario file or a shipped name ({', '.join(names)}){hint}")


def load(path: str | Path, overrides: list[str] | None = None) -> Scenario:
    """Read and validate a scenario file (a path or a shipped name), with ``KEY=VALUE`` overrides applied
    (``set_value``); raises ``ScenarioError`` naming the first bad field."""
    path = find(path)
    try:
        size = path.stat().st_size
        # The size a file reports is not always what it holds (procfs says 0): read no more than the limit allows.
        with path.open("rb") as f:
            raw = f.read(MAX_FILE_BYTES + 1)
        if size > MAX_FILE_BYTES or len(raw) > MAX_FILE_BYTES:
            raise ScenarioError("SCENARIO", str(path), f"a scenario file under {MAX_FILE_BYTES >> 10} KiB "
                                f"(this one has {max(size, len(raw))}{'' if size > MAX_FILE_BYTES else ' or more'} "
                                "bytes)")
        text = raw.decode("utf-8")
    except OSError as exc:
        raise ScenarioError("SCENARIO", str(path), f"a readable TOML file is required ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise ScenarioError("SCENARIO", str(path), f"a UTF-8 text file (byte {exc.start} is not UTF-8)") from None
    data = loads(text, str(path))
    for item in overrides or []:
        set_value(data, item)
    return parse(data, source=path.name)


def loads(text: str, where: str = "<string>") -> dict:
    """TOML text to a dict, every failure (syntax, nesting too deep for the parser) a ScenarioError."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError("SCENARIO", where, f"valid TOML is required ({exc})") from None
    except RecursionError:
        raise ScenarioError("SCENARIO", where, "TOML without arrays or tables nested hundreds deep") from None


def set_value(data: dict, item: str) -> None:
    """Apply one ``dotted.key=VALUE`` override (VALUE in TOML syntax; a bare word is a string). A
    ``[[devices]]`` entry is addressed by its name: ``devices.mtq.channel=can1``."""
    key, sep, text = item.partition("=")
    if not sep or not key.strip():
        raise ScenarioError("--set", item, "KEY=VALUE with a dotted key, e.g. devices.mtq.channel=can1")
    try:
        value = tomllib.loads(f"v = {text.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = text.strip()
    parts = key.strip().split(".")
    if any(not part.strip() for part in parts):
        raise ScenarioError("--set", item, "a dotted key without an empty part, e.g. devices.mtq.channel=can1")
    node: Any = data
    for i, part in enumerate(parts[:-1]):
        if isinstance(node, list):
            match = [d for d in node if isinstance(d, dict) and d.get("name") == part]
            if not match:
                raise ScenarioError("--set", item, f"a name of an entry of {'.'.join(parts[:i]) or 'the list'}")
            node = match[0]
        else:
            node = node.setdefault(part, {})
            if not isinstance(node, dict | list):
                raise ScenarioError("--set", item, f"a key inside a table ({'.'.join(parts[:i + 1])} is a value)")
    if isinstance(node, list):
        names = [str(d.get("name")) for d in node if isinstance(d, dict)]
        where = ".".join(parts[:-1])
        if parts[-1] not in names:
            raise ScenarioError("--set", item, f"a name of an entry of {where} ({', '.join(names) or 'none'}) "
                                "and one of its keys, e.g. devices.mtq.channel=can1")
        raise ScenarioError("--set", item, f"a key inside the entry: {key.strip()} names an entry of {where}, so "
                            f"set one of its keys, e.g. {key.strip()}.KEY=VALUE")
    if not isinstance(node, dict):
        raise ScenarioError("--set", item, "a key of a table")
    node[parts[-1]] = value  # an inline table replaces the whole table: --set 'controller={kind = "external"}'


def parse(data: dict, source: str | None = None) -> Scenario:
    root = Table(data, "", source)
    sc = root.table("scenario")
    name = sc.text("name")
    if not NAME_PATTERN.fullmatch(name):
        raise sc.error("name", name, "a plain name of letters, digits, '_', '.' and '-' (at most 100, not "
                       "starting with '.'): it names the run's folder, which stays inside the output folder")
    description = sc.raw("description", "")
    epoch_text = sc.text("epoch")
    try:
        epoch = Epoch.from_iso(epoch_text)
    except ValueError as exc:
        # The value is already in the sentence (cut to its first 200 characters); the model's message repeats it.
        raise sc.error("epoch", epoch_text, str(exc).replace(f"epoch {epoch_text!r}", "the epoch").rstrip(".")) \
            from None
    duration_s = sc.number("duration_s", lo=0, lo_open=True, hi=30 * 86400)
    if not isinstance(description, str) or len(description) > 2000 or CONTROL.search(description):
        # It is printed on consoles and in reports: no control characters (terminal escapes, NUL), no novels.
        raise sc.error("description", description, "a string of at most 2000 characters without control characters")
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
    if step_s > duration_s:
        raise dyn.error("step_s", step_s, f"a step no longer than the run (scenario.duration_s = {duration_s:g} s): "
                        "a run simulates whole steps")
    dyn.check_unknown()

    orbit = _orbit(root.table("orbit"))
    spacecraft = _spacecraft(root.table("spacecraft"), step_s, integrator)
    env_table = root.table("environment", required=False)
    environment = _environment(env_table, epoch)

    devices_raw = root.raw("devices", [])
    if not isinstance(devices_raw, list):
        raise root.error("devices", devices_raw, "an array of [[devices]] tables is expected")
    devices = tuple(_device(Table(d, f"devices[{k}]", source), step_s) for k, d in enumerate(devices_raw))
    names = [d.name for d in devices]
    if len(set(names)) != len(names):
        raise root.error("devices", names, "device names must be unique")
    _check_refs(devices, source)
    _check_environment_used(env_table, environment, epoch, torques, orbit, devices)

    controller = _controller(root.table("controller", required=False), step_s, devices)
    _check_torque_reach(spacecraft, orbit, devices, torques, controller, step_s, integrator, source)
    crit_raw = root.raw("criteria", [])
    if not isinstance(crit_raw, list):
        raise root.error("criteria", crit_raw, "an array of [[criteria]] tables is expected")
    criteria = tuple(_criterion(Table(c, f"criteria[{k}]", source), duration_s) for k, c in enumerate(crit_raw))

    rec = root.table("recording", required=False)
    record_rate_hz = rate(rec, "rate_hz", step_s, default=1.0 / step_s)
    rec.check_unknown()
    rendezvous = None
    if root.has("rendezvous"):
        from .rendezvous import parse_rendezvous

        rendezvous = parse_rendezvous(root.table("rendezvous"), duration_s, orbit, source)
    root.check_unknown()
    sc = Scenario(name, description, source or "<string>", epoch, duration_s, seed, step_s, integrator,
                  tuple(torques), orbit, spacecraft, environment, devices, controller, criteria,
                  record_rate_hz, rendezvous)
    if controller.kind == "pointing":
        _check_pointing(sc)
    return sc


def _check_pointing(sc: Scenario) -> None:
    """Construct the pointing controller over unopened devices, so a bad option is a ScenarioError at load."""
    from .adcs import PluginError, check_controller

    try:
        check_controller(sc)
    except PluginError as exc:
        text = str(exc).removeprefix("controller.kind = 'pointing': ").rstrip(".")
        m = re.match(r"options\.(\w+)", text)
        options = sc.controller.params["options"]
        key = m.group(1) if m else None
        if key and "; " in text:
            text = text.split("; ", 1)[1]  # the rule only: the value is shown once, shortened, by the error
        text = " ".join(text.split())[:300]
        raise ScenarioError(f"controller.options.{key}" if key else "controller.options",
                            options.get(key, MISSING) if key else sorted(options)[:20],
                            f"an option PointingController accepts ({text})", sc.source) from None


def rate(t: Table, key: str, step_s: float, default=MISSING) -> float:
    """A rate in Hz whose period is a whole number of dynamics steps (rates are exact ratios)."""
    hz = t.number(key, default, lo=0, lo_open=True, hi=1.0 / step_s)
    # Compared before dividing: hz * step_s may underflow to 0 for a tiny rate.
    if hz < 1.0 / (MAX_STEPS_PER_PERIOD * step_s):
        raise t.error(key, hz, f"a rate whose period is at most {MAX_STEPS_PER_PERIOD:g} dynamics steps "
                      f"({step_s:g} s), i.e. >= {1.0 / (MAX_STEPS_PER_PERIOD * step_s):.6g} Hz")
    ratio = 1.0 / (hz * step_s)
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise t.error(key, hz, f"a rate whose period is a whole number of dynamics steps ({step_s:g} s), "
                      f"e.g. {1.0 / step_s:g}, {0.5 / step_s:g} or {0.1 / step_s:g} Hz")
    return hz


def pair(t: Table, key: str, default, lo, hi, integer: bool) -> tuple:
    """A list of two numbers ``[x, y]``, each within ``[lo, hi]``."""
    value = t.raw(key, list(default))
    kind = "whole numbers" if integer else "numbers"
    ok = isinstance(value, list) and len(value) == 2 and all(
        not isinstance(v, bool) and isinstance(v, int if integer else int | float)
        and math.isfinite(v) and lo <= v <= hi for v in value)
    if not ok:
        raise t.error(key, value, f"a list of 2 {kind} [x, y], each from {lo:g} to {hi:g}")
    return tuple(int(v) if integer else float(v) for v in value)


def _orbit(t: Table) -> OrbitSpec:
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
        # Beyond the Earth's Hill sphere (1.5 million km) an orbit about the Earth alone means nothing.
        a_m = t.number("a_km", lo=-HILL_KM, hi=HILL_KM) * 1e3
        if e < 1.0 and a_m <= 0:
            raise t.error("a_km", a_m / 1e3, "a positive semi-major axis for an elliptic orbit (e < 1)")
        if e > 1.0 and a_m >= 0:
            raise t.error("a_km", a_m / 1e3, "a negative semi-major axis for a hyperbolic orbit (e > 1)")
        if e == 1.0:
            raise t.error("a_km", a_m / 1e3, "p_km instead: a parabola (e = 1) has no finite semi-major axis")
    else:
        p_m = t.number("p_km", lo=0.0, lo_open=True, hi=2 * HILL_KM) * 1e3
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
    if spec.gravity != "jgm3":
        t.refuse_unused("gravity_degree", f"orbit.gravity = {spec.gravity!r} (only the JGM-3 field has a degree)",
                        "remove it, or set gravity = 'jgm3'")
    return spec


def _subset(t: Table, key: str, options) -> list:
    value = t.raw(key, [])
    if not isinstance(value, list) or any(v not in options for v in value) or len(set(value)) != len(value):
        raise t.error(key, value, "a list drawn from " + ", ".join(repr(o) for o in options) + " without repeats")
    return value


def _coefficients(t: Table, key: str, spec: dict) -> dict | None:
    """An optional table of named numbers: ``{name: (default or None if required, lo, hi)}``."""
    if not t.has(key):
        t.raw(key)
        return None
    sub = t.table(key)
    out = {name: sub.number(name, MISSING if d is None else d, lo=lo, hi=hi) for name, (d, lo, hi) in spec.items()}
    sub.check_unknown()
    return out


def _spacecraft(t: Table, step_s: float, integrator: str) -> SpacecraftSpec:
    from sim.attitude import check_step
    from sim.integrators import max_angle_rad
    from sim.rotations import check_unit

    mass = t.number("mass_kg", lo=0.0, lo_open=True, hi=1e7)
    raw_I = t.raw("inertia_kg_m2")
    if not (_numbers(raw_I, 3) or (isinstance(raw_I, list) and len(raw_I) == 3 and all(_numbers(r, 3) for r in raw_I))):
        raise t.error("inertia_kg_m2", raw_I, "3 principal moments [I1, I2, I3] or a 3x3 symmetric matrix of finite "
                      "numbers, kg m^2")
    too_large = f"principal moments from 1e-9 to {MAX_INERTIA_KG_M2:g} kg m^2 (a CubeSat is about 0.01, a space " \
                "station about 1e8)"
    if np.max(np.abs(np.asarray(raw_I, dtype=float))) > MAX_INERTIA_KG_M2:
        raise t.error("inertia_kg_m2", raw_I, too_large)  # before the eigenvalues, which would overflow
    try:
        inertia = check_inertia(raw_I, "spacecraft.inertia_kg_m2")
    except (ValueError, TypeError) as exc:
        raise t.error("inertia_kg_m2", raw_I, str(exc).rstrip(".")) from None
    moments = np.linalg.eigvalsh(inertia)
    if moments.min() < 1e-9 or moments.max() > MAX_INERTIA_KG_M2:
        raise t.error("inertia_kg_m2", raw_I, too_large)
    q = t.vector("q_BN", 4, [1.0, 0.0, 0.0, 0.0], lo=-2.0, hi=2.0)
    try:
        check_unit(q, "spacecraft.q_BN")
    except ValueError:
        raise t.error("q_BN", q.tolist(),
                      f"a unit quaternion [w, x, y, z] (its norm is {np.linalg.norm(q):.9g})") from None
    # Far beyond what any step integrates (check_step below says how far); the bound keeps the arithmetic finite.
    omega = np.radians(t.vector("omega_BN_B_deg_s", 3, [0.0, 0.0, 0.0], lo=-1e6, hi=1e6))
    try:
        check_step(inertia, omega, step_s, "dynamics.step_s", max_angle_rad(integrator), integrator)
    except ValueError as exc:
        raise ScenarioError("dynamics.step_s", step_s, str(exc).rstrip("."), t.source) from None
    t.check_unknown()
    return SpacecraftSpec(mass, inertia, q, omega)


def _numbers(value, n: int) -> bool:
    """A list of n finite numbers (booleans are not numbers here)."""
    return isinstance(value, list) and len(value) == n and all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in value)


def _check_torque_reach(spacecraft: SpacecraftSpec, orbit: OrbitSpec, devices, torques, controller: ControllerSpec,
                        step_s: float, integrator: str, source: str | None) -> None:
    """Refuse a body that the largest torque could spin, within one control period (the zero-order hold), past the
    rate the dynamics step integrates accurately: such a run would pass check and abort in its first seconds."""
    from sim.integrators import max_angle_rad

    moments = np.linalg.eigvalsh(spacecraft.inertia_kg_m2)
    r_p = orbit.a_m * (1.0 - orbit.e) if orbit.a_m is not None else orbit.p_m / (1.0 + orbit.e)
    dipole = math.sqrt(3.0) * sum(getattr(d, "max_dipole_A_m2", 0.0) for d in devices)
    magnetic = dipole * MAX_FIELD_T * (R_EARTH / r_p) ** 3 if "magnetic" in torques else 0.0
    # |r x I r| over unit vectors r is at most (I_max - I_min) / 2.
    gravity = 1.5 * MU_EARTH / r_p**3 * (moments[-1] - moments[0]) if "gravity_gradient" in torques else 0.0
    hold_s = 1.0 / controller.rate_hz
    reach = float(np.linalg.norm(spacecraft.omega_BN_B)) + (magnetic + gravity) / moments[0] * hold_s
    limit = max_angle_rad(integrator) / step_s
    if reach > limit:
        raise ScenarioError("spacecraft.inertia_kg_m2", spacecraft.inertia_kg_m2.tolist(),
                            f"a body the torques cannot spin past what dynamics.step_s = {step_s:g} s integrates "
                            f"({limit:.4g} rad/s) within one control period ({hold_s:g} s): the largest torque "
                            f"({magnetic + gravity:.3g} N m, from dipoles of {dipole:.3g} A m^2 in fields up to "
                            f"{MAX_FIELD_T * (R_EARTH / r_p) ** 3:.3g} T and gravity gradient) over the smallest "
                            f"principal moment ({moments[0]:.3g} kg m^2) reaches {reach:.4g} rad/s", source)


def _environment(t: Table, epoch: Epoch) -> EnvironmentSpec:
    spec = EnvironmentSpec(
        # IGRF-14 unless the scenario asks for the centred dipole (comparison cases).
        magnetic_field=t.choice("magnetic_field", ("igrf", "dipole"), "igrf"),
        earth_rotation=t.choice("earth_rotation", ("iau2006", "uniform"), "iau2006"),
        era0_rad=math.radians(t.number("era0_deg", 0.0, lo=-360.0, hi=360.0)),
        igrf_degree=int(t.number("igrf_degree", 13, lo=1, hi=13, integer=True)),
        eop=t.choice("eop", ("iers", "none"), "iers"),
    )
    t.check_unknown()
    if spec.magnetic_field == "dipole":
        t.refuse_unused("igrf_degree", "environment.magnetic_field = 'dipole'",
                        "remove it, or set magnetic_field = 'igrf' for the IGRF field it truncates")
    if spec.earth_rotation == "iau2006":
        t.refuse_unused("era0_deg", "environment.earth_rotation = 'iau2006' (the Earth's angle follows from the "
                        "epoch and UT1)", "remove it, or set earth_rotation = 'uniform' for the angle at the epoch, "
                        "or disperse scenario.epoch instead")
    else:
        t.refuse_unused("eop", "environment.earth_rotation = 'uniform' (no UT1 or polar motion)",
                        "remove it, or set earth_rotation = 'iau2006' for the IERS corrections")
    return spec


def earth_models(torques, orbit: OrbitSpec, devices) -> tuple[list[str], list[str]]:
    """Why the scene evaluates the geomagnetic field and the Earth's rotation, ``(field reasons, rotation reasons)``;
    a list is empty when nothing does (stand.compose builds exactly these models)."""
    from stand import devices as kinds

    field_why = [why for d in devices if (why := kinds.get(d.kind).needs(d).get("magnetic_field"))]
    field_why += ["magnetic torque"] if "magnetic" in torques else []
    rotation_why = [why for why, on in (("the field model", bool(field_why)), ("harmonic gravity", orbit.gravity ==
                                        "jgm3"), ("drag", orbit.drag is not None)) if on]
    return field_why, rotation_why


def _check_environment_used(t: Table, env: EnvironmentSpec, epoch: Epoch, torques, orbit: OrbitSpec,
                            devices) -> None:
    """Refuse an [environment] setting of a model the scene never evaluates, and an IGRF epoch out of range."""
    field_why, rotation_why = earth_models(torques, orbit, devices)
    if not field_why:
        for key in ("magnetic_field", "igrf_degree"):
            t.refuse_unused(key, "a scene without a magnetic field (no magnetic torque in dynamics.torques, no "
                            "magnetometer, magnetorquer or cage)", "remove it, or add what reads the field")
    elif env.magnetic_field == "igrf" and not 1900.0 <= epoch.decimal_year <= 2030.0:
        raise t.error("magnetic_field", "igrf", "a scenario epoch within IGRF-14's validity, 1900.0 to 2030.0, "
                      "or magnetic_field = 'dipole'")
    if not rotation_why:
        for key in ("earth_rotation", "era0_deg", "eop"):
            t.refuse_unused(key, "a scene with nothing Earth-fixed (no magnetic field, harmonic gravity or drag)",
                            "remove it, or add what turns with the Earth")


def _device(t: Table, step_s: float) -> DeviceSpec:
    """The common part of a ``[[devices]]`` table; the kind's own module validates the rest."""
    from stand import devices

    names = devices.kind_names()
    kind_name = t.choice("kind", names)
    kind = devices.get(kind_name)
    name = t.text("name")
    if not NAME_PATTERN.fullmatch(name):
        raise t.error("name", name, "a plain name of letters, digits, '_', '.' and '-' (it names telemetry columns)")
    link = t.choice("link", kind.links, kind.default_link)
    q_SB = t.vector("q_SB", 4, [1.0, 0.0, 0.0, 0.0], lo=-2.0, hi=2.0)
    if abs(np.linalg.norm(q_SB) - 1.0) > 1e-6:
        raise t.error("q_SB", q_SB.tolist(), "a unit quaternion [w, x, y, z] (sensor frame relative to body)")
    return kind.parse(t, DeviceSpec(name=name, kind=kind_name, link=link, q_SB=q_SB), step_s)


def _check_refs(specs, source) -> None:
    """A device that takes something from another (a magnetometer reading a cage's field) names one that exists
    and provides it."""
    from stand import devices

    by_name = {d.name: d for d in specs}
    for k, d in enumerate(specs):
        for key, (target, what) in devices.get(d.kind).refs(d).items():
            providers = [x.name for x in specs if what in devices.get(x.kind).provides]
            if target not in by_name or target not in providers:
                raise ScenarioError(f"devices[{k}].{key}", target, "'truth' or the name of a device that makes the "
                                    f"{what.replace('_', ' ')} ({', '.join(providers) or 'none in this scenario'})",
                                    source)


#: The keys of each controller kind (beside ``kind``): a key of another kind is unused under this one.
CONTROLLER_KEYS = {"bdot": ("rate_hz", "budget_s", "device", "gain_A_m2_s_per_T", "max_dipole_A_m2",
                            "skip_coil_active", "duty_cycle"),
                   "plugin": ("rate_hz", "budget_s", "module", "path", "options"),
                   "pointing": ("rate_hz", "budget_s", "options", "datasheet", "datasheet_margin")}


def _controller(t: Table, step_s: float, devices) -> ControllerSpec:
    kind = t.choice("kind", CONTROLLER_KINDS, "none")
    for key in sorted({k for keys in CONTROLLER_KEYS.values() for k in keys} - set(CONTROLLER_KEYS.get(kind, ()))):
        owners = [k for k, keys in CONTROLLER_KEYS.items() if key in keys]
        t.refuse_unused(key, f"controller.kind = {kind!r}", f"remove it (it is a key of kind "
                        f"{' or '.join(repr(o) for o in owners)})")
    served = [d.name for d in devices if d.link == "served"]
    if kind in ("none", "external"):
        if kind == "external" and not served:
            raise t.error("kind", kind, "a scenario with served devices ([[devices]] link = 'served') for the "
                          "flight computer outside to close the loop through")
        t.check_unknown()
        return ControllerSpec(kind, 1.0 / step_s)
    rate_hz = rate(t, "rate_hz", step_s)
    # Wall-clock seconds one call into the flight code may take before the run ends aborted (stand.loop._Watchdog).
    params: dict = {"budget_s": t.number("budget_s", DEFAULT_BUDGET_S, lo=0.01, hi=3600.0)}
    if kind == "bdot":
        _bdot(t, rate_hz, step_s, devices, params)
    elif kind == "pointing":
        params["options"] = _pointing(t, devices)
    else:
        params["module"] = t.text("module")
        params["path"] = t.text("path") if t.has("path") else None
        options = t.raw("options", {})
        if not isinstance(options, dict):
            raise t.error("options", options, "a table of keyword arguments for the plug-in's constructor")
        params["options"] = options
    t.check_unknown()
    return ControllerSpec(kind, rate_hz, params)


def _unusable(v) -> bool:
    """A value with a non-finite or subnormal number or a NUL byte anywhere inside."""
    if isinstance(v, float):
        return not math.isfinite(v) or 0.0 < abs(v) < sys.float_info.min
    if isinstance(v, str):
        return "\x00" in v
    if isinstance(v, list):
        return any(_unusable(x) for x in v)
    if isinstance(v, dict):
        return any(_unusable(x) for x in v.values())
    return False


def _pointing(t: Table, devices) -> dict:
    """The options of the reference pointing ADCS: the devices it reads and commands must exist, be of the right
    kind and have a host driver in the stand (not served); the rest is checked by its constructor."""
    from dataclasses import fields

    from .adcs.modes import ModeConfig
    from .adcs.pointing import OPTIONS

    options = t.raw("options", {})
    if not isinstance(options, dict):
        raise t.error("options", options, "a table of options of stand.adcs.pointing.PointingController")
    opt = Table(options, t._name("options"), t.source)
    opt.check_unknown(tuple(OPTIONS))

    for key, value in options.items():
        if _unusable(value):
            raise opt.error(key, value, "finite numbers of normal size (no subnormals) and text without NUL bytes")
    if "modes" in options:
        opt.table("modes").check_unknown(tuple(f.name for f in fields(ModeConfig)))
    by_name = {d.name: d for d in devices}

    def check(key: str, name, kind: str) -> None:
        d = by_name.get(name) if isinstance(name, str) else None
        if d is None or d.kind != kind:
            have = [x.name for x in devices if x.kind == kind]
            raise opt.error(key, name, f"the name of a [[devices]] entry of kind {kind!r} "
                          f"({', '.join(have) or 'none in this scenario'})")
        if d.link == "served":
            raise opt.error(key, name, "a device the stand's controller can use: this one is served to a "
                          "flight computer outside (link = 'served'); use controller.kind = 'external'")

    if "gyro" not in options:
        raise opt.error("gyro", MISSING, "the name of the gyro the pointing controller reads")
    for key, kind in POINTING_DEVICES.items():
        if key in options:
            check(key, options[key], kind)
    wheels = options.get("wheels", [d.name for d in devices if d.kind == "reaction_wheel"])
    if not isinstance(wheels, list) or len(wheels) < 3:
        raise opt.error("wheels", wheels, "a list of at least three reaction wheel device names")
    for name in wheels:
        check("wheels", name, "reaction_wheel")
    return {**options, "wheels": list(wheels), **_datasheets(t, options, by_name)}


ARCSEC_RAD = math.radians(1.0 / 3600.0)
DEG_H_RAD_S = math.radians(1.0) / 3600.0
#: What each datasheet gives, per device kind: key -> (default or MISSING if required, lo, hi), datasheet units.
DATASHEET_KEYS = {
    # 1-sigma noise of a solution, about the boresight's cross axes and about the boresight (roll).
    "star_tracker": {"noise_cross_arcsec": (MISSING, 0.0, 3600.0), "noise_roll_arcsec": (MISSING, 0.0, 3600.0)},
    # Angle random walk, rate random walk and the bound on the turn-on bias (taken as 3 sigma): what the MEKF's
    # model holds. A bias instability is a bounded, correlated wander its random-walk bias cannot represent (turned
    # into a random walk it made the bias estimate noisy and the knowledge through a 900 s tracker outage 50 %
    # worse): the filter does not take it, and the simulated gyro's instability stays an unmodelled error.
    "gyro": {"arw_deg_sqrt_h": (MISSING, 0.0, 100.0), "rrw_deg_h_sqrt_h": (MISSING, 0.0, 1e4),
             "turn_on_bias_deg_h": (MISSING, 0.0, 1e5)},
}
#: The filter options each kind's datasheet sets (they cannot be given beside it).
DATASHEET_OPTIONS = {"star_tracker": ("tracker_sigma_rad",),
                     "gyro": ("gyro_arw_rad_s05", "gyro_rrw_rad_s15", "sigma_bias_rad_s")}
#: The smallest tracker noise handed to the filter (arcsec): a noiseless tracker still quantises its quaternion.
MIN_TRACKER_SIGMA_ARCSEC = 0.5


def _datasheets(t: Table, options: dict, by_name: dict) -> dict:
    """The reference ADCS's filter tuning from the datasheets the scenario declares, ``[controller.datasheet.NAME]``
    for the star tracker and the gyro it uses, each noise figure times ``controller.datasheet_margin``: what a
    flight team knows, never the simulated device's own settings (which may differ; docs/adcs.md)."""
    sheets = t.table("datasheet", required=False)
    margin = t.number("datasheet_margin", 1.0, lo=1.0, hi=10.0)
    out: dict = {}
    for role, kind in (("star_tracker", "star_tracker"), ("gyro", "gyro")):
        name = options.get(role)
        if name is None:
            continue
        given = [k for k in DATASHEET_OPTIONS[kind] if k in options]
        if not sheets.has(name):
            if len(given) < len(DATASHEET_OPTIONS[kind]):
                raise sheets.error(name, MISSING, f"the datasheet of the {kind.replace('_', ' ')} the ADCS is tuned "
                                   f"from: a table [controller.datasheet.{name}] of "
                                   f"{', '.join(DATASHEET_KEYS[kind])} (or the options "
                                   f"{', '.join(DATASHEET_OPTIONS[kind])})")
            continue
        if given:
            raise sheets.error(name, sheets.raw(name), f"a datasheet or the option {given[0]}, not both (the datasheet "
                               "sets it)")
        sheet = sheets.table(name)
        v = {k: sheet.number(k, d, lo=lo, hi=hi) for k, (d, lo, hi) in DATASHEET_KEYS[kind].items()}
        sheet.check_unknown()
        if kind == "star_tracker":
            out["tracker_sigma_rad"] = [max(v[k], MIN_TRACKER_SIGMA_ARCSEC) * ARCSEC_RAD * margin
                                        for k in ("noise_cross_arcsec", "noise_roll_arcsec")]
        else:
            out.update(_gyro_tuning(v, margin))
    sheets.check_unknown()
    if not out:
        t.refuse_unused("datasheet_margin", "a controller without datasheets", "remove it, or declare the "
                        "datasheets of the tracker and the gyro in [controller.datasheet.NAME] tables")
    return out


def _gyro_tuning(v: dict, margin: float) -> dict:
    """MEKF noise from a gyro datasheet, each figure times the margin."""
    arw = v["arw_deg_sqrt_h"] * math.radians(1.0) / 60.0
    rrw = v["rrw_deg_h_sqrt_h"] * DEG_H_RAD_S / 60.0
    # Floors far below any real gyro keep the covariance from collapsing to zero with a perfect datasheet.
    return {"gyro_arw_rad_s05": max(arw * margin, 1e-12), "gyro_rrw_rad_s15": max(rrw * margin, 1e-15),
            "sigma_bias_rad_s": max(v["turn_on_bias_deg_h"] * DEG_H_RAD_S / 3.0 * margin, 1e-12)}


def _bdot(t: Table, rate_hz: float, step_s: float, devices, params: dict) -> None:
    boards = [d for d in devices if d.kind == "magnetorquer"]
    if not boards:
        raise t.error("kind", "bdot", "a controller that has its devices: B-dot needs a [[devices]] entry "
                      "of kind 'magnetorquer'")
    names = [d.name for d in boards]
    params["device"] = t.choice("device", names, names[0])
    board = boards[names.index(params["device"])]
    if board.link == "served":
        raise t.error("device", board.name, "a board the stand's B-dot can command: this one is served to a flight "
                      "computer outside (link = 'served'); use controller.kind = 'external' or another link")
    params["gain_A_m2_s_per_T"] = t.number("gain_A_m2_s_per_T", lo=0.0, lo_open=True, hi=1e12)
    # A command the board cannot carry would abort the run at its first saturation.
    params["max_dipole_A_m2"] = t.number("max_dipole_A_m2", lo=0.0, lo_open=True, hi=board.max_dipole_A_m2)
    params["skip_coil_active"] = t.flag("skip_coil_active", True)
    # Coils on for this fraction of the control period; the on-time must be whole dynamics steps so the
    # zero-order hold switches exactly on a step boundary, and it must fit the command's duration field.
    duty = t.number("duty_cycle", 1.0, lo=0.0, lo_open=True, hi=1.0)
    on_steps = duty / (rate_hz * step_s)
    if abs(on_steps - round(on_steps)) > 1e-9 * on_steps:
        raise t.error("duty_cycle", duty, f"a fraction whose on-time is whole dynamics steps of {step_s:g} s "
                      f"(the control period is {1.0 / rate_hz:g} s)")
    from stand.devices.magnetorquer import _codec

    max_on_s = _codec().dbc.signal_range("MTQ_DIPOLE_CMD", "duration_ms")[1] * 1e-3
    if duty / rate_hz > max_on_s:
        raise t.error("rate_hz", rate_hz, f"a control rate whose on-time (duty_cycle / rate_hz = "
                      f"{duty / rate_hz:g} s) fits the command's duration field (at most {max_on_s:g} s), "
                      f"i.e. rate_hz >= {duty / max_on_s:.6g}")
    params["duty_cycle"] = duty


def _criterion(t: Table, duration_s: float) -> Criterion:
    metric = t.choice("metric", tuple(all_metrics()))
    c = Criterion(
        name=t.text("name", metric),
        metric=metric,
        max=t.number("max") if t.has("max") else None,
        min=t.number("min") if t.has("min") else None,
        at_s=t.number("at_s", lo=0.0, hi=duration_s) if t.has("at_s") else None,
    )
    if c.max is None and c.min is None:
        raise t.error("max", MISSING, "a max or a min limit for the criterion")
    if metric in _metrics_at() and c.at_s is None:
        raise t.error("at_s", MISSING, f"a time in [0, {duration_s:g}] s for metric {metric!r}")
    t.check_unknown()
    if metric not in _metrics_at():
        t.refuse_unused("at_s", f"metric = {metric!r} (it takes no time)", "remove it, or choose a metric that "
                        "takes one (" + ", ".join(sorted(_metrics_at())) + ")")
    return c


def _metrics_at() -> set[str]:
    from stand import devices

    out = {"rate_deg_s_at", "max_rate_deg_s_after", *POINTING_METRICS}
    for name in devices.kind_names():
        out.update(devices.get(name).metrics_at)
    return out
