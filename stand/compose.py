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
from sim.rotations import dcm
from sim.time import NS_PER_S, seconds_to_ns
from sim.truth import TruthModel, rotate_to_body

from .adcs import BDot, load_plugin
from .devices.star_tracker import build_tracker
from .devices.sun_sensor import SunSensorLink
from .scenario import Scenario


@dataclass(frozen=True)
class Choice:
    model: str
    built: bool
    reason: str


def plan(sc: Scenario) -> list[Choice]:
    """Every model the stand knows, built or left out, with the reason."""
    mtq = [d for d in sc.devices if d.kind == "magnetorquer"]
    o, env = sc.orbit, sc.environment
    needs_field = bool(mtq) or "magnetic" in sc.torques
    field_why = []
    if mtq:
        field_why.append("magnetometer of " + ", ".join(d.name for d in mtq))
    if "magnetic" in sc.torques:
        field_why.append("magnetic torque")
    if env.magnetic_field == "igrf":
        field_why.append(f"degree {env.igrf_degree}")
    rotation_why = [why for why, on in (("the field model", needs_field), ("harmonic gravity", o.gravity == "jgm3"),
                                        ("drag", o.drag is not None)) if on]
    needs_rotation = bool(rotation_why)
    needs_eop = needs_rotation and env.earth_rotation == "iau2006" and env.eop == "iers"
    trackers = [d.name for d in sc.devices if d.kind == "star_tracker"]
    sun_sensors = [d.name for d in sc.devices if d.kind == "sun_sensor"]
    exclusion = f"exclusion of {', '.join(trackers)}" if trackers else ""
    sun_why = [w for w, on in (("third-body Sun", "sun" in o.third_bodies), ("radiation pressure", o.srp),
                                (exclusion, bool(trackers)), ("sun sensor " + ", ".join(sun_sensors),
                                                              bool(sun_sensors))) if on]
    shadow_why = [w for w, on in (("radiation pressure", o.srp is not None),
                                   ("sun sensor " + ", ".join(sun_sensors), bool(sun_sensors))) if on]
    moon_why = [w for w, on in (("third-body Moon", "moon" in o.third_bodies), (exclusion, bool(trackers))) if on]
    gg = "gravity_gradient" in sc.torques
    gravity = {"point": "point-mass", "j2": "J2", "jgm3": f"JGM-3 to degree and order {o.gravity_degree}"}[o.gravity]

    def listed(on: bool, where: str) -> str:
        return f"listed in {where}" if on else f"not in {where}"

    choices = [
        Choice("orbit", True, f"{gravity} gravity, RK4 at {o.step_s:g} s with the force re-evaluated at every "
               "stage, Hermite-interpolated to the dynamics steps"),
        Choice("attitude", True, f"rigid body, {sc.integrator.upper()} at {sc.step_s:g} s"),
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
        _star_screen_choice(sc),
    ]
    for d in sc.devices:
        if d.kind == "sun_sensor":
            why = f"{d.type} sun sensor sampled from the truth at {d.rate_hz:g} Hz, eclipse-aware (no bus)"
        elif d.kind == "magnetorquer":
            why = (f"magnetorquer board, {d.link} on CAN {d.interface}:{d.channel}, magnetometer at "
                   f"{d.sample_rate_hz:g} Hz")
        else:
            what = ("solved from its rendered detector image" if d.source == "image"
                    else f"{d.source} plus noise")
            why = (f"star tracker, {d.link} on a serial {d.port} pair, {what}, a solution every "
                   f"{d.emulator['output_interval_s']:g} s")
        choices.append(Choice(f"device.{d.name}", True, why))
    if sc.rendezvous is not None:
        from .rendezvous import describe

        choices.append(Choice("rendezvous.shadow", True, describe(sc.rendezvous)))
    ctl = sc.controller
    choices.append(Choice(f"controller.{ctl.kind}", ctl.kind != "none",
                          f"at {ctl.rate_hz:g} Hz through the host drivers" if ctl.kind != "none"
                          else "no controller in the scenario: open loop"))
    return choices


