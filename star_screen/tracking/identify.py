"""Star identification: lost-in-space by 4-star patterns, tracking from a prior attitude.

Pattern database (built once per field size from the catalog, in memory, deterministic):

* pattern stars: catalog stars to ``pattern_mag_limit`` thinned to an even density, brightest
  first: a star is kept unless ``thin_count`` brighter kept stars already lie within
  ``thin_radius``. Dense Milky Way fields then do not explode the pattern count, sparse fields keep
  fainter stars, and the stars kept are the locally brightest, which is what an image shows first;
* patterns: *every* 4-star combination of pattern stars whose six separations are all at most
  ``max_edge`` (about half the short side of the field, so a pattern fits anywhere in the image
  and no "pattern per field centre" bookkeeping can miss one);
* key: the six separations sorted, divided by the largest (5 numbers, invariant to rotation and to
  the plate scale), bucketed on a grid over three of them and looked up with a max-norm tolerance;
* the 4 stars of a pattern are ordered by their distance from the pattern's centroid, the same
  rule on both sides, so a key hit gives the star correspondence.

Lost in space: 4-star combinations of the brightest image stars, brightest combinations first,
keyed and looked up in small doubling batches (a grid over the keys, one typed loop a key): most frames are solved
by their first pattern, and the first verified hypothesis ends the search, so the keys of the
hundreds of fainter combinations are never built. Each catalog hit whose largest separation also
agrees gives a 4-pair attitude, which is accepted only after *verification*: the catalog stars predicted
in the field must match enough image stars that a chance alignment is improbable. With ``k``
catalog stars predicted on the image, a match radius ``r`` px and an ``W x H`` image, a random
image star lands near one with probability ``p = k pi r^2 / (W H)``; the chance that ``m`` of ``n``
image stars do so is the binomial tail ``P(X >= m)``, multiplied by the number of hypotheses
tried (Bonferroni). A solution needs ``m >= min_matches`` and that bound below ``max_false_prob``.

Tracking: the catalog projected with the prior attitude; a vote over displacements between the
brightest image and catalog stars finds the common offset (so a prior up to ``track_radius_px``
off still converges), nearest-neighbour matching of those, a first estimate, then one tight
nearest-neighbour pass over all image stars; the chance-alignment bound uses all image stars.
Capture range of the default 20 x 15 deg, 1024 x 768 tracker: 40 px cross-boresight (0.79 deg)
with a roll that moves the field corners by less than about 3 px (0.27 deg).

The tight pass of both modes is the same rule, so tracking and lost in space give the same
attitude on the same frame: every catalog star predicted on the detector takes its nearest image
star within the radius, and an image star that several catalog stars take is a blend and is left
out (its centroid lies between them, and its small photometric sigma would weight that bias).
The final estimate leaves out pairs whose residual exceeds ``OUTLIER_GATE`` robust sigmas.
Matching sorts the image stars by x and sweeps (no k-d tree per frame); the cone of catalog stars
around the boresight comes from a cube-map index over the places built once per places table.

The steps that only choose (the cone, the image patterns and their keys, the attitude of a few pairs that
predicts where catalog stars fall, the projection) run as typed loops in :mod:`star_screen.tracking.lis_steps`
(compiled where the install could); the attitude and covariance a solution reports are computed by numpy
from the chosen pairs, as before, so the choices being the same gives the same bits.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import betainc

import compiled_paths
from star_screen.catalog import StarPlaces
from star_screen.geometry import TrackerOptics
from star_screen.tracking.estimate import AttitudeEstimate, estimate_attitude_robust_weighted

__all__ = ["PatternDatabase", "Match", "identify_lis", "identify_tracking", "verify", "false_match_probability"]

#: The radius matching's sweep: compiled where the install could (compiled_paths), else the same Python.
_nearest = compiled_paths.load("star_screen.tracking.nearest")
_NEAREST_COMPILED = compiled_paths.is_compiled(_nearest)
#: The lost-in-space decision steps (cone, image pattern keys, the attitude of a few pairs): likewise.
_lis = compiled_paths.load("star_screen.tracking.lis_steps")
_LIS_COMPILED = compiled_paths.is_compiled(_lis)


def _chord(angle_rad: float) -> float:
    return 2.0 * math.sin(0.5 * angle_rad)


def false_match_probability(m: int, n: int, p: float) -> float:
    """Binomial tail ``P(X >= m)`` for ``X ~ Binomial(n, p)`` (0 <= p <= 1)."""
    if m <= 0:
        return 1.0
    if m > n:
        return 0.0
    p = min(max(p, 0.0), 1.0)
    return float(betainc(m, n - m + 1, p))


#: The six pairs of a 4-star pattern, in the order of its edges.
_PAIR_I = np.array([0, 0, 0, 1, 1, 2])
_PAIR_J = np.array([1, 2, 3, 2, 3, 3])


def _angle_of_chord(d: np.ndarray) -> np.ndarray:
    # np.clip's result by two ufuncs (np.clip itself costs several microseconds of argument handling a call).
    return 2.0 * np.arcsin(np.minimum(np.maximum(0.5 * d, 0.0), 1.0))


def _row_norm(x: np.ndarray, keepdims: bool = False) -> np.ndarray:
    """``np.linalg.norm(x, axis=-1)`` by numpy's own formula for real vectors (the same bits), without its
    argument handling, which costs more than the arithmetic on a tracker's few vectors."""
    return np.sqrt(np.add.reduce(x * x, axis=-1, keepdims=keepdims))


