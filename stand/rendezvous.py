"""Shadows on the docking target during a rendezvous: the ``[rendezvous]`` scenario section.

A chaser approaches a target vehicle whose docking target (circular marks on a base plate) its
camera must read. This module validates the section (``parse_rendezvous``), builds the approach
geometry over time (:class:`Approach`), evaluates how much of the marks is in shadow
(:meth:`Approach.evaluate`), finds the obscuration intervals (:func:`find_intervals`, the ends
refined by bisection or left to one sample) and writes the outputs (:func:`run_shadow`):
``obscuration.csv``, ``summary.json``, ``obscured.png``, ``tracks.png``, ``report.md`` and one
``camera_<t>s.png`` per requested time (:func:`render_camera`).

Frames (all right-handed; ``dcm_XY`` maps Y components to X components):

* N: GCRS. L: the target's LVLH (z nadir, y negative orbit normal, x along-track).
* T: target body, LVLH-fixed: ``dcm_TL = dcm(q_TL)``.
* P: plate, fixed in T at ``center_m`` with ``dcm_PT = dcm(q_PT)``; +z_P is the plate normal facing
  the approaching chaser, marks lie in z_P = 0 at ``marks_m`` = [x_P, y_P].
* C: chaser, origin at its docking port, +x_C the docking axis, pointed at the plate centre at every
  instant, +z_C as near nadir as it can be (then ``roll_deg`` about +x_C).
* K: docking camera at ``position_m`` in C, looking along +x_C: +z_K = +x_C (boresight),
  +x_K = +y_C (image right), +y_K = +z_C (image down).

The target flies a two-body orbit from ``[orbit]`` (J2 moves the LVLH frame by well under a
degree over an approach). The Sun comes from the ERFA ephemeris (:class:`sim.ephemeris.EphemerisTrack`),
the Earth's shadow from :func:`sim.environment.shadow_fraction` (conical, with penumbra). Shadows
on the plate are exact ray tests (:mod:`sim.obscuration`) against the plate itself (a Sun below its
horizon), the target's bodies and the chaser's bodies, with the Sun as a sampled disk or a point.

``obscured_percent`` is the shadowed share of the marks' area: the mean over marks of the area-
weighted fraction of the solar disk hidden from each mark point (a mark point half in penumbra
counts half). The Earth's shadow is reported beside it (``earth_lit_fraction``, eclipse intervals),
not mixed into it: it darkens everything at once and is not a shadow on the plate.
"""

from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sim.constants import MU_EARTH
from sim.environment import shadow_fraction
from sim.ephemeris import EphemerisTrack
from sim.frames import dcm_lvlh_gcrs
from sim.obscuration import (
    SUN_RADIUS_RAD_1AU,
    Box,
    Frustum,
    HalfSpace,
    Occluder,
    Panel,
    SunDisk,
    mark_points,
    project_to_plate,
    visible_fraction,
)
from sim.orbit import elements_to_state, propagate_kepler
from sim.relative_motion import cw_state, kepler_relative_state, line_state, mean_motion, pointing_dcm
from sim.rotations import dcm

from .errors import MISSING, ScenarioError

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
    from .scenario import Table

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
    from .scenario import pair

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
    geo = _static(spec)
    r_L = _chaser_path(spec, orbit, t)
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


def _static(spec: RendezvousSpec) -> dict:
    dcm_TL = dcm(spec.q_TL)
    dcm_PT = dcm(spec.plate.q_PT)
    dcm_PL = dcm_PT @ dcm_TL
    r_PL_L = dcm_TL.T @ spec.plate.center_T_m
    return {"dcm_TL": dcm_TL, "dcm_PT": dcm_PT, "dcm_PL": dcm_PL, "r_PL_L": r_PL_L}


def _target_state0(orbit) -> tuple[np.ndarray, np.ndarray]:
    r, v = elements_to_state(e=orbit.e, i=orbit.i_rad, raan=orbit.raan_rad, argp=orbit.argp_rad, a=orbit.a_m,
                             p=orbit.p_m, nu=orbit.nu_rad, M=orbit.mean_anomaly_rad)
    return np.asarray(r, dtype=float), np.asarray(v, dtype=float)


