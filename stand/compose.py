"""Composition: build only what the scene needs, and say what was left out and why.

The scenario names its devices, controller and torques. ``plan`` walks back from them to the
models they need; ``build`` creates exactly those (the field model exists only when a device or a
torque needs it, and so on). ``stand check`` prints the plan without opening any bus.
"""

from __future__ import annotations

import dataclasses
import math
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim.environment import magnetic_field_itrs
from sim.ephemeris import EphemerisTrack
from sim.forces import OrbitForces
from sim.frames import EarthRotation
from sim.time import seconds_to_ns
from sim.truth import CHUNK_S, TruthModel, chunk_points
from sim.wheels import WheelCluster

from . import controllers, devices, faults, scenario
from .checks import ticks_per
from .devices import BuildContext
from .errors import ScenarioError
from .scenario import Scenario, earth_models

__all__ = ["Budget", "Choice", "Scene", "budget", "build", "check_budget", "device_needs", "initial_state", "plan",
           "ticks_per", "wheel_cluster"]


@dataclass(frozen=True)
class Choice:
    model: str
    built: bool
    reason: str


def device_needs(sc: Scenario) -> dict[str, list[str]]:
    """Truth model -> the reasons devices give for it (``stand.devices.TRUTH_MODELS``)."""
    needs: dict[str, list[str]] = {m: [] for m in devices.TRUTH_MODELS}
    for d in sc.devices:
        for model, why in devices.get(d.kind).needs(d).items():
            needs[model].append(why)
    return needs


def plan(sc: Scenario, duration_s: float | None = None, out_dir: Path | None = None) -> list[Choice]:
    """Every model the stand knows, built or left out, with the reason, and the run's estimated cost (refused with a
    ScenarioError past the machine's limits: ``check_budget`` for a run of ``duration_s`` into ``out_dir``)."""
    o, env = sc.orbit, sc.environment
    dev = device_needs(sc)
    # The same reasons the loader refuses [environment] settings of models nothing evaluates by.
    field_why, rotation_why = earth_models(sc.torques, o, sc.devices)
    needs_field = bool(field_why)
    if needs_field and env.magnetic_field == "igrf":
        field_why.append(f"degree {env.igrf_degree}")
    needs_rotation = bool(rotation_why)
    needs_eop = needs_rotation and env.earth_rotation == "iau2006" and env.eop == "iers"
    sun_why = [w for w, on in (("third-body Sun", "sun" in o.third_bodies), ("radiation pressure", o.srp))
               if on] + dev["sun"]
    shadow_why = (["radiation pressure"] if o.srp is not None else []) + dev["eclipse"]
    moon_why = (["third-body Moon"] if "moon" in o.third_bodies else []) + dev["moon"]
    gg = "gravity_gradient" in sc.torques
    gravity = {"point": "point-mass", "j2": "J2", "jgm3": f"JGM-3 to degree and order {o.gravity_degree}"}[o.gravity]

    def listed(on: bool, where: str) -> str:
        return f"listed in {where}" if on else f"not in {where}"

    choices = [
        Choice("orbit", True, f"{gravity} gravity, RK4 at {o.step_s:g} s with the force re-evaluated at every "
               "stage, Hermite-interpolated to the dynamics steps"),
        Choice("attitude", True, f"rigid body{_wheels_text(sc)}, {sc.integrator.upper()} at {sc.step_s:g} s"),
        Choice(f"magnetic_field.{env.magnetic_field}", needs_field,
               "needed by " + ", ".join(field_why) if needs_field
               else "no magnetometer, magnetorquer, cage or magnetic torque in the scene"),
        Choice(f"earth_rotation.{env.earth_rotation}", needs_rotation,
               "Earth-fixed: " + ", ".join(rotation_why) if needs_rotation else "nothing Earth-fixed is evaluated"),
        Choice("eop.iers", needs_eop, _eop_reason(sc, needs_rotation)),
        Choice("torque.magnetic", "magnetic" in sc.torques, listed("magnetic" in sc.torques, "dynamics.torques")),
        Choice("torque.gravity_gradient", gg, listed(gg, "dynamics.torques")),
        Choice("third_body.sun", "sun" in o.third_bodies, listed("sun" in o.third_bodies, "orbit.third_bodies")),
        Choice("third_body.moon", "moon" in o.third_bodies, listed("moon" in o.third_bodies, "orbit.third_bodies")),
        Choice("srp.cannonball", o.srp is not None,
               "listed in [orbit.srp]" if o.srp is not None else "no [orbit.srp] table in the scenario"),
        Choice("sun", bool(sun_why), "ephemeris track for " + ", ".join(sun_why) if sun_why
               else "no sun sensor, star tracker, radiation pressure or third-body Sun in the scene"),
        Choice("moon", bool(moon_why), "ephemeris track for " + ", ".join(moon_why) if moon_why
               else "no star tracker, sensor or force that cares about the Moon in the scene"),
        Choice("eclipse", bool(shadow_why), "conical shadow for " + ", ".join(shadow_why) if shadow_why
               else "no sun sensor, power model or radiation pressure in the scene"),
        Choice("atmosphere", o.drag is not None, "exponential density for drag" if o.drag is not None
               else "no drag requested (no [orbit.drag] table)"),
        _star_screen_choice(sc, dev["star_screen"]),
    ]
    for d in sc.devices:
        choices.append(Choice(f"device.{d.name}", True, devices.get(d.kind).describe(d)))
    for key, spec in sc.sections.items():
        section = scenario.section(key)
        choices.append(Choice(section.model, True, section.describe(spec)))
    for f in sc.faults:
        choices.append(Choice(f"fault.{f.name}", True, f.describe()))
    if not sc.faults:
        choices.append(Choice("faults", False, "no [[faults]] in the scenario: no fault schedule, nothing per tick "
                              "(stand run --view builds one for faults injected live)"))
    ctl = controllers.get(sc.controller.kind)
    choices.append(Choice(f"controller.{sc.controller.kind}", ctl.in_stand, ctl.describe(sc)))
    choices.append(Choice("estimate", True, check_budget(sc, duration_s, out_dir).text()))
    return choices


