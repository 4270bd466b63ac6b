"""star_screen.tracking.nearest, the star tracker's radius matching: its compiled twin (Cython, compiled_paths) and the
plain module give the same pairs and squared distances to the bit, and both give the pairs of a brute-force search."""

from __future__ import annotations

import numpy as np
import pytest

import compiled_paths
import star_screen.tracking.nearest as plain
from star_screen.tracking import identify
from tests.oracles import build_fixtures

from .star_screen_helpers import assert_same_solutions_on_both_builds

compiled, build = build_fixtures("star_screen.tracking.nearest")


def _match(module, img: np.ndarray, cat: np.ndarray, radius: float, drop_blends: bool):
    """(image index, catalog index, squared distance) lists from ``module.match_radius``, called as
    ``identify._match_radius`` calls it: arrays for the compiled build, lists for the plain one."""
    order = np.argsort(img[:, 0], kind="stable")
    n, k = len(img), len(cat)
    xs, ys = np.ascontiguousarray(img[order, 0]), np.ascontiguousarray(img[order, 1])
    cx, cy = np.ascontiguousarray(cat[:, 0]), np.ascontiguousarray(cat[:, 1])
    if compiled_paths.is_compiled(module):
        args = (xs, ys, order, cx, cy)
        out = (np.zeros(n, np.int64), np.empty(k, np.int64), np.empty(k, np.int64), np.empty(k))
    else:
        args = (xs.tolist(), ys.tolist(), order.tolist(), cx.tolist(), cy.tolist())
        out = ([0] * n, [0] * k, [0] * k, [0.0] * k)
    w = module.match_radius(*args, radius, drop_blends, *out)
    return [int(v) for v in out[1][:w]], [int(v) for v in out[2][:w]], [float(v) for v in out[3][:w]]


def _brute_force(img: np.ndarray, cat: np.ndarray, radius: float, drop_blends: bool):
    """Nearest image star per catalog star (squared distance below radius^2), then per image star the closest claim
    (or none of several with ``drop_blends``); pairs in catalog order."""
    claims: dict[int, list] = {}
    for j, (x, y) in enumerate(cat.tolist()):
        d2 = [(xi - x) * (xi - x) + (yi - y) * (yi - y) for xi, yi in img.tolist()]
        if d2 and min(d2) < radius * radius:
            i = int(np.argmin(d2))
            claims.setdefault(i, []).append((d2[i], j))
    pairs = sorted((min(v)[1], i) for i, v in claims.items() if not (drop_blends and len(v) > 1))
    return [i for _, i in pairs], [j for j, _ in pairs]


def _cases(seed: int, count: int):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        n, k, r = int(rng.integers(0, 90)), int(rng.integers(0, 120)), float(rng.uniform(0.5, 4.0))
        img = rng.uniform(0, 80, (n, 2))
        # Half the catalog near image stars (pairs and blends), half anywhere; a few exactly on an image star.
        near = img[: k // 2] + rng.normal(0, 0.6 * r, (min(k // 2, n), 2))
        cat = np.vstack((near, img[: min(3, n)], rng.uniform(-5, 85, (k, 2))))[:k]
        yield img, cat, r


@pytest.mark.parametrize("drop_blends", [False, True])
def test_pairs_are_the_brute_force_nearest_one_to_one_pairs(build, drop_blends) -> None:
    for img, cat, r in _cases(31, 60):
        image, catalog, d2 = _match(build, img, cat, r, drop_blends)
        assert (image, catalog) == _brute_force(img, cat, r, drop_blends)
        for i, j, d in zip(image, catalog, d2, strict=True):
            dx, dy = float(img[i, 0] - cat[j, 0]), float(img[i, 1] - cat[j, 1])
            assert d == dx * dx + dy * dy and d < r * r


def test_compiled_and_plain_give_the_same_pairs_and_distances_to_the_bit(compiled) -> None:
    for img, cat, r in _cases(32, 60):
        for drop_blends in (False, True):
            assert _match(compiled, img, cat, r, drop_blends) == _match(plain, img, cat, r, drop_blends)


def test_a_blend_keeps_its_closest_claim_or_none(build) -> None:
    """Two catalog stars nearest to one image star: without ``drop_blends`` the closer keeps it (the earlier of two
    equally close ones); with it, neither does. A lone pair is kept either way."""
    img = np.array([[10.0, 10.0], [40.0, 10.0]])
    cat = np.array([[10.5, 10.0], [9.8, 10.0], [40.0, 11.0], [39.0, 10.0]])  # 0, 1 on star 0; 2, 3 tie on star 1
    assert _match(build, img, cat, 1.5, False)[:2] == ([0, 1], [1, 2])
    assert _match(build, img, cat, 1.5, True)[:2] == ([], [])
    lone = np.array([[10.2, 10.0]])
    assert _match(build, img, lone, 1.5, True)[:2] == ([0], [0])


def test_lost_in_space_and_tracking_solutions_are_the_same_on_both_builds(compiled, monkeypatch, epoch) -> None:
    """The whole solve, lost in space and tracking, on rendered frames with camera noise: the same matched stars and
    the same attitude and covariance to the bit whichever build of the matching runs."""

    def use(module) -> None:
        monkeypatch.setattr(identify, "_nearest", module)
        monkeypatch.setattr(identify, "_NEAREST_COMPILED", compiled_paths.is_compiled(module))

    assert_same_solutions_on_both_builds(epoch, 2611, (compiled, plain), use)