def _chaser_path(spec: RendezvousSpec, orbit, t) -> np.ndarray:
    if spec.trajectory == "line":
        return line_state(spec.r0_L_m, spec.v0_L_m_s, t)[0]
    if spec.trajectory == "cw":
        a = orbit.a_m if orbit.a_m is not None else orbit.p_m / (1 - orbit.e ** 2)
        return cw_state(spec.r0_L_m, spec.v0_L_m_s, t, mean_motion(a))[0]
    r0, v0 = _target_state0(orbit)
    return kepler_relative_state(r0, v0, spec.r0_L_m, spec.v0_L_m_s, t)[0]


class Approach:
    """The approach of a scenario: everything as a function of sim time (s since the epoch)."""

    def __init__(self, sc, spec: RendezvousSpec | None = None):
        self.sc = sc
        self.spec = spec if spec is not None else sc.rendezvous
        if self.spec is None:
            raise ScenarioError("rendezvous", MISSING, "a [rendezvous] section for 'stand shadow'", sc.source)
        self.geo = _static(self.spec)
        self.r0_N, self.v0_N = _target_state0(sc.orbit)
        self.sun = EphemerisTrack(sc.epoch, "sun")
        pts, w = mark_points(self.spec.plate.marks_m, self.spec.plate.mark_radius_m, self.spec.plate.mark_rings)
        self.mark_pts, self.mark_w = pts, w
        self.plate_occ = Occluder("target plate (Sun below its horizon)", "target", HalfSpace([0, 0, 0], [0, 0, 1]))
        self.occluders = (self.plate_occ, *self.spec.target_bodies, *self.spec.chaser_bodies)
        self.evaluations = 0

    # -- kinematics -------------------------------------------------------------------------------
    def states(self, t_s) -> dict:
        """Frames, positions and the Sun at times ``t_s`` ``(T,)``."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        g = self.geo
        r_T, v_T = propagate_kepler(self.r0_N, self.v0_N, t, MU_EARTH)
        r_sun = self.sun.position_gcrs(t)
        dcm_LN = dcm_lvlh_gcrs(r_T, v_T)
        s_N = r_sun - r_T
        s_N /= np.linalg.norm(s_N, axis=-1, keepdims=True)
        s_L = np.einsum("tij,tj->ti", dcm_LN, s_N)
        s_P = s_L @ g["dcm_PL"].T
        r_CL_L = _chaser_path(self.spec, self.sc.orbit, t)
        dcm_CL = pointing_dcm(g["r_PL_L"] - r_CL_L, (0.0, 0.0, 1.0), self.spec.roll_rad)
        earth = shadow_fraction(r_T, r_sun) if self.spec.earth_shadow else np.ones(len(t))
        return {"t_s": t, "r_T_N": r_T, "v_T_N": v_T, "sun_P": s_P, "sun_L": s_L, "r_CL_L": r_CL_L,
                "dcm_CL": dcm_CL, "earth_lit": earth,
                "r_CP_P": (r_CL_L - g["r_PL_L"]) @ g["dcm_PL"].T,
                "dcm_CP": dcm_CL @ g["dcm_PL"].T}

    def poses(self, st: dict) -> list[tuple[np.ndarray, np.ndarray]]:
        """``(r_VP_P, dcm_VP)`` of every occluder (plate, target bodies, chaser bodies) at ``st``'s times."""
        g = self.geo
        r_TP_P = -g["dcm_PT"] @ self.spec.plate.center_T_m
        dcm_TP = g["dcm_PT"].T
        out = [(np.zeros(3), np.eye(3))]
        out += [(r_TP_P, dcm_TP)] * len(self.spec.target_bodies)
        out += [(st["r_CP_P"], st["dcm_CP"])] * len(self.spec.chaser_bodies)
        return out

    # -- shadows ----------------------------------------------------------------------------------
    def evaluate(self, t_s, per_occluder: bool = False) -> dict:
        """Obscuration at times ``t_s``: ``obscured_percent`` ``(T,)``, ``mark_shadow`` ``(T, marks)``
        (shadowed area fraction of each mark), and with ``per_occluder`` ``occluder_percent``
        ``(n_occluders, T)`` (the share each occluder alone hides)."""
        st = self.states(t_s)
        n_marks, m = self.mark_pts.shape[:2]
        pts = self.mark_pts.reshape(-1, 3)
        res = visible_fraction(pts, st["sun_P"], self.occluders, self.poses(st), self.spec.sun_disk(),
                               per_occluder=per_occluder)
        vis, alone = res if per_occluder else (res, None)
        self.evaluations += len(st["t_s"])
        shadow = (1.0 - vis).reshape(len(st["t_s"]), n_marks, m) @ self.mark_w
        st["mark_shadow"] = shadow
        st["obscured_percent"] = 100.0 * shadow.mean(axis=1)
        if alone is not None:
            st["occluder_percent"] = 100.0 * (alone.reshape(len(self.occluders), -1, n_marks, m)
                                              @ self.mark_w).mean(axis=-1)
        return st

    def obscured(self, t_s) -> np.ndarray:
        return self.evaluate(t_s)["obscured_percent"] > self.spec.threshold_percent


