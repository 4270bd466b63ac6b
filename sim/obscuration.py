"""Shadows on a docking target: which marks on a base plate the Sun cannot reach.

A camera on an approaching ship reads a docking target: marks (circles) on a base plate of the
target vehicle. Bodies between the plate and the Sun, the target's own front cone, the approaching
ship's body and its solar panels, throw shadows across the marks. This module answers, for points
on the plate, how much of the Sun each point sees.

Method (exact geometry, no rasterising): a point ``p`` is in the shadow of a convex body when the
ray ``p + lam d`` toward the Sun (``d`` unit, ``lam > LAM_MIN_M``) enters the body. Each shape
solves its own ray intersection in closed form and returns the entry distance (``inf`` for a
miss), vectorised over any broadcast of points and directions:

* :class:`Frustum` (cone frustum; a cylinder when both radii agree, a cone when one is 0): the
  axial slab gives an interval of ``lam``; inside the slab the solid is ``|x_perp|^2 <= r(z)^2``,
  a quadratic in ``lam`` whose first root after the slab entry is the surface.
* :class:`Box`: slabs along its three axes.
* :class:`Panel` (a flat parallelogram: solar panel, plate, radiator): the plane crossing and its
  two edge coordinates in [0, 1].
* :class:`HalfSpace`: everything behind a plane; the plate itself is one, so a Sun below the
  plate's horizon darkens every mark.

The Sun is either a point (``SunDisk(0.0)``, umbra only) or a disk of angular radius ``alpha``
sampled by a fixed polar quadrature (:class:`SunDisk`): the centre, then rings at ``alpha j / n``
for ``j = 1..n`` with ``6 j`` points each, weighted by the annulus each ring stands for. The last
ring lies on the limb, so the outer edge of a penumbra is exact up to the azimuth spacing of
the limb points (an angular error of at most ``alpha (1 - cos(pi / 6 n))``, 1e-4 alpha at n = 6).
The hidden fraction is a step function of the edge position (it jumps as the edge passes a
sample); across a straight edge's penumbra it stays within 0.069, 0.029, 0.015 and 0.009 of the
circular-segment area at n = 2, 4, 6 and 10 (measured; ``tests/sim/test_obscuration.py`` keeps
both bounds). Limb darkening is not modelled: every part of the disk counts the same.

Frames: everything is handed over in one frame (the plate frame P of :mod:`stand.rendezvous`:
origin at the plate centre, +z the plate normal toward the approaching ship). A body fixed to a
vehicle V is given in V's frame and placed with ``r_VP_P`` (V's origin in P) and ``dcm_VP`` (P
components to V components), both either constant or one per time.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "Box", "Frustum", "HalfSpace", "Occluder", "Panel", "SunDisk", "LAM_MIN_M", "SUN_RADIUS_RAD_1AU",
    "mark_points", "project_to_plate", "visible_fraction", "straight_edge_hidden_fraction",
]

#: Rays start this far from their point so a point on a body's surface does not shadow itself.
LAM_MIN_M = 1e-7
#: Farthest intersection looked for: beyond it nothing of a docking scene exists.
LAM_MAX_M = 1e7
#: Angular radius of the Sun seen from 1 au (R_sun = 6.957e8 m, IAU 2015 B3), rad.
SUN_RADIUS_RAD_1AU = float(np.arcsin(6.957e8 / 149597870700.0))


def _dot(a, b) -> np.ndarray:
    return np.sum(a * b, axis=-1)


def _unit(v, name: str) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if v.shape[-1:] != (3,) or not np.all(np.isfinite(v)) or np.any(n == 0.0):
        raise ValueError(f"{name} = {v.tolist()} must be a finite non-zero 3-vector.")
    return v / n


def _vec(v, name: str) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} = {np.asarray(v).tolist()} must be a list of 3 finite numbers (m).")
    return v


def _positive(x, name: str, allow_zero: bool = False) -> float:
    x = float(x)
    if not np.isfinite(x) or x < 0.0 or (x == 0.0 and not allow_zero):
        raise ValueError(f"{name} = {x!r} must be a finite number {'>= 0' if allow_zero else '> 0'} (m).")
    return x


@dataclass(frozen=True)
class Frustum:
    """A solid cone frustum: base disk centred on ``base_m`` with radius ``base_radius_m``, axis
    ``axis`` (unit, base to top), length ``length_m``, top radius ``top_radius_m``. A cylinder has
    equal radii; a cone has a 0 top (or base) radius. Coordinates in the vehicle frame (m)."""

    base_m: np.ndarray
    axis: np.ndarray
    length_m: float
    base_radius_m: float
    top_radius_m: float

    def __post_init__(self):
        object.__setattr__(self, "base_m", _vec(self.base_m, "base_m"))
        object.__setattr__(self, "axis", _unit(self.axis, "axis"))
        object.__setattr__(self, "length_m", _positive(self.length_m, "length_m"))
        object.__setattr__(self, "base_radius_m", _positive(self.base_radius_m, "base_radius_m", True))
        object.__setattr__(self, "top_radius_m", _positive(self.top_radius_m, "top_radius_m", True))
        if self.base_radius_m == 0.0 and self.top_radius_m == 0.0:
            raise ValueError("a frustum needs base_radius_m or top_radius_m > 0 (both are 0: a line casts no shadow).")

    def entry(self, p, d, lam_min: float = LAM_MIN_M) -> np.ndarray:
        """Smallest ``lam >= lam_min`` with ``p + lam d`` inside the solid, else ``inf``; ``(...)``."""
        a, h = self.axis, self.length_m
        k = (self.top_radius_m - self.base_radius_m) / h
        w = np.asarray(p, dtype=float) - self.base_m
        d = np.asarray(d, dtype=float)
        pz, dz = _dot(w, a), _dot(d, a)
        q = w - pz[..., None] * a
        e = d - dz[..., None] * a
        r0 = self.base_radius_m + k * pz
        # f(lam) = |q + lam e|^2 - (r0 + k dz lam)^2 = A lam^2 + 2 B lam + C; inside the slab r >= 0, so
        # f <= 0 is exactly "inside the frustum" there.
        A = _dot(e, e) - (k * dz) ** 2
        B = _dot(q, e) - k * dz * r0
        C = _dot(q, q) - r0 * r0
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = -pz / dz, (h - pz) / dz
            parallel = dz == 0.0
            inside_slab = (pz >= 0.0) & (pz <= h)
            lo = np.where(parallel, np.where(inside_slab, -np.inf, np.inf), np.minimum(t1, t2))
            hi = np.where(parallel, np.where(inside_slab, np.inf, -np.inf), np.maximum(t1, t2))
        lo = np.maximum(lo, lam_min)
        hi = np.minimum(hi, LAM_MAX_M)
        ok = lo <= hi
        f_lo = (A * lo + 2.0 * B) * lo + C
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            disc = B * B - A * C
            sq = np.sqrt(np.maximum(disc, 0.0))
            # Stable roots of A x^2 + 2 B x + C: x1 = -(B + sign(B) sq) / A, x2 = C / (-(B + sign(B) sq)).
            qq = -(B + np.where(B >= 0.0, sq, -sq))
            x1 = np.where(A != 0.0, qq / A, np.inf)
            x2 = np.where(qq != 0.0, C / qq, np.where(A == 0.0, np.where(B != 0.0, -C / (2.0 * B), np.inf), np.inf))
        x1 = np.where(np.isfinite(x1), x1, np.inf)
        x2 = np.where(np.isfinite(x2), x2, np.inf)
        has_root = disc >= 0.0
        cand = np.full(np.shape(lo), np.inf)
        for x in (x1, x2):
            good = has_root & (x > lo) & (x <= hi)
            cand = np.where(good, np.minimum(cand, x), cand)
        out = np.where(f_lo <= 0.0, lo, cand)
        return np.where(ok, out, np.inf)

    def normal(self, x) -> np.ndarray:
        """Outward unit normal at surface points ``x`` (vehicle frame), ``(..., 3)``."""
        a, h = self.axis, self.length_m
        k = (self.top_radius_m - self.base_radius_m) / h
        w = np.asarray(x, dtype=float) - self.base_m
        z = _dot(w, a)
        perp = w - z[..., None] * a
        rho = np.linalg.norm(perp, axis=-1)
        r = self.base_radius_m + k * z
        side = perp / np.maximum(rho, 1e-300)[..., None] - k * a
        side = side / np.linalg.norm(side, axis=-1, keepdims=True)
        # The face whose defining function is closest to zero owns the point.
        d_side = np.abs(rho - r) / np.sqrt(1 + k * k)
        d_base, d_top = np.abs(z), np.abs(z - h)
        n = np.where((d_base < d_side)[..., None] & (d_base <= d_top)[..., None], -a, side)
        return np.where((d_top < d_side)[..., None] & (d_top < d_base)[..., None], a, n)

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        c = self.base_m + 0.5 * self.length_m * self.axis
        return c, float(np.hypot(0.5 * self.length_m, max(self.base_radius_m, self.top_radius_m)))

    def outline_m(self, n: int = 48) -> np.ndarray:
        """Points on the rims of both end disks ``(2 n, 3)``: their projection's hull is the shadow."""
        u = np.cross(self.axis, [1.0, 0.0, 0.0])
        if np.linalg.norm(u) < 0.1:
            u = np.cross(self.axis, [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(self.axis, u)
        phi = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
        ring = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v
        top = self.base_m + self.length_m * self.axis
        return np.concatenate((self.base_m + self.base_radius_m * ring, top + self.top_radius_m * ring))


@dataclass(frozen=True)
class Box:
    """A solid box centred on ``center_m`` with half sizes ``half_size_m`` along its own axes;
    ``dcm_XV`` maps vehicle components to box-axis components (identity: axes as the vehicle's)."""

    center_m: np.ndarray
    half_size_m: np.ndarray
    dcm_XV: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        object.__setattr__(self, "center_m", _vec(self.center_m, "center_m"))
        hs = _vec(self.half_size_m, "half_size_m")
        if np.any(hs <= 0.0):
            raise ValueError(f"half_size_m = {hs.tolist()} must be three numbers > 0 (m).")
        object.__setattr__(self, "half_size_m", hs)
        C = np.asarray(self.dcm_XV, dtype=float)
        if C.shape != (3, 3) or not np.allclose(C @ C.T, np.eye(3), atol=1e-9) or np.linalg.det(C) < 0:
            raise ValueError("dcm_XV must be a proper rotation matrix (3 x 3, orthonormal, det +1).")
        object.__setattr__(self, "dcm_XV", C)

    def _local(self, p, d):
        C = self.dcm_XV
        return (np.asarray(p, dtype=float) - self.center_m) @ C.T, np.asarray(d, dtype=float) @ C.T

    def entry(self, p, d, lam_min: float = LAM_MIN_M) -> np.ndarray:
        pl, dl = self._local(p, d)
        hs = self.half_size_m
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-hs - pl) / dl, (hs - pl) / dl
            par = dl == 0.0
            inside = np.abs(pl) <= hs
            lo_ax = np.where(par, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
            hi_ax = np.where(par, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
        lo = np.maximum(np.max(lo_ax, axis=-1), lam_min)
        hi = np.minimum(np.min(hi_ax, axis=-1), LAM_MAX_M)
        return np.where(lo <= hi, lo, np.inf)

    def normal(self, x) -> np.ndarray:
        xl = (np.asarray(x, dtype=float) - self.center_m) @ self.dcm_XV.T
        u = xl / self.half_size_m
        k = np.argmax(np.abs(u), axis=-1)
        nl = np.zeros_like(xl)
        np.put_along_axis(nl, k[..., None], np.sign(np.take_along_axis(u, k[..., None], -1)), axis=-1)
        return nl @ self.dcm_XV

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        return self.center_m, float(np.linalg.norm(self.half_size_m))

    def outline_m(self, n: int = 0) -> np.ndarray:
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
        return self.center_m + (signs * self.half_size_m) @ self.dcm_XV


@dataclass(frozen=True)
class Panel:
    """A flat parallelogram: corner ``corner_m`` and edges ``edge_u_m``, ``edge_v_m`` (vehicle
    frame, m); the points ``corner + a u + b v`` with ``a, b`` in [0, 1]. Opaque from both sides."""

    corner_m: np.ndarray
    edge_u_m: np.ndarray
    edge_v_m: np.ndarray

    def __post_init__(self):
        for name in ("corner_m", "edge_u_m", "edge_v_m"):
            object.__setattr__(self, name, _vec(getattr(self, name), name))
        n = np.cross(self.edge_u_m, self.edge_v_m)
        if np.linalg.norm(n) <= 1e-12 * np.linalg.norm(self.edge_u_m) * np.linalg.norm(self.edge_v_m) or \
                np.linalg.norm(n) == 0.0:
            raise ValueError(f"edge_u_m = {self.edge_u_m.tolist()} and edge_v_m = {self.edge_v_m.tolist()} "
                             "must be non-zero and not parallel (they span the panel).")

    def entry(self, p, d, lam_min: float = LAM_MIN_M) -> np.ndarray:
        u, v = self.edge_u_m, self.edge_v_m
        n = np.cross(u, v)
        nn = float(n @ n)
        w = np.asarray(p, dtype=float) - self.corner_m
        d = np.asarray(d, dtype=float)
        den = _dot(d, n)
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = -_dot(w, n) / den
        q = w + np.where(np.isfinite(lam), lam, 0.0)[..., None] * d
        a = _dot(q, np.cross(v, n)) / nn
        b = _dot(q, np.cross(n, u)) / nn
        hit = (den != 0.0) & (lam >= lam_min) & (lam <= LAM_MAX_M) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
        return np.where(hit, lam, np.inf)

    def normal(self, x) -> np.ndarray:
        n = np.cross(self.edge_u_m, self.edge_v_m)
        return np.broadcast_to(n / np.linalg.norm(n), np.shape(x)).copy()

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        c = self.corner_m + 0.5 * (self.edge_u_m + self.edge_v_m)
        return c, 0.5 * max(float(np.linalg.norm(self.edge_u_m + self.edge_v_m)),
                            float(np.linalg.norm(self.edge_u_m - self.edge_v_m)))

    def outline_m(self, n: int = 0) -> np.ndarray:
        c, u, v = self.corner_m, self.edge_u_m, self.edge_v_m
        return np.stack((c, c + u, c + u + v, c + v))


@dataclass(frozen=True)
class HalfSpace:
    """Everything on the side of the plane through ``point_m`` opposite to ``normal``: the plate
    as an occluder of its own marks (a Sun below the horizon of the plate lights none of them)."""

    point_m: np.ndarray
    normal: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "point_m", _vec(self.point_m, "point_m"))
        object.__setattr__(self, "normal", _unit(self.normal, "normal"))

    def entry(self, p, d, lam_min: float = LAM_MIN_M) -> np.ndarray:
        g0 = _dot(np.asarray(p, dtype=float) - self.point_m, self.normal)
        gd = _dot(np.asarray(d, dtype=float), self.normal)
        # Inside where g0 + lam gd <= 0: at lam_min already, or from -g0/gd on when heading in.
        at_min = g0 + lam_min * gd <= 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            later = np.where(gd < 0.0, -g0 / gd, np.inf)
        return np.where(at_min, lam_min, np.where(later <= LAM_MAX_M, later, np.inf))


Shape = Frustum | Box | Panel | HalfSpace


@dataclass(frozen=True)
class Occluder:
    """A shape fixed to a vehicle, named for reports (``"target front cone"``, ``"chaser panel +y"``)."""

    name: str
    vehicle: str
    shape: Shape


@dataclass(frozen=True)
class SunDisk:
    """Directions to sample the Sun with: ``angular_radius_rad = 0`` is a point Sun (umbra only);
    otherwise the polar quadrature of the module docstring with ``rings`` rings (``1 + 3 n (n + 1)``
    directions, weights summing to 1)."""

    angular_radius_rad: float = SUN_RADIUS_RAD_1AU
    rings: int = 6

    def __post_init__(self):
        a = float(self.angular_radius_rad)
        if not np.isfinite(a) or not 0.0 <= a < 0.1:
            raise ValueError(f"angular_radius_rad = {a!r} must lie in [0, 0.1) rad (the Sun is 0.00465 rad).")
        if int(self.rings) != self.rings or not 1 <= self.rings <= 40:
            raise ValueError(f"rings = {self.rings!r} must be a whole number from 1 to 40.")

    @property
    def is_point(self) -> bool:
        return self.angular_radius_rad == 0.0

    def offsets(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(rho_rad, phi_rad, weight)``, each ``(K,)``: angular distance from the centre, azimuth, weight."""
        if self.is_point:
            return np.zeros(1), np.zeros(1), np.ones(1)
        n = int(self.rings)
        rho, phi, wt = [0.0], [0.0], [(0.5 / n) ** 2]
        for j in range(1, n + 1):
            m = 6 * j
            outer = min(j + 0.5, n) / n
            area = outer ** 2 - ((j - 0.5) / n) ** 2
            # Odd rings turn by half a spacing, plus an irrational fraction, so no edge lines up with a
            # whole column of samples.
            start = (0.5 * (j % 2) + 0.1234567) * 2 * np.pi / m
            for i in range(m):
                rho.append(self.angular_radius_rad * j / n)
                phi.append(start + 2 * np.pi * i / m)
                wt.append(area / m)
        w = np.asarray(wt)
        return np.asarray(rho), np.asarray(phi), w / w.sum()

    def directions(self, sunhat) -> tuple[np.ndarray, np.ndarray]:
        """Unit directions ``(..., K, 3)`` to the sampled disk around ``sunhat`` ``(..., 3)`` and weights ``(K,)``."""
        s = _unit(sunhat, "sunhat")
        rho, phi, w = self.offsets()
        helper = np.where(np.abs(s[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        e1 = np.cross(s, helper)
        e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
        e2 = np.cross(s, e1)
        dirs = (np.cos(rho)[:, None] * s[..., None, :]
                + np.sin(rho)[:, None] * (np.cos(phi)[:, None] * e1[..., None, :]
                                          + np.sin(phi)[:, None] * e2[..., None, :]))
        return dirs, w


def mark_points(centers_m, radius_m, rings: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Discretise circular marks on the plate (``z = 0``): centre plus ``rings`` rings of ``6 j``
    points at radii ``radius j / rings`` (the last on the rim), weighted by the area each stands for.

    ``centers_m`` ``(n, 2)`` in the plate frame (m); ``radius_m`` a number or ``(n,)``. Returns
    points ``(n, m, 3)`` and weights ``(m,)`` summing to 1 (the area fraction of one mark).
    """
    c = np.asarray(centers_m, dtype=float).reshape(-1, 2)
    r = np.broadcast_to(np.asarray(radius_m, dtype=float), (len(c),))
    if not np.all(np.isfinite(c)) or np.any(~np.isfinite(r) | (r <= 0)):
        raise ValueError("mark centres must be finite and mark radii finite numbers > 0 (m).")
    if int(rings) != rings or not 0 <= rings <= 30:
        raise ValueError(f"mark rings = {rings!r} must be a whole number from 0 to 30.")
    if rings == 0:
        return np.concatenate((c, np.zeros((len(c), 1))), axis=1)[:, None, :], np.ones(1)
    disk = SunDisk(1.0e-3, int(rings))  # the same polar quadrature, scaled to the mark
    rho, phi, w = disk.offsets()
    rho = rho / 1.0e-3
    xy = np.stack((rho * np.cos(phi), rho * np.sin(phi)), axis=-1)
    pts = c[:, None, :] + r[:, None, None] * xy[None]
    return np.concatenate((pts, np.zeros(pts.shape[:-1] + (1,))), axis=-1), w


def project_to_plate(points_P, sunhat_P) -> np.ndarray:
    """Where the sunlight through ``points_P`` ``(..., 3)`` meets the plate ``z = 0`` (plate frame):
    ``x - (x_z / s_z) s``. ``nan`` where the Sun is on or below the plate's horizon (``s_z <= 0``)."""
    x = np.asarray(points_P, dtype=float)
    s = np.asarray(sunhat_P, dtype=float)
    sz = s[..., 2:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = x - (x[..., 2:3] / sz) * s
    return np.where(sz > 0.0, out, np.nan)


def _culled(occ: Occluder, r_VP_P, dcm_VP, pts, s, alpha) -> np.ndarray:
    """``(T,)`` True where no ray from any point toward any part of the Sun can reach ``occ``'s
    bounding sphere (conservative: a ball around the points and the disk's angular radius)."""
    ball = getattr(occ.shape, "bounding_sphere", None)
    if ball is None:
        return np.zeros(len(s), dtype=bool)
    o_V, rho = ball()
    o_P = r_VP_P + np.einsum("tji,j->ti", dcm_VP, o_V)  # V -> P is the transpose of dcm_VP
    c = pts.mean(axis=0)
    r_pts = float(np.max(np.linalg.norm(pts - c, axis=-1)))
    w = o_P - c
    dist = np.linalg.norm(w, axis=-1)
    slack = rho + r_pts + dist * (1.01 * alpha) + 1e-9 * (1.0 + dist)
    off_axis = np.linalg.norm(np.cross(w, s), axis=-1) > slack
    behind = np.sum(w * s, axis=-1) < -slack
    return off_axis | behind


def visible_fraction(points_P, sunhat_P, occluders, poses, disk: SunDisk, max_elements: int = 1_000_000,
                     lam_min: float = LAM_MIN_M, per_occluder: bool = False):
    """Fraction of the Sun's disk each point sees past every occluder, ``(T, M)`` in [0, 1].

    ``points_P``: ``(M, 3)`` points (plate frame, m). ``sunhat_P``: ``(T, 3)`` unit Sun directions.
    ``occluders``: a sequence of :class:`Occluder`; ``poses``: for each, ``(r_VP_P, dcm_VP)`` with
    shapes ``(3,)``/``(3, 3)`` (fixed) or ``(T, 3)``/``(T, 3, 3)`` (one per time). Times at which an
    occluder's bounding sphere is out of reach of every ray are skipped (exactly: the test is
    conservative). Work is chunked so no temporary exceeds about ``max_elements`` rays.

    With ``per_occluder=True`` also returns ``(n_occluders, T, M)``: the fraction each occluder
    alone hides (they overlap, so these do not add up to ``1 - visible``).
    """
    pts = np.asarray(points_P, dtype=float).reshape(-1, 3)
    s = np.asarray(sunhat_P, dtype=float).reshape(-1, 3)
    T, M = len(s), len(pts)
    dirs, w = disk.directions(s)  # (T, K, 3)
    K = len(w)
    n_occ = len(occluders)
    poses = [(np.broadcast_to(np.asarray(r, dtype=float), (T, 3)), np.broadcast_to(np.asarray(C, dtype=float),
                                                                                   (T, 3, 3)))
             for r, C in poses]
    if len(poses) != n_occ:
        raise ValueError(f"{len(poses)} poses for {n_occ} occluders; give one (r_VP_P, dcm_VP) per occluder.")
    active = [~_culled(o, r, C, pts, s, disk.angular_radius_rad) for o, (r, C) in zip(occluders, poses, strict=True)]
    blocked = np.zeros((T, M))
    alone = np.zeros((n_occ, T, M)) if per_occluder else None
    m_chunk = max(1, min(M, int(max_elements // K)))
    for m0 in range(0, M, m_chunk):
        msl = slice(m0, min(M, m0 + m_chunk))
        p = pts[msl]
        t_chunk = max(1, int(max_elements // (K * len(p))))
        times = np.flatnonzero(np.any(np.stack(active), axis=0)) if n_occ else np.zeros(0, dtype=int)
        for t0 in range(0, len(times), t_chunk):
            ti = times[t0:t0 + t_chunk]
            d = dirs[ti]  # (t, K, 3)
            hit_any = np.zeros((len(ti), K, len(p)), dtype=bool)
            for j, (occ, (r, C)) in enumerate(zip(occluders, poses, strict=True)):
                sel = active[j][ti]
                if not np.any(sel):
                    continue
                tj = ti[sel]
                # p_V = C (p - r), d_V = C d, then broadcast to (t, K, M, 3).
                p_V = np.einsum("tij,tmj->tmi", C[tj], p[None] - r[tj][:, None, :])
                d_V = np.einsum("tij,tkj->tki", C[tj], d[sel])
                hit = np.isfinite(occ.shape.entry(p_V[:, None, :, :], d_V[:, :, None, :], lam_min))
                hit_any[sel] |= hit
                if alone is not None:
                    alone[j, tj, msl] = np.einsum("tkm,k->tm", hit, w)
            blocked[ti, msl] = np.einsum("tkm,k->tm", hit_any, w)
    vis = np.clip(1.0 - blocked, 0.0, 1.0)
    return (vis, alone) if per_occluder else vis


def straight_edge_hidden_fraction(offset_rad, radius_rad) -> np.ndarray:
    """Fraction of a uniform disk of angular radius ``radius_rad`` hidden behind a straight edge
    whose line passes ``offset_rad`` from the disk centre (positive: the centre is still visible):
    the circular segment ``(a^2 acos(x/a) - x sqrt(a^2 - x^2)) / (pi a^2)``. The closed form the
    penumbra of a long straight edge follows, far from its corners."""
    a = float(radius_rad)
    x = np.clip(np.asarray(offset_rad, dtype=float), -a, a)
    return (a * a * np.arccos(x / a) - x * np.sqrt(a * a - x * x)) / (np.pi * a * a)
