"""Helpers shared by the star_screen tests (units, synthetic catalogs)."""

import numpy as np

from star_screen.catalog import Catalog

EPOCH_ISO = "2026-01-01T00:00:00Z"
ARCSEC = np.pi / (180 * 3600)
MAS = ARCSEC / 1000


def synthetic_catalog(ra_deg, dec_deg, mag, hip=None) -> Catalog:
    """A catalog of given stars (no proper motion, no parallax), sorted by magnitude."""
    ra = np.radians(np.atleast_1d(np.asarray(ra_deg, float)))
    dec = np.radians(np.atleast_1d(np.asarray(dec_deg, float)))
    mag = np.broadcast_to(np.asarray(mag, np.float32), ra.shape).copy()
    hip = np.arange(1, ra.size + 1, dtype=np.int32) if hip is None else np.asarray(hip, np.int32)
    o = np.argsort(mag, kind="stable")
    z32 = np.zeros(ra.size, np.float32)
    return Catalog(hip[o], ra[o], dec[o], z32, z32, z32, mag[o], z32, 9.0)


def separation(u, v) -> np.ndarray:
    """Angle (rad) between unit vectors, accurate at small angles."""
    u = np.asarray(u, float)
    v = np.asarray(v, float)
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1))


def noisy_frames_with_priors(tracker, optics, epoch, seed: int, count: int) -> list:
    """``count`` frames of the default bench at random attitudes, rendered with camera noise and extracted, each with
    a tracking prior 0.1 deg off the truth: [(stars, prior q_SN), ...]."""
    from sim.rotations import compose, quat_from_axis_angle
    from star_screen.geometry import default_bench
    from star_screen.render import Renderer
    from star_screen.tracking.extract import extract_stars
    from star_screen.tracking.noise import camera_noise

    renderer = Renderer(default_bench(), aberration=False)
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(count):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        img = camera_noise(renderer.render(q, epoch, screen=False).detector, rng)
        stars = extract_stars(img, optics.psf_sigma_px, k_sigma=tracker.k_sigma, max_stars=tracker.max_centroids)
        frames.append((stars, compose(quat_from_axis_angle(rng.normal(size=3), np.radians(0.1)), q)))
    return frames


def assert_same_solutions_on_both_builds(epoch, seed: int, builds, use) -> None:
    """The whole solve, lost in space and tracking, on four rendered frames with camera noise, once per module of
    ``builds`` (the compiled twin and the plain module of one compiled path) after ``use(module)`` switched
    identification to it: every solution valid, both modes seen, and the same validity, mode, attitude and covariance
    bytes, matched stars, hypotheses and chance-alignment bound on every build."""
    from star_screen.geometry import default_bench
    from star_screen.tracking import StarTracker

    optics = default_bench().tracker
    tracker = StarTracker(epoch=epoch)
    frames = noisy_frames_with_priors(tracker, optics, epoch, seed, 4)
    records = []
    for module in builds:
        use(module)
        out = []
        for stars, prior in frames:
            for sol in (tracker.solve_stars(stars, optics), tracker.solve_stars(stars, optics, prior=prior)):
                out.append((sol.valid, sol.mode, sol.q_SN.tobytes(), sol.cov_S.tobytes(), sol.matched_hip.tolist(),
                            sol.hypotheses, sol.false_prob))
        records.append(out)
    assert all(valid for valid, *_ in records[0]) and {mode for _, mode, *_ in records[0]} == {"lis", "tracking"}
    assert all(r == records[0] for r in records[1:])