# ------------------------------------------------------------------------------------------------
# Intervals


@dataclass(frozen=True)
class Interval:
    start_s: float
    end_s: float
    start_open: bool  # already obscured at the start of the run
    end_open: bool  # still obscured at its end
    max_percent: float = math.nan
    causes: tuple[str, ...] = ()

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


def sample_times(duration_s: float, step_s: float) -> np.ndarray:
    """``0, step, 2 step, ...`` up to and including ``duration_s`` (the last step may be short)."""
    n = int(math.floor(duration_s / step_s + 1e-9))
    t = np.arange(n + 1) * step_s
    return t if t[-1] >= duration_s - 1e-9 * max(1.0, duration_s) else np.append(t, duration_s)


def _bisect(fn, lo: np.ndarray, hi: np.ndarray, lo_state: bool, tol_s: float) -> np.ndarray:
    """Vectorised bisection of ``fn`` (times -> bool) between brackets where it is ``lo_state`` at
    ``lo`` and not at ``hi``; returns the bracket midpoints once narrower than ``tol_s``."""
    lo, hi = lo.astype(float).copy(), hi.astype(float).copy()
    for _ in range(MAX_BISECTIONS):
        if len(lo) == 0 or np.all(hi - lo <= tol_s):
            break
        mid = 0.5 * (lo + hi)
        same = fn(mid) == lo_state
        lo = np.where(same, mid, lo)
        hi = np.where(same, hi, mid)
    return 0.5 * (lo + hi)


def find_intervals(t: np.ndarray, flag: np.ndarray, fn=None, tol_s: float = 1e-3) -> list[tuple[float, float,
                                                                                                bool, bool]]:
    """Intervals where ``flag`` (bool over the sample times ``t``) holds.

    Without ``fn`` each end is reported at the sample where the state is first seen (a start at the
    first obscured sample, an end at the first clear one: within one step after the true change).
    With ``fn`` (times -> bool, the same test at any time) each end is bisected between its two
    samples down to ``tol_s``. Returns ``(start, end, start_open, end_open)``; an open end is the run's
    own start or end.
    """
    f = np.asarray(flag, dtype=bool)
    rise = np.flatnonzero(~f[:-1] & f[1:]) + 1
    fall = np.flatnonzero(f[:-1] & ~f[1:]) + 1
    starts, ends = t[rise].astype(float), t[fall].astype(float)
    if fn is not None:
        starts = _bisect(fn, t[rise - 1], t[rise], False, tol_s)
        ends = _bisect(fn, t[fall - 1], t[fall], True, tol_s)
    s_list = ([t[0]] if f[0] else []) + list(starts)
    s_open = ([True] if f[0] else []) + [False] * len(starts)
    e_list = list(ends) + ([t[-1]] if f[-1] else [])
    e_open = [False] * len(ends) + ([True] if f[-1] else [])
    return [(float(a), float(b), oa, ob) for a, b, oa, ob in zip(s_list, e_list, s_open, e_open, strict=True)]


@dataclass
class ShadowResult:
    t_s: np.ndarray
    samples: dict
    intervals: list[Interval]
    eclipses: list[Interval]
    wall_time_s: float
    evaluations: int
    step_s: float
    refined: bool