def _wheels_text(sc: Scenario) -> str:
    n = sum(devices.get(d.kind).momentum_wheel(d) is not None for d in sc.devices)
    return f" with {n} momentum wheel{'s' if n > 1 else ''} in its state" if n else ""


# --- what a run costs, estimated before t = 0 -------------------------------------------------------------------
# Figures measured on this stand's loop (detumble, 2-core machine): a tick of the truth alone about 25 us, a device
# looking for what arrived about 35 us every tick, a device's publish (codec round trip) and a controller update
# about 30 us each, a telemetry row about 5 us (the default run: about 130 us a tick); an
# orbit node about 50 us with point-mass or J2 gravity and about 1.2 ms with JGM-3 to degree 20 (the cost grows
# with the square of the degree). Memory: the interpreter with numpy, python-can and matplotlib about 150 MB, a
# point of the orbit track's chunk about 1.5 KB (12 KB with the IGRF field's temporaries), a telemetry row loaded
# for the report and its plots three times over.
TICK_S = 25e-6
RECEIVE_S = 35e-6
PUBLISH_S = 30e-6
CONTROL_S = 30e-6
ROW_S = 5e-6
NODE_S = 50e-6
NODE_JGM3_S = 1.2e-3
BASE_BYTES = 150 << 20
TRACK_POINT_BYTES = 1536
TRACK_POINT_FIELD_BYTES = 12 << 10
REPORT_COPIES = 3
#: A run may use at most this fraction of the machine's memory.
MEMORY_FRACTION = 0.5
#: Longest computation a run may ask for, s: longer than any scenario's own duration (30 days), so a paced soak
#: test is never refused by it, yet a step a million times too small is.
MAX_COMPUTE_S = 31 * 86400.0


@dataclass(frozen=True)
class Budget:
    """The estimated cost of a run: ticks, telemetry, peak memory and computation (as fast as possible)."""

    duration_s: float
    ticks: int
    rows: int
    row_floats: int
    telemetry_bytes: int
    memory_bytes: int
    compute_s: float
    parts: dict  # memory by part (bytes), for the message naming the largest

    def text(self) -> str:
        return (f"about {self.ticks:,} ticks for {self.duration_s:g} s, {self.rows:,} telemetry rows of "
                f"{self.row_floats} floats ({_size(self.telemetry_bytes)} on disk), peak memory about "
                f"{_size(self.memory_bytes)}, about {_duration(self.compute_s)} of computation as fast as possible")


