"""Star extraction from a detector image: background, threshold, blobs, sub-pixel centroids.

Pixel convention (as in star_screen.geometry): (0.5, 0.5) is the centre of the top-left pixel, x to the right
(columns), y down (rows), so pixel (column i, row j) has its centre at (i + 0.5, j + 0.5).

Steps, all vectorised (no per-star Python loop):

1. background level and noise: median and MAD of a regular subsample of the image (stars cover
   well under 1 % of a star-tracker frame, so both statistics ignore them);
2. threshold at ``background + k_sigma * noise``; each star is the strict local maximum (3 x 3)
   of its above-threshold pixels with at least ``min_area`` of them above threshold, so a single
   hot noise pixel is not a star; maxima closer than the centroid window are merged (brighter kept).
   Only above-threshold pixels are visited (cheaper than labelling all components of the frame);
3. centroid: a Gaussian-weighted first moment in a window around each blob, iterated. With the
   weight's sigma ``s_w`` and the spot's effective sigma ``s_p`` (the PSF convolved with the pixel,
   ``s_p^2 = psf^2 + 1/12``), the weighted mean of a Gaussian spot centred at ``x0`` seen from a
   guess ``c`` is ``(x0 s_w^2 + c s_p^2) / (s_w^2 + s_p^2)``; we solve that for ``x0`` each
   iteration, which converges in two or three steps. The weight is close to the matched filter,
   so faint stars get near the photon-noise (Cramer-Rao) limit, and the window truncation
   bias of a plain moment is gone;
4. brightness: background-subtracted sum over the window (electrons if the image is in electrons).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["BACKGROUND_STEP", "ExtractedStars", "background_level", "extract_candidates", "extract_stars",
           "window_radius"]


@dataclass(frozen=True)
class ExtractedStars:
    """Stars found in one image, brightest first.

    ``xy`` (n, 2) centroids in pixel coordinates (x right, y down; (0.5, 0.5) centre of the
    top-left pixel); ``flux`` (n,) background-subtracted window sums in image units; ``area`` (n,)
    pixels above threshold; ``background`` and ``noise`` in image units per pixel.
    """

    xy: np.ndarray
    flux: np.ndarray
    area: np.ndarray
    background: float
    noise: float

    def __len__(self) -> int:
        return len(self.flux)


#: ``background_level`` looks at every BACKGROUND_STEP-th pixel of every BACKGROUND_STEP-th row.
BACKGROUND_STEP = 8


def background_level(image: np.ndarray, step: int = BACKGROUND_STEP) -> tuple[float, float]:
    """Background (median) and noise (1.4826 MAD) of ``image`` from every ``step``-th pixel."""
    sub = np.asarray(image[::step, ::step], dtype=np.float32).ravel()
    med = float(np.median(sub))
    mad = float(np.median(np.abs(sub - med)))
    noise = 1.4826 * mad
    if noise <= 0.0:
        # Noise-free synthetic frames (or quantised ones with sub-count noise) have a MAD of zero:
        # take a token noise level, so every pixel above the exact background level can count.
        noise = max(float(np.std(sub)) * 1e-3, 1e-6 * max(abs(med), 1.0), 1e-3)
    return med, noise


def window_radius(psf_sigma_px: float) -> int:
    """Half width (pixels) of the centroid window around a star's peak pixel."""
    s_p2 = psf_sigma_px**2 + 1.0 / 12.0
    return max(2, int(math.ceil(3.0 * math.sqrt(s_p2))))


def extract_stars(
    image: np.ndarray,
    psf_sigma_px: float = 1.0,
    *,
    k_sigma: float = 5.0,
    min_area: int = 2,
    max_stars: int | None = None,
    iterations: int = 3,
) -> ExtractedStars:
    """Find stars in a 2-D detector image (any real dtype; counts or electrons).

    ``psf_sigma_px`` is the Gaussian sigma of the spot (tracker pixels); ``k_sigma`` the detection
    threshold above the background in noise sigmas; ``max_stars`` keeps only the brightest.
    Stars whose centroid window would cross the image border are dropped (their centroid would be
    biased). Returns :class:`ExtractedStars`, brightest first.
    """
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"extract_stars takes a 2-D image; got shape {img.shape}.")
    _check_psf(psf_sigma_px)
    bg, noise = background_level(img)
    thr = bg + k_sigma * noise
    flat = img.reshape(-1)
    return extract_candidates(flat.__getitem__, np.flatnonzero(flat > thr), img.shape, bg, noise, thr, psf_sigma_px,
                              min_area=min_area, max_stars=max_stars, iterations=iterations)


def _check_psf(psf_sigma_px: float) -> None:
    if not (math.isfinite(psf_sigma_px) and psf_sigma_px > 0):
        raise ValueError(f"psf_sigma_px = {psf_sigma_px!r}; it must be a positive number of pixels.")


