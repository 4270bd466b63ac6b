"""The physical sections: ``[orbit]``, ``[spacecraft]`` and ``[environment]``, and the checks across them (a torque
that would spin the body past what the step integrates, an environment model nothing evaluates)."""

from __future__ import annotations

import math

import numpy as np

from sim.attitude import check_inertia, check_step
from sim.constants import MU_EARTH, R_EARTH
from sim.integrators import max_angle_rad
from sim.rotations import check_unit
from sim.time import Epoch
from stand import devices as kinds
from stand.checks import MISSING, ScenarioError, Table

from .model import ControllerSpec, EnvironmentSpec, OrbitSpec, SpacecraftSpec

TORQUES = ("magnetic", "gravity_gradient")
#: The Earth's Hill sphere radius, km: the largest orbit the Earth alone governs.
HILL_KM = 1.5e6
#: Largest principal moment of inertia a scenario may give (a space station is about 1e8 kg m^2).
MAX_INERTIA_KG_M2 = 1e10
#: Strongest geomagnetic field at the Earth's surface, T (IGRF: about 66 uT south of Australia; the centred
#: dipole's pole field is 61 uT); it falls with the cube of the distance.
MAX_FIELD_T = 6.7e-5


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