def compute(approach: Approach, step_s: float | None = None, refine: bool | None = None,
            tol_s: float | None = None, per_occluder: bool = True) -> ShadowResult:
    """Sample the approach over the scenario's duration and find the obscuration intervals."""
    spec = approach.spec
    step = spec.step_s if step_s is None else float(step_s)
    refine = spec.refine if refine is None else refine
    tol = spec.refine_tol_s if tol_s is None else float(tol_s)
    t0 = time.perf_counter()
    evals0 = approach.evaluations
    t = sample_times(approach.sc.duration_s, step)
    st = approach.evaluate(t, per_occluder=per_occluder)
    flag = st["obscured_percent"] > spec.threshold_percent
    raw = find_intervals(t, flag, approach.obscured if refine else None, tol)
    intervals = []
    names = [o.name for o in approach.occluders]
    for a, b, oa, ob in raw:
        sel = (t >= a) & (t <= b)
        # An interval shorter than a step may hold no sample: look at its middle instead.
        ev = st if sel.any() else approach.evaluate([0.5 * (a + b)], per_occluder=per_occluder)
        sel = sel if sel.any() else np.array([True])
        peak = float(ev["obscured_percent"][sel].max())
        causes = ()
        if "occluder_percent" in ev:
            causes = tuple(n for n, row in zip(names, ev["occluder_percent"][:, sel], strict=True) if np.any(row > 0))
        intervals.append(Interval(a, b, oa, ob, peak, causes))
    lit = st["earth_lit"]
    eclipses = [Interval(a, b, oa, ob, float(100 * (1 - lit[(t >= a) & (t <= b)].min())) if np.any(
        (t >= a) & (t <= b)) else math.nan) for a, b, oa, ob in find_intervals(t, lit < 1.0)]
    return ShadowResult(t, st, intervals, eclipses, time.perf_counter() - t0, approach.evaluations - evals0, step,
                        refine)


# ------------------------------------------------------------------------------------------------
# Camera


def render_camera(approach: Approach, t_s: float, camera: CameraSpec | None = None) -> np.ndarray:
    """What the docking camera sees at ``t_s``: a grey image ``(h, w)`` in [0, 1].

    Pinhole on the chaser's docking axis (frame K above), pixel (0.5, 0.5) the centre of the top-left
    pixel. Rays meet the plate (a disk, marks bright on a dark plate) and the target's bodies (nearest
    hit wins); each surface point is shaded Lambertian by the Sun's visible fraction there (the same
    shadow tests, Sun disk at most ``CAMERA_SUN_RINGS`` rings) times the Earth's shadow factor, plus a
    small ambient term. The chaser's own bodies are behind the camera and are not drawn.
    """
    cam = camera or approach.spec.camera or CameraSpec(np.zeros(3), (30.0, 22.5), (480, 360), (t_s,))
    st = approach.states([t_s])
    w, h = cam.resolution_px
    fx = 0.5 * w / math.tan(math.radians(cam.fov_deg[0]) / 2)
    fy = 0.5 * h / math.tan(math.radians(cam.fov_deg[1]) / 2)
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    d_K = np.stack(((u - w / 2) / fx, (v - h / 2) / fy, np.ones_like(u)), axis=-1).reshape(-1, 3)
    d_K /= np.linalg.norm(d_K, axis=1, keepdims=True)
    dcm_CP = st["dcm_CP"][0]
    d_P = d_K @ (dcm_CP.T @ DCM_KC.T).T  # d_P = dcm_PC dcm_CK d_K, on rows
    o_P = st["r_CP_P"][0] + dcm_CP.T @ cam.position_C_m
    plate = approach.spec.plate
    with np.errstate(divide="ignore", invalid="ignore"):
        lam_plate = np.where(d_P[:, 2] < 0, -o_P[2] / d_P[:, 2], np.inf)
    hit_plate = o_P + np.where(np.isfinite(lam_plate), lam_plate, 0.0)[:, None] * d_P
    lam_plate = np.where(np.linalg.norm(hit_plate[:, :2], axis=1) <= plate.radius_m, lam_plate, np.inf)
    g = approach.geo
    r_TP_P, dcm_TP = -g["dcm_PT"] @ plate.center_T_m, g["dcm_PT"].T
    o_T, d_T = dcm_TP @ (o_P - r_TP_P), d_P @ dcm_TP.T
    lam_best, which = lam_plate.copy(), np.full(len(d_P), -1)
    for j, occ in enumerate(approach.spec.target_bodies):
        lam = occ.shape.entry(o_T, d_T, 0.0)
        closer = lam < lam_best
        lam_best, which = np.where(closer, lam, lam_best), np.where(closer, j, which)
    img = np.zeros(len(d_P))
    seen = np.isfinite(lam_best)
    x_P = o_P + np.where(seen, lam_best, 0.0)[:, None] * d_P
    normal = np.tile([0.0, 0.0, 1.0], (len(d_P), 1))
    albedo = np.full(len(d_P), 0.3)
    on_plate = seen & (which < 0)
    dist = np.linalg.norm(x_P[:, None, :2] - plate.marks_m[None], axis=-1).min(axis=1)
    albedo[on_plate & (dist <= plate.mark_radius_m)] = 1.0
    for j, occ in enumerate(approach.spec.target_bodies):
        sel = seen & (which == j)
        if np.any(sel):
            n_T = occ.shape.normal((x_P[sel] - r_TP_P) @ dcm_TP.T)
            n_P = n_T @ dcm_TP
            # A panel is seen from either side; a solid's outward normal faces the camera already.
            normal[sel] = np.where((np.sum(n_P * d_P[sel], axis=1) > 0)[:, None], -n_P, n_P)
            albedo[sel] = 0.55
    s = st["sun_P"][0]
    cos_i = np.clip(normal @ s, 0.0, None)
    idx = np.flatnonzero(seen & (cos_i > 0))
    if len(idx):
        vis = visible_fraction(x_P[idx] + 1e-6 * normal[idx], st["sun_P"], approach.occluders, approach.poses(st),
                               approach.spec.sun_disk(CAMERA_SUN_RINGS))[0]
        img[idx] = albedo[idx] * cos_i[idx] * vis * float(st["earth_lit"][0])
    img[seen] += 0.04 * albedo[seen]
    return np.clip(img.reshape(h, w), 0.0, 1.0)


