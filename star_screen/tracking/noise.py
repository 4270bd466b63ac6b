"""Camera noise for rendered detector images (the renderer's detector is ideal and noise-free)."""

from __future__ import annotations

import numpy as np

__all__ = ["camera_noise"]


def camera_noise(
    image_e: np.ndarray,
    rng: np.random.Generator,
    *,
    background_e: float = 20.0,
    read_noise_e: float = 10.0,
) -> np.ndarray:
    """A noisy exposure (float32 electrons) of an ideal image in electrons.

    Shot noise: Poisson draw of signal plus a uniform ``background_e`` per pixel (sky, stray light
    and dark current together); read noise: Gaussian of ``read_noise_e`` rms. The background level
    stays in the result, as a real detector reports it. ``rng`` makes the draw reproducible.
    """
    if background_e < 0 or read_noise_e < 0:
        raise ValueError(
            f"background_e = {background_e}, read_noise_e = {read_noise_e}; both must be >= 0 electrons."
        )
    lam = np.maximum(np.asarray(image_e, dtype=np.float64), 0.0) + background_e
    out = rng.poisson(lam).astype(np.float32)
    if read_noise_e > 0:
        out += rng.normal(0.0, read_noise_e, size=out.shape).astype(np.float32)
    return out
