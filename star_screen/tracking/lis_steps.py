"""The lost-in-space solve's decision steps on floats: which catalog stars lie in a cone, which image 4-star patterns
exist and what their keys are, and the attitude of a few matched pairs that decides which stars are matched.

Plain Python, and compiled by Cython in pure-Python mode where the install has a C compiler (``compiled_paths``
lists it; docs/fast_paths.md): the ``cython.*`` declarations give the compiled build C doubles, C integers and typed
memoryviews, and do nothing in plain Python. Both builds do the same IEEE-754 operations in the same order (setup.py
compiles without contraction and fast-math), so they return the same results to the bit.

:mod:`star_screen.tracking.identify` takes this module through
``compiled_paths.load("star_screen.tracking.lis_steps")`` and hands the compiled build numpy arrays, the plain one
lists (plain Python reads them faster); nothing else imports it directly.

What is computed here only *chooses*: the rows of a cone, the image patterns looked up and their keys, the attitude
that predicts where catalog stars fall so that they can be matched. The keys are built from the separations numpy
computed (the same arcsine as the database's), with the database's own arithmetic, so they are the same to the bit.
The attitude of a few pairs (:func:`fit_pairs`, Davenport's q-method) agrees with the SVD solution to rounding, which
moves a predicted star by about 1e-12 px: a decision it feeds would flip only for a star within that of a match
radius. The attitude, covariance and residuals a solution reports are still numpy's, from the chosen pairs.
"""

from __future__ import annotations

import math

import cython
from cython.cimports.libc.math import fabs, sqrt  # C's when compiled, Python's math otherwise: the same

#: Jacobi sweeps of :func:`fit_pairs` at most (a 4 x 4 symmetric matrix converges in five or six).
MAX_SWEEPS = 30


@cython.cfunc
@cython.locals(bounds=cython.Py_ssize_t, src=cython.Py_ssize_t, dst=cython.Py_ssize_t, r=cython.Py_ssize_t,
               merged=cython.Py_ssize_t, lo=cython.Py_ssize_t, mid=cython.Py_ssize_t, hi=cython.Py_ssize_t,
               p=cython.Py_ssize_t, q=cython.Py_ssize_t, o=cython.Py_ssize_t)
def _merge_runs(work: cython.longlong[:], cap: cython.Py_ssize_t, runs: cython.Py_ssize_t) -> cython.Py_ssize_t:
    """Merge the ``runs`` ascending runs of (row, position) pairs in ``work`` (rows at ``work[:cap]``, positions
    ``cap`` later, run ``r`` from ``work[4 cap + r]`` to ``work[4 cap + r + 1]``) by row, neighbours pairwise until
    one run is left; the merged rows end at ``work[src:]``, positions ``cap`` later: returns ``src`` (0 or
    ``2 cap``)."""
    bounds = 4 * cap
    src = 0
    dst = 2 * cap
    while runs > 1:
        merged = 0
        for r in range(0, runs, 2):
            lo = work[bounds + r]
            mid = work[bounds + r + 1]
            hi = work[bounds + r + 2] if r + 2 <= runs else mid
            p = lo
            q = mid
            o = lo
            while p < mid or q < hi:
                if q >= hi or (p < mid and work[src + p] < work[src + q]):
                    work[dst + o] = work[src + p]
                    work[dst + cap + o] = work[src + cap + p]
                    p += 1
                else:
                    work[dst + o] = work[src + q]
                    work[dst + cap + o] = work[src + cap + q]
                    q += 1
                o += 1
            merged += 1
            work[bounds + merged] = hi
        runs = merged
        src, dst = dst, src
    return src


@cython.locals(cap=cython.Py_ssize_t, cells=cython.Py_ssize_t, c=cython.Py_ssize_t, i=cython.Py_ssize_t,
               m=cython.Py_ssize_t, runs=cython.Py_ssize_t, d=cython.double, dx=cython.double, dy=cython.double,
               dz=cython.double, reach=cython.double, bounds=cython.Py_ssize_t, src=cython.Py_ssize_t,
               w=cython.Py_ssize_t, k=cython.Py_ssize_t, ux=cython.double, uy=cython.double,
               uz=cython.double, on=cython.bint, x=cython.double, y=cython.double)