def write_png(path: Path, image: np.ndarray) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.imsave(path, image, cmap="gray", vmin=0.0, vmax=1.0)


# ------------------------------------------------------------------------------------------------
# Outputs


def _interval_json(iv: Interval) -> dict:
    return {"start_s": iv.start_s, "end_s": iv.end_s, "duration_s": iv.duration_s, "start_open": iv.start_open,
            "end_open": iv.end_open, "max_percent": iv.max_percent, "causes": list(iv.causes)}


def _write_csv(path: Path, approach: Approach, res: ShadowResult) -> None:
    st = res.samples
    names = [o.name for o in approach.occluders]
    n_marks = st["mark_shadow"].shape[1]
    rng = np.linalg.norm(st["r_CP_P"], axis=1)
    elev = np.degrees(np.arcsin(np.clip(st["sun_P"][:, 2], -1, 1)))
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "obscured_percent", "earth_lit_fraction", "sun_elevation_on_plate_deg", "range_m",
                    "x_L_m", "y_L_m", "z_L_m"] + [f"mark{k}_shadow" for k in range(n_marks)]
                   + [f"percent[{n}]" for n in names if "occluder_percent" in st])
        for i, t in enumerate(res.t_s):
            row = [f"{t:.6f}", f"{st['obscured_percent'][i]:.6f}", f"{st['earth_lit'][i]:.6f}", f"{elev[i]:.5f}",
                   f"{rng[i]:.4f}", *(f"{x:.4f}" for x in st["r_CL_L"][i]),
                   *(f"{x:.6f}" for x in st["mark_shadow"][i])]
            if "occluder_percent" in st:
                row += [f"{x:.6f}" for x in st["occluder_percent"][:, i]]
            w.writerow(row)


