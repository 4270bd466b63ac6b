"""Radius matching of predicted catalog stars to image stars: the star tracker's hot kernel.

Plain Python, and compiled by Cython in pure-Python mode where the install has a C compiler (``compiled_paths``
lists it; docs/fast_paths.md): the ``cython.*`` declarations give the compiled build C doubles, C integers and typed
memoryviews, and do nothing in plain Python. Both builds do the same IEEE-754 operations in the same order (setup.py
compiles without contraction and fast-math), so they return the same pairs and the same squared distances to the
bit.

:mod:`star_screen.tracking.identify` takes this module through ``compiled_paths.load("star_screen.tracking.nearest")``
(its ``_match_radius`` sorts the image stars, allocates the outputs and hands the compiled build numpy arrays, the
plain one lists); nothing else imports it directly.

Why a loop: a tracker frame matches a few hundred stars, and a sweep over the image stars sorted by x looks at two or
three of them per catalog star. Written with numpy, the same rule took about forty small-array calls per match, and
two such matches were a third of a lost-in-space solve; compiled, the loop costs a few microseconds.
"""

from __future__ import annotations

import cython

#: The sweep looks at image stars up to this many radii away in x. Only the squared distance decides a pair; the
#: wider window only keeps a rounding of ``x -+ radius`` from hiding a star at the very edge of the radius.
WINDOW = 1.25


@cython.cfunc
@cython.inline
@cython.locals(lo=cython.Py_ssize_t, hi=cython.Py_ssize_t, mid=cython.Py_ssize_t, xm=cython.double)
def _first_at_least(xs: cython.double[:], n: cython.Py_ssize_t, value: cython.double) -> cython.Py_ssize_t:
    """The first position in the ascending ``xs[:n]`` whose value is at least ``value`` (``n`` when none is)."""
    lo = 0
    hi = n
    while lo < hi:
        mid = (lo + hi) // 2
        xm = xs[mid]
        if xm < value:
            lo = mid + 1
        else:
            hi = mid
    return lo


@cython.locals(n=cython.Py_ssize_t, k=cython.Py_ssize_t, c=cython.Py_ssize_t, j=cython.Py_ssize_t,
               best=cython.Py_ssize_t, m=cython.Py_ssize_t, w=cython.Py_ssize_t, i=cython.Py_ssize_t,
               x=cython.double, y=cython.double, xj=cython.double, yj=cython.double, dx=cython.double,
               dy=cython.double, d2=cython.double, best_d2=cython.double, r2=cython.double, hi=cython.double,
               reach=cython.double, mark=cython.longlong)
def match_radius(xs: cython.double[:], ys: cython.double[:], order: cython.longlong[:], cat_x: cython.double[:],
                 cat_y: cython.double[:], radius: cython.double, drop_blends: cython.bint, claims: cython.longlong[:],
                 out_image: cython.longlong[:], out_catalog: cython.longlong[:],
                 out_d2: cython.double[:]) -> cython.Py_ssize_t:
    """One-to-one pairs of catalog stars and image stars closer than ``radius``; returns their number ``w``.

    ``xs, ys``: the image stars sorted by x (ascending), ``order[p]`` the image index of sorted position ``p``;
    ``cat_x, cat_y``: the catalog stars. Each catalog star, in order, takes its nearest image star with a squared
    distance ``dx * dx + dy * dy`` below ``radius ** 2`` (of equally near ones the first in the sorted order); an
    image star claimed by several catalog stars keeps the closest claim (the first in catalog order of equally close
    ones), or with ``drop_blends`` none of them. The pairs are written, in catalog order, to ``out_image[:w]``
    (image index), ``out_catalog[:w]`` and ``out_d2[:w]``, which hold at least as many entries as there are catalog
    stars; ``claims`` (one zero per image star) is scratch."""
    n = len(xs)
    k = len(cat_x)
    r2 = radius * radius
    reach = WINDOW * radius
    m = 0
    for c in range(k):
        x = cat_x[c]
        y = cat_y[c]
        j = _first_at_least(xs, n, x - reach)
        hi = x + reach
        best = -1
        best_d2 = r2
        while j < n:
            xj = xs[j]
            if xj > hi:
                break
            yj = ys[j]
            dx = xj - x
            dy = yj - y
            d2 = dx * dx + dy * dy
            if d2 < best_d2:
                best = j
                best_d2 = d2
            j += 1
        if best >= 0:
            out_catalog[m] = c
            out_image[m] = best
            out_d2[m] = best_d2
            claims[best] += 1
            m += 1
    if not drop_blends:
        # The closest claim of each blended image star: its ``claims`` entry becomes -(1 + that claim's index).
        for i in range(m):
            j = out_image[i]
            mark = claims[j]
            if mark > 1 or (mark < 0 and out_d2[i] < out_d2[-mark - 1]):
                claims[j] = -(i + 1)
    w = 0
    for i in range(m):
        mark = claims[out_image[i]]
        if mark == 1 or mark == -(i + 1):
            out_catalog[w] = out_catalog[i]
            out_image[w] = out_image[i]
            out_d2[w] = out_d2[i]
            w += 1
    for i in range(w):
        out_image[i] = order[out_image[i]]
    return w
