"""The ``[rendezvous]`` section: its tables (the target, its plate and marks, the chaser and its bodies, the
camera), their validation (:func:`parse_rendezvous`) and the chaser's path relative to the target.

Frames and conventions are in :mod:`stand.rendezvous`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sim.obscuration import (
    SUN_RADIUS_RAD_1AU,
    Box,
    Frustum,
    Occluder,
    Panel,
    SunDisk,
)
from sim.orbit import elements_to_state
from sim.relative_motion import cw_state, kepler_relative_state, line_state, mean_motion
from sim.rotations import dcm
from stand.checks import Table, pair
from stand.errors import MISSING

TRAJECTORIES = ("line", "cw", "kepler")
BODY_KINDS = ("frustum", "cone", "cylinder", "box", "panel")
SUN_MODELS = ("disk", "point")
#: Largest target eccentricity the CW equations are allowed for (their error grows with e times the
#: separation; beyond this use trajectory = "kepler").
CW_MAX_E = 0.005
#: The camera's image is rendered with at most this many Sun-disk rings (a penumbra a few pixels wide
#: does not need more).
CAMERA_SUN_RINGS = 3
#: Bisection of interval ends stops at this many halvings whatever the tolerance.
MAX_BISECTIONS = 60
#: K (camera) from C (chaser): image right = +y_C, image down = +z_C, boresight = +x_C.
DCM_KC = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class PlateSpec:
    center_T_m: np.ndarray
    q_PT: np.ndarray
    radius_m: float
    marks_m: np.ndarray  # (n, 2) in P
    mark_radius_m: float
    mark_rings: int


@dataclass(frozen=True)
class CameraSpec:
    position_C_m: np.ndarray
    fov_deg: tuple[float, float]
    resolution_px: tuple[int, int]
    times_s: tuple[float, ...]


@dataclass(frozen=True)
class RendezvousSpec:
    """The validated ``[rendezvous]`` section (SI inside)."""

    step_s: float
    refine: bool
    refine_tol_s: float
    threshold_percent: float
    sun: str
    sun_rings: int
    earth_shadow: bool
    q_TL: np.ndarray
    plate: PlateSpec
    target_bodies: tuple[Occluder, ...]
    trajectory: str
    r0_L_m: np.ndarray
    v0_L_m_s: np.ndarray
    roll_rad: float
    chaser_bodies: tuple[Occluder, ...]
    camera: CameraSpec | None
    track_times: int = 6
    source: str | None = field(default=None, compare=False)

    def sun_disk(self, rings: int | None = None) -> SunDisk:
        if self.sun == "point":
            return SunDisk(0.0)
        return SunDisk(SUN_RADIUS_RAD_1AU, min(self.sun_rings, rings) if rings else self.sun_rings)


# ------------------------------------------------------------------------------------------------
# Validation


#: Largest coordinate of the target and chaser geometry, m (a docking target is metres, a station 100 m), and of the
#: chaser's start: the approach is relative motion near the target, which the linear (CW) model holds to ~10 km.
MAX_SIZE_M = 1000.0
MAX_RANGE_M = 1e5
#: Largest chaser speed relative to the target, m/s.
MAX_SPEED_M_S = 1000.0


def _unit_quat(t, key: str, default) -> np.ndarray:
    q = t.vector(key, 4, default, lo=-2.0, hi=2.0)
    if abs(np.linalg.norm(q) - 1.0) > 1e-6:
        raise t.error(key, q.tolist(), f"a unit quaternion [w, x, y, z] (its norm is {np.linalg.norm(q):.9g})")
    return q


def _nonzero(t, key: str, default=MISSING) -> np.ndarray:
    v = t.vector(key, 3, default, lo=-MAX_SIZE_M, hi=MAX_SIZE_M)
    if np.linalg.norm(v) == 0.0:
        raise t.error(key, v.tolist(), "a non-zero direction [x, y, z]")
    return v


def _body(t, vehicle: str, k: int) -> Occluder:
    kind = t.choice("kind", BODY_KINDS)
    name = t.text("name", f"{kind} {k}")
    pos = {"lo": 0.0, "lo_open": True, "hi": 1000.0}
    if kind in ("frustum", "cone", "cylinder"):
        base, axis = t.vector("base_m", 3, lo=-MAX_SIZE_M, hi=MAX_SIZE_M), _nonzero(t, "axis")
        length = t.number("length_m", **pos)
        if kind == "cylinder":
            r0 = r1 = t.number("radius_m", **pos)
        elif kind == "cone":
            r0, r1 = t.number("base_radius_m", **pos), 0.0
        else:
            r0 = t.number("base_radius_m", lo=0.0, hi=1000.0)
            r1 = t.number("top_radius_m", lo=0.0, hi=1000.0)
            if r0 == 0.0 and r1 == 0.0:
                raise t.error("top_radius_m", r1, "a radius > 0 at one end at least (base_radius_m is 0 too)")
        shape = Frustum(base, axis, length, r0, r1)
    elif kind == "box":
        size = t.vector("size_m", 3)
        if np.any(size <= 0) or np.any(size > 1000):
            raise t.error("size_m", size.tolist(), "three edge lengths [x, y, z], each > 0 and <= 1000 m")
        q = _unit_quat(t, "q_XV", [1.0, 0.0, 0.0, 0.0])
        shape = Box(t.vector("center_m", 3, lo=-MAX_SIZE_M, hi=MAX_SIZE_M), size / 2.0, dcm(q))
    else:
        corner = t.vector("corner_m", 3, lo=-MAX_SIZE_M, hi=MAX_SIZE_M)
        u, v = _nonzero(t, "edge_u_m"), _nonzero(t, "edge_v_m")
        if np.linalg.norm(np.cross(u, v)) <= 1e-9 * np.linalg.norm(u) * np.linalg.norm(v):
            raise t.error("edge_v_m", v.tolist(), f"an edge not parallel to edge_u_m = {u.tolist()} "
                          "(the two edges span the panel)")
        shape = Panel(corner, u, v)
    t.check_unknown()
    return Occluder(f"{vehicle} {name}", vehicle, shape)


def _bodies(t, vehicle: str) -> tuple[Occluder, ...]:
    raw = t.raw("bodies", [])
    if not isinstance(raw, list):
        raise t.error("bodies", raw, f"an array of [[rendezvous.{vehicle}.bodies]] tables")
    out = tuple(_body(Table(b, f"{t.path}.bodies[{k}]", t.source), vehicle, k) for k, b in enumerate(raw))
    names = [o.name for o in out]
    if len(set(names)) != len(names):
        raise t.error("bodies", names, "bodies with unique names")
    return out


def _marks(t) -> np.ndarray:
    raw = t.raw("marks_m", MISSING)
    try:
        arr = np.asarray(raw, dtype=float)
    except (TypeError, ValueError):
        arr = None
    if raw is MISSING or arr is None or arr.ndim != 2 or arr.shape[1] != 2 or len(arr) == 0 \
            or not np.all(np.isfinite(arr)) or len(arr) > 500 or np.max(np.abs(arr)) > MAX_SIZE_M:
        raise t.error("marks_m", raw, "a list of 1 to 500 mark centres [x, y] on the plate (m, plate frame)")
    return arr


def _plate(t) -> PlateSpec:
    radius = t.number("radius_m", lo=0.0, lo_open=True, hi=100.0)
    marks = _marks(t)
    mark_r = t.number("mark_radius_m", lo=0.0, lo_open=True, hi=radius)
    far = np.linalg.norm(marks, axis=1) + mark_r
    if np.any(far > radius * (1 + 1e-12)):
        k = int(np.argmax(far))
        raise t.error("marks_m", marks[k].tolist(), f"marks that lie on the plate (radius_m = {radius:g}: this "
                      f"one reaches {far[k]:.4g} m from the centre)")
    center = t.vector("center_m", 3, lo=-MAX_SIZE_M, hi=MAX_SIZE_M)
    spec = PlateSpec(center_T_m=center, q_PT=_unit_quat(t, "q_PT", [1.0, 0.0, 0.0, 0.0]),
                     radius_m=radius, marks_m=marks, mark_radius_m=mark_r,
                     mark_rings=int(t.number("mark_rings", 2, lo=0, hi=12, integer=True)))
    t.check_unknown()
    return spec


def _camera(t, duration_s: float) -> CameraSpec:
    times = t.raw("times_s", [0.0])
    if not isinstance(times, list) or not times or len(times) > 50 or any(
            isinstance(x, bool) or not isinstance(x, int | float) or not 0 <= x <= duration_s for x in times):
        raise t.error("times_s", times, f"a list of 1 to 50 times in [0, {duration_s:g}] s")
    spec = CameraSpec(position_C_m=t.vector("position_m", 3, [0.0, 0.0, 0.0], lo=-MAX_SIZE_M, hi=MAX_SIZE_M),
                      fov_deg=pair(t, "fov_deg", (30.0, 22.5), 1.0, 120.0, False),
                      resolution_px=pair(t, "resolution_px", (480, 360), 16, 2048, True),
                      times_s=tuple(float(x) for x in times))
    t.check_unknown()
    return spec


def parse_rendezvous(t, duration_s: float, orbit, source: str | None = None) -> RendezvousSpec:
    """Validate a ``[rendezvous]`` table (a ``stand.scenario.Table``) against the scenario's
    duration and ``[orbit]``; raises ``ScenarioError`` naming the first bad field."""
    step = t.number("step_s", 1.0, lo=1e-3, hi=max(duration_s / 2.0, 1e-3))
    refine = t.raw("refine", True)
    if not isinstance(refine, bool):
        raise t.error("refine", refine, "true (bisect interval ends) or false (report them to one sample)")
    tol = t.number("refine_tol_s", 1e-3, lo=1e-6, hi=step)
    threshold = t.number("threshold_percent", 0.0, lo=0.0, hi=100.0, hi_open=True)
    sun = t.choice("sun", SUN_MODELS, "disk")
    rings = int(t.number("sun_rings", 4, lo=1, hi=20, integer=True))
    earth = t.raw("earth_shadow", True)
    if not isinstance(earth, bool):
        raise t.error("earth_shadow", earth, "true (conical Earth shadow) or false")
    track_times = int(t.number("track_times", 6, lo=1, hi=50, integer=True))
    tgt = t.table("target")
    q_TL = _unit_quat(tgt, "q_TL", [1.0, 0.0, 0.0, 0.0])
    plate = _plate(tgt.table("plate"))
    target_bodies = _bodies(tgt, "target")
    tgt.check_unknown()
    ch = t.table("chaser")
    traj = ch.choice("trajectory", TRAJECTORIES, "line")
    if traj == "cw" and orbit.e > CW_MAX_E:
        raise ch.error("trajectory", traj, f"'line' or 'kepler' for this target orbit: the Clohessy-Wiltshire "
                       f"equations assume a circular one and orbit.e = {orbit.e:g} exceeds {CW_MAX_E:g}")
    r0 = ch.vector("r0_m", 3, lo=-MAX_RANGE_M, hi=MAX_RANGE_M)
    v0 = ch.vector("v0_m_s", 3, [0.0, 0.0, 0.0], lo=-MAX_SPEED_M_S, hi=MAX_SPEED_M_S)
    roll = math.radians(ch.number("roll_deg", 0.0, lo=-180.0, hi=180.0))
    chaser_bodies = _bodies(ch, "chaser")
    ch.check_unknown()
    camera = _camera(t.table("camera"), duration_s) if t.has("camera") else None
    t.raw("camera")
    t.check_unknown()
    spec = RendezvousSpec(step, refine, tol, threshold, sun, rings, earth, q_TL, plate, target_bodies, traj,
                          r0, v0, roll, chaser_bodies, camera, track_times, source)
    _check_in_front(spec, duration_s, orbit, ch)
    return spec


def _check_in_front(spec: RendezvousSpec, duration_s: float, orbit, ch) -> None:
    """Refuse a trajectory that reaches the plate plane or the docking axis' nadir singularity."""
    n = max(2, min(100_000, int(math.ceil(duration_s / spec.step_s)) + 1))
    t = np.linspace(0.0, duration_s, n)
    geo = static_geometry(spec)
    r_L = chaser_path(spec, orbit, t)
    z_P = np.einsum("ij,tj->ti", geo["dcm_PL"], r_L - geo["r_PL_L"])[:, 2]
    if np.any(z_P <= 0.0):
        k = int(np.argmax(z_P <= 0.0))
        raise ch.error("r0_m" if k == 0 else "v0_m_s", (spec.r0_L_m if k == 0 else spec.v0_L_m_s).tolist(),
                       f"a trajectory that stays in front of the plate (its docking port reaches the plate plane "
                       f"at t = {t[k]:.4g} s, {float(z_P[k]):.3g} m from it)")
    axis = geo["r_PL_L"] - r_L
    cosn = axis[:, 2] / np.linalg.norm(axis, axis=1)
    if np.any(np.abs(cosn) > 1 - 1e-9):
        raise ch.error("r0_m", spec.r0_L_m.tolist(), "an approach that is never exactly along the nadir line "
                       "(the chaser's roll about its docking axis is set from nadir)")


