"""Image-based star tracking: extract stars, identify them, estimate the attitude with a covariance.

    tracker = StarTracker()                      # hip2 catalog to Hp 8 at the default epoch
    sol = tracker.solve(frame.detector, optics)  # lost in space
    sol = tracker.solve(next_image, optics, prior=sol.q_SN)   # tracking

``Solution.q_SN`` is the tracker frame S (+z boresight, +x image right, +y image down) relative to
GCRS, scalar first with w >= 0; it is ``None``-free: an invalid solution carries NaNs. Pattern
databases are built in memory at first use for each field size (about half a second) and kept on
the object. Nothing here reads the wall clock; speed is measured by ``stand bench tracker``.

Tracking mode keeps nothing per frame: everything that does not depend on the image is cached on
first use (places per epoch, a k-d tree over them per places table, the projection constants per
optics), and a frame costs one cone query, two projections of the cone, a vote, one match and two
or three 3 x 3 SVDs (timed by ``stand bench tracker``; extraction is timed separately).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sim.ephemeris import aberrate
from sim.rotations import UNIT_NORM_TOLERANCE, dcm
from sim.time import Epoch
from star_screen.catalog import Catalog, StarPlaces
from star_screen.geometry import TrackerOptics
from star_screen.tracking.estimate import AttitudeEstimate, estimate_attitude
from star_screen.tracking.extract import ExtractedStars, extract_stars
from star_screen.tracking.identify import PatternDatabase, identify_lis, identify_tracking

__all__ = ["StarTracker", "Solution", "DEFAULT_EPOCH_ISO"]

DEFAULT_EPOCH_ISO = "2026-01-01T00:00:00Z"
_ARCSEC = math.pi / (180.0 * 3600.0)


@dataclass(frozen=True)
class Solution:
    """One star-tracker solution.

    ``q_SN`` (4,) scalar first, w >= 0 (NaN when not valid); ``sigma_cross_arcsec``: RMS angle between
    the estimated and true boresight; ``sigma_roll_arcsec``: 1-sigma about the boresight;
    ``cov_S`` (3, 3) rad^2 in tracker axes (see :mod:`star_screen.tracking.estimate`);
    ``false_prob``: bound on the probability that the identification is a chance alignment.
    """

    q_SN: np.ndarray
    valid: bool
    stars_centroided: int
    stars_matched: int
    sigma_cross_arcsec: float
    sigma_roll_arcsec: float
    mode: str  #: "lis" or "tracking"
    cov_S: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    false_prob: float = 1.0
    hypotheses: int = 0
    matched_hip: np.ndarray = field(default_factory=lambda: np.empty(0, np.int32))
    stars: ExtractedStars | None = None


def _invalid(mode: str, n_centroided: int, n_matched: int = 0, stars=None, hyp: int = 0, pf: float = 1.0):
    return Solution(np.full(4, np.nan), False, n_centroided, n_matched, math.nan, math.nan, mode,
                    false_prob=pf, hypotheses=hyp, stars=stars)


def _prior_dcm(q) -> np.ndarray:
    """``dcm(q)`` of a prior quaternion on Python floats; anything unusual (wrong shape, not unit,
    not finite) goes through :func:`sim.rotations.dcm`, which explains what is wrong."""
    if isinstance(q, np.ndarray) and q.shape == (4,) or isinstance(q, (list, tuple)) and len(q) == 4:
        try:
            w, x, y, z = (float(v) for v in (q.tolist() if isinstance(q, np.ndarray) else q))
            n2 = w * w + x * x + y * y + z * z
        except (TypeError, ValueError):
            n2 = math.nan
        if math.isfinite(n2) and abs(math.sqrt(n2) - 1.0) <= UNIT_NORM_TOLERANCE:
            return np.array((
                (1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)),
                (2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)),
                (2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)),
            ))
    return dcm(np.asarray(q, float))


def _unproject(xy: np.ndarray, optics: TrackerOptics) -> np.ndarray:
    """``optics.unproject(xy)`` with a direct path for distortion-free optics and float64 centroids (what extraction
    gives)."""
    if not optics.distortion.is_zero or xy.dtype != np.float64:
        return optics.unproject(xy)
    # Both image axes in one subtraction and one division into the output's columns (the same operations on each
    # element as column by column, with fewer numpy calls and no temporaries).
    d = np.empty((len(xy), 3))
    d_xy = d[:, :2]
    np.subtract(xy, (optics.cx, optics.cy), out=d_xy)
    d_xy /= (optics.fx, optics.fy)
    d[:, 2] = 1.0
    norm = np.einsum("ij,ij->i", d, d)
    d /= np.sqrt(norm, out=norm)[:, None]
    return d


class StarTracker:
    """Lost-in-space and tracking star tracker on detector images.

    ``catalog``: the hip2 fixture by default, cut at ``mag_limit`` (verification stars);
    ``pattern_mag_limit``: faintest pattern star (the database thins them to an even density);
    ``min_matches``: fewest matched stars for a valid solution; ``max_false_prob``: bound on a
    chance identification; ``k_sigma``: detection threshold; ``epoch``: default epoch of the
    catalog places (proper motion), overridable per solve.
    """

    def __init__(
        self,
        catalog: Catalog | None = None,
        *,
        mag_limit: float = 8.0,
        pattern_mag_limit: float = 7.0,
        min_matches: int = 8,
        max_false_prob: float = 1e-9,
        k_sigma: float = 5.0,
        epoch: Epoch | str = DEFAULT_EPOCH_ISO,
        max_centroids: int = 400,
    ):
        if min_matches < 4:
            raise ValueError(f"min_matches = {min_matches}; a verified solution needs at least 4 matched stars.")
        if not (0.0 < max_false_prob < 1.0):
            raise ValueError(f"max_false_prob = {max_false_prob}; it must lie strictly between 0 and 1.")
        self.catalog = catalog if catalog is not None else Catalog.load(mag_limit=mag_limit)
        self.mag_limit = float(min(mag_limit, self.catalog.hp_limit))
        self.pattern_mag_limit = float(min(pattern_mag_limit, self.mag_limit))
        self.min_matches = int(min_matches)
        self.max_false_prob = float(max_false_prob)
        self.k_sigma = float(k_sigma)
        self.max_centroids = int(max_centroids)
        self.epoch = Epoch.from_iso(epoch) if isinstance(epoch, str) else epoch
        self._dbs: dict[float, PatternDatabase] = {}
        self._places: dict[tuple, StarPlaces] = {}
        self._last_places: tuple | None = None  #: (epoch object, parallax, places) of the last call of places()
        self._last_db: tuple | None = None  #: (optics object, pattern database) of the last call of database()

    # ------------------------------------------------------------------ catalog side
    def places(self, epoch: Epoch | None = None, parallax: bool = False) -> StarPlaces:
        """Verification places (proper motion to ``epoch``), brightest first."""
        ep = epoch if epoch is not None else self.epoch
        last = self._last_places
        if last is not None and last[0] is ep and last[1] == bool(parallax):
            # The same (frozen) epoch object as the previous solve's: its places, without working out its TT date.
            return last[2]
        key = (ep.jd_tt, bool(parallax))
        if key not in self._places:
            if len(self._places) > 4:
                self._places.clear()
            # One object per epoch, so the identification's k-d tree over it is built only once.
            self._places[key] = self.catalog.places(ep, parallax=parallax).brighter_than(self.mag_limit)
        self._last_places = (ep, bool(parallax), self._places[key])
        return self._places[key]

    @staticmethod
    def max_edge_deg(optics: TrackerOptics) -> float:
        """Largest pattern separation for these optics: 8/15 of the short side of the field."""
        return round(min(optics.fov_deg) * 8.0 / 15.0, 3)

    def database(self, optics: TrackerOptics) -> PatternDatabase:
        """The pattern database for this field size (built at first use, then cached)."""
        last = self._last_db
        if last is not None and last[0] is optics:
            # The same (frozen) optics object as the previous solve's: its database, without working out its field.
            return last[1]
        key = self.max_edge_deg(optics)
        if key not in self._dbs:
            self._dbs[key] = PatternDatabase.build(
                self.catalog.places(self.epoch, parallax=False), key, self.pattern_mag_limit
            )
        self._last_db = (optics, self._dbs[key])
        return self._dbs[key]

    # ------------------------------------------------------------------ solve
    def centroid_sigma_rad(self, stars: ExtractedStars, optics: TrackerOptics) -> np.ndarray:
        """Per-star centroid sigma (rad): photon noise (image taken as electrons) plus background
        noise of a Gaussian spot, with a 0.01 px floor for residual systematics. Only the ratios
        matter: the estimate scales the covariance by its residuals."""
        s2 = optics.psf_sigma_px**2 + 1.0 / 12.0
        F = np.maximum(stars.flux, 1e-12)
        var = s2 / F + 4.0 * math.pi * s2**2 * stars.noise**2 / F**2 + 0.01**2
        return np.sqrt(var) / optics.fx

    def solve(
        self,
        image: np.ndarray,
        optics: TrackerOptics,
        prior=None,
        *,
        epoch: Epoch | None = None,
        observer_velocity_m_s=None,
    ) -> Solution:
        """Solve one detector image (2-D, any real dtype).

        ``prior``: previous ``q_SN`` for tracking (falls back to lost in space when tracking fails);
        ``epoch``: catalog epoch (default the tracker's). Places and their k-d tree are cached per
        epoch, so in a loop keep one epoch per run (proper motion moves stars < 1 mas per day)
        instead of passing every tick's epoch; ``observer_velocity_m_s``: barycentric
        velocity of the tracker (m/s, GCRS axes) to solve against apparent places (aberration), as
        the renderer draws them by default; ``None`` solves against astrometric places.
        """
        img = np.asarray(image)
        if img.ndim != 2 or img.shape != (optics.height, optics.width):
            raise ValueError(
                f"image shape {img.shape} does not match the optics ({optics.height} rows x {optics.width} "
                "columns); pass the detector image the optics describe."
            )
        stars = extract_stars(img, optics.psf_sigma_px, k_sigma=self.k_sigma, max_stars=self.max_centroids)
        return self.solve_stars(stars, optics, prior, epoch=epoch, observer_velocity_m_s=observer_velocity_m_s)

    def sparse_exposure(self, optics: TrackerOptics, *, background_e: float = 20.0, read_noise_e: float = 10.0):
        """A :class:`~star_screen.tracking.exposure.SparseExposure` of these optics with this tracker's
        extraction settings: for an emulated tracker, ``solve_stars(exposure.stars(idx, e, rng), ...)``
        with ``idx, e`` from :meth:`star_screen.render.Renderer.detector_signal` is distributed as
        ``solve(camera_noise(image, rng, ...), ...)`` and costs a fraction of it."""
        from star_screen.tracking.exposure import SparseExposure

        return SparseExposure(optics.width, optics.height, optics.psf_sigma_px, background_e=background_e,
                              read_noise_e=read_noise_e, k_sigma=self.k_sigma, max_stars=self.max_centroids)

    def solve_stars(self, stars: ExtractedStars, optics: TrackerOptics, prior=None, *, epoch=None,
                    observer_velocity_m_s=None) -> Solution:
        """Identify and estimate from already extracted stars (brightest first)."""
        n = len(stars)
        mode = "tracking" if prior is not None else "lis"
        if n < 4:
            return _invalid(mode, n, stars=stars)
        apparent = observer_velocity_m_s is not None
        places = self.places(epoch, parallax=apparent)
        b_S = _unproject(stars.xy, optics)
        sig = self.centroid_sigma_rad(stars, optics)
        kw = dict(min_matches=self.min_matches, max_false_prob=self.max_false_prob)
        match = None
        if prior is not None:
            match = identify_tracking(_prior_dcm(prior), stars.xy, b_S, sig, optics, places, **kw)
            if match.estimate is None:
                match = None
        if match is None:
            mode = "lis"
            match = identify_lis(stars.xy, b_S, sig, optics, self.database(optics), places, **kw)
        est: AttitudeEstimate | None = match.estimate
        if est is None:
            return _invalid(mode, n, match.n_matched, stars, match.hypotheses, match.false_prob)
        if apparent:
            r_N = aberrate(places.u_N[match.catalog_row], np.asarray(observer_velocity_m_s, float))
            est = estimate_attitude(b_S[match.image_index], r_N, sig[match.image_index])
        valid = match.n_matched >= self.min_matches and match.false_prob <= self.max_false_prob
        return Solution(
            est.q_SN, bool(valid), n, match.n_matched, est.sigma_cross_rad / _ARCSEC, est.sigma_roll_rad / _ARCSEC,
            mode, est.cov_S, match.false_prob, match.hypotheses, places.hip[match.catalog_row], stars,
        )