def cone_sorted(cell_xyz: cython.double[:], cell_cos: cython.double[:], cell_sin: cython.double[:],
                starts: cython.longlong[:], star_xyz: cython.double[:], star_row: cython.longlong[:],
                bx: cython.double, by: cython.double, bz: cython.double, cos_cone: cython.double,
                sin_cone: cython.double, chord2: cython.double, project: cython.bint, kc: cython.double[:],
                margin: cython.double, width: cython.double, height: cython.double, cap: cython.Py_ssize_t,
                work: cython.longlong[:], out_rows: cython.longlong[:], out_u: cython.double[:],
                out_x: cython.double[:], out_y: cython.double[:]) -> cython.Py_ssize_t:
    """The stars whose squared chord ``|u - b|^2`` from the boresight ``b`` is at most ``chord2``, in ascending row:
    their rows in ``out_rows[:w]`` and directions in ``out_u[3w]`` (flat x, y, z); returns ``w``. With ``project``,
    only those the pinhole camera ``kc`` (the camera matrix times the attitude, flat row-major) puts on the ``width``
    x ``height`` detector grown by ``margin`` px are kept (the rule of :func:`project_pinhole`), their pixels in
    ``out_x``, ``out_y``. At most ``cap`` stars fit the buffers: a cone that holds more writes nothing and returns
    minus its number of stars (call again with buffers that large).

    The stars are bucketed in cells (``starts[c]:starts[c + 1]`` of ``star_xyz`` and ``star_row``, rows ascending
    within a cell); cell ``c`` has centre ``cell_xyz[3c:3c + 3]`` and angular radius ``rho`` with ``cell_cos[c] =
    cos(rho)``, ``cell_sin[c] = sin(rho)``. A cell is read when the cone (``cos_cone``, ``sin_cone`` of its half-angle)
    can reach it: ``cos(angle(b, centre)) >= cos(cone + rho)``, with a margin of 1e-9 so rounding never skips one.
    Each cell's stars in the cone are a run of ascending rows, and the runs are merged pairwise (a natural merge sort),
    so the order is the catalog's, as the matching's ties and the estimate's sums need. ``work`` holds ``4 cap +
    cells + 1`` integers (rows and positions twice, and the runs' bounds)."""
    cells = len(cell_cos)
    bounds = 4 * cap
    work[bounds] = 0
    m = 0
    runs = 0
    for c in range(cells):
        d = cell_xyz[3 * c] * bx + cell_xyz[3 * c + 1] * by + cell_xyz[3 * c + 2] * bz
        # cos(cone + rho), or -1 when cone + rho reaches past the antipode (sin(cone + rho) < 0).
        if sin_cone * cell_cos[c] + cos_cone * cell_sin[c] < 0.0:
            reach = -1.0
        else:
            reach = cos_cone * cell_cos[c] - sin_cone * cell_sin[c]
        if d < reach - 1e-9:
            continue
        for i in range(starts[c], starts[c + 1]):
            dx = star_xyz[3 * i] - bx
            dy = star_xyz[3 * i + 1] - by
            dz = star_xyz[3 * i + 2] - bz
            if dx * dx + dy * dy + dz * dz <= chord2:
                if m < cap:
                    work[m] = star_row[i]
                    work[cap + m] = i
                m += 1
        if m > work[bounds + runs] and m <= cap:
            runs += 1
            work[bounds + runs] = m
    if m > cap:
        return -m
    src = _merge_runs(work, cap, runs)
    w = 0
    for k in range(m):
        i = work[src + cap + k]
        ux = star_xyz[3 * i]
        uy = star_xyz[3 * i + 1]
        uz = star_xyz[3 * i + 2]
        if project:
            on, x, y = _pixel(kc[0], kc[1], kc[2], kc[3], kc[4], kc[5], kc[6], kc[7], kc[8], ux, uy, uz, margin, width,
                              height)
            if not on:
                continue
            out_x[w] = x
            out_y[w] = y
        out_rows[w] = work[src + k]
        out_u[3 * w] = ux
        out_u[3 * w + 1] = uy
        out_u[3 * w + 2] = uz
        w += 1
    return w


