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
  the plate scale), stored in a ``cKDTree`` and looked up with a max-norm tolerance;
* the 4 stars of a pattern are ordered by their distance from the pattern's centroid, the same
  rule on both sides, so a key hit gives the star correspondence.

Lost in space: 4-star combinations of the brightest image stars, brightest combinations first,
looked up in one vectorised tree query; each catalog hit whose largest separation also agrees
gives a 4-pair attitude, which is accepted only after *verification*: the catalog stars predicted
in the field must match enough image stars that a chance alignment is improbable. With ``k``
catalog stars predicted on the image, a match radius ``r`` px and an ``W x H`` image, a random
image star lands near one with probability ``p = k pi r^2 / (W H)``; the chance that ``m`` of ``n``
image stars do so is the binomial tail ``P(X >= m)``, multiplied by the number of hypotheses
tried (Bonferroni). A solution needs ``m >= min_matches`` and that bound below ``max_false_prob``.

Tracking: the catalog projected with the prior attitude; a vote over displacements between the
brightest image and catalog stars finds the common offset (so a prior up to ``track_radius_px``
off still converges), nearest-neighbour matching of those, a first estimate, then one tight
nearest-neighbour pass over all image stars; the chance-alignment bound uses all image stars.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import betainc

from star_screen.catalog import StarPlaces
from star_screen.geometry import TrackerOptics
from star_screen.tracking.estimate import AttitudeEstimate, estimate_attitude, wahba_dcm

__all__ = ["PatternDatabase", "Match", "identify_lis", "identify_tracking", "verify", "false_match_probability"]


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


def _edges(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Separations (rad) of 4-star sets ``u (P, 4, 3)``: (P, 6) unsorted, in pair order (01 02 03 12 13 23)."""
    ii = np.array([0, 0, 0, 1, 1, 2])
    jj = np.array([1, 2, 3, 2, 3, 3])
    d = np.linalg.norm(u[:, ii] - u[:, jj], axis=-1)
    return 2.0 * np.arcsin(np.clip(0.5 * d, 0.0, 1.0)), d


def _canonical(u: np.ndarray) -> np.ndarray:
    """Per pattern, the permutation (P, 4) ordering its stars by distance from the centroid."""
    c = u.mean(axis=1, keepdims=True)
    c /= np.linalg.norm(c, axis=-1, keepdims=True)
    return np.argsort(np.linalg.norm(u - c, axis=-1), axis=1, kind="stable")


def _keys(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e, _ = _edges(u)
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
    tree: cKDTree  #: over the (P, 5) keys

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
        return cls(D, float(pattern_mag_limit), rows, u, P, largest, cKDTree(keys))

    def __len__(self) -> int:
        return len(self.patterns)


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


def _match_nn(img_tree: cKDTree, n_img: int, cat_px: np.ndarray, radius: float):
    """One-to-one nearest-neighbour pairs (image index, catalog index) within ``radius`` px."""
    if len(cat_px) == 0 or n_img == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0)
    d, j = img_tree.query(cat_px, k=1, distance_upper_bound=radius)
    ok = np.isfinite(d)
    ci = np.flatnonzero(ok)
    ii = j[ok]
    dd = d[ok]
    # Several catalog stars near one image star (a blend): keep the closest.
    o = np.lexsort((dd, ii))
    ii, ci, dd = ii[o], ci[o], dd[o]
    first = np.ones(len(ii), bool)
    first[1:] = ii[1:] != ii[:-1]
    return ii[first], ci[first], dd[first]


_TREES: dict[int, tuple[StarPlaces, cKDTree]] = {}


def _cone(C: np.ndarray, places: StarPlaces, cos_cull: float) -> np.ndarray:
    """Rows of the places within the cull cone around the boresight of ``C``, sorted (brightest first).

    A k-d tree over the places (built once per places table, kept for the few most recent) answers
    in a fraction of the cost of a product with every catalog star."""
    entry = _TREES.get(id(places.u_N))
    if entry is None or entry[0].u_N is not places.u_N:
        if len(_TREES) > 4:
            _TREES.clear()
        entry = (places, cKDTree(places.u_N))
        _TREES[id(places.u_N)] = entry
    chord = math.sqrt(max(2.0 - 2.0 * cos_cull, 0.0))
    rows = np.asarray(entry[1].query_ball_point(C[2], chord), dtype=np.int64)
    rows.sort()
    return rows


def _project_field(C: np.ndarray, places: StarPlaces, optics: TrackerOptics, rows: np.ndarray, margin: float = 0.0):
    """Catalog rows (from ``rows``, a cone wide enough for ``C``) landing on the detector, and their pixels."""
    d = places.u_N[rows] @ C.T
    px, front = optics.project(d)
    ok = (
        front
        & (px[:, 0] >= -margin)
        & (px[:, 0] < optics.width + margin)
        & (px[:, 1] >= -margin)
        & (px[:, 1] < optics.height + margin)
    )
    return rows[ok], px[ok]


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

    Returns (image indices, catalog rows, rows of all catalog stars predicted, false-match bound).
    """
    n = min(n_verify, len(img_xy))
    rows, px = _project_field(C, places, optics, _cone(C, places, cos_cull))
    if n == 0 or len(rows) == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64), len(rows), 1.0
    tree = cKDTree(img_xy[:n])
    ii, ci, _ = _match_nn(tree, n, px, radius_px)
    p = len(rows) * math.pi * radius_px**2 / (optics.width * optics.height)
    pf = min(1.0, false_match_probability(len(ii), n, p) * max(hypotheses, 1))
    return ii, rows[ci], rows, pf


