"""What a tracker's detector collects from a screen seen through a collimator.

The renderer draws stars on the screen (drive codes) for a bench it believes in; a real tracker
in front of the real collimator sees that screen through the *physical* geometry, which may
differ (a collimator with its own distortion, an axis a few pixels off). :func:`screen_to_detector`
is that optical path as a pure function, so an emulated tracker can look at the screen and the
optical chain is tested end to end:

1. the panel turns each lit pixel's 8-bit drive code into relative luminance through its response
   (gamma or measured table): the quantisation of the panel stays in the signal;
2. each lit pixel, a square of ``pitch`` on the panel, is seen through the collimator in the
   direction :meth:`Bench.screen_to_direction` gives for its centre (collimator distortion, axis,
   fold mirrors of the physical bench) and lands on the detector where the tracker optics project
   that direction (the tracker's own distortion);
3. the tracker is focused at infinity but slightly defocused, as star trackers are: each pixel's
   light spreads as a Gaussian of ``defocus_sigma_px`` detector pixels, widened by the variance of
   the pixel's own square footprint (``(w / 12)`` with ``w`` its width in detector pixels), and is
   integrated exactly over detector pixels;
4. ``e_per_luminance_px`` converts luminance summed over screen pixels into electrons for one
   exposure (aperture, exposure time, panel brightness and quantum efficiency together). With
   :func:`matched_gain` a star the renderer drew unclipped yields the electrons the renderer's own
   ideal detector gives it.

Only lit pixels are mapped (a star field lights a few thousand pixels of two million), so the
cost grows with the stars, not the panel. The result is noise-free (electrons, float32); camera
noise is :func:`star_screen.tracking.noise.camera_noise`. The panel's pixel grid, its 8-bit steps
and the spot shapes it can draw are what separate this image from the renderer's ideal detector.
"""

from __future__ import annotations

import math

import numpy as np

from star_screen.geometry import Bench
from star_screen.render import Photometry, splat_gaussians

__all__ = ["screen_to_detector", "matched_gain"]


def matched_gain(flux_full: float, flux_mag0_e: float, photometry: Photometry | None = None) -> float:
    """Electrons per unit of luminance summed over screen pixels that make a star drawn unclipped by a
    renderer (``Renderer.flux_full``, its photometry) give the detector the signal of the same star seen
    directly (``TrackerOptics.flux_mag0_e``): the radiometric calibration of an ideal bench."""
    ph = photometry if photometry is not None else Photometry()
    if not (flux_full > 0 and flux_mag0_e > 0):
        raise ValueError(f"flux_full = {flux_full!r}, flux_mag0_e = {flux_mag0_e!r}; both must be positive.")
    return float(flux_mag0_e * 10.0 ** (-0.4 * ph.mag_full) / flux_full)


def screen_to_detector(
    screen_codes: np.ndarray,
    bench: Bench,
    *,
    e_per_luminance_px: float,
    defocus_sigma_px: float = 0.8,
    truncate_sigmas: float = 4.0,
) -> np.ndarray:
    """The noise-free detector image (float32 electrons, ``(height, width)`` of ``bench.tracker``) that the
    tracker of the physical ``bench`` collects from a screen showing ``screen_codes`` (uint8 drive codes,
    ``(height, width)`` of ``bench.screen``)."""
    codes = np.asarray(screen_codes)
    s, t = bench.screen, bench.tracker
    if codes.shape != (s.height, s.width):
        raise ValueError(f"screen image shape {codes.shape} does not match the bench's screen ({s.height} rows x "
                         f"{s.width} columns).")
    if codes.dtype != np.uint8:
        raise ValueError(f"screen image dtype {codes.dtype}; a panel shows 8-bit drive codes (uint8).")
    if not (math.isfinite(e_per_luminance_px) and e_per_luminance_px > 0):
        raise ValueError(f"e_per_luminance_px = {e_per_luminance_px!r}; it must be a positive number of electrons.")
    if not (math.isfinite(defocus_sigma_px) and 0.0 <= defocus_sigma_px <= 10.0):
        raise ValueError(f"defocus_sigma_px = {defocus_sigma_px!r}; allowed 0 to 10 detector pixels.")
    out = np.zeros((t.height, t.width), np.float32)
    flat = codes.reshape(-1)
    lit = np.flatnonzero(flat)
    if lit.size == 0:
        return out
    lum = s.response()[flat[lit]]
    rows, cols = np.divmod(lit, s.width)
    centre = np.stack((cols + 0.5, rows + 0.5), axis=-1)
    det, front = t.project(bench.screen_to_direction(centre))
    # A screen pixel is a uniform square w detector pixels wide: its footprint adds w^2/12 of variance per axis
    # (the Gaussian of equal variance keeps centroids exact, which is what a tracker measures).
    w = 1.0 / bench.screen_px_per_tracker_px
    sigma = math.sqrt(defocus_sigma_px**2 + w * w / 12.0)
    ok = front & np.isfinite(det).all(axis=-1)
    idx, val, _ = splat_gaussians(det[ok, 0], det[ok, 1], lum[ok] * e_per_luminance_px, sigma, t.width, t.height,
                                  truncate_sigmas)
    # bincount sums repeated indices an order of magnitude faster than np.add.at.
    return np.bincount(idx, weights=val, minlength=out.size).astype(np.float32).reshape(out.shape)
