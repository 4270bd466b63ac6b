"""The approach over time (:class:`Approach`): poses, the Sun and the Earth's shadow, how much of the marks is
in shadow; the obscuration intervals (:func:`find_intervals`, ends refined by bisection) and the docking camera's
image (:func:`render_camera`)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from sim.constants import MU_EARTH
from sim.environment import shadow_fraction
from sim.ephemeris import EphemerisTrack
from sim.frames import dcm_lvlh_gcrs
from sim.obscuration import (
    HalfSpace,
    Occluder,
    mark_points,
    visible_fraction,
)
from sim.orbit import propagate_kepler
from sim.relative_motion import pointing_dcm
from stand.errors import MISSING, ScenarioError

from .spec import (
    CAMERA_SUN_RINGS,
    DCM_KC,
    MAX_BISECTIONS,
    CameraSpec,
    RendezvousSpec,
    chaser_path,
    static_geometry,
    target_state0,
)


class Approach:
    """The approach of a scenario: everything as a function of sim time (s since the epoch)."""

    def __init__(self, sc, spec: RendezvousSpec | None = None):
        self.sc = sc
        self.spec = spec if spec is not None else sc.rendezvous
        if self.spec is None:
            raise ScenarioError("rendezvous", MISSING, "a [rendezvous] section for 'stand shadow'", sc.source)
        self.geo = static_geometry(self.spec)
        self.r0_N, self.v0_N = target_state0(sc.orbit)
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
        r_CL_L = chaser_path(self.spec, self.sc.orbit, t)
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

