"""Composition: build only what the scene needs, and say what was left out and why.

The scenario names its devices, controller and torques. ``plan`` walks back from them to the
models they need; ``build`` creates exactly those (the field model exists only when a device or a
torque needs it, and so on). ``stand check`` prints the plan without opening any bus.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim.environment import magnetic_field_itrs
from sim.ephemeris import EphemerisTrack
from sim.forces import OrbitForces
from sim.frames import EarthRotation
from sim.orbit import elements_to_state
from sim.time import NS_PER_S, seconds_to_ns
from sim.truth import TruthModel
from sim.wheels import WheelCluster

from . import devices
from .adcs import build_controller
from .devices import BuildContext
from .scenario import Scenario


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


def plan(sc: Scenario) -> list[Choice]:
    """Every model the stand knows, built or left out, with the reason."""
    o, env = sc.orbit, sc.environment
    dev = device_needs(sc)
    field_why = dev["magnetic_field"] + (["magnetic torque"] if "magnetic" in sc.torques else [])
    needs_field = bool(field_why)
    if needs_field and env.magnetic_field == "igrf":
        field_why.append(f"degree {env.igrf_degree}")
    rotation_why = [why for why, on in (("the field model", needs_field), ("harmonic gravity", o.gravity == "jgm3"),
                                        ("drag", o.drag is not None)) if on]
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
    if sc.rendezvous is not None:
        from .rendezvous import describe

        choices.append(Choice("rendezvous.shadow", True, describe(sc.rendezvous)))
    ctl = sc.controller
    ctl_why = {"none": "no controller in the scenario: open loop",
               "external": "a flight computer outside closes the loop through the served devices ("
                           + ", ".join(d.name for d in sc.devices if d.link == "served") + "); the run is paced"}
    choices.append(Choice(f"controller.{ctl.kind}", ctl.kind not in ("none", "external"),
                          ctl_why.get(ctl.kind, f"at {ctl.rate_hz:g} Hz through the host drivers")))
    return choices


def _wheels_text(sc: Scenario) -> str:
    n = sum(devices.get(d.kind).momentum_wheel(d) is not None for d in sc.devices)
    return f" with {n} momentum wheel{'s' if n > 1 else ''} in its state" if n else ""


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
    o = sc.orbit
    r, v = elements_to_state(e=o.e, i=o.i_rad, raan=o.raan_rad, argp=o.argp_rad, a=o.a_m, p=o.p_m,
                             nu=o.nu_rad, M=o.mean_anomaly_rad)
    return np.asarray(r, dtype=float), np.asarray(v, dtype=float)


def build(sc: Scenario, speed: float | None = None, base: Path | None = None) -> Scene:
    """Create the truth model, every device for its link, and the controller. ``speed`` is the pacing factor
    (None: as fast as possible), which wall-time devices need; ``base`` is the folder plug-in paths are
    relative to (the scenario's)."""
    choices = plan(sc)
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
        scene.controller = build_controller(sc, scene.devices, base)
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


def ticks_per(rate_hz: float, step_s: float) -> int:
    """Dynamics steps per period of a rate (validated to be whole by the scenario loader)."""
    return max(1, round(NS_PER_S / rate_hz) // seconds_to_ns(step_s))
