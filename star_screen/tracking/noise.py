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

    Shot noise of the signal: an exact Poisson draw, on the pixels that carry signal (stars cover a
    few percent of a frame). Shot noise of the uniform ``background_e`` (sky, stray light and dark
    current together) plus read noise of ``read_noise_e`` rms: one Gaussian of their summed
    variance, drawn in float32. A Poisson draw of every pixel costs ~40 ms per megapixel and decides
    nothing: at 20 e- the Poisson background is within 0.22 skewness of that Gaussian, and the
    extractor's 5-sigma threshold on it sees no difference (tests/star_screen/test_tracking.py).
    The background level stays in the result, as a real detector reports it. ``rng`` makes the
    draw reproducible.
    """
    if background_e < 0 or read_noise_e < 0:
        raise ValueError(
            f"background_e = {background_e}, read_noise_e = {read_noise_e}; both must be >= 0 electrons."
        )
    signal = np.maximum(np.asarray(image_e, dtype=np.float64), 0.0)
    out = rng.standard_normal(signal.shape, dtype=np.float32)
    out *= np.float32(np.sqrt(background_e + read_noise_e**2))
    out += np.float32(background_e)
    lit = np.flatnonzero(signal > 0.0)
    if lit.size:
        flat = out.reshape(-1)
        flat[lit] += rng.poisson(signal.reshape(-1)[lit]).astype(np.float32)
    return out