@cython.locals(total=cython.Py_ssize_t, p=cython.Py_ssize_t, w=cython.Py_ssize_t, k=cython.Py_ssize_t,
               j=cython.Py_ssize_t, t=cython.Py_ssize_t, i0=cython.Py_ssize_t, i1=cython.Py_ssize_t,
               i2=cython.Py_ssize_t, i3=cython.Py_ssize_t, cx=cython.double, cy=cython.double, cz=cython.double,
               norm=cython.double, ex=cython.double, ey=cython.double, ez=cython.double, dk=cython.double,
               e=cython.double, largest=cython.double, ik=cython.longlong)
def pattern_keys(n: cython.Py_ssize_t, quads: cython.longlong[:], start: cython.Py_ssize_t, fits: cython.uchar[:],
                 sep: cython.double[:], u: cython.double[:], count: cython.Py_ssize_t, out_quad: cython.longlong[:],
                 out_key: cython.double[:], out_largest: cython.double[:], scratch: cython.double[:],
                 cursor: cython.longlong[:]) -> cython.Py_ssize_t:
    """The next ``count`` image 4-star patterns from position ``start`` of ``quads`` (flat, four star indices each,
    brightest combinations first) whose six pairs all fit (``fits[i * n + j]`` nonzero); returns how many it found.

    Per pattern: its stars in canonical order (by distance from the normalised centroid of the directions ``u``, flat
    x, y, z; stable, as numpy's argsort) in ``out_quad[4w:4w + 4]``, the key (the six separations ``sep[i * n + j]``
    sorted, the five smaller over the largest) in ``out_key[5w:5w + 5]`` and the largest separation in
    ``out_largest[w]``: the arithmetic of ``identify._canonical`` and ``identify._keys_of_edges``, so the same bits.
    ``cursor[0]`` is set to the position after the last pattern looked at; ``scratch`` holds ten doubles."""
    total = len(quads) // 4
    w = 0
    p = start
    while p < total and w < count:
        i0 = quads[4 * p]
        i1 = quads[4 * p + 1]
        i2 = quads[4 * p + 2]
        i3 = quads[4 * p + 3]
        p += 1
        if not (fits[i0 * n + i1] and fits[i0 * n + i2] and fits[i0 * n + i3] and fits[i1 * n + i2]
                and fits[i1 * n + i3] and fits[i2 * n + i3]):
            continue
        # The centroid's direction, summed in pattern order and normalised (as _canonical).
        cx = u[3 * i0] + u[3 * i1] + u[3 * i2] + u[3 * i3]
        cy = u[3 * i0 + 1] + u[3 * i1 + 1] + u[3 * i2 + 1] + u[3 * i3 + 1]
        cz = u[3 * i0 + 2] + u[3 * i1 + 2] + u[3 * i2 + 2] + u[3 * i3 + 2]
        norm = sqrt(cx * cx + cy * cy + cz * cz)
        cx = cx / norm
        cy = cy / norm
        cz = cz / norm
        # Distances from it, and a stable insertion sort of the four (ties keep pattern order).
        for k in range(4):
            ik = quads[4 * (p - 1) + k]
            ex = u[3 * ik] - cx
            ey = u[3 * ik + 1] - cy
            ez = u[3 * ik + 2] - cz
            dk = sqrt(ex * ex + ey * ey + ez * ez)
            j = k
            while j > 0 and scratch[j - 1] > dk:
                scratch[j] = scratch[j - 1]
                out_quad[4 * w + j] = out_quad[4 * w + j - 1]
                j -= 1
            scratch[j] = dk
            out_quad[4 * w + j] = ik
        # The six separations in pair order (01 02 03 12 13 23 of the canonical order), sorted ascending.
        i0 = out_quad[4 * w]
        i1 = out_quad[4 * w + 1]
        i2 = out_quad[4 * w + 2]
        i3 = out_quad[4 * w + 3]
        scratch[4] = sep[i0 * n + i1]
        scratch[5] = sep[i0 * n + i2]
        scratch[6] = sep[i0 * n + i3]
        scratch[7] = sep[i1 * n + i2]
        scratch[8] = sep[i1 * n + i3]
        scratch[9] = sep[i2 * n + i3]
        for k in range(5, 10):
            e = scratch[k]
            j = k
            while j > 4 and scratch[j - 1] > e:
                scratch[j] = scratch[j - 1]
                j -= 1
            scratch[j] = e
        largest = scratch[9]
        for t in range(5):
            out_key[5 * w + t] = scratch[4 + t] / largest
        out_largest[w] = largest
        w += 1
    cursor[0] = p
    return w