def _plots(out: Path, approach: Approach, res: ShadowResult) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Polygon
    from scipy.spatial import ConvexHull, QhullError

    st, t = res.samples, res.t_s
    fig, ax = plt.subplots(figsize=(9, 4.5))
    ax.plot(t, st["obscured_percent"], "k-", lw=1.6, label="marks in shadow (all)")
    for name, row in zip([o.name for o in approach.occluders], st.get("occluder_percent", []), strict=False):
        if np.any(row > 0):
            ax.plot(t, row, lw=0.9, label=name)
    for iv in res.intervals:
        ax.axvspan(iv.start_s, iv.end_s, color="tab:red", alpha=0.08)
    for iv in res.eclipses:
        ax.axvspan(iv.start_s, iv.end_s, color="tab:blue", alpha=0.12)
    ax.set_xlabel("time since epoch (s)")
    ax.set_ylabel("marks' area in shadow (%)")
    ax.set_title(f"{approach.sc.name}: obscuration (red: intervals, blue: Earth shadow)")
    ax.legend(fontsize=7, loc="upper right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "obscured.png", dpi=110)
    plt.close(fig)

    plate = approach.spec.plate
    fig, ax = plt.subplots(figsize=(6.5, 6.5))
    ax.add_patch(Circle((0, 0), plate.radius_m, fc="0.85", ec="k"))
    for c in plate.marks_m:
        ax.add_patch(Circle(tuple(c), plate.mark_radius_m, fc="w", ec="k", lw=0.8))
    bodies = [(o, p) for o, p in zip(approach.occluders, approach.poses(st), strict=True) if hasattr(o.shape,
                                                                                                     "outline_m")]
    cmap = plt.get_cmap("viridis")
    k_show = np.unique(np.linspace(0, len(t) - 1, approach.spec.track_times).round().astype(int))
    lim = 1.3 * plate.radius_m
    for j, (occ, (r, C)) in enumerate(bodies):
        pts_V = occ.shape.outline_m()
        r_all = np.broadcast_to(r, (len(t), 3))
        C_all = np.broadcast_to(C, (len(t), 3, 3))
        centre_P = r_all + np.einsum("tji,j->ti", C_all, pts_V.mean(axis=0))
        track = project_to_plate(centre_P, st["sun_P"])
        near = np.linalg.norm(track[:, :2], axis=1) < 3 * plate.radius_m
        if np.any(near):
            xy = np.where(near[:, None], track[:, :2], np.nan)
            ax.plot(xy[:, 0], xy[:, 1], "-", lw=0.8, color=f"C{j % 10}", label=f"track: {occ.name}")
        for n_k, k in enumerate(k_show):
            pts_P = r_all[k] + pts_V @ C_all[k]
            proj = project_to_plate(pts_P, st["sun_P"][k])[:, :2]
            if not np.all(np.isfinite(proj)):
                continue
            try:
                hull = proj[ConvexHull(proj).vertices]
            except (QhullError, ValueError):
                continue
            if np.all(hull.min(axis=0) < lim) and np.all(hull.max(axis=0) > -lim):
                ax.add_patch(Polygon(hull, closed=True, fc=cmap(n_k / max(len(k_show) - 1, 1)), alpha=0.25,
                                     ec=f"C{j % 10}", lw=0.6))
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_aspect("equal")
    ax.set_xlabel("x_P (m)")
    ax.set_ylabel("y_P (m)")
    ax.set_title("shadows on the plate at " + ", ".join(f"{t[k]:.0f}" for k in k_show) + " s\n(purple to yellow: "
                 "earlier to later) and the tracks of the bodies' centres")
    ax.legend(fontsize=6, loc="lower left")
    fig.tight_layout()
    fig.savefig(out / "tracks.png", dpi=110)
    plt.close(fig)
    return ["obscured.png", "tracks.png"]


def _report(out: Path, approach: Approach, res: ShadowResult, images: list[str], summary: dict) -> None:
    spec = approach.spec
    lines = [f"# Shadows on the docking target: {approach.sc.name}", "",
             approach.sc.description or "", "",
             f"- epoch {approach.sc.epoch.iso}, {approach.sc.duration_s:g} s sampled every {res.step_s:g} s "
             f"({len(res.t_s)} samples), interval ends "
             + (f"bisected to {spec.refine_tol_s:g} s" if res.refined else "to one sample (not refined)"),
             f"- chaser trajectory: {spec.trajectory}, r0 = {spec.r0_L_m.tolist()} m, v0 = {spec.v0_L_m_s.tolist()}"
             " m/s (LVLH)",
             f"- Sun: {'point (umbra only)' if spec.sun == 'point' else f'disk sampled with {spec.sun_rings} rings'}"
             f"; Earth shadow {'conical' if spec.earth_shadow else 'off'}",
             f"- {len(spec.plate.marks_m)} marks of radius {spec.plate.mark_radius_m:g} m, each sampled at "
             f"{approach.mark_pts.shape[1]} points; obscured when above {spec.threshold_percent:g} %",
             f"- computed in {res.wall_time_s:.2f} s ({res.evaluations} evaluations)", "",
             "## Obscuration intervals", "",
             "| # | start (s) | end (s) | duration (s) | peak (%) | cast by |", "|---|---|---|---|---|---|"]
    for k, iv in enumerate(res.intervals):
        s = f"{iv.start_s:.3f}" + (" (run start)" if iv.start_open else "")
        e = f"{iv.end_s:.3f}" + (" (run end)" if iv.end_open else "")
        lines.append(f"| {k + 1} | {s} | {e} | {iv.duration_s:.3f} | {iv.max_percent:.1f} | "
                     f"{', '.join(iv.causes)} |")
    if not res.intervals:
        lines.append("| - | none | | | | |")
    lines += ["", "## Earth shadow", ""]
    lines += [f"- {iv.start_s:.1f} s to {iv.end_s:.1f} s (darkest {iv.max_percent:.0f} % of the Sun hidden)"
              for iv in res.eclipses] or ["- none: the target is in sunlight throughout"]
    lines += ["", "## Figures", "", "![obscured](obscured.png)", "", "![tracks](tracks.png)", ""]
    lines += [f"![camera]({name})" for name in images]
    lines += ["", f"Peak obscuration {summary['max_obscured_percent']:.1f} %, obscured "
              f"{summary['obscured_time_s']:.1f} s of {approach.sc.duration_s:g} s.", ""]
    (out / "report.md").write_text("\n".join(lines))


def run_shadow(sc, out: Path, step_s: float | None = None, refine: bool | None = None,
               camera_times_s: tuple[float, ...] | None = None) -> dict:
    """``stand shadow``: compute, then write every output into ``out``; returns the summary."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    approach = Approach(sc)
    res = compute(approach, step_s, refine)
    _write_csv(out / "obscuration.csv", approach, res)
    plots = _plots(out, approach, res)
    images = []
    cam = approach.spec.camera
    times = camera_times_s if camera_times_s is not None else (cam.times_s if cam else ())
    for tc in times:
        name = f"camera_{tc:08.1f}s.png".replace(" ", "0")
        write_png(out / name, render_camera(approach, tc, cam))
        images.append(name)
    op = res.samples["obscured_percent"]
    dt = np.diff(res.t_s)
    summary: dict[str, Any] = {
        "scenario": sc.name,
        "sim_duration_s": sc.duration_s,
        "wall_time_s": res.wall_time_s,
        "step_s": res.step_s,
        "refined": res.refined,
        "refine_tol_s": approach.spec.refine_tol_s if res.refined else None,
        "threshold_percent": approach.spec.threshold_percent,
        "samples": len(res.t_s),
        "evaluations": res.evaluations,
        "max_obscured_percent": float(op.max()),
        "obscured_time_s": float(np.sum(dt * (op[:-1] > approach.spec.threshold_percent))),
        "intervals": [_interval_json(iv) for iv in res.intervals],
        "eclipses": [_interval_json(iv) for iv in res.eclipses],
        "occluders": [o.name for o in approach.occluders],
        "outputs": ["obscuration.csv", "summary.json", "report.md", *plots, *images],
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    _report(out, approach, res, images, summary)
    return summary


def describe(spec: RendezvousSpec) -> str:
    """One line for ``stand check``."""
    earth = "conical Earth shadow" if spec.earth_shadow else "no Earth shadow"
    return (f"{spec.trajectory} approach from {np.linalg.norm(spec.r0_L_m):.4g} m off the target's centre, "
            f"{len(spec.plate.marks_m)} marks, "
            f"{len(spec.target_bodies)} target and {len(spec.chaser_bodies)} chaser bodies, Sun ({spec.sun}) from "
            f"the ephemeris, {earth}, every {spec.step_s:g} s (run with 'stand shadow')")