def extract_candidates(
    values,
    cand: np.ndarray,
    shape: tuple[int, int],
    bg: float,
    noise: float,
    thr: float,
    psf_sigma_px: float,
    *,
    min_area: int = 2,
    max_stars: int | None = None,
    iterations: int = 3,
) -> ExtractedStars:
    """Steps 2-4 of :func:`extract_stars` from its candidate pixels, for images held otherwise.

    ``values(flat_index_array)`` returns the pixel values at raster indices (any index shape);
    ``cand``: every raster index whose value exceeds ``thr``, ascending; ``bg``, ``noise``: the
    background statistics (:func:`background_level`). :func:`extract_stars` is this with
    ``values = image.ravel().__getitem__``; :class:`star_screen.tracking.exposure.SparseExposure`
    passes an image whose pixels are drawn when first read.
    """
    _check_psf(psf_sigma_px)
    h, w = shape
    empty = ExtractedStars(np.empty((0, 2)), np.empty(0), np.empty(0, np.int32), bg, noise)
    s_p2 = psf_sigma_px**2 + 1.0 / 12.0
    s_w2 = s_p2
    gain = (s_w2 + s_p2) / s_w2
    R = window_radius(psf_sigma_px)
    # Candidate pixels: above threshold and a strict local maximum of their 3 x 3 neighbourhood
    # (a tie goes to the earlier pixel in raster order), with at least ``min_area`` pixels of it above threshold. Only
    # the few above-threshold pixels are touched after the first compare, which keeps this well
    # below the cost of labelling the whole frame.
    if len(cand) == 0:
        return empty
    iy, ix = np.divmod(cand, w)
    inner = (ix >= R) & (ix < w - R) & (iy >= R) & (iy < h - R)
    cand, ix, iy = cand[inner], ix[inner], iy[inner]
    nbv = values(cand[:, None] + np.array([-w - 1, -w, -w + 1, -1, 1, w - 1, w, w + 1]))
    v = values(cand)[:, None]
    peak = np.all(v > nbv[:, :4], axis=1) & np.all(v >= nbv[:, 4:], axis=1)
    area = np.count_nonzero(nbv > thr, axis=1) + 1
    keep = peak & (area >= min_area)
    cand, ix, iy, area = cand[keep], ix[keep], iy[keep], area[keep]
    if len(cand) == 0:
        return empty
    # Two peaks closer than the window (a noisy flat top, or a pair the optics blend): keep the brighter.
    if len(cand) > 1:
        o = np.argsort(-values(cand), kind="stable")
        cand, ix, iy, area = cand[o], ix[o], iy[o], area[o]
        from scipy.spatial import cKDTree

        pairs = cKDTree(np.column_stack((ix, iy))).query_pairs(R, output_type="ndarray")
        if len(pairs):
            drop = np.zeros(len(cand), bool)
            drop[pairs.max(axis=1)] = True
            cand, ix, iy, area = cand[~drop], ix[~drop], iy[~drop], area[~drop]
    guess = np.column_stack((ix + 0.5, iy + 0.5))
    k = np.arange(-R, R + 1)
    cols = ix[:, None] + k  # (n, K)
    rows = iy[:, None] + k
    win = values(rows[:, :, None] * w + cols[:, None, :]).astype(np.float64) - bg  # (n, K, K)
    xc = cols + 0.5  # pixel-centre coordinates
    yc = rows + 0.5
    c = guess.copy()
    for _ in range(iterations):
        wx = np.exp(-0.5 * (xc - c[:, :1]) ** 2 / s_w2)
        wy = np.exp(-0.5 * (yc - c[:, 1:]) ** 2 / s_w2)
        # The weight is separable: column sums weighted by wy, row sums weighted by wx, as two
        # batched products instead of the (n, K, K) weighted window.
        col = np.matmul(wy[:, None, :], win)[:, 0, :] * wx  # sum over rows of ww
        row = np.matmul(win, wx[:, :, None])[:, :, 0] * wy  # sum over columns of ww
        s = col.sum(axis=1)
        ok = s > 0
        s = np.where(ok, s, 1.0)
        mx = (col * xc).sum(axis=1) / s
        my = (row * yc).sum(axis=1) / s
        step = np.stack((mx - c[:, 0], my - c[:, 1]), axis=-1) * gain
        # A step longer than the window means the fit wandered (blend, cosmic ray): keep the guess.
        step = np.where((ok[:, None]) & (np.abs(step) < R), step, 0.0)
        c = c + step
    flux = win.sum(axis=(1, 2))
    keep = (flux > 0) & np.all(np.abs(c - guess) < R, axis=1)
    c, flux, area = c[keep], flux[keep], area[keep]
    order = np.argsort(-flux, kind="stable")
    if max_stars is not None:
        order = order[:max_stars]
    return ExtractedStars(c[order], flux[order], area[order].astype(np.int32), bg, noise)