@cython.cfunc
@cython.locals(_sweep=cython.int, p=cython.int, q=cython.int, k=cython.int, off=cython.double, scale=cython.double,
               apq=cython.double, theta=cython.double, t=cython.double, c=cython.double, s=cython.double,
               x=cython.double, y=cython.double)
def _jacobi4(a: cython.double[:]) -> cython.void:
    """Eigen-decomposition of the symmetric 4 x 4 ``a[:16]`` (flat, row-major) by cyclic Jacobi rotations: it ends
    diagonal (the eigenvalues), and ``a[16:32]`` (set to the identity here) holds the eigenvectors in its columns.
    One buffer, not two slices: a slice of a list is a copy."""
    for k in range(16):
        a[16 + k] = 1.0 if k % 5 == 0 else 0.0
    scale = fabs(a[0]) + fabs(a[5]) + fabs(a[10]) + fabs(a[15])
    for _sweep in range(MAX_SWEEPS):
        off = fabs(a[1]) + fabs(a[2]) + fabs(a[3]) + fabs(a[6]) + fabs(a[7]) + fabs(a[11])
        if off <= 1e-30 * scale or off == 0.0:
            break
        for p in range(3):
            for q in range(p + 1, 4):
                apq = a[4 * p + q]
                if apq == 0.0:
                    continue
                theta = (a[4 * q + q] - a[4 * p + p]) / (2.0 * apq)
                t = 1.0 / (fabs(theta) + sqrt(theta * theta + 1.0))
                if theta < 0.0:
                    t = -t
                c = 1.0 / sqrt(t * t + 1.0)
                s = t * c
                for k in range(4):  # columns p, q: a J
                    x = a[4 * k + p]
                    y = a[4 * k + q]
                    a[4 * k + p] = c * x - s * y
                    a[4 * k + q] = s * x + c * y
                for k in range(4):  # rows p, q: J^T (a J)
                    x = a[4 * p + k]
                    y = a[4 * q + k]
                    a[4 * p + k] = c * x - s * y
                    a[4 * q + k] = s * x + c * y
                for k in range(4):
                    x = a[16 + 4 * k + p]
                    y = a[16 + 4 * k + q]
                    a[16 + 4 * k + p] = c * x - s * y
                    a[16 + 4 * k + q] = s * x + c * y


@cython.locals(m=cython.Py_ssize_t, i=cython.Py_ssize_t, k=cython.int, best=cython.int, w=cython.double,
               b0=cython.double, b1=cython.double, b2=cython.double, r0=cython.double, r1=cython.double,
               r2=cython.double, B00=cython.double, B01=cython.double, B02=cython.double, B10=cython.double,
               B11=cython.double, B12=cython.double, B20=cython.double, B21=cython.double, B22=cython.double,
               tr=cython.double, q1=cython.double, q2=cython.double, q3=cython.double, q4=cython.double,
               norm=cython.double, ex=cython.double, ey=cython.double, ez=cython.double, e2=cython.double,
               worst=cython.double)