def _star_screen_choice(sc: Scenario) -> Choice:
    trackers = [d for d in sc.devices if d.kind == "star_tracker"]
    image = [d for d in trackers if d.source == "image"]
    truth = [d.name for d in trackers if d.source != "image"]
    if not image:
        return Choice("star_screen", False, "trackers use truth plus noise: " + ", ".join(truth) if truth
                      else "no star tracker in the scene")
    parts = []
    for d in image:
        o, cam = d.optics, d.camera
        fx, fy = o.fov_deg
        parts.append(f"renders the detector image of {d.name} ({fx:g} x {fy:g} deg on {o.width} x {o.height} px, "
                     f"stars to Hp {o.mag_limit:g}, PSF sigma {o.psf_sigma_px:g} px, aberration, rate smear), "
                     f"adds camera noise (read {cam['read_noise_e']:g} e-, background {cam['background_e']:g} e-) "
                     "and solves it (pattern database built at compose time)")
    if truth:
        parts.append("truth plus noise for " + ", ".join(truth))
    return Choice("star_screen", True, "; ".join(parts))


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
    """The live objects of one run. Close it to release the buses (idempotent)."""

    scenario: Scenario
    truth: TruthModel
    choices: list[Choice]
    emulators: dict = field(default_factory=dict)
    hosts: dict = field(default_factory=dict)
    buses: list = field(default_factory=list)
    trackers: dict = field(default_factory=dict)
    sun_sensors: dict = field(default_factory=dict)
    controller: object | None = None
    closed: bool = False

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        if self.controller is not None and hasattr(self.controller, "close"):
            self.controller.close()
        for link in self.trackers.values():
            link.close()
        for h in self.hosts.values():
            h.close()
        for b in self.buses:
            b.shutdown()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def initial_state(sc: Scenario):
    o = sc.orbit
    r, v = elements_to_state(e=o.e, i=o.i_rad, raan=o.raan_rad, argp=o.argp_rad, a=o.a_m, p=o.p_m,
                             nu=o.nu_rad, M=o.mean_anomaly_rad)
    return np.asarray(r, dtype=float), np.asarray(v, dtype=float)


def build(sc: Scenario) -> Scene:
    """Create the truth model, the device emulators and host drivers, and the controller."""
    from drivers.can_bus import open_bus
    from drivers.magnetorquer.emulator import EmulatorConfig, MagnetorquerEmulator
    from drivers.magnetorquer.host import MagnetorquerBoard

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

    truth = TruthModel(
        inertia=sc.spacecraft.inertia_kg_m2, q_BN=sc.spacecraft.q_BN, omega_BN_B=sc.spacecraft.omega_BN_B,
        r_N=r0, v_N=v0, step_ns=seconds_to_ns(sc.step_s), gravity=sc.orbit.gravity,
        orbit_step_s=sc.orbit.step_s,
        field_itrs=field_itrs if needs_field else None,
        earth_rotation=rotation, torques=sc.torques, forces=forces, integrator=sc.integrator,
    )
    scene = Scene(sc, truth, choices)
    try:
        rng = np.random.SeedSequence(sc.seed)
        for d, child in zip(sc.devices, rng.spawn(len(sc.devices)), strict=True):
            if d.kind == "sun_sensor":
                scene.sun_sensors[d.name] = SunSensorLink(d, truth, tracks["sun"], np.random.default_rng(child))
                continue
            if d.kind == "star_tracker":
                scene.trackers[d.name] = build_tracker(d, truth, tracks, np.random.default_rng(child),
                                                       epoch=sc.epoch)
                continue
            dcm_SB = dcm(d.q_SB)
            q_SB = tuple(float(x) for x in d.q_SB)

            def field_S(_t_s, q_SB=q_SB):
                # Composition of q_SB after q_BN on floats: v_S = dcm(q_SB) dcm(q_BN) b_N.
                return rotate_to_body(q_SB, truth.b_B())

            config = EmulatorConfig(
                max_dipole_A_m2=d.max_dipole_A_m2, dipole_lsb_A_m2=d.dipole_lsb_A_m2,
                mag_noise_T=d.mag_noise_T, mag_bias_T=tuple(d.mag_bias_T),
                coil_coupling_T_per_A_m2=np.diag(d.coil_coupling_T_per_A_m2) @ dcm_SB.T,
                sample_period_s=1.0 / d.sample_rate_hz,
            )
            emu_bus = open_bus(d.interface, d.channel)
            scene.buses.append(emu_bus)
            host_bus = open_bus(d.interface, d.channel)
            scene.buses.append(host_bus)
            scene.emulators[d.name] = MagnetorquerEmulator(emu_bus, field_S, config, np.random.default_rng(child))
            scene.hosts[d.name] = MagnetorquerBoard(host_bus, name=d.name)
        ctl = sc.controller
        period = 1.0 / ctl.rate_hz
        if ctl.kind == "bdot":
            d = next(d for d in sc.devices if d.kind == "magnetorquer")
            p = ctl.params
            scene.controller = BDot(scene.hosts[d.name], period, p["gain_A_m2_s_per_T"], p["max_dipole_A_m2"],
                                    q_SB=d.q_SB, skip_coil_active=p["skip_coil_active"],
                                    duty_cycle=p.get("duty_cycle", 1.0))
        elif ctl.kind == "plugin":
            cls = load_plugin(ctl.params["module"])
            scene.controller = cls(scene.hosts, period, **ctl.params["options"])
    except BaseException:
        scene.close()
        raise
    return scene


def ticks_per(rate_hz: float, step_s: float) -> int:
    """Dynamics steps per period of a rate (validated to be whole by the scenario loader)."""
    return max(1, round(NS_PER_S / rate_hz) // seconds_to_ns(step_s))
