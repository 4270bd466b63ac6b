"""Measurements on rendered frames: emitted-light centroids and fluxes, isolation, reference WCS.

Used by the tests and by ``stand bench render``. The reference projection
(:func:`reference_tan_pixels`) is independent of the renderer's vector/DCM path: it uses
astropy's WCS TAN projection when astropy is installed and otherwise the textbook spherical
trigonometry of the gnomonic projection (standard coordinates xi, eta).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["emitted_centroids", "isolated", "tan_wcs_params", "reference_tan_pixels"]


def emitted_centroids(image_codes: np.ndarray, response: np.ndarray, xy, radius):
    """Centroid (n, 2) and summed luminance (n,) of the emitted light in a (2 radius + 1)^2 window
    around each position ``xy`` (pixel coordinates; (0.5, 0.5) is the centre of pixel (0, 0)).
    ``radius`` is a whole number of pixels, scalar or per position. Windows crossing the image
    border give NaN."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    radius = np.broadcast_to(np.asarray(radius, int), (len(xy),))
    c = np.full((len(xy), 2), np.nan)
    flux = np.full(len(xy), np.nan)
    for R in np.unique(radius):
        sel = np.flatnonzero(radius == R)
        c[sel], flux[sel] = _window_moments(image_codes, response, xy[sel], int(R))
    return c, flux


def _window_moments(image_codes, response, xy, radius):
    h, w = image_codes.shape
    lum = np.asarray(response, float)
    ix = np.floor(xy[:, 0]).astype(int)
    iy = np.floor(xy[:, 1]).astype(int)
    k = np.arange(-radius, radius + 1)
    cols = ix[:, None] + k
    rows = iy[:, None] + k
    inside = (cols.min(1) >= 0) & (cols.max(1) < w) & (rows.min(1) >= 0) & (rows.max(1) < h)
    cols = np.clip(cols, 0, w - 1)
    rows = np.clip(rows, 0, h - 1)
    win = lum[image_codes[rows[:, :, None], cols[:, None, :]]]  # (n, K, K)
    flux = win.sum(axis=(1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        cx = (win.sum(axis=1) * (cols + 0.5)).sum(axis=1) / flux
        cy = (win.sum(axis=2) * (rows + 0.5)).sum(axis=1) / flux
    c = np.stack((cx, cy), axis=-1)
    c[~inside] = np.nan
    flux = np.where(inside, flux, np.nan)
    return c, flux


def isolated(xy, radius, gap: float = 3.0) -> np.ndarray:
    """Mask of points whose window of ``radius`` (scalar or per point, px) keeps ``gap`` px away from
    every other point's window: ``|p_i - p_j| >= r_i + r_j + gap`` for all j."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    r = np.broadcast_to(np.asarray(radius, float), (len(xy),))
    ok = np.ones(len(xy), bool)
    if len(xy) < 2:
        return ok
    pairs = cKDTree(xy).query_pairs(2 * float(r.max()) + gap, output_type="ndarray")
    if len(pairs):
        d = np.linalg.norm(xy[pairs[:, 0]] - xy[pairs[:, 1]], axis=1)
        close = pairs[d < r[pairs[:, 0]] + r[pairs[:, 1]] + gap]
        ok[close.ravel()] = False
    return ok


def tan_wcs_params(ra_deg, dec_deg, roll_deg, fx, fy, cx, cy):
    """FITS WCS keywords of a TAN projection for the pointing convention of
    :mod:`star_screen.attitude` and pixels ``u = cx + fx X``, ``v = cy + fy Y`` (0.5-centred):
    ``[u - cx, v - cy] = -F M(roll) [xi, eta]``  =>  ``CD = -(180/pi) M^T F^-1``, CRPIX = c + 0.5."""
    r = math.radians(roll_deg)
    M = np.array([[math.cos(r), math.sin(r)], [-math.sin(r), math.cos(r)]])
    cd = -(180.0 / math.pi) * M.T @ np.diag([1.0 / fx, 1.0 / fy])
    return {"crval": (float(ra_deg), float(dec_deg)), "crpix": (cx + 0.5, cy + 0.5), "cd": cd}


def reference_tan_pixels(
    ra_deg, dec_deg, star_ra_deg, star_dec_deg, roll_deg, fx, fy, cx, cy, use_astropy: bool | None = None
):
    """Pixel positions of stars by an independent TAN projection; returns (xy (n, 2), name of the method)."""
    p = tan_wcs_params(ra_deg, dec_deg, roll_deg, fx, fy, cx, cy)
    sra = np.asarray(star_ra_deg, float)
    sdec = np.asarray(star_dec_deg, float)
    if use_astropy is not False:
        try:
            from astropy.wcs import WCS
        except ImportError:
            if use_astropy:
                raise
        else:
            w = WCS(naxis=2)
            w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
            w.wcs.crval = list(p["crval"])
            w.wcs.crpix = list(p["crpix"])
            w.wcs.cd = p["cd"]
            # LONPOLE = 180 always (the FITS default except exactly at dec = +90, where the default
            # 0 would flip the image by 180 deg relative to the limit approaching the pole).
            w.wcs.lonpole = 180.0
            px = np.stack(w.all_world2pix(sra, sdec, 1), axis=-1)
            return px - 0.5, "astropy WCS TAN"
    # Gnomonic standard coordinates (spherical trigonometry).
    a0, d0 = math.radians(ra_deg), math.radians(dec_deg)
    a, d = np.radians(sra), np.radians(sdec)
    cosc = math.sin(d0) * np.sin(d) + math.cos(d0) * np.cos(d) * np.cos(a - a0)
    xi = np.cos(d) * np.sin(a - a0) / cosc
    eta = (math.cos(d0) * np.sin(d) - math.sin(d0) * np.cos(d) * np.cos(a - a0)) / cosc
    cdinv = np.linalg.inv(p["cd"]) * (180.0 / math.pi)
    pix = np.stack((xi, eta), axis=-1) @ cdinv.T
    return pix + np.array([cx, cy]), "gnomonic standard coordinates"