def fit_pairs(b: cython.double[:], r: cython.double[:], weight: cython.double[:], unit_weights: cython.bint,
              out_dcm: cython.double[:], scratch: cython.double[:]) -> cython.double:
    """``dcm_SN`` (flat, row-major, in ``out_dcm``) minimising ``sum_i w_i |b_i - dcm r_i|^2`` over the pairs ``b``,
    ``r`` (flat x, y, z each; weights ``weight``, or all one with ``unit_weights``), by Davenport's q-method (the
    largest eigenvector of the 4 x 4 K matrix, Jacobi rotations): always a proper rotation, the SVD solution's to
    rounding. Returns the largest residual ``max |b_i - dcm r_i|``. ``scratch`` holds 32 doubles."""
    m = len(b) // 3
    B00 = B01 = B02 = B10 = B11 = B12 = B20 = B21 = B22 = 0.0
    for i in range(m):
        w = 1.0 if unit_weights else weight[i]
        b0 = w * b[3 * i]
        b1 = w * b[3 * i + 1]
        b2 = w * b[3 * i + 2]
        r0 = r[3 * i]
        r1 = r[3 * i + 1]
        r2 = r[3 * i + 2]
        B00 += b0 * r0
        B01 += b0 * r1
        B02 += b0 * r2
        B10 += b1 * r0
        B11 += b1 * r1
        B12 += b1 * r2
        B20 += b2 * r0
        B21 += b2 * r1
        B22 += b2 * r2
    # K = [[S - tr I, z], [z^T, tr]], S = B + B^T, z = (B12 - B21, B20 - B02, B01 - B10) (Markley and Crassidis).
    tr = B00 + B11 + B22
    scratch[0] = 2.0 * B00 - tr
    scratch[1] = scratch[4] = B01 + B10
    scratch[2] = scratch[8] = B02 + B20
    scratch[3] = scratch[12] = B12 - B21
    scratch[5] = 2.0 * B11 - tr
    scratch[6] = scratch[9] = B12 + B21
    scratch[7] = scratch[13] = B20 - B02
    scratch[10] = 2.0 * B22 - tr
    scratch[11] = scratch[14] = B01 - B10
    scratch[15] = tr
    _jacobi4(scratch)
    best = 0
    for k in range(1, 4):
        if scratch[5 * k] > scratch[5 * best]:
            best = k
    q1 = scratch[16 + best]
    q2 = scratch[20 + best]
    q3 = scratch[24 + best]
    q4 = scratch[28 + best]
    norm = sqrt(q1 * q1 + q2 * q2 + q3 * q3 + q4 * q4)
    q1 = q1 / norm
    q2 = q2 / norm
    q3 = q3 / norm
    q4 = q4 / norm
    # The attitude matrix of q = (q1, q2, q3, q4) (vector first): b = A r.
    out_dcm[0] = q1 * q1 - q2 * q2 - q3 * q3 + q4 * q4
    out_dcm[1] = 2.0 * (q1 * q2 + q3 * q4)
    out_dcm[2] = 2.0 * (q1 * q3 - q2 * q4)
    out_dcm[3] = 2.0 * (q1 * q2 - q3 * q4)
    out_dcm[4] = -q1 * q1 + q2 * q2 - q3 * q3 + q4 * q4
    out_dcm[5] = 2.0 * (q2 * q3 + q1 * q4)
    out_dcm[6] = 2.0 * (q1 * q3 + q2 * q4)
    out_dcm[7] = 2.0 * (q2 * q3 - q1 * q4)
    out_dcm[8] = -q1 * q1 - q2 * q2 + q3 * q3 + q4 * q4
    worst = 0.0
    for i in range(m):
        r0 = r[3 * i]
        r1 = r[3 * i + 1]
        r2 = r[3 * i + 2]
        ex = b[3 * i] - (out_dcm[0] * r0 + out_dcm[1] * r1 + out_dcm[2] * r2)
        ey = b[3 * i + 1] - (out_dcm[3] * r0 + out_dcm[4] * r1 + out_dcm[5] * r2)
        ez = b[3 * i + 2] - (out_dcm[6] * r0 + out_dcm[7] * r1 + out_dcm[8] * r2)
        e2 = ex * ex + ey * ey + ez * ez
        if e2 > worst:
            worst = e2
    return sqrt(worst)


@cython.cfunc
@cython.inline
@cython.locals(z=cython.double, hx=cython.double, hy=cython.double, iz=cython.double, x=cython.double,
               y=cython.double)