def _size(n: float) -> str:
    for unit, scale in (("TB", 1 << 40), ("GB", 1 << 30), ("MB", 1 << 20), ("KB", 1 << 10)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{int(n)} B"


def _duration(s: float) -> str:
    for unit, scale in (("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if s >= scale:
            return f"{s / scale:.3g} {unit}"
    return f"{s:.2g} s"


def machine_memory_bytes() -> int | None:
    """Memory this process may use: the physical memory, or the container's (cgroup v2) limit when smaller; None
    where the system does not say."""
    sizes = []
    try:
        sizes.append(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        pass
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit.isdigit():
            sizes.append(int(limit))
    except OSError:
        pass
    return min(sizes) if sizes else None


def free_disk_bytes(folder: Path) -> tuple[Path, int | None]:
    """Free space of the file system the folder is (or will be) on: its nearest existing ancestor's."""
    p = Path(folder).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        return p, shutil.disk_usage(p).free
    except OSError:
        return p, None


def budget(sc: Scenario, duration_s: float | None = None) -> Budget:
    """Estimate the run's ticks, telemetry size, peak memory and computation from the scenario alone."""
    duration = sc.duration_s if duration_s is None else float(duration_s)
    step_ns = seconds_to_ns(sc.step_s)
    ticks = seconds_to_ns(duration) // step_ns
    rec_every = ticks_per(sc.record_rate_hz, sc.step_s)
    rows = ticks // rec_every + 1
    costs = [devices.get(d.kind).cost(d) for d in sc.devices]
    field_on = "magnetic" in sc.torques or any(devices.get(d.kind).needs(d).get("magnetic_field")
                                               for d in sc.devices)
    # What the controller records (ControllerKind.row_floats: B-dot its commanded dipole...).
    row_floats = 14 + 3 * field_on + sum(c.row_floats for c in costs) + controllers.get(sc.controller.kind).row_floats
    telemetry = rows * row_floats * 8
    o = sc.orbit
    points = chunk_points(sc.step_s / 2)
    nodes_per_chunk = math.ceil(min(CHUNK_S, points * sc.step_s / 2) / o.step_s) + 2
    parts = {
        "the interpreter and libraries": BASE_BYTES,
        "the orbit track": points * (TRACK_POINT_FIELD_BYTES if field_on and sc.environment.magnetic_field == "igrf"
                                     else TRACK_POINT_BYTES)
        + nodes_per_chunk * 64,
        "the telemetry loaded for the report": REPORT_COPIES * telemetry,
    }
    for d, c in zip(sc.devices, costs, strict=True):
        if c.memory_bytes:
            parts[f"device {d.name}"] = c.memory_bytes
    compute = ticks * (TICK_S + RECEIVE_S * len(costs)) + rows * ROW_S
    node_s = NODE_JGM3_S * (o.gravity_degree / 20) ** 2 if o.gravity == "jgm3" else NODE_S
    compute += duration / o.step_s * node_s
    for c in costs:
        publishes = ticks if c.rate_hz is None else duration * c.rate_hz
        compute += publishes * (PUBLISH_S + c.publish_s)
    if controllers.get(sc.controller.kind).in_stand:
        compute += duration * sc.controller.rate_hz * CONTROL_S
    return Budget(duration, int(ticks), int(rows), int(row_floats), int(telemetry), int(sum(parts.values())),
                  compute, parts)


def check_budget(sc: Scenario, duration_s: float | None = None, out_dir: Path | None = None,
                 memory_bytes: int | None = None) -> Budget:
    """The run's ``budget``, refused with a ScenarioError naming the figure when the peak memory exceeds
    MEMORY_FRACTION of this machine's memory (``memory_bytes``, default the physical memory), the telemetry exceeds
    the free disk of the output folder (default ``runs``, where ``stand run`` writes), or the computation exceeds
    MAX_COMPUTE_S."""
    b = budget(sc, duration_s)
    src = sc.source
    how = (f"{b.ticks:,} ticks of dynamics.step_s = {sc.step_s:g} s over {b.duration_s:g} s, recorded at "
           f"recording.rate_hz = {sc.record_rate_hz:g}")
    if b.compute_s > MAX_COMPUTE_S:
        raise ScenarioError("dynamics.step_s", sc.step_s, f"a run this stand can finish: {how} is about "
                            f"{_duration(b.compute_s)} of computation (at most {_duration(MAX_COMPUTE_S)}); use a "
                            "larger step or a shorter scenario.duration_s", src)
    ram = machine_memory_bytes() if memory_bytes is None else memory_bytes
    if ram is not None and b.memory_bytes > MEMORY_FRACTION * ram:
        largest = max(b.parts, key=b.parts.get)
        field, value = (("recording.rate_hz", sc.record_rate_hz) if largest.startswith("the telemetry") else
                        ("devices", [d.name for d in sc.devices]) if largest.startswith("device") else
                        ("dynamics.step_s", sc.step_s))
        raise ScenarioError(field, value, f"a run whose estimated peak memory (about {_size(b.memory_bytes)}; "
                            f"{largest} {_size(b.parts[largest])}) fits in {MEMORY_FRACTION:.0%} of this machine's "
                            f"{_size(ram)}; {how}", src)
    folder, free = free_disk_bytes(Path("runs") if out_dir is None else Path(out_dir))
    if free is not None and b.telemetry_bytes > free:
        raise ScenarioError("recording.rate_hz", sc.record_rate_hz, f"a recording whose telemetry fits on the disk: "
                            f"{b.rows:,} rows of {b.row_floats} floats is {_size(b.telemetry_bytes)}, and {folder} "
                            f"has {_size(free)} free; record less often or for a shorter scenario.duration_s", src)
    return b


def _star_screen_choice(sc: Scenario, why: list[str]) -> Choice:
    if why:
        return Choice("star_screen", True, "; ".join(why))
    return Choice("star_screen", False, "no device looks at rendered stars (an image-source star tracker does)")


def _eop_reason(sc: Scenario, needs_field: bool) -> str:
    env = sc.environment
    if not needs_field:
        return "nothing Earth-fixed is evaluated"
    if env.earth_rotation != "iau2006":
        return f"earth_rotation = {env.earth_rotation!r} has no UT1 or polar motion"
    if env.eop == "none":
        return "environment.eop = 'none': UT1 - UTC and polar motion taken as 0"
    from sim.eop import eop_at

    e = eop_at(sc.epoch)
    if not e.available:
        return "no IERS table installed or epoch outside it: UT1 - UTC and polar motion taken as 0"
    return (f"UT1 - UTC = {e.dut1_s:+.4f} s, polar motion ({e.xp_rad * 206264806.2:.1f}, "
            f"{e.yp_rad * 206264806.2:.1f}) mas from {Path(e.source).name}{' (predicted)' if e.predicted else ''}")


@dataclass
class Scene:
    """The live objects of one run. Close it to release the buses and ports (idempotent)."""

    scenario: Scenario
    truth: TruthModel
    choices: list[Choice]
    devices: dict = field(default_factory=dict)  # name -> stand.devices.Device
    controller: object | None = None
    #: The run's fault schedule (``stand.faults.FaultSchedule``), or None: no ``[[faults]]`` and none taken live.
    faults: object | None = None
    closed: bool = False

    @property
    def hosts(self) -> dict:
        """Device name -> host driver, as the flight code sees them (None for a served device)."""
        return {name: d.host for name, d in self.devices.items()}

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        errors = []
        if self.controller is not None and hasattr(self.controller, "close"):
            try:
                self.controller.close()
            except Exception as exc:  # a plug-in's close must not keep the buses open
                errors.append(f"controller: {exc}")
        for d in self.devices.values():
            try:
                d.close()
            except Exception as exc:  # a peer that hung up makes shutdown raise; the others still close
                errors.append(f"{d.name}: {exc}")
        self.close_errors = errors

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def initial_state(sc: Scenario):
    """The spacecraft's position and velocity at the epoch, GCRS (m, m/s)."""
    return sc.orbit.initial_state()


def build(sc: Scenario, speed: float | None = None, base: Path | None = None, *, duration_s: float | None = None,
          out_dir: Path | None = None, allow_remote: tuple[str, ...] | list[str] = (), live_faults: bool = False
          ) -> Scene:
    """Create the truth model, every device for its link, and the controller. ``speed`` is the pacing factor
    (None: as fast as possible), which wall-time devices need; ``base`` is the folder plug-in paths are
    relative to (the scenario's); ``duration_s`` and ``out_dir``, the run's length (default the scenario's) and
    folder (default ``runs``), are what the estimate before t = 0 is checked for (``plan``); ``allow_remote``, the
    hosts and multicast groups beyond this machine the operator allows devices to reach
    (:func:`stand.devices.check_network`); ``live_faults``, whether the operator may inject faults during the run
    (the fault schedule is built then even without ``[[faults]]``)."""
    devices.check_network(sc.devices, allow_remote)  # before anything connects
    choices = plan(sc, duration_s, out_dir)
    built = {c.model for c in choices if c.built}
    r0, v0 = initial_state(sc)
    env = sc.environment
    needs_field = f"magnetic_field.{env.magnetic_field}" in built
    epoch, xp, yp = sc.epoch, 0.0, 0.0
    if "eop.iers" in built:
        from sim.eop import eop_at

        e = eop_at(sc.epoch)
        epoch, xp, yp = dataclasses.replace(sc.epoch, dut1_s=e.dut1_s), e.xp_rad, e.yp_rad
    needs_rotation = f"earth_rotation.{env.earth_rotation}" in built
    rotation = EarthRotation(epoch, env.earth_rotation, env.era0_rad, xp, yp) if needs_rotation else None
    o = sc.orbit
    forces = None
    tracks = {b: EphemerisTrack(sc.epoch, b) for b in ("sun", "moon") if b in built}
    if o.gravity == "jgm3" or o.third_bodies or o.drag or o.srp:
        forces = OrbitForces(gravity=o.gravity, degree=o.gravity_degree, rotation=rotation, tracks=tracks,
                             third_bodies=o.third_bodies, drag=o.drag, srp=o.srp, mass_kg=sc.spacecraft.mass_kg)

    def field_itrs(t_s, r_itrs):
        return magnetic_field_itrs(epoch + t_s, r_itrs, env.magnetic_field, env.igrf_degree)

    wheels = wheel_cluster(sc)
    truth = TruthModel(
        inertia=sc.spacecraft.inertia_kg_m2, q_BN=sc.spacecraft.q_BN, omega_BN_B=sc.spacecraft.omega_BN_B,
        r_N=r0, v_N=v0, step_ns=seconds_to_ns(sc.step_s), gravity=sc.orbit.gravity,
        orbit_step_s=sc.orbit.step_s,
        field_itrs=field_itrs if needs_field else None,
        earth_rotation=rotation, torques=sc.torques, forces=forces, integrator=sc.integrator,
        **({} if wheels is None else {"wheels": wheels[0], "wheel_speeds_rad_s": wheels[1]}),
    )
    scene = Scene(sc, truth, choices)
    try:
        seeds = dict(zip((d.name for d in sc.devices), np.random.SeedSequence(sc.seed).spawn(len(sc.devices)),
                         strict=True))
        stimuli: dict = {}
        # Stimulators first, so they are built, and step each tick, before the devices that read them.
        for d in sorted(sc.devices, key=lambda d: not devices.get(d.kind).provides):
            ctx = BuildContext(truth, tracks, sc.epoch, np.random.default_rng(seeds[d.name]), sc.step_s, speed,
                               stimuli, {} if wheels is None else wheels[2])
            scene.devices[d.name] = built = devices.get(d.kind).build(d, ctx)
            if devices.get(d.kind).provides:
                stimuli[d.name] = built
        scene.controller = controllers.build_controller(sc, scene.devices, base)
        scene.faults = faults.build(sc, scene.devices, scene.controller, live_faults, duration_s)
    except BaseException:
        scene.close()
        raise
    return scene


def wheel_cluster(sc: Scenario):
    """``(WheelCluster, speeds_rad_s, {device name: column})`` of the scenario's momentum wheels, in device order,
    or None when no device is one (``DeviceKind.momentum_wheel``)."""
    axes, inertias, speeds, index = [], [], [], {}
    for d in sc.devices:
        w = devices.get(d.kind).momentum_wheel(d)
        if w is not None:
            index[d.name] = len(axes)
            axes.append(np.asarray(w[0], dtype=float))
            inertias.append(float(w[1]))
            speeds.append(float(w[2]))
    if not axes:
        return None
    return WheelCluster(np.column_stack(axes), inertias), speeds, index

