"""star_screen.tracking.lis_steps, the lost-in-space decision steps: its compiled twin (Cython, compiled_paths) and the
plain module give the same cones, pattern keys and pair attitudes to the bit; the cone is the brute-force cone, the
keys are numpy's keys, and the pair attitude is the SVD solution's to rounding."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

import compiled_paths
import star_screen.tracking.lis_steps as plain
from sim.rotations import dcm, quat_from_axis_angle
from star_screen.tracking import identify
from star_screen.tracking.estimate import wahba_dcm
from tests.oracles import build_fixtures

from .star_screen_helpers import assert_same_solutions_on_both_builds

compiled, build = build_fixtures("star_screen.tracking.lis_steps")


def _unit(rng, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _near(rng, centre: np.ndarray, n: int, spread_rad: float) -> np.ndarray:
    v = centre + rng.normal(0.0, spread_rad, (n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _as_args(module, *arrays):
    return tuple(np.ascontiguousarray(a) for a in arrays) if compiled_paths.is_compiled(module) else tuple(
        a.tolist() for a in arrays)


def _cone(module, index_u: np.ndarray, b: np.ndarray, cos_cone: float, kc: np.ndarray | None = None,
          cap: int | None = None):
    """``module.cone_sorted`` over a cube-map index of the directions ``index_u``, called as
    ``identify._SkyIndex._query`` calls it: (rows, directions, x, y) of what it kept, or minus the cone's count when it
    holds more than ``cap``. ``kc``: the pinhole camera to project with (the 1024 x 768 detector)."""
    n = identify.CONE_CELLS_PER_FACE
    cell = identify._cube_cell_of(index_u, n)
    order = np.argsort(cell, kind="stable")
    starts = np.searchsorted(cell[order], np.arange(6 * n * n + 1)).astype(np.int64)
    centre, cos_rho, sin_rho = identify._cube_cells(n)
    cap = len(index_u) if cap is None else cap
    if compiled_paths.is_compiled(module):
        work, rows, u, x, y = (np.zeros(4 * cap + 6 * n * n + 1, np.int64), np.zeros(cap, np.int64),
                               np.zeros(3 * cap), np.zeros(cap), np.zeros(cap))
    else:
        work, rows, u, x, y = [0] * (4 * cap + 6 * n * n + 1), [0] * cap, [0.0] * (3 * cap), [0.0] * cap, [0.0] * cap
    chord = math.sqrt(max(2.0 - 2.0 * cos_cone, 0.0))
    bx, by, bz = b.tolist()
    camera = np.zeros(9) if kc is None else np.ascontiguousarray(kc).ravel()
    m = module.cone_sorted(*_as_args(module, centre.ravel(), cos_rho, sin_rho, starts),
                           *_as_args(module, index_u[order].ravel(), order.astype(np.int64)), bx, by, bz, cos_cone,
                           math.sqrt(1.0 - cos_cone * cos_cone), chord * chord, kc is not None,
                           *_as_args(module, camera), 0.0, 1024.0, 768.0, cap, work, rows, u, x, y)
    if m < 0:
        return m
    rows = [int(r) for r in rows[:m]]
    # Each row comes with its own direction, to the bit.
    assert np.asarray(u[: 3 * m], float).tobytes() == index_u[rows].tobytes()
    return rows, np.asarray(u[: 3 * m], float).tobytes(), np.asarray(x[:m], float).tobytes(), np.asarray(
        y[:m], float).tobytes()


def _cone_cases(seed: int, count: int):
    rng = np.random.default_rng(seed)
    u = _unit(rng, 4000)
    for k in range(count):
        # Random boresights, and some on cube edges and corners (cells of three faces at once).
        b = _unit(rng, 1)[0] if k % 3 else np.array([1.0, (-1.0) ** k, 1.0 if k % 2 else 0.0])
        b = b / np.linalg.norm(b)
        yield u, b, math.cos(math.radians(rng.uniform(0.5, 100.0 if k % 7 == 0 else 20.0)))


def test_cone_is_every_star_within_the_chord(build) -> None:
    """The cone is the brute-force chord test over every star, in ascending row (the runs of the cells merged)."""
    for u, b, cos_cone in _cone_cases(41, 40):
        chord = math.sqrt(max(2.0 - 2.0 * cos_cone, 0.0))
        d = u - b
        brute = [int(r) for r in np.flatnonzero((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2]
                                                 <= chord * chord)]
        assert _cone(build, u, b, cos_cone)[0] == brute


def test_compiled_and_plain_cones_are_the_same(compiled) -> None:
    for u, b, cos_cone in _cone_cases(42, 30):
        assert _cone(compiled, u, b, cos_cone) == _cone(plain, u, b, cos_cone)


def _cameras(seed: int, count: int):
    """Cone cases with the pinhole camera (the default tracker's, 1024 x 768 px) of an attitude near the boresight."""
    rng = np.random.default_rng(seed)
    K = np.array(((2900.0, 0.0, 511.5), (0.0, 2900.0, 383.5), (0.0, 0.0, 1.0)))
    for u, b, cos_cone in _cone_cases(seed, count):
        # An attitude whose boresight (third row) is b, rolled at random.
        x = np.cross(b, _unit(rng, 1)[0])
        x /= np.linalg.norm(x)
        C = np.array((x, np.cross(b, x), b))
        yield u, b, cos_cone, K @ C


def test_cone_projected_in_one_loop_is_the_cone_then_the_projection(build) -> None:
    """``cone_sorted`` with a camera keeps what :func:`project_pinhole` keeps of the whole sorted cone, with the same
    pixels to the bit: the verification's one loop is the cone query followed by the projection."""
    kept = 0
    for u, b, cos_cone, kc in _cameras(50, 40):
        rows, _, _, _ = _cone(build, u, b, cos_cone)
        cone_u = u[rows]
        m = len(rows)
        if compiled_paths.is_compiled(build):
            keep, x, y = np.zeros(m, np.int64), np.zeros(m), np.zeros(m)
        else:
            keep, x, y = [0] * m, [0.0] * m, [0.0] * m
        w = build.project_pinhole(*_as_args(build, cone_u.ravel(), kc.ravel()), 0.0, 1024.0, 768.0, m, keep, x, y)
        want = ([rows[int(k)] for k in keep[:w]], cone_u[np.asarray(keep[:w], np.int64)].tobytes(),
                np.asarray(x[:w], float).tobytes(), np.asarray(y[:w], float).tobytes())
        assert _cone(build, u, b, cos_cone, kc) == want
        kept += w
    assert kept > 500  # most cases put stars on the detector (727 on these)


def test_compiled_and_plain_projected_cones_are_the_same(compiled) -> None:
    for u, b, cos_cone, kc in _cameras(51, 30):
        assert _cone(compiled, u, b, cos_cone, kc) == _cone(plain, u, b, cos_cone, kc)


def test_a_cone_larger_than_its_buffers_writes_nothing_and_says_how_large(build) -> None:
    """A cone holding more stars than ``cap`` returns minus its count; buffers of that size then hold it all; and
    the cone index grows its buffers so (its solutions do not depend on the first size)."""
    for u, b, cos_cone in _cone_cases(52, 12):
        rows = _cone(build, u, b, cos_cone)[0]
        if len(rows) < 2:
            continue
        assert _cone(build, u, b, cos_cone, cap=len(rows) - 1) == -len(rows)
        assert _cone(build, u, b, cos_cone, cap=len(rows))[0] == rows


def test_the_cone_index_grows_its_buffers(monkeypatch) -> None:
    rng = np.random.default_rng(53)

    class Places:
        u_N = _unit(rng, 5000)

    monkeypatch.setattr(identify, "CONE_CAP", 8)
    index = identify._SkyIndex(Places)
    b = Places.u_N[0]
    rows, U = index.cone(b, math.cos(math.radians(20.0)))
    d = Places.u_N - b
    chord2 = 2.0 - 2.0 * math.cos(math.radians(20.0))
    assert rows.tolist() == np.flatnonzero(np.einsum("ij,ij->i", d, d) <= chord2).tolist()
    assert U.tobytes() == Places.u_N[rows].tobytes() and index.cap == len(rows) > 8


def _keys(module, u: np.ndarray, max_edge_cos: float, batch: int):
    """Every (canonical quad, key, largest) of ``module.pattern_keys`` over the directions ``u``, ``batch`` a call."""
    n = len(u)
    quads = identify._quads_brightest_first(n)[0].ravel()
    fits = ((u @ u.T) >= max_edge_cos).ravel().view(np.uint8)
    sep = identify._angle_of_chord(identify._row_norm(u[:, None, :] - u[None, :, :])).ravel()
    scratch, cursor = np.empty(10), np.zeros(1, np.int64)
    start, found = 0, []
    for _ in range(len(quads)):  # bounded: each call looks at one pattern at least
        q, k, big = np.empty(4 * batch, np.int64), np.empty(5 * batch), np.empty(batch)
        w = module.pattern_keys(n, quads, start, fits, sep, np.ascontiguousarray(u).ravel(), batch, q, k, big,
                                scratch, cursor)
        found += [(q[4 * i:4 * i + 4].tolist(), k[5 * i:5 * i + 5].tobytes(), big[i].tobytes()) for i in range(w)]
        if w == 0:
            break
        start = int(cursor[0])
    return found


def test_pattern_keys_are_numpys_keys_to_the_bit(build) -> None:
    """The patterns, brightest combinations first, in canonical order with the keys and largest separations of
    ``identify._canonical`` and ``identify._keys`` (the database's own functions) to the bit."""
    rng = np.random.default_rng(43)
    for trial in range(6):
        u = _near(rng, _unit(rng, 1)[0], 12, math.radians(3.0))
        max_cos = math.cos(math.radians(8.0))
        quads = identify._quads_brightest_first(len(u))[0]
        fits = [q for q in quads if all(float(u[a] @ u[b]) >= max_cos for a, b in itertools.combinations(q, 2))]
        assert 0 < len(fits) < len(quads) or trial > 0
        canon = np.take_along_axis(np.array(fits), identify._canonical(u[np.array(fits)]), axis=1)
        keys, largest = identify._keys(u[canon])
        expected = [(c.tolist(), k.tobytes(), g.tobytes()) for c, k, g in zip(canon, keys, largest, strict=True)]
        assert _keys(build, u, max_cos, 1 + trial) == expected


def test_compiled_and_plain_pattern_keys_are_the_same(compiled) -> None:
    rng = np.random.default_rng(44)
    for _ in range(5):
        u = _near(rng, _unit(rng, 1)[0], 16, math.radians(4.0))
        assert _keys(compiled, u, math.cos(math.radians(8.0)), 3) == _keys(plain, u, math.cos(math.radians(8.0)), 3)


def _fit(module, b: np.ndarray, r: np.ndarray, w: np.ndarray | None):
    out, scratch = np.empty(9), np.empty(32)
    worst = module.fit_pairs(b.ravel().copy(), r.ravel().copy(), np.ones(len(b)) if w is None else w.copy(),
                             w is None, out, scratch)
    return out.reshape(3, 3), worst


def _fit_cases(seed: int, count: int):
    rng = np.random.default_rng(seed)
    for k in range(count):
        n = 4 if k % 2 else int(rng.integers(3, 60))
        r = _near(rng, _unit(rng, 1)[0], n, math.radians(rng.uniform(0.5, 6.0)))
        C = dcm(quat_from_axis_angle(rng.normal(size=3), rng.uniform(0.0, math.pi)))
        b = r @ C.T + rng.normal(0.0, 1e-5, (n, 3))
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        if k % 5 == 0:
            b = b[::-1].copy()  # a wrong correspondence: the best rotation is a poor fit
        yield b, r, (None if k % 2 else rng.uniform(0.5, 2.0, n) * 1e10)


def test_pair_attitude_is_the_svd_solution_to_rounding(build) -> None:
    """Davenport's q-method against the SVD solution (``estimate.wahba_dcm``): a proper rotation, the same matrix to
    1e-11 and its largest residual. Both are exact to rounding over the problem's conditioning: four stars within
    half a degree pin the roll weakly, and there the two differ by up to 3.5e-12 (measured on these cases), which moves
    a predicted star by 1e-8 px; well-spread pairs agree to a few 1e-14."""
    for b, r, w in _fit_cases(45, 60):
        C, worst = _fit(build, b, r, w)
        ref = wahba_dcm(b, r, np.ones(len(b)) if w is None else w)
        assert np.max(np.abs(C - ref)) < 1e-11
        assert abs(np.linalg.det(C) - 1.0) < 1e-14 and np.max(np.abs(C @ C.T - np.eye(3))) < 1e-14
        assert abs(worst - np.max(np.linalg.norm(b - r @ C.T, axis=1))) < 1e-15


def test_compiled_and_plain_pair_attitudes_are_the_same(compiled) -> None:
    for b, r, w in _fit_cases(46, 40):
        (Cc, wc), (Cp, wp) = _fit(compiled, b, r, w), _fit(plain, b, r, w)
        assert Cc.tobytes() == Cp.tobytes() and wc == wp


def test_lost_in_space_and_tracking_solutions_are_the_same_on_both_builds(compiled, monkeypatch, epoch) -> None:
    """The whole solve, lost in space and tracking, on rendered frames with camera noise: the same matched stars,
    hypotheses and bound, and the same attitude and covariance to the bit whichever build of the steps runs."""

    def use(module) -> None:
        monkeypatch.setattr(identify, "_lis", module)
        monkeypatch.setattr(identify, "_LIS_COMPILED", compiled_paths.is_compiled(module))
        monkeypatch.setattr(identify, "_INDEXES", {})  # the cone index holds arrays or lists by build

    assert_same_solutions_on_both_builds(epoch, 2612, (compiled, plain), use)


@pytest.mark.parametrize("n", [4, 16])
def test_cube_cells_cover_their_stars(n) -> None:
    """Every direction lies within its cell's radius of the cell's centre (the cone query's bound is safe)."""
    rng = np.random.default_rng(47)
    u = _unit(rng, 20000)
    centre, cos_rho, _ = identify._cube_cells(n)
    cell = identify._cube_cell_of(u, n)
    assert np.all(np.einsum("ij,ij->i", u, centre[cell]) >= cos_rho[cell])


def _lookup(module, grid, key: np.ndarray, largest: float, cap: int, tol: float = 0.01, edge_tol: float = 0.01):
    out = np.zeros(max(cap, 1), np.int64)
    m = module.lookup_key(np.ascontiguousarray(key, float), tol, *grid, largest, edge_tol, cap, out)
    return m, out[: min(m, cap)].tolist()


def _lookup_cases(seed: int, count: int):
    """A synthetic pattern table (keys sorted like real ones, in [0, 1]) and queries near its keys: some exactly
    ``tolerance`` away in a component (the ball's edge), some off the grid's range, most with a few hits."""
    rng = np.random.default_rng(seed)
    keys = np.sort(rng.uniform(0.0, 1.0, (20000, 5)) ** 0.5, axis=1)
    keys[:50, 4] = 1.0
    largest = rng.uniform(0.05, 0.14, len(keys))
    grid = identify._key_grid(keys, largest)
    for k in range(count):
        p = int(rng.integers(len(keys)))
        q = keys[p] + rng.normal(0.0, 0.004, 5)
        if k % 5 == 0:
            q = keys[p].copy()
            q[k % 5] += 0.01 * (-1) ** k  # on the edge of the ball
        if k % 11 == 0:
            q = np.full(5, 1.02) if k % 2 else np.full(5, -0.02)
        yield keys, largest, grid, q, largest[p] * (1.0 + rng.normal(0.0, 0.006))


def test_lookup_is_the_k_d_tree_max_norm_ball_with_the_largest_separation(build) -> None:
    """The hits of the grid are those of a k-d tree's max-norm ball query (return_sorted), filtered by the largest
    separation with numpy, in the same ascending order; only the first ``cap`` are written, the count is all."""
    from scipy.spatial import cKDTree

    trees = {}
    n_hits = 0
    for keys, largest, grid, q, big in _lookup_cases(48, 300):
        tree = trees.setdefault(id(keys), cKDTree(keys))
        cand = np.asarray(tree.query_ball_point(q, 0.01, p=np.inf, return_sorted=True), np.int64)
        want = cand[np.abs(largest[cand] - big) <= 0.01 * big].tolist()
        n_hits += len(want)
        assert _lookup(build, grid, q, float(big), 201) == (len(want), want)
        assert _lookup(build, grid, q, float(big), 1) == (len(want), want[:1])
        assert _lookup(build, grid, q, float(big), 0) == (len(want), [])
    assert n_hits > 150  # 190 hits on these cases: most queries find their pattern, some a neighbour too


def test_compiled_and_plain_lookups_are_the_same(compiled) -> None:
    for _, _, grid, q, big in _lookup_cases(49, 100):
        assert _lookup(compiled, grid, q, float(big), 3) == _lookup(plain, grid, q, float(big), 3)


def _gather(module, b, r, sigma, image, catalog):
    m = len(image)
    at_r, at_a, at_ba = 3 * m + 1, 6 * m + 2, 7 * m + 3  # odd offsets too: the caller's padding is not needed here
    out = np.zeros(at_ba + 3 * m) if compiled_paths.is_compiled(module) else [0.0] * (at_ba + 3 * m)
    module.gather_pairs(*_as_args(module, b.ravel(), r.ravel(), sigma, image, catalog), at_r, at_a, at_ba, out)
    out = np.asarray(out, float)
    return (out[: 3 * m].reshape(m, 3), out[at_r : at_r + 3 * m].reshape(m, 3), out[at_a : at_a + m],
            out[at_ba:].reshape(m, 3))


def _gather_cases(seed: int, count: int):
    rng = np.random.default_rng(seed)
    for k in range(count):
        n, c = int(rng.integers(4, 400)), int(rng.integers(4, 900))
        b, r = _unit(rng, n), _unit(rng, c)
        # Centroid sigmas as the tracker gives them (1e-6 to 1e-4 rad), and some extreme ones.
        sigma = 10.0 ** rng.uniform(-6.0, -4.0, n)
        if k % 4 == 0:
            sigma[:3] = (1e-160, 1e155, 5e-324)
        m = int(rng.integers(0, n))
        yield b, r, sigma, rng.choice(n, m, replace=False).astype(np.int64), rng.integers(0, c, m).astype(np.int64)


def test_gathered_pairs_are_numpys_to_the_bit(build) -> None:
    """The gathered directions and weights are numpy's ``b[i]``, ``r[j]``, ``1.0 / sigma[i] ** 2`` and
    ``b[i] * a[:, None]`` to the bit (overflow and underflow of the weight included)."""
    with np.errstate(over="ignore", divide="ignore"):
        for b, r, sigma, image, catalog in _gather_cases(54, 40):
            a = 1.0 / sigma[image] ** 2
            want = (b[image], r[catalog], a, b[image] * a[:, None])
            got = _gather(build, b, r, sigma, image, catalog)
            assert [g.tobytes() for g in got] == [w.tobytes() for w in want]


def test_compiled_and_plain_gathered_pairs_are_the_same(compiled) -> None:
    for b, r, sigma, image, catalog in _gather_cases(55, 20):
        got_c, got_p = _gather(compiled, b, r, sigma, image, catalog), _gather(plain, b, r, sigma, image, catalog)
        assert [g.tobytes() for g in got_c] == [g.tobytes() for g in got_p]


def test_final_estimate_of_gathered_pairs_is_the_estimate_of_numpys_pairs(build, monkeypatch) -> None:
    """``identify._estimate_robust`` (pairs gathered in one block) gives the estimate of
    ``estimate_attitude_robust`` on the pairs numpy gathers, to the bit: attitude, covariance, residuals, kept pairs
    (outliers among the pairs, so the gate drops some in part of the cases)."""
    from star_screen.tracking.estimate import estimate_attitude_robust

    monkeypatch.setattr(identify, "_lis", build)
    monkeypatch.setattr(identify, "_LIS_COMPILED", compiled_paths.is_compiled(build))
    rng = np.random.default_rng(56)
    dropped = 0
    for k in range(30):
        n = int(rng.integers(8, 200))
        C = dcm(quat_from_axis_angle(_unit(rng, 1)[0], rng.uniform(0.0, math.pi)))
        r = _unit(rng, n)
        sigma = 10.0 ** rng.uniform(-6.0, -4.5, n)
        b = r @ C.T + rng.normal(size=(n, 3)) * sigma[:, None]
        b[: k % 3] += 1e-2  # outliers
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        image = rng.permutation(n)[: n - 2].astype(np.int64)
        catalog = image.copy()
        got, keep_got = identify._estimate_robust(b, r, sigma, image, catalog)
        want, keep_want = estimate_attitude_robust(b[image], r[catalog], sigma[image], identify.OUTLIER_GATE)
        assert (keep_got is None) == (keep_want is None)
        if keep_got is not None:
            assert keep_got.tolist() == keep_want.tolist()
            dropped += 1
        for name in ("q_SN", "dcm_SN", "cov_S", "residual_rad"):
            assert getattr(got, name).tobytes() == getattr(want, name).tobytes(), name
        assert (got.sigma_cross_rad, got.sigma_roll_rad) == (want.sigma_cross_rad, want.sigma_roll_rad)
    assert dropped >= 10