def _pixel(k0: cython.double, k1: cython.double, k2: cython.double, k3: cython.double, k4: cython.double,
           k5: cython.double, k6: cython.double, k7: cython.double, k8: cython.double, ux: cython.double,
           uy: cython.double, uz: cython.double, margin: cython.double, width: cython.double,
           height: cython.double) -> tuple[cython.bint, cython.double, cython.double]:
    """(on the detector, x, y) of the direction ``u`` through the pinhole camera ``k`` (the camera matrix times the
    attitude, row-major): homogeneous ``h = k u``, pixel ``(h_x / h_z, h_y / h_z)`` for ``h_z > 1e-9``, on the
    ``width`` x ``height`` detector grown by ``margin`` px. The nine elements come as C doubles, not a buffer: this
    is called once a star."""
    z = k6 * ux + k7 * uy + k8 * uz
    if not z > 1e-9:
        return False, 0.0, 0.0
    hx = k0 * ux + k1 * uy + k2 * uz
    hy = k3 * ux + k4 * uy + k5 * uz
    iz = 1.0 / z
    x = hx * iz
    y = hy * iz
    return (x >= -margin and x < width + margin and y >= -margin and y < height + margin), x, y


@cython.locals(m=cython.Py_ssize_t, i=cython.Py_ssize_t, w=cython.Py_ssize_t, on=cython.bint, x=cython.double,
               y=cython.double)
def project_pinhole(u: cython.double[:], kc: cython.double[:], margin: cython.double, width: cython.double,
                    height: cython.double, limit: cython.Py_ssize_t, out_keep: cython.longlong[:],
                    out_x: cython.double[:], out_y: cython.double[:]) -> cython.Py_ssize_t:
    """Pixels of the directions ``u`` (flat x, y, z) through the pinhole camera ``kc`` (:func:`_pixel`). The first
    ``limit`` directions (in order) that land on the ``width`` x ``height`` detector grown by ``margin`` px are
    written as (index into ``u``, x, y) to ``out_keep``, ``out_x``, ``out_y``; returns how many."""
    m = len(u) // 3
    w = 0
    for i in range(m):
        if w >= limit:
            break
        on, x, y = _pixel(kc[0], kc[1], kc[2], kc[3], kc[4], kc[5], kc[6], kc[7], kc[8], u[3 * i], u[3 * i + 1],
                          u[3 * i + 2], margin, width, height)
        if on:
            out_keep[w] = i
            out_x[w] = x
            out_y[w] = y
            w += 1
    return w


@cython.locals(m=cython.Py_ssize_t, t=cython.Py_ssize_t, c=cython.Py_ssize_t, i=cython.longlong,
               j=cython.longlong, s=cython.double, a=cython.double, at_r=cython.Py_ssize_t, at_a=cython.Py_ssize_t,
               at_ba=cython.Py_ssize_t)
def gather_pairs(b: cython.double[:], r: cython.double[:], sigma: cython.double[:], image: cython.longlong[:],
                 catalog: cython.longlong[:], at_r: cython.Py_ssize_t, at_a: cython.Py_ssize_t,
                 at_ba: cython.Py_ssize_t, out: cython.double[:]) -> cython.void:
    """The final estimate's inputs for the pairs ``t`` of image star ``image[t]`` and catalog entry ``catalog[t]``,
    in ``out``: the image directions ``b[image]`` (flat x, y, z; ``b`` likewise) from 0, the catalog directions
    ``r[catalog]`` from ``at_r``, the weights ``a = 1 / sigma[image]^2`` from ``at_a`` and ``b[image] * a`` from
    ``at_ba``: the bits of numpy's ``1.0 / sigma ** 2`` (a square, then a division) and ``b * a[:, None]``, with one
    call instead of seven."""
    m = len(image)
    for t in range(m):
        i = image[t]
        j = catalog[t]
        s = sigma[i] * sigma[i]
        # numpy's 1 / 0 is inf; Python's (and Cython's with Python division) would raise.
        a = 1.0 / s if s != 0.0 else math.inf
        out[at_a + t] = a
        for c in range(3):
            out[3 * t + c] = b[3 * i + c]
            out[at_r + 3 * t + c] = r[3 * j + c]
            out[at_ba + 3 * t + c] = b[3 * i + c] * a


