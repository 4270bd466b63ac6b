"""The emulated tracker's sparse exposure (noise drawn only where extraction looks) against the dense
pipeline it stands for (``camera_noise`` on the whole frame, then ``extract_stars``), and the
renderer's sparse detector signal against its detector image.

The two exposures use different draws, so their stars are compared in distribution (seeded, many
frames, tolerances of several standard errors); the lazy drawing itself is checked exactly: a dense
extraction of the sparse frame, with any values below the level L where nothing was drawn,
returns the very same stars.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import erf, ndtr

from sim.rotations import quat_from_axis_angle
from star_screen.geometry import default_bench
from star_screen.render import Renderer, _path_stamps, _pixel_integrals, splat_gaussians
from star_screen.tracking import StarTracker
from star_screen.tracking.exposure import SparseExposure
from star_screen.tracking.extract import extract_stars
from star_screen.tracking.noise import camera_noise

W, H = 320, 240


def _signal(x, y, flux, sigma=1.0, w=W, h=H):
    """Unique lit pixels and their summed signal, and the same as a float32 image."""
    idx, val, _ = splat_gaussians(x, y, flux, sigma, w, h)
    img = np.zeros(w * h, np.float32)
    np.add.at(img, idx, val)
    lit = np.flatnonzero(img)
    return lit, img[lit].astype(np.float64), img.reshape(h, w)


def _field(rng, n=30):
    """Spots on a jittered grid (well separated), bright to barely detectable (peak ~5 sigma)."""
    gx, gy = np.meshgrid(np.arange(24, W - 20, 46.0), np.arange(24, H - 20, 46.0))
    x = gx.ravel()[:n] + rng.uniform(-0.5, 0.5, n)
    y = gy.ravel()[:n] + rng.uniform(-0.5, 0.5, n)
    flux = np.geomspace(250.0, 8000.0, n)
    return x, y, flux


# ------------------------------------------------------------------------------- renderer signal
@pytest.mark.parametrize(("sigma", "R"), [(1.0, 4), (0.6, 3), (1.7, 7)])
def test_tabulated_pixel_integrals_match_erf(sigma, R):
    rng = np.random.default_rng(3)
    c = np.concatenate([rng.uniform(-50.0, 50.0, 5000), [0.0, 1e-12, 1.0 - 1e-12, 3.5, -2.0, 17.999999]])
    edges = np.floor(c)[:, None] + np.arange(2 * R + 2) - R
    ref = 0.5 * np.diff(erf((edges - c[:, None]) / (math.sqrt(2.0) * sigma)), axis=1)
    assert np.abs(_pixel_integrals(c, sigma, R) - ref).max() < 1e-12


def test_path_stamps_equal_the_sum_of_the_sample_spots():
    rng = np.random.default_rng(1)
    n, k = 12, 6
    x = rng.uniform(-3, W + 3, n)[:, None] + np.linspace(0, 2.7, k) * rng.normal(size=(n, 1))
    y = rng.uniform(-3, H + 3, n)[:, None] + np.linspace(0, 2.7, k) * rng.normal(size=(n, 1))
    flux = rng.uniform(100, 1e4, n)
    idx, val = _path_stamps(x, y, flux, 1.3, W, H)
    got = np.zeros(W * H)
    np.add.at(got, idx, val)
    ref_idx, ref_val, _ = splat_gaussians(x.ravel(), y.ravel(), np.repeat(flux, k), 1.3, W, H)
    ref = np.zeros(W * H)
    np.add.at(ref, ref_idx, ref_val.astype(np.float64))
    np.testing.assert_allclose(got, ref, rtol=1e-6, atol=1e-9 * ref.max())  # ref went through float32
    assert set(idx.tolist()) == set(ref_idx.tolist())  # the same pixels, truncated the same way


@pytest.mark.parametrize("omega", [None, (0.0, 0.0, 0.0), (0.003, 0.004, 0.002), (0.0, 0.03, 0.01)])
def test_detector_signal_is_the_detector_image(epoch, omega):
    renderer = Renderer(default_bench(), aberration=True)
    q = quat_from_axis_angle([0.3, -0.5, 0.8], 2.1)
    v = [1000.0, -7000.0, 2000.0]
    frame = renderer.render(q, epoch, v_sc_gcrs_m_s=v, omega_SN_S=omega, screen=False)
    stars, idx, e = renderer.detector_signal(q, epoch, v_sc_gcrs_m_s=v, omega_SN_S=omega)
    assert len(np.unique(idx)) == len(idx) and len(stars) == len(frame.stars) > 50
    image = np.zeros(frame.detector.size)
    image[idx] = e
    dense = frame.detector.reshape(-1).astype(np.float64)
    np.testing.assert_allclose(image, dense, rtol=2e-6, atol=1e-6 * dense.max())
    assert np.count_nonzero(image.astype(np.float32)) == np.count_nonzero(dense)


def test_overlapping_stars_are_summed_once_per_pixel():
    renderer = Renderer(default_bench(), aberration=False)
    idx = np.array([5, 9, 5, 7, 9, 5])
    val = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    u, total = renderer._sum_duplicates(idx, val, 16)
    assert dict(zip(u.tolist(), total.tolist(), strict=True)) == {5: 10.0, 9: 7.0, 7: 4.0}


# ------------------------------------------------------------------------------- exact lazy drawing
@pytest.mark.parametrize("k_sigma", [5.0, 3.0])
def test_dense_extraction_of_the_sparse_frame_finds_the_same_stars(k_sigma):
    """Whatever the undrawn pixels hold below L, a dense extraction returns exactly the stars the
    sparse one did: extraction never needed them (thresholds, peaks, areas, windows)."""
    rng = np.random.default_rng(4)
    lit, e, _ = _signal(*_field(rng))
    exposure = SparseExposure(W, H, 1.0, k_sigma=k_sigma)
    for seed in range(5):
        sparse = exposure.stars(lit, e, np.random.default_rng(seed))
        drawn = exposure.drawn()
        assert drawn.sum() < 0.3 * W * H
        below = exposure.level_e
        assert below < exposure.threshold_e
        base = exposure.image()
        for fill in (np.full((H, W), below - 1e-3), rng.uniform(below - 60.0, below - 1e-3, (H, W))):
            image = np.where(drawn, base, fill).astype(np.float32)
            dense = extract_stars(image, 1.0, k_sigma=k_sigma)
            assert len(sparse) > 15
            np.testing.assert_array_equal(dense.xy, sparse.xy)
            np.testing.assert_array_equal(dense.flux, sparse.flux)
            np.testing.assert_array_equal(dense.area, sparse.area)
            assert (dense.background, dense.noise) == (sparse.background, sparse.noise)


# ------------------------------------------------------------------------------- same distribution
def _stats(stars, x, y):
    """(detections, matched, sum of squared centroid errors, fluxes of the matched) against the truth."""
    if len(stars) == 0:
        return 0, 0, 0.0, []
    d2 = (stars.xy[:, None, 0] - x[None]) ** 2 + (stars.xy[:, None, 1] - y[None]) ** 2
    j = d2.argmin(axis=1)
    ok = d2[np.arange(len(stars)), j] < 1.0
    return len(stars), int(ok.sum()), float(d2[np.arange(len(stars)), j][ok].sum()), stars.flux[ok].tolist()


def test_sparse_and_dense_exposures_give_stars_of_the_same_distribution():
    rng = np.random.default_rng(11)
    x, y, flux = _field(rng)
    lit, e, ideal = _signal(x, y, flux)
    exposure = SparseExposure(W, H, 1.0)
    runs = {"dense": [], "sparse": []}
    for seed in range(120):
        r = np.random.default_rng(1000 + seed)
        runs["dense"].append(_stats(extract_stars(camera_noise(ideal, r), 1.0), x, y))
        runs["sparse"].append(_stats(exposure.stars(lit, e, r), x, y))
    out = {}
    for name, rows in runs.items():
        n = np.array([r[0] for r in rows], float)
        m = np.array([r[1] for r in rows], float)
        out[name] = (n, m.sum(), math.sqrt(sum(r[2] for r in rows) / m.sum()), np.concatenate([r[3] for r in rows]))
    (nd, md, rms_d, fd), (ns, ms, rms_s, fs) = out["dense"], out["sparse"]
    # The faint end sits at the detection limit: how many are found is itself random.
    assert 0 < nd.std() and abs(nd.mean() - ns.mean()) < 4.0 * math.hypot(nd.std(), ns.std()) / math.sqrt(len(nd))
    assert abs(md / ms - 1.0) < 0.05  # detections that are the spots
    assert abs(rms_d / rms_s - 1.0) < 0.12  # centroid scatter (about 0.1 px)
    assert abs(np.median(fd) / np.median(fs) - 1.0) < 0.03


def test_noise_only_detections_have_the_same_rate():
    """At a low threshold (2.5 sigma) noise alone makes stars: the tail of the background (drawn as
    a Binomial number of pixels) and the lazily drawn neighbours must make them as often."""
    empty = np.zeros((H, W), np.float32)
    exposure = SparseExposure(W, H, 1.0, k_sigma=2.5)
    free = W * H - len(np.arange(0, H, 8)) * len(np.arange(0, W, 8))
    dense, sparse, tails, expected = [], [], [], []
    for seed in range(40):
        r = np.random.default_rng(seed)
        dense.append(len(extract_stars(camera_noise(empty, r), 1.0, k_sigma=2.5)))
        before = exposure.counts["tail"]
        sparse.append(len(exposure.stars(np.empty(0, np.int64), np.empty(0), r)))
        tails.append(exposure.counts["tail"] - before)
        # The level follows each frame's threshold (from its background grid): the expected tail too.
        expected.append(free * ndtr(-(exposure.level_e - exposure.background_e) / exposure.sigma_e))
    dense, sparse = np.array(dense, float), np.array(sparse, float)
    assert dense.mean() > 5
    se = math.hypot(dense.std(), sparse.std()) / math.sqrt(len(dense))
    assert abs(dense.mean() - sparse.mean()) < 4 * se
    assert abs(np.sum(tails) - np.sum(expected)) < 4 * math.sqrt(np.sum(expected))  # Binomial, q small


def test_noise_free_camera_and_bad_settings():
    lit, e, ideal = _signal(np.array([100.3]), np.array([80.7]), np.array([5e4]))
    exposure = SparseExposure(W, H, 1.0, background_e=0.0, read_noise_e=0.0)
    got = exposure.stars(lit, e, np.random.default_rng(0))
    ref = extract_stars(camera_noise(ideal, np.random.default_rng(0), background_e=0.0, read_noise_e=0.0), 1.0)
    assert len(got) == len(ref) == 1
    np.testing.assert_allclose(got.xy, ref.xy, atol=0.05)  # Poisson draws differ; both near (100.3, 80.7)
    with pytest.raises(ValueError, match="background_e = -1.*>= 0 electrons"):
        SparseExposure(W, H, 1.0, background_e=-1.0)


def test_tracker_solves_the_sparse_exposure_of_a_rendered_sky(epoch):
    renderer = Renderer(default_bench(), aberration=False)
    tracker = StarTracker(catalog=renderer.catalog, epoch=epoch)
    optics = renderer.bench.tracker
    exposure = tracker.sparse_exposure(optics, background_e=20.0, read_noise_e=10.0)
    assert (exposure.k_sigma, exposure._extract_kw["max_stars"]) == (tracker.k_sigma, tracker.max_centroids)
    rng = np.random.default_rng(2)
    for _ in range(3):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        _, idx, e = renderer.detector_signal(q, epoch)
        sol = tracker.solve_stars(exposure.stars(idx, e, rng), optics)
        from star_screen.tracking.estimate import attitude_error_S

        err = np.degrees(np.abs(attitude_error_S(sol.q_SN, q))) * 3600.0
        assert sol.valid and err.max() < 10.0