def _refine(C, img_xy, b_S, sigma_rad, places, optics, cone_rows, radius_px, passes: int = 1):
    """Re-match all image stars to the catalog predicted by ``C`` and re-estimate (``passes`` times).

    ``cone_rows``: catalog rows near the field (the predicted stars of the verification pass, which
    still cover the field: a verified attitude moves by far less than the cull margin)."""
    tree = cKDTree(img_xy)
    est = None
    ii = ci = np.empty(0, np.int64)
    for _ in range(passes):
        rows, px = _project_field(C, places, optics, cone_rows, margin=radius_px)
        ii, cj, _ = _match_nn(tree, len(img_xy), px, radius_px)
        if len(ii) < 3:
            return None, ii, np.empty(0, np.int64)
        ci = rows[cj]
        est = estimate_attitude(b_S[ii], places.u_N[ci], sigma_rad[ii])
        C = est.dcm_SN
    return est, ii, ci


@functools.lru_cache(maxsize=16)
def cull_cos(optics: TrackerOptics) -> float:
    """Cosine of the cone that holds every direction the detector can see, plus 0.1 deg."""
    return math.cos(optics.half_diagonal_rad() + math.radians(0.1))


_COMBO_CACHE: dict[int, np.ndarray] = {}


def _combos_brightest_first(n: int) -> np.ndarray:
    """All 4-subsets of range(n), ordered so that combinations of brighter stars come first."""
    if n not in _COMBO_CACHE:
        c = np.array(list(itertools.combinations(range(n), 4)), dtype=np.int64).reshape(-1, 4)
        o = np.lexsort((c[:, 2], c[:, 1], c[:, 0], c[:, 3]))  # by the faintest member, then the rest
        _COMBO_CACHE[n] = c[o]
    return _COMBO_CACHE[n]


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
    if n < 4:
        return _NO_MATCH
    u = b_S[:n]
    combos = _combos_brightest_first(n)
    cos_d = math.cos(db.max_edge_rad * (1.0 + edge_tolerance))
    G = (u @ u.T) >= cos_d
    ok = (
        G[combos[:, 0], combos[:, 1]]
        & G[combos[:, 0], combos[:, 2]]
        & G[combos[:, 0], combos[:, 3]]
        & G[combos[:, 1], combos[:, 2]]
        & G[combos[:, 1], combos[:, 3]]
        & G[combos[:, 2], combos[:, 3]]
    )
    combos = combos[ok]
    if len(combos) == 0 or len(db) == 0:
        return _NO_MATCH
    uc = u[combos]
    perm = _canonical(uc)
    combos = np.take_along_axis(combos, perm, axis=1)
    uc = np.take_along_axis(uc, perm[:, :, None], axis=1)
    keys, largest = _keys(uc)
    cos_cull = cull_cos(optics)
    hyp = 0
    hits: list = []
    for q in range(len(combos)):
        if q == len(hits):
            # Query the tree in growing batches: the brightest combinations usually solve it.
            hits.extend(db.tree.query_ball_point(keys[q : q + max(16, q)], key_tolerance, p=np.inf))
        cand = hits[q]
        if not cand:
            continue
        cand = np.asarray(cand)
        cand = cand[np.abs(db.largest_edge_rad[cand] - largest[q]) <= edge_tolerance * largest[q]]
        for p in cand:
            hyp += 1
            if hyp > max_hypotheses:
                return _NO_MATCH
            r_N = db.u_N[db.patterns[p]]
            b4 = uc[q]
            C4 = wahba_dcm(b4, r_N, np.ones(4))
            if np.max(np.linalg.norm(b4 - r_N @ C4.T, axis=1)) > fit_tolerance_rad:
                continue  # mirror image or wrong correspondence
            ii, ci, field_rows, pf = verify(
                C4, img_xy, n_verify, places, optics, cos_cull, match_radius_px, hyp
            )
            if len(ii) < min_matches or pf > max_false_prob:
                continue
            n_ver = min(n_verify, len(img_xy))
            # Re-estimate from the verified pairs before matching all stars at the tight radius.
            C1 = wahba_dcm(b_S[ii], places.u_N[ci], 1.0 / sigma_rad[ii] ** 2)
            est2, ii2, ci2 = _refine(
                C1, img_xy, b_S, sigma_rad, places, optics, field_rows, refine_radius_px
            )
            if est2 is None or len(ii2) < min_matches:
                continue
            return Match(est2, ii2, ci2, n_ver, pf, hyp)
    return Match(None, np.empty(0, np.int64), np.empty(0, np.int64), min(n_verify, len(img_xy)), 1.0, hyp)


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
    error moves the field corners by less than about ``vote_bin_px``.
    """
    if len(img_xy) < 3:
        return _NO_MATCH
    cos_cull = cull_cos(optics)
    cone = _cone(C_prior, places, math.cos(math.acos(cos_cull) + track_radius_px / optics.fx))
    rows, px = _project_field(C_prior, places, optics, cone, margin=track_radius_px)
    if len(rows) < 3:
        return _NO_MATCH
    # Vote for the common image offset between bright image and bright predicted stars.
    a = img_xy[:vote_image_stars]
    c = px[:vote_catalog_stars]  # places are brightest first, so rows (and px) are too
    D = a[:, None, :] - c[None, :, :]  # (na, nc, 2) displacement image - predicted
    d = D.reshape(-1, 2)
    span = int(2 * math.ceil(track_radius_px / vote_bin_px) + 4)
    cells = np.floor(d / vote_bin_px).astype(np.int64) + span // 2
    inside = np.all((cells >= 1) & (cells < span - 1), axis=1)
    if not inside.any():
        return _NO_MATCH
    flat = cells[inside, 0] * span + cells[inside, 1]
    # Each displacement votes for its cell and the 8 around it, so an offset on a border is not split.
    around = np.array([-span - 1, -span, -span + 1, -1, 0, 1, span - 1, span, span + 1])
    box = np.bincount((flat[:, None] + around).ravel(), minlength=span * span)
    bi, bj = divmod(int(np.argmax(box)), span)
    centre = (np.array([bi, bj]) - span // 2 + 0.5) * vote_bin_px
    dist = np.max(np.abs(D - centre), axis=2)  # (na, nc)
    near = dist <= 1.5 * vote_bin_px
    if not near.any():
        return _NO_MATCH
    offset = D[near].mean(axis=0)
    # First pairs: each bright image star with the bright predicted star nearest to it after the
    # common offset, if within two bins and not claimed by another image star.
    dist = np.hypot(D[..., 0] - offset[0], D[..., 1] - offset[1])
    cj = np.argmin(dist, axis=1)
    ii = np.flatnonzero(dist[np.arange(len(a)), cj] <= 2.0 * vote_bin_px)
    cj = cj[ii]
    uniq, cnt = np.unique(cj, return_counts=True)
    single = np.isin(cj, uniq[cnt == 1])
    ii, cj = ii[single], cj[single]
    if len(ii) < 3:
        return _NO_MATCH
    C1 = wahba_dcm(b_S[ii], places.u_N[rows[cj]], 1.0 / sigma_rad[ii] ** 2)
    # One tight matching pass over the brightest ``max_stars`` image stars and the brightest predicted
    # stars (1.5 n + 20 of them). The chance-alignment bound uses those n image and k catalog stars,
    # so no separate verification pass is needed. (Cutting n to 150 saves only ~5 % of the time.)
    n_all = min(len(img_xy), max_stars)
    tree = cKDTree(img_xy[:n_all])
    rows1, px1 = _project_field(C1, places, optics, cone)
    k_cat = int(1.5 * n_all) + 20
    rows1, px1 = rows1[:k_cat], px1[:k_cat]
    ii2, cj2, _ = _match_nn(tree, n_all, px1, refine_radius_px)
    p = len(rows1) * math.pi * refine_radius_px**2 / (optics.width * optics.height)
    pf = false_match_probability(len(ii2), n_all, p)
    ci2 = rows1[cj2]
    if len(ii2) < min_matches or pf > max_false_prob:
        return Match(None, ii2, ci2, n_all, pf, 1)
    est2 = estimate_attitude(b_S[ii2], places.u_N[ci2], sigma_rad[ii2])
    return Match(est2, ii2, ci2, n_all, pf, 1)
