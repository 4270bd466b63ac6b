"""The viewing stretch of detector images: stars bright, the sky dark grey rather than black."""

import numpy as np
import pytest

from star_screen.outputs import stretch_for_viewing

H, W = 240, 320
#: peak counts of the synthetic stars, faint (as Hp 8 at 10 e-/count) to bright
PEAKS = [20.0, 60.0, 300.0, 3000.0, 20000.0]


def _stars(noise_counts: float = 0.0, sky: float = 0.0, seed: int = 0):
    """Five Gaussian stars (sigma 1 px) on a flat sky, in 16-bit counts as detector_raw.png holds."""
    xy = np.array([[40.5, 60.5], [100.5, 120.5], [160.5, 60.5], [220.5, 180.5], [280.5, 120.5]])
    yy, xx = np.mgrid[0:H, 0:W] + 0.5
    img = np.full((H, W), sky)
    for (x, y), peak in zip(xy, PEAKS, strict=True):
        img += peak * np.exp(-0.5 * ((xx - x) ** 2 + (yy - y) ** 2))
    if noise_counts:
        img += np.random.default_rng(seed).normal(0.0, noise_counts, img.shape)
    counts = np.clip(np.rint(img), 0, 65535).astype(np.uint16)
    return counts, xy


def _peak(view, xy):
    return np.array([view[int(y) - 1:int(y) + 2, int(x) - 1:int(x) + 2].max() for x, y in xy])


@pytest.mark.parametrize("noise, sky", [(0.0, 0.0), (1.1, 2.0), (3.0, 100.0)])
def test_stars_are_bright_and_the_sky_is_not_black(noise, sky):
    counts, xy = _stars(noise, sky)
    # On the raw 16-bit scale an image viewer shows all but the brightest star near black.
    assert (counts.astype(float)[tuple(np.rint(xy[:4, ::-1] - 0.5).astype(int).T)] / 65535 < 0.05).all()
    view = stretch_for_viewing(counts)
    assert view.dtype == np.uint8 and view.shape == counts.shape
    bg = float(np.median(view))
    assert 20 <= bg <= 45  # dark grey, not black
    peaks = _peak(view, xy)
    assert peaks[-1] == 255 and peaks[-2] > 200  # bright stars are white
    assert peaks[0] > bg + 25  # the faintest star (20 counts) stands clear of the sky
    assert np.all(np.diff(peaks.astype(int)) >= 0)  # brighter stays brighter
    if noise:  # the noise stays visible, not clipped to one level
        sky_px = view[:30, :30]
        assert sky_px.std() > 1.0 and (sky_px == 0).mean() < 0.01


def test_the_stretch_is_monotonic():
    counts, _ = _stars(2.0, 10.0)
    view = stretch_for_viewing(counts)
    order = np.argsort(counts, axis=None, kind="stable")
    assert np.all(np.diff(view.ravel()[order].astype(int)) >= 0)


def test_a_flat_image_is_sky_grey():
    view = stretch_for_viewing(np.full((8, 8), 7, dtype=np.uint16))
    assert np.all(view == round(255 * 0.12))


@pytest.mark.parametrize("image, word", [(np.zeros((2, 2, 3)), "2-D"), (np.array([[np.nan, 1.0]]), "finite")])
def test_bad_images_are_refused(image, word):
    with pytest.raises(ValueError, match=word):
        stretch_for_viewing(image)
