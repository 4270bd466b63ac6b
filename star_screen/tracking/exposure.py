"""A noisy detector exposure drawn only where star extraction looks, for an emulated tracker.

:func:`~star_screen.tracking.noise.camera_noise` draws every pixel of the frame, about 0.8 million
Gaussian deviates for the default tracker, and almost none of them changes what
:func:`~star_screen.tracking.extract.extract_stars` returns: the extractor reads the background
grid (every 8th pixel of every 8th row), the pixels above its threshold (about 5 sigma), their 3 x 3
neighbours and the centroid windows around the peaks. :class:`SparseExposure` draws those and
nothing else, and its stars have exactly the distribution the dense pipeline's have (not the same
numbers: a different sequence of draws):

1. lit pixels (signal > 0): background + read noise (one Gaussian, as ``camera_noise``) plus an
   exact Poisson draw of the signal;
2. unlit pixels of the background grid: the same Gaussian. From the grid the threshold follows
   (:func:`~star_screen.tracking.extract.background_level`, as the extractor computes it);
3. every other pixel is pure background, independent and identically distributed. Whether it
   lies above a level ``L`` just below the threshold is a Bernoulli trial of known probability
   ``q``, so the pixels above ``L`` are a Binomial number of pixels, uniformly placed, with values
   from the Gaussian's tail beyond ``L``; they are drawn now (a fraction of one per frame at 5 sigma);
4. the rest are below ``L``: their values are drawn, from the Gaussian truncated at ``L``, only
   when the extractor first reads one (a neighbour or window pixel of a candidate). Where it never
   reads, nothing is drawn: there the extractor only needs to know a pixel is below the threshold.

The candidates (pixels above the threshold) are then all among the pixels drawn in steps 1-3, and
:func:`~star_screen.tracking.extract.extract_candidates` runs the extractor's own steps on them.
A frame costs the draws for a few tens of thousands of pixels instead of the whole array.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ndtr, ndtri

from star_screen.tracking.extract import (
    BACKGROUND_STEP,
    ExtractedStars,
    background_level,
    extract_candidates,
)

__all__ = ["SparseExposure"]

#: The level L sits this many background sigmas below the threshold, so that a value rounded to
#: float32 on the far side of the threshold still counts as drawn.
_L_BELOW_THRESHOLD_SIGMA = 0.05


class SparseExposure:
    """Exposures of one detector (``width`` x ``height`` pixels) with ``camera_noise``'s model,
    extracted with ``extract_stars``' algorithm and settings, drawing only what extraction reads.

    ``exposure.stars(idx, signal_e, rng)``: ``idx`` the raster indices of the lit pixels (each
    once) and ``signal_e`` their ideal signal in electrons (as
    :meth:`star_screen.render.Renderer.detector_signal` returns them); returns
    :class:`~star_screen.tracking.extract.ExtractedStars`. ``rng`` drives every draw.

    After a frame, ``threshold_e`` is the extractor's threshold and ``level_e`` the level L: every
    pixel not drawn (``drawn()`` is False) lies below it; ``image()`` is the frame with undrawn
    pixels at the background level (for a look, or a dense extraction: it returns the same stars).
    """

    def __init__(
        self,
        width: int,
        height: int,
        psf_sigma_px: float,
        *,
        background_e: float = 20.0,
        read_noise_e: float = 10.0,
        k_sigma: float = 5.0,
        min_area: int = 2,
        max_stars: int | None = None,
        iterations: int = 3,
    ) -> None:
        if background_e < 0 or read_noise_e < 0:
            raise ValueError(
                f"background_e = {background_e}, read_noise_e = {read_noise_e}; both must be >= 0 electrons."
            )
        self.width, self.height = int(width), int(height)
        self.psf_sigma_px = float(psf_sigma_px)
        self.background_e = float(background_e)
        self.sigma_e = math.sqrt(background_e + read_noise_e**2)
        self.k_sigma = float(k_sigma)
        self._extract_kw = dict(min_area=min_area, max_stars=max_stars, iterations=iterations)
        size = self.width * self.height
        self._img = np.zeros(size, np.float32)
        self._drawn = np.zeros(size, bool)
        self._written: list[np.ndarray] = []
        step = BACKGROUND_STEP
        rows = np.arange(0, self.height, step)
        cols = np.arange(0, self.width, step)
        self._grid_shape = (len(rows), len(cols))
        self._grid = (rows[:, None] * self.width + cols[None, :]).ravel()
        self.counts = {"frames": 0, "drawn": 0, "tail": 0}
        self.threshold_e = self.level_e = math.nan

    # -- drawing ------------------------------------------------------------------------------

    def _gauss(self, rng: np.random.Generator, n: int) -> np.ndarray:
        out = rng.standard_normal(n, dtype=np.float32)
        out *= np.float32(self.sigma_e)
        out += np.float32(self.background_e)
        return out

    def _set(self, idx: np.ndarray, values: np.ndarray) -> None:
        self._img[idx] = values
        self._drawn[idx] = True
        self._written.append(idx)

    def _clear(self) -> None:
        for idx in self._written:
            self._drawn[idx] = False
        self._written.clear()

    def _below(self, rng: np.random.Generator, n: int, z_max: float) -> np.ndarray:
        """``n`` background values conditioned below ``background + z_max sigma`` (rejection)."""
        z = rng.standard_normal(n)
        bad = np.flatnonzero(z >= z_max)
        while len(bad):  # a few per hundred thousand at 5 sigma
            z[bad] = rng.standard_normal(len(bad))
            bad = bad[z[bad] >= z_max]
        return (self.background_e + self.sigma_e * z).astype(np.float32)

    def _tail(self, rng: np.random.Generator, z_min: float, free: int) -> np.ndarray:
        """Step 3: the ``free`` unlit, off-grid pixels above ``z_min`` sigmas, drawn and set; their indices."""
        q = float(ndtr(-z_min))
        n = int(rng.binomial(free, q)) if free > 0 and q > 0.0 else 0
        if n == 0:
            return np.empty(0, np.int64)
        # Uniform without replacement over the free pixels: draw over the whole array and keep
        # free, not yet chosen ones until there are n (rejection keeps the choice uniform).
        chosen = np.empty(0, np.int64)
        while len(chosen) < n:
            pick = rng.integers(0, self._drawn.size, size=n - len(chosen))
            pick = pick[~self._drawn[pick]]
            chosen = np.concatenate((chosen, pick))
            _, first = np.unique(chosen, return_index=True)
            chosen = chosen[np.sort(first)]
        # Inverse survival function of uniform deviates in (0, q): the Gaussian's tail beyond z_min.
        z = -ndtri(q * (1.0 - rng.random(n)))
        self._set(chosen, (self.background_e + self.sigma_e * z).astype(np.float32))
        return chosen

    # -- one exposure -------------------------------------------------------------------------

    def drawn(self) -> np.ndarray:
        """(height, width) bool: the pixels the last frame drew (a copy)."""
        return self._drawn.reshape(self.height, self.width).copy()

    def image(self) -> np.ndarray:
        """(height, width) float32: the last frame, undrawn pixels at the background level."""
        return np.where(self._drawn, self._img, np.float32(self.background_e)).reshape(self.height, self.width)

    def stars(self, idx: np.ndarray, signal_e: np.ndarray, rng: np.random.Generator) -> ExtractedStars:
        """Expose the lit pixels ``idx`` (signal ``signal_e``, electrons) and extract the stars."""
        self._clear()
        idx = np.asarray(idx, dtype=np.int64)
        signal = np.maximum(np.asarray(signal_e, dtype=np.float64), 0.0).astype(np.float32)
        lit = signal > 0.0  # as camera_noise: Poisson where the float32 image holds light
        idx, signal = idx[lit], signal[lit]
        # 1. lit pixels; 2. the rest of the background grid.
        values = self._gauss(rng, len(idx))
        values += rng.poisson(signal.astype(np.float64)).astype(np.float32)
        self._set(idx, values)
        grid = self._grid[~self._drawn[self._grid]]
        self._set(grid, self._gauss(rng, len(grid)))
        bg, noise = background_level(self._img[self._grid].reshape(self._grid_shape), step=1)
        thr = bg + self.k_sigma * noise
        # 3. the background pixels above L, just below the threshold; 4. the rest on demand.
        z_level = (thr - self.background_e) / self.sigma_e - _L_BELOW_THRESHOLD_SIGMA if self.sigma_e > 0 else math.inf
        self.threshold_e = thr
        self.level_e = self.background_e + z_level * self.sigma_e if self.sigma_e > 0 else thr
        tail = self._tail(rng, z_level, self._drawn.size - len(idx) - len(grid))
        drawn = np.concatenate((idx, grid, tail))
        cand = np.sort(drawn[self._img[drawn] > thr])

        def values_at(where: np.ndarray) -> np.ndarray:
            flat = where.reshape(-1)
            new = flat[~self._drawn[flat]]
            if len(new):
                new = np.unique(new)
                self._set(new, self._below(rng, len(new), z_level))
            return self._img[where]

        stars = extract_candidates(values_at, cand, (self.height, self.width), bg, noise, thr, self.psf_sigma_px,
                                   **self._extract_kw)
        self.counts["frames"] += 1
        self.counts["drawn"] += sum(len(w) for w in self._written)
        self.counts["tail"] += len(tail)
        return stars