# ------------------------------------------------------------------------------------------------
# Geometry over time


def static_geometry(spec: RendezvousSpec) -> dict:
    dcm_TL = dcm(spec.q_TL)
    dcm_PT = dcm(spec.plate.q_PT)
    dcm_PL = dcm_PT @ dcm_TL
    r_PL_L = dcm_TL.T @ spec.plate.center_T_m
    return {"dcm_TL": dcm_TL, "dcm_PT": dcm_PT, "dcm_PL": dcm_PL, "r_PL_L": r_PL_L}


def target_state0(orbit) -> tuple[np.ndarray, np.ndarray]:
    r, v = elements_to_state(e=orbit.e, i=orbit.i_rad, raan=orbit.raan_rad, argp=orbit.argp_rad, a=orbit.a_m,
                             p=orbit.p_m, nu=orbit.nu_rad, M=orbit.mean_anomaly_rad)
    return np.asarray(r, dtype=float), np.asarray(v, dtype=float)


def chaser_path(spec: RendezvousSpec, orbit, t) -> np.ndarray:
    if spec.trajectory == "line":
        return line_state(spec.r0_L_m, spec.v0_L_m_s, t)[0]
    if spec.trajectory == "cw":
        a = orbit.a_m if orbit.a_m is not None else orbit.p_m / (1 - orbit.e ** 2)
        return cw_state(spec.r0_L_m, spec.v0_L_m_s, t, mean_motion(a))[0]
    r0, v0 = target_state0(orbit)
    return kepler_relative_state(r0, v0, spec.r0_L_m, spec.v0_L_m_s, t)[0]



def describe(spec: RendezvousSpec) -> str:
    """One line for ``stand check``."""
    earth = "conical Earth shadow" if spec.earth_shadow else "no Earth shadow"
    return (f"{spec.trajectory} approach from {np.linalg.norm(spec.r0_L_m):.4g} m off the target's centre, "
            f"{len(spec.plate.marks_m)} marks, "
            f"{len(spec.target_bodies)} target and {len(spec.chaser_bodies)} chaser bodies, Sun ({spec.sun}) from "
            f"the ephemeris, {earth}, every {spec.step_s:g} s (run with 'stand shadow')")