def _edges(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Separations (rad) of 4-star sets ``u (P, 4, 3)``: (P, 6) unsorted, in pair order (01 02 03 12 13 23)."""
    d = _row_norm(u[:, _PAIR_I] - u[:, _PAIR_J])
    return _angle_of_chord(d), d


def _canonical(u: np.ndarray) -> np.ndarray:
    """Per pattern, the permutation (P, 4) ordering its stars by distance from the centroid."""
    # The centroid's direction: the sum of the four, normalised, is the normalised mean to the bit (a factor 4 is
    # exact), without np.mean's overhead.
    c = np.add.reduce(u, axis=1, keepdims=True)
    c /= _row_norm(c, keepdims=True)
    return np.argsort(_row_norm(u - c), axis=1, kind="stable")


def _keys(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keys (P, 5) and largest separation (P,) of 4-star sets ``u (P, 4, 3)`` in canonical order."""
    return _keys_of_edges(_edges(u)[0])


def _keys_of_edges(e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keys (P, 5): the six separations ``e (P, 6)`` sorted, over the largest; and the largest (P,)."""
    e.sort(axis=1)
    return e[:, :5] / e[:, 5:], e[:, 5]


@dataclass
class PatternDatabase:
    """4-star pattern table for one field size; build with :meth:`build`."""

    max_edge_rad: float
    pattern_mag_limit: float
    star_rows: np.ndarray  #: (S,) rows of the pattern stars in the places table
    u_N: np.ndarray  #: (S, 3) pattern-star directions at the build epoch
    patterns: np.ndarray  #: (P, 4) pattern-star indices in canonical order
    largest_edge_rad: np.ndarray  #: (P,)
    #: The keys on a grid (:func:`_key_grid`): (cell starts, keys (flat), pattern indices, largest separations)
    key_grid: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

    @classmethod
    def build(
        cls,
        places: StarPlaces,
        max_edge_deg: float = 8.0,
        pattern_mag_limit: float = 7.0,
        thin_radius_deg: float | None = None,
        thin_count: int = 4,
    ) -> PatternDatabase:
        """Build from astrometric ``places`` (brightest first). Deterministic; ~0.5 s for 20 x 15 deg."""
        if not (0.5 <= max_edge_deg <= 60.0):
            raise ValueError(f"max_edge_deg = {max_edge_deg!r}; it must lie in [0.5, 60] deg.")
        D = math.radians(max_edge_deg)
        rho = math.radians(thin_radius_deg if thin_radius_deg is not None else 0.5 * max_edge_deg)
        sub = places.brighter_than(pattern_mag_limit)
        u_all = sub.u_N
        nb = cKDTree(u_all).query_ball_point(u_all, _chord(rho))
        kept = np.zeros(len(u_all), bool)
        # Sequential by construction (each decision depends on the brighter stars kept before it);
        # ~14k stars, a few tens of ms.
        for i, lst in enumerate(nb):
            if np.count_nonzero(kept[lst]) < thin_count:
                kept[i] = True
        rows = np.flatnonzero(kept)
        u = u_all[rows]
        n = len(u)
        pairs = cKDTree(u).query_pairs(_chord(D), output_type="ndarray")
        pairs.sort(axis=1)
        pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
        starts = np.searchsorted(pairs[:, 0], np.arange(n + 1))
        cos_d = math.cos(D)
        combos: dict[int, np.ndarray] = {}
        parts = []
        for i in range(n):
            nbr = pairs[starts[i] : starts[i + 1], 1]
            m = len(nbr)
            if m < 3:
                continue
            if m not in combos:
                combos[m] = np.array(list(itertools.combinations(range(m), 3)), dtype=np.int32)
            c = combos[m]
            G = (u[nbr] @ u[nbr].T) >= cos_d
            ok = G[c[:, 0], c[:, 1]] & G[c[:, 0], c[:, 2]] & G[c[:, 1], c[:, 2]]
            t = nbr[c[ok]]
            parts.append(np.column_stack((np.full(len(t), i), t)))
        P = np.concatenate(parts).astype(np.int32) if parts else np.empty((0, 4), np.int32)
        up = u[P]
        perm = _canonical(up)
        P = np.take_along_axis(P, perm, axis=1)
        keys, largest = _keys(u[P])
        return cls(D, float(pattern_mag_limit), rows, u, P, largest, _key_grid(keys, largest))

    def __len__(self) -> int:
        return len(self.patterns)


def _key_grid(keys: np.ndarray, largest: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pattern keys (P, 5) bucketed for :func:`star_screen.tracking.lis_steps.lookup_key`: cells of
    ``GRID_CELL`` along key components ``GRID_COMPONENTS`` (``GRID_SIZE`` a component), the patterns of a cell
    contiguous and in index order. Returns (cell starts, keys flat, pattern indices, largest separations), the last
    three in cell order; numpy arrays for both builds (as lists they would take some 50 MB)."""
    g = _lis.GRID_SIZE
    comp = np.clip(np.floor(keys[:, list(_lis.GRID_COMPONENTS)] / _lis.GRID_CELL), 0, g - 1).astype(np.int64)
    cell = (comp[:, 0] * g + comp[:, 1]) * g + comp[:, 2]
    order = np.argsort(cell, kind="stable")
    starts = np.searchsorted(cell[order], np.arange(g**3 + 1)).astype(np.int64)
    return (starts, np.ascontiguousarray(keys[order], dtype=float).ravel(), order.astype(np.int64),
            np.ascontiguousarray(largest[order], dtype=float))


@dataclass(frozen=True)
class Match:
    """Result of identification: attitude estimate (or None), matched pairs, statistics."""

    estimate: AttitudeEstimate | None
    image_index: np.ndarray  #: (m,) indices into the extracted stars
    catalog_row: np.ndarray  #: (m,) rows into the verification places
    n_considered: int
    false_prob: float
    hypotheses: int

    @property
    def n_matched(self) -> int:
        return len(self.image_index)


_NO_MATCH = Match(None, np.empty(0, np.int64), np.empty(0, np.int64), 0, 1.0, 0)


#: Cells per edge of a cube face in the cone index: 8 x 8 x 6 cells of about 11 deg, so a 12.6 deg cone reads ten or
#: so of them (about a thousand stars to Hp 8 looked at for the five hundred it holds).
CONE_CELLS_PER_FACE = 8


class _SkyIndex:
    """Cone queries over one places table: the unit vectors bucketed in the cells of a cube map (each star in the cell
    its direction passes through), stored cell by cell, rows ascending within a cell. A query reads the cells the cone
    can reach, keeps the stars within its chord and merges the cells' runs into catalog order
    (:func:`star_screen.tracking.lis_steps.cone_sorted`, compiled where the install could): a thousand or so stars
    looked at, no tree walked, nothing sorted by numpy. Built in a few milliseconds per table."""

    __slots__ = ("places", "cells", "stars", "size", "u", "cap")

    def __init__(self, places: StarPlaces):
        self.places = places
        u = np.ascontiguousarray(places.u_N, dtype=float)
        n = CONE_CELLS_PER_FACE
        cell = _cube_cell_of(u, n)
        order = np.argsort(cell, kind="stable")
        starts = np.searchsorted(cell[order], np.arange(6 * n * n + 1)).astype(np.int64)
        centre, cos_rho, sin_rho = _cube_cells(n)
        self.cells = _native_args(centre.ravel(), cos_rho, sin_rho, starts)
        #: The unit vectors in cell order: a cone's vectors are taken from here, where the query has just read them
        #: (from the places table they would be one cache miss per star, the catalog being sorted by magnitude).
        self.u = np.ascontiguousarray(u[order])
        self.stars = _native_args(self.u.ravel(), order.astype(np.int64))
        self.size = len(u)
        #: Stars a query's buffers hold (the largest cone seen so far, at least CONE_CAP): small buffers, so a query
        #: allocates and touches a few pages, not buffers the size of the catalog.
        self.cap = min(CONE_CAP, self.size)

    def cone(self, boresight: np.ndarray, cos_cull: float) -> tuple[np.ndarray, np.ndarray]:
        """Rows of the places within the cone (sorted: brightest first) and their unit vectors."""
        rows, u, _, _ = self._query(boresight, cos_cull, None, 0.0, 0.0, 0.0)
        return rows, u

    def field(self, C: np.ndarray, cos_cull: float, K: np.ndarray, width: float, height: float):
        """The cone around the boresight of ``C`` (dcm_SN) seen through the pinhole camera ``K``: the rows (sorted) of
        the places that land on the ``width`` x ``height`` detector, their unit vectors and their pixels (x, y): the
        cone of :meth:`cone` projected as :meth:`_Field.project` projects it, in one loop."""
        return self._query(C[2], cos_cull, (K @ C).ravel(), 0.0, width, height)

    def _query(self, boresight, cos_cull, kc, margin, width, height):
        chord = math.sqrt(max(2.0 - 2.0 * cos_cull, 0.0))
        bx, by, bz = boresight.tolist()
        sin_cone = math.sqrt(max(1.0 - cos_cull * cos_cull, 0.0))
        project = kc is not None
        if kc is None:  # a camera read by no one
            kc = np.zeros(9) if _LIS_COMPILED else [0.0] * 9
        elif not _LIS_COMPILED:
            kc = kc.tolist()
        n_cells = len(self.cells[1])
        for _ in range(2):  # a second time only with buffers as large as the cone the first found
            cap = self.cap
            if _LIS_COMPILED:
                ints, floats = np.empty(5 * cap + n_cells + 1, np.int64), np.empty(5 * cap)
                work, rows = ints[cap:], ints[:cap]
                u, x, y = floats[: 3 * cap], floats[3 * cap : 4 * cap], floats[4 * cap :]
            else:
                work, rows = [0] * (4 * cap + n_cells + 1), [0] * cap
                u, x, y = [0.0] * (3 * cap), [0.0] * cap, [0.0] * cap
            m = _lis.cone_sorted(*self.cells, *self.stars, bx, by, bz, cos_cull, sin_cone, chord * chord, project, kc,
                                 margin, width, height, cap, work, rows, u, x, y)
            if m >= 0:
                break
            self.cap = -m
        if _LIS_COMPILED:
            return rows[:m], u[: 3 * m].reshape(m, 3), x[:m], y[:m]
        return (np.array(rows[:m], np.int64), np.array(u[: 3 * m], float).reshape(m, 3), np.array(x[:m], float),
                np.array(y[:m], float))


#: Stars a cone query's buffers hold at first (:class:`_SkyIndex`): the lost-in-space cone of the default tracker
#: holds some five hundred stars to Hp 8, a dense Milky Way field about twice that.
CONE_CAP = 2048

def _cube_cell_of(u: np.ndarray, n: int) -> np.ndarray:
    """The cube-map cell (:func:`_cube_cells`' numbering) each unit vector of ``u (S, 3)`` passes through."""
    axis = np.argmax(np.abs(u), axis=1)
    major = u[np.arange(len(u)), axis]
    a = np.take_along_axis(u, ((axis + 1) % 3)[:, None], axis=1)[:, 0] / np.abs(major)
    b = np.take_along_axis(u, ((axis + 2) % 3)[:, None], axis=1)[:, 0] / np.abs(major)
    i = np.clip(np.floor((a + 1.0) * (0.5 * n)).astype(np.int64), 0, n - 1)
    j = np.clip(np.floor((b + 1.0) * (0.5 * n)).astype(np.int64), 0, n - 1)
    return ((2 * axis + (major < 0)) * n + i) * n + j


def _cube_cells(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre directions (6 n n, 3) of the cells of a cube map with ``n`` x ``n`` cells a face (face ``2 axis +
    (negative)``, cell ``(face n + i) n + j`` along the next two axes) and the cosine and sine of each cell's angular
    radius (its farthest corner from the centre, plus 1e-6 rad)."""
    edges = np.linspace(-1.0, 1.0, n + 1)
    mid = 0.5 * (edges[:-1] + edges[1:])
    centre, rho = np.empty((6, n, n, 3)), np.empty((6, n, n))

    def direction(axis, sign, s, t):
        v = np.zeros(np.broadcast(s, t).shape + (3,))
        v[..., axis], v[..., (axis + 1) % 3], v[..., (axis + 2) % 3] = sign, s, t
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    for face in range(6):
        axis, sign = face // 2, -1.0 if face % 2 else 1.0
        c = direction(axis, sign, mid[:, None], mid[None, :])
        centre[face] = c
        worst = np.zeros((n, n))
        for di in (0, 1):
            for dj in (0, 1):
                corner = direction(axis, sign, edges[di : n + di][:, None], edges[dj : n + dj][None, :])
                cosang = np.clip(np.einsum("ijk,ijk->ij", c, corner), -1.0, 1.0)
                worst = np.maximum(worst, np.arccos(cosang))
        rho[face] = worst + 1e-6
    return centre.reshape(-1, 3), np.cos(rho).ravel(), np.sin(rho).ravel()


def _native_args(*arrays: np.ndarray) -> tuple:
    """Arrays as :mod:`star_screen.tracking.lis_steps` reads them fastest: C-contiguous numpy arrays for the compiled
    build (typed memoryviews), lists for the plain one."""
    if _LIS_COMPILED:
        return tuple(np.ascontiguousarray(a) for a in arrays)
    return tuple(a.tolist() for a in arrays)


_INDEXES: dict[int, _SkyIndex] = {}


def _sky_index(places: StarPlaces) -> _SkyIndex:
    """The cone index of ``places`` (built once per places table, kept for the few most recent)."""
    entry = _INDEXES.get(id(places.u_N))
    if entry is None or entry.places.u_N is not places.u_N:
        if len(_INDEXES) > 4:
            _INDEXES.clear()
        entry = _INDEXES[id(places.u_N)] = _SkyIndex(places)
    return entry


def verify(
    C: np.ndarray,
    img_xy: np.ndarray,
    n_verify: int,
    places: StarPlaces,
    optics: TrackerOptics,
    cos_cull: float,
    radius_px: float,
    hypotheses: int,
):
    """Matches of the ``n_verify`` brightest image stars with the catalog predicted by ``C``.

    Returns (image indices, catalog rows, the catalog stars predicted on the detector as (rows,
    unit vectors), false-match bound). The cone and the projection are the tracking path's (one
    cube-map query, one projection through the camera matrix times ``C``), so both modes see the same field.
    """
    n = min(n_verify, len(img_xy))
    fld = _field(optics)
    if fld.pinhole:
        rows, U, x, y = _sky_index(places).field(C, cos_cull, fld.K, fld.width, fld.height)
    else:
        cone, U = _sky_index(places).cone(C[2], cos_cull)
        k, x, y = fld.project(U, C, 0.0)
        rows, U = cone[k], U[k]
    field = (rows, U)
    if n == 0 or len(rows) == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64), field, 1.0
    ii, ci, _ = _match_radius(img_xy[:n, 0], img_xy[:n, 1], x, y, radius_px)
    p = len(rows) * math.pi * radius_px**2 / (optics.width * optics.height)
    pf = min(1.0, false_match_probability(len(ii), n, p) * max(hypotheses, 1))
    return ii, field[0][ci], field, pf


#: Pairs whose residual exceeds this many robust sigmas (from the median residual) are left out of
#: the final estimate. The per-star sigmas come from a photometric model that knows nothing of blends
#: with stars near the match radius, faint neighbours or a spot on a hot pixel, and a bright star's
#: small sigma gives such a bias a large weight (one star moved the roll by 10 arcsec).
OUTLIER_GATE = 8.0


def _estimate_robust(b_S: np.ndarray, U: np.ndarray, sigma_rad: np.ndarray, image: np.ndarray, catalog: np.ndarray):
    """Final estimate from the pairs of image stars ``b_S[image]`` (sigmas ``sigma_rad[image]``) and catalog
    directions ``U[catalog]``, with pairs beyond ``OUTLIER_GATE`` robust sigmas left out: (estimate, kept indices into
    the pairs or ``None`` when all are kept). The pairs and their weights are gathered in one typed pass
    (:func:`star_screen.tracking.lis_steps.gather_pairs`), each part of the block starting on 16 bytes as a fresh array
    would."""
    m = len(image)
    step = 3 * m + (3 * m) % 2
    at_r, at_a = step, 2 * step
    at_ba = at_a + m + m % 2
    if _LIS_COMPILED:
        out = np.empty(at_ba + 3 * m)
        _lis.gather_pairs(b_S.reshape(-1), U.reshape(-1), sigma_rad, image, catalog, at_r, at_a, at_ba, out)
    else:
        out = [0.0] * (at_ba + 3 * m)
        _lis.gather_pairs(b_S.ravel().tolist(), U.ravel().tolist(), sigma_rad.tolist(), image.tolist(),
                          catalog.tolist(), at_r, at_a, at_ba, out)
        out = np.array(out)
    return estimate_attitude_robust_weighted(out[: 3 * m].reshape(m, 3), out[at_r : at_r + 3 * m].reshape(m, 3),
                                             out[at_a : at_a + m], out[at_ba:].reshape(m, 3), OUTLIER_GATE)


def _refine(C, img_xy, b_S, sigma_rad, optics, field, radius_px):
    """Match all image stars to the catalog predicted by ``C`` at the tight radius and estimate:
    (estimate or ``None``, image indices, catalog rows).

    ``field``: (rows, unit vectors) of the catalog stars near the field (those predicted by the
    verification pass, which still cover it: a verified attitude moves by far less than the cull
    margin)."""
    rows, U = field
    k, x, y = _field(optics).project(U, C, radius_px)
    ii, cj, _ = _match_radius(img_xy[:, 0], img_xy[:, 1], x, y, radius_px, True)
    if len(ii) < 3:
        return None, ii, np.empty(0, np.int64)
    kj = k[cj]
    est, keep = _estimate_robust(b_S, U, sigma_rad, ii, kj)
    ci = rows[kj]
    if keep is not None:
        ii, ci = ii[keep], ci[keep]
    return est, ii, ci


@functools.lru_cache(maxsize=16)
def cull_cos(optics: TrackerOptics) -> float:
    """Cosine of the cone that holds every direction the detector can see, plus 0.1 deg."""
    return math.cos(optics.half_diagonal_rad() + math.radians(0.1))


_QUADS: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def _quads_brightest_first(n: int) -> tuple[np.ndarray, np.ndarray]:
    """All 4-subsets of range(n), those of brighter stars first (by the faintest member, then
    lexicographic), (C(n, 4), 4); and the flat indices (C(n, 4), 6) of their six pairs in an
    ``n x n`` matrix (cached per n)."""
    entry = _QUADS.get(n)
    if entry is None:
        q = np.array(list(itertools.combinations(range(n), 4)), dtype=np.int64).reshape(-1, 4)
        q = np.ascontiguousarray(q[np.lexsort((q[:, 2], q[:, 1], q[:, 0], q[:, 3]))])
        entry = _QUADS[n] = (q, q[:, _PAIR_I] * n + q[:, _PAIR_J])
    return entry


#: Image patterns per lookup batch at first; each later batch is as large as all before it, so a frame
#: solved by its first patterns (most) builds and looks up only those, and one that needs many takes few batches.
#: One: on ``stand bench tracker``'s frames the first pattern alone solves 867 of 1000 (the first two 941), so a
#: second key up front is mostly thrown away.
FIRST_BATCH = 1

#: The weights of a 4-pair attitude (read only when the pairs are weighted; these are not).
_ONES4 = np.ones(4)


def _image_patterns(u: np.ndarray, max_edge_cos: float):
    """Image 4-star patterns of the directions ``u`` (brightest first), brightest combinations first.

    Every 4-subset whose six separations all pass ``max_edge_cos``, ordered by its faintest member,
    then lexicographically, yielded in batches (``FIRST_BATCH``, then doubling) as (star indices (k, 4)
    in canonical order, keys (k, 5), largest separation (k,)). The separations of all pairs are
    computed once per frame with the arithmetic of :func:`_edges`, and the canonical order and keys
    with that of :func:`_canonical` and :func:`_keys_of_edges` (:func:`lis_steps.pattern_keys`), so the
    keys are those the database uses, to the bit."""
    n = len(u)
    quads = _quads_brightest_first(n)[0].ravel()
    fits = ((u @ u.T) >= max_edge_cos).ravel().view(np.uint8)
    sep = _angle_of_chord(_row_norm(u[:, None, :] - u[None, :, :])).ravel()
    u_flat = np.ascontiguousarray(u).ravel()
    scratch, cursor = np.empty(10), np.zeros(1, np.int64)
    start, done, size = 0, 0, FIRST_BATCH
    while True:
        out_quad, out_key, out_largest = np.empty(4 * size, np.int64), np.empty(5 * size), np.empty(size)
        w = _lis.pattern_keys(n, quads, start, fits, sep, u_flat, size, out_quad, out_key, out_largest, scratch,
                              cursor)
        if w == 0:
            return
        yield out_quad[: 4 * w].reshape(w, 4), out_key[: 5 * w].reshape(w, 5), out_largest[:w]
        start = int(cursor[0])
        done += w
        size = done


def identify_lis(
    img_xy: np.ndarray,
    b_S: np.ndarray,
    sigma_rad: np.ndarray,
    optics: TrackerOptics,
    db: PatternDatabase,
    places: StarPlaces,
    *,
    pattern_stars: int = 16,
    key_tolerance: float = 0.01,
    edge_tolerance: float = 0.01,
    fit_tolerance_rad: float = math.radians(0.02),
    n_verify: int = 40,
    match_radius_px: float = 2.5,
    refine_radius_px: float = 1.5,
    min_matches: int = 8,
    max_false_prob: float = 1e-9,
    max_hypotheses: int = 200,
) -> Match:
    """Lost-in-space identification of extracted stars (brightest first).

    ``img_xy`` pixels (n, 2), ``b_S`` their unit tracker-frame directions, ``sigma_rad`` their
    centroid sigmas (weights of the final estimate). ``places`` are the verification stars (at the
    solve epoch, brightest first); ``db`` the pattern table. Tolerances: ``key_tolerance`` on the
    edge ratios (max-norm), ``edge_tolerance`` relative on the largest edge (plate scale).
    """
    n = min(pattern_stars, len(img_xy))
    if n < 4 or len(db) == 0:
        return _NO_MATCH
    cos_cull = _field(optics).cos_cull
    n_ver = min(n_verify, len(img_xy))
    hyp = 0
    dcm = np.empty(9)
    scratch = np.empty(32)
    # A key's hits beyond the first max_hypotheses + 1 are never tried: the search ends before.
    cap = max_hypotheses + 1
    hits = np.empty(cap, np.int64)
    for quads, keys, largest in _image_patterns(b_S[:n], math.cos(db.max_edge_rad * (1.0 + edge_tolerance))):
        for q in range(len(keys)):
            # The catalog patterns with the key within key_tolerance (max-norm) and the largest separation within
            # edge_tolerance, ascending.
            m = _lis.lookup_key(keys[q], key_tolerance, *db.key_grid, float(largest[q]), edge_tolerance, cap, hits)
            if m == 0:
                continue
            b4 = b_S[quads[q]].ravel()
            for p in hits[: min(m, cap)].tolist():
                hyp += 1
                if hyp > max_hypotheses:
                    return _NO_MATCH
                # The 4-pair attitude only decides (whether the pattern fits, which stars verification matches):
                # Davenport's q-method, the SVD solution's to rounding.
                if _lis.fit_pairs(b4, db.u_N[db.patterns[p]].ravel(), _ONES4, True, dcm, scratch) > fit_tolerance_rad:
                    continue  # mirror image or wrong correspondence
                C4 = dcm.reshape(3, 3).copy()
                ii, ci, field, pf = verify(C4, img_xy, n_verify, places, optics, cos_cull, match_radius_px, hyp)
                if len(ii) < min_matches or pf > max_false_prob:
                    continue
                # Re-estimate from the verified pairs before matching all stars at the tight radius.
                _lis.fit_pairs(b_S[ii].ravel(), places.u_N[ci].ravel(), 1.0 / sigma_rad[ii] ** 2, False, dcm,
                               scratch)
                est2, ii2, ci2 = _refine(dcm.reshape(3, 3), img_xy, b_S, sigma_rad, optics, field, refine_radius_px)
                if est2 is None or len(ii2) < min_matches:
                    continue
                return Match(est2, ii2, ci2, n_ver, pf, hyp)
    return Match(None, np.empty(0, np.int64), np.empty(0, np.int64), n_ver, 1.0, hyp)


class _Field:
    """Per-optics constants of the tracking path (cached by identity: hashing the frozen optics
    costs more than the lookup it guards)."""

    __slots__ = ("optics", "pinhole", "fx", "fy", "cx", "cy", "width", "height", "area", "cos_cull", "cull_rad", "K")

    def __init__(self, optics: TrackerOptics):
        self.optics = optics
        self.pinhole = optics.distortion.is_zero
        self.fx, self.fy, self.cx, self.cy = float(optics.fx), float(optics.fy), float(optics.cx), float(optics.cy)
        self.width, self.height = float(optics.width), float(optics.height)
        self.area = self.width * self.height
        self.cos_cull = cull_cos(optics)
        self.cull_rad = math.acos(self.cos_cull)
        self.K = np.array(((self.fx, 0.0, self.cx), (0.0, self.fy, self.cy), (0.0, 0.0, 1.0)))

    def project(self, u_N: np.ndarray, C: np.ndarray, margin: float, limit: int | None = None):
        """Pixels ``(x, y)`` of directions ``u_N`` seen at ``C`` (dcm_SN) that land on the detector
        grown by ``margin`` px, the kept indices into ``u_N`` (order kept), at most ``limit`` of them."""
        if self.pinhole:
            # Homogeneous pixels through the camera matrix times the attitude, in one loop (lis_steps): where the
            # catalog falls only decides which stars pair up.
            m = len(u_N) if limit is None else min(limit, len(u_N))
            u, kc = _native_args(u_N.ravel(), (self.K @ C).ravel())
            if _LIS_COMPILED:
                keep, x, y = np.empty(m, np.int64), np.empty(m), np.empty(m)
            else:
                keep, x, y = [0] * m, [0.0] * m, [0.0] * m
            w = _lis.project_pinhole(u, kc, float(margin), self.width, self.height, m, keep, x, y)
            return np.asarray(keep[:w], np.int64), np.asarray(x[:w], float), np.asarray(y[:w], float)
        px, front = self.optics.project(u_N @ C.T)
        x, y = px[:, 0], px[:, 1]
        ok = front & (x >= -margin) & (x < self.width + margin) & (y >= -margin) & (y < self.height + margin)
        keep = np.flatnonzero(ok)
        if limit is not None:
            keep = keep[:limit]
        return keep, x[keep], y[keep]


_FIELDS: dict[int, _Field] = {}


def _field(optics: TrackerOptics) -> _Field:
    f = _FIELDS.get(id(optics))
    if f is None or f.optics is not optics:
        if len(_FIELDS) > 8:
            _FIELDS.clear()
        f = _FIELDS[id(optics)] = _Field(optics)
    return f


def _match_radius(img_x: np.ndarray, img_y: np.ndarray, cat_x: np.ndarray, cat_y: np.ndarray, radius: float,
                  drop_blends: bool = False):
    """One-to-one pairs (image index, catalog index, distance) within ``radius`` px, in catalog
    order: each catalog star takes its nearest image star, and an image star claimed by several
    keeps the closest (``drop_blends``: is left out).

    The pairs of a k-d tree query over the image stars followed by the blend rule, for a
    fraction of the cost at tracker sizes (no tree to build per frame): the image stars sorted by x
    once, then the sweep of :mod:`star_screen.tracking.nearest` (two or three image stars looked at
    per catalog star; compiled where the install could)."""
    n = len(img_x)
    if n == 0 or len(cat_x) == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0)
    order = img_x.argsort(kind="stable")
    xs, ys = img_x[order], img_y[order]
    k = len(cat_x)
    if _NEAREST_COMPILED:  # typed memoryviews (any strides) of float64 and int64 arrays; the integer outputs in one
        args = (np.asarray(xs, float), np.asarray(ys, float), order, np.asarray(cat_x, float), np.asarray(cat_y, float))
        ints = np.zeros(n + 2 * k, np.int64)
        out = (ints[:n], ints[n : n + k], ints[n + k :], np.empty(k))
    else:  # plain Python reads and writes lists far faster than numpy scalars
        args = (xs.tolist(), ys.tolist(), order.tolist(), cat_x.tolist(), cat_y.tolist())
        out = ([0] * n, [0] * k, [0] * k, [0.0] * k)
    w = _nearest.match_radius(*args, float(radius), bool(drop_blends), *out)
    _, out_image, out_catalog, out_d2 = out
    return (np.asarray(out_image[:w], np.int64), np.asarray(out_catalog[:w], np.int64),
            np.sqrt(np.asarray(out_d2[:w], float)))


def identify_tracking(
    C_prior: np.ndarray,
    img_xy: np.ndarray,
    b_S: np.ndarray,
    sigma_rad: np.ndarray,
    optics: TrackerOptics,
    places: StarPlaces,
    *,
    track_radius_px: float = 40.0,
    vote_image_stars: int = 20,
    vote_catalog_stars: int = 40,
    vote_bin_px: float = 3.0,
    refine_radius_px: float = 1.5,
    max_stars: int = 400,
    min_matches: int = 8,
    max_false_prob: float = 1e-9,
) -> Match:
    """Identify extracted stars near the catalog predicted by a prior attitude ``C_prior`` (dcm_SN).

    Converges when the prior's cross-boresight error is below ``track_radius_px`` pixels and its roll
    error moves the field corners by less than about ``vote_bin_px`` (default tracker: 0.79 deg and
    about 0.27 deg); the result is then the lost-in-space result of the same stars (same tight pass,
    same outlier gate).

    Per call: one cone query of the cube-map index over the places (built once per places table), one
    projection of the cone's brightest stars with the prior (vote) and one of the cone with the
    first estimate (tight match), a column-sorted nearest-neighbour match, a q-method fit for the
    first estimate (it only decides the matches) and one or two SVDs for the final (two when the
    outlier gate drops pairs).
    """
    if len(img_xy) < 3:
        return _NO_MATCH
    fld = _field(optics)
    cone, U = _sky_index(places).cone(C_prior[2], math.cos(fld.cull_rad + track_radius_px / fld.fx))
    # The vote needs only the brightest predicted stars: project a brightest chunk of the cone first.
    chunk = 3 * vote_catalog_stars
    kv, cx, cy = fld.project(U[:chunk], C_prior, track_radius_px, vote_catalog_stars)
    if len(kv) < vote_catalog_stars and len(U) > chunk:
        kv, cx, cy = fld.project(U, C_prior, track_radius_px, vote_catalog_stars)
    if len(kv) < 3:
        return _NO_MATCH
    # Vote for the common image offset between bright image and bright predicted stars.
    a = img_xy[:vote_image_stars]
    Dx = a[:, 0:1] - cx  # (na, nc) displacement image - predicted
    Dy = a[:, 1:2] - cy
    half = int(math.ceil(track_radius_px / vote_bin_px)) + 2
    span = 2 * half
    ix = np.floor(Dx.ravel() * (1.0 / vote_bin_px)).astype(np.int64) + half
    iy = np.floor(Dy.ravel() * (1.0 / vote_bin_px)).astype(np.int64) + half
    inside = (ix >= 1) & (ix < span - 1) & (iy >= 1) & (iy < span - 1)
    if not inside.any():
        return _NO_MATCH
    # Each displacement votes for its cell and the 8 around it (a 3 x 3 box sum of the histogram),
    # so an offset on a border is not split.
    h = np.bincount(ix[inside] * span + iy[inside], minlength=span * span).reshape(span, span)
    h = h[:-2] + h[1:-1] + h[2:]
    box = h[:, :-2] + h[:, 1:-1] + h[:, 2:]
    bi, bj = divmod(int(np.argmax(box)), span - 2)
    ox = (bi + 1 - half + 0.5) * vote_bin_px
    oy = (bj + 1 - half + 0.5) * vote_bin_px
    near = np.maximum(np.abs(Dx - ox), np.abs(Dy - oy)) <= 1.5 * vote_bin_px
    if not near.any():
        return _NO_MATCH
    m = 1.0 / np.count_nonzero(near)
    ox, oy = float(Dx[near].sum()) * m, float(Dy[near].sum()) * m
    # First pairs: each bright image star with the bright predicted star nearest to it after the
    # common offset, if within two bins and not claimed by another image star.
    ex, ey = Dx - ox, Dy - oy
    dist2 = ex * ex + ey * ey
    cj = np.argmin(dist2, axis=1)
    ii = np.flatnonzero(dist2[np.arange(len(a)), cj] <= (2.0 * vote_bin_px) ** 2)
    cj = cj[ii]
    single = np.bincount(cj, minlength=len(kv))[cj] == 1
    ii, cj = ii[single], cj[single]
    if len(ii) < 3:
        return _NO_MATCH
    # The first attitude only decides which stars the tight pass matches: Davenport's q-method (lis_steps), the SVD
    # solution's to rounding.
    C1 = np.empty(9)
    _lis.fit_pairs(b_S[ii].ravel(), U[kv[cj]].ravel(), 1.0 / sigma_rad[ii] ** 2, False, C1, np.empty(32))
    C1 = C1.reshape(3, 3)
    # One tight matching pass, the rule of the lost-in-space refinement (:func:`_refine`): the
    # brightest ``max_stars`` image stars against every catalog star predicted on the detector (grown
    # by the match radius), so tracking and lost in space agree on the same frame. The chance-alignment
    # bound uses those n image and k catalog stars, so no separate verification pass is needed.
    n_all = min(len(img_xy), max_stars)
    k1, px, py = fld.project(U, C1, refine_radius_px)
    ii2, cj2, _ = _match_radius(img_xy[:n_all, 0], img_xy[:n_all, 1], px, py, refine_radius_px, True)
    p = len(k1) * math.pi * refine_radius_px**2 / fld.area
    pf = false_match_probability(len(ii2), n_all, p)
    ci2 = cone[k1[cj2]]
    if len(ii2) < min_matches or pf > max_false_prob:
        return Match(None, ii2, ci2, n_all, pf, 1)
    est2, keep = _estimate_robust(b_S, U, sigma_rad, ii2, k1[cj2])
    if keep is not None:
        ii2, ci2 = ii2[keep], ci2[keep]
    return Match(est2, ii2, ci2, n_all, pf, 1)