#: The key components the lookup grid is cut along (of the five; the three that spread the patterns best) and its
#: cell width: a query box of +-0.01 spans at most two cells a component.
GRID_COMPONENTS = (0, 1, 3)
GRID_CELL = 0.02
GRID_SIZE = 50


@cython.locals(a0=cython.Py_ssize_t, a1=cython.Py_ssize_t, b0=cython.Py_ssize_t, b1=cython.Py_ssize_t,
               c0=cython.Py_ssize_t, c1=cython.Py_ssize_t, a=cython.Py_ssize_t, b=cython.Py_ssize_t,
               c=cython.Py_ssize_t, cell=cython.Py_ssize_t, i=cython.Py_ssize_t, t=cython.Py_ssize_t,
               j=cython.Py_ssize_t, total=cython.Py_ssize_t, w=cython.Py_ssize_t, ok=cython.bint,
               p=cython.longlong, le=cython.double)
def lookup_key(key: cython.double[:], tolerance: cython.double, starts: cython.longlong[:],
               grid_keys: cython.double[:], grid_pattern: cython.longlong[:], grid_largest: cython.double[:],
               largest: cython.double, edge_tolerance: cython.double, cap: cython.Py_ssize_t,
               out: cython.longlong[:]) -> cython.Py_ssize_t:
    """The patterns whose key lies within ``tolerance`` of ``key`` in every component (``|k_i - q_i| <= tolerance``,
    the max-norm ball of a k-d tree query) and whose largest separation agrees, ``|L_p - largest| <= edge_tolerance
    * largest``; returns how many there are, and writes the ``cap`` smallest pattern indices among them, ascending,
    to ``out``.

    The patterns are bucketed on a grid over key components :data:`GRID_COMPONENTS` (cells of :data:`GRID_CELL`,
    ``GRID_SIZE`` a component): cell ``(a, b, c)`` holds ``grid_pattern[starts[s]:starts[s + 1]]``, ``s = (a G + b) G +
    c``, with their keys (five each, flat) in ``grid_keys`` and largest separations in ``grid_largest``. A query reads
    the cells its box reaches (with a margin of 1e-9, so rounding never skips one) and checks every pattern in them."""
    a0, a1 = _cell_span(key[0], tolerance)
    b0, b1 = _cell_span(key[1], tolerance)
    c0, c1 = _cell_span(key[3], tolerance)
    total = 0
    for a in range(a0, a1 + 1):
        for b in range(b0, b1 + 1):
            cell = (a * GRID_SIZE + b) * GRID_SIZE
            for i in range(starts[cell + c0], starts[cell + c1 + 1]):
                ok = True
                for t in range(5):
                    if not fabs(grid_keys[5 * i + t] - key[t]) <= tolerance:
                        ok = False
                        break
                if not ok:
                    continue
                le = grid_largest[i]
                if not fabs(le - largest) <= edge_tolerance * largest:
                    continue
                # Keep the cap smallest indices, ascending (an insertion: hits are few).
                p = grid_pattern[i]
                w = total if total < cap else cap
                total += 1
                if w == cap and (cap == 0 or out[cap - 1] < p):
                    continue
                j = w if w < cap else cap - 1
                while j > 0 and out[j - 1] > p:
                    out[j] = out[j - 1]
                    j -= 1
                out[j] = p
    return total


@cython.cfunc
@cython.inline
@cython.locals(lo=cython.double, hi=cython.double, first=cython.Py_ssize_t, last=cython.Py_ssize_t)
def _cell_span(value: cython.double, tolerance: cython.double) -> tuple[cython.Py_ssize_t, cython.Py_ssize_t]:
    """The first and last grid cell (of a component) that ``value -+ tolerance`` reaches, with a margin of 1e-9."""
    lo = (value - tolerance - 1e-9) / GRID_CELL
    hi = (value + tolerance + 1e-9) / GRID_CELL
    first = 0 if not lo > 0.0 else (GRID_SIZE - 1 if lo >= GRID_SIZE - 1 else int(lo))
    last = 0 if not hi > 0.0 else (GRID_SIZE - 1 if hi >= GRID_SIZE - 1 else int(hi))
    return first, last
