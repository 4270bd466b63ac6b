"""Star-screen renderer: the stars a tracker sees at an attitude, drawn on the screen and on an ideal
detector, with their truth.

Per frame (``Renderer.render``), with no per-star Python loop:

1. astrometric places at the epoch (proper motion, parallax; cached per epoch), cut at the
   tracker's limiting magnitude once;
2. one matrix-vector product and one compare cull the catalog to a cone around the boresight;
3. annual plus orbital aberration for the culled stars only (``aberration=False`` skips it and the
   parallax: catalog places with proper motion only, for comparisons);
4. rotation to the tracker frame, projection to detector pixels (tracker optics) and to screen
   pixels (collimator + screen), keeping stars that land on the detector;
5. pixel-integrated Gaussian spots (exact ``erf`` integrals, so the emitted-light centroid of a
   spot is its ideal position up to truncation at 4 sigma), smeared along each star's path during
   the exposure when the tracker rotates (a trail up to ``max_smear_px`` long, default
   :data:`MAX_SMEAR_PX`; a longer one is refused with :class:`SmearTooLong`, which bounds the
   work of a frame: at most ``max_smear_samples`` spots per star);
6. screen: linear luminance accumulated in a persistent float buffer, converted to drive codes
   through the panel's inverse response (nearest emitted luminance), and written into a
   persistent uint8 frame, clearing only the pixels the previous frame lit (cost grows with the
   number of stars, not the screen size);
7. detector: the same spots at the tracker's own PSF sigma, in electrons (noise-free float32).

``Renderer.detector_signal`` is step 7 alone, as lit pixels and their values instead of an image
(what an emulated tracker needs, see :class:`star_screen.tracking.exposure.SparseExposure`): one
stamp per star covering its whole smeared path (the samples' separable spots summed by one small
matrix product per star) instead of one stamp per sample.

Dynamic-range policy (screen, see docs/star_screen.md):

* A star of magnitude ``mag_full`` centred on a pixel has a peak of full scale at the nominal
  spot sigma. Fainter stars scale in flux by 10^(-0.4 dm) at the same sigma.
* Brighter stars keep their flux and are *widened* (sigma grows so the centred peak stays at full
  scale) up to ``max_bright_sigma_px``; stars brighter still are drawn at that sigma with full-scale
  peak and flagged ``clipped`` in the truth with the magnitude actually shown (``mag_shown``).
* Stars fainter than the tracker's ``mag_limit`` are not drawn. With mag_full = 2 and a limit of 8
  the faintest peak is ~1/255 of full scale in luminance (code ~20 of 255 on a gamma-2.2 panel).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.special import erf, erfinv

from sim.ephemeris import aberrate, earth_pv_bcrs
from sim.rotations import dcm
from sim.time import Epoch
from star_screen.catalog import Catalog
from star_screen.geometry import Bench

__all__ = [
    "MAX_SMEAR_PX",
    "Frame",
    "Photometry",
    "Renderer",
    "SmearTooLong",
    "StarsInField",
    "centred_peak_fraction",
    "splat_gaussians",
]

_SQRT2 = math.sqrt(2.0)
#: Cull margin beyond the detector's half diagonal: aberration (25") + spot wings + safety.
_CULL_MARGIN_RAD = math.radians(0.25)
#: Longest smear trail drawn (px, on the finer of the screen and detector grids). The trail is
#: sampled every half spot sigma, so this caps the spots per star, hence the work of a frame, for
#: any rate: on the default bench (3974 screen px/rad, 0.1 s exposure) 32 px is 4.6 deg/s, over
#: four times the default tracker's rate limit, and 93 samples per star (about 100 ms for the
#: densest field of a 20 x 15 deg tracker, 330 stars, against 1.5 ms unsmeared). A faster state
#: is refused (SmearTooLong) rather than drawn as a dotted line that no tracker would see.
MAX_SMEAR_PX = 32.0
_C_LIGHT = 299_792_458.0


class SmearTooLong(ValueError):
    """The rate and exposure of a frame trail its stars further than the renderer's ``max_smear_px``."""


def centred_peak_fraction(sigma) -> np.ndarray:
    """Fraction of a pixel-integrated Gaussian's flux in its central pixel when centred on it."""
    return erf(0.5 / (_SQRT2 * np.asarray(sigma, dtype=float))) ** 2


#: Time grid (days) of the catalog places (proper motion, parallax); see Renderer._places_at.
PLACES_GRID_DAYS = 1.0 / 24.0


@dataclass(frozen=True)
class Photometry:
    """Screen spot size and brightness policy (see the module docstring)."""

    mag_full: float = 2.0
    defocus_fraction: float = 0.5  #: screen sigma = this x tracker PSF sigma (in screen px), clipped
    min_sigma_px: float = 0.7  #: below ~0.6 screen px the sampled centroid is biased
    max_sigma_px: float = 1.0
    max_bright_sigma_px: float = 3.0
    truncate_sigmas: float = 4.0

    def __post_init__(self):
        if not (0.5 <= self.min_sigma_px <= self.max_sigma_px <= self.max_bright_sigma_px):
            raise ValueError(
                "photometry needs 0.5 <= min_sigma_px <= max_sigma_px <= max_bright_sigma_px; got "
                f"{self.min_sigma_px}, {self.max_sigma_px}, {self.max_bright_sigma_px}."
            )


def splat_gaussians(x, y, flux, sigma, width: int, height: int, truncate: float = 4.0):
    """Pixel-integrated Gaussian spots as (flat pixel indices, values, per-spot peak value).

    ``x, y`` are spot centres in pixel coordinates ((0.5, 0.5) is the centre of pixel (0, 0)),
    ``flux`` their integrals, ``sigma`` scalar or per spot. Spots are grouped by stamp radius
    (a handful of groups), each group vectorised. Pixels outside the array are dropped.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    flux = np.asarray(flux, dtype=float)
    sigma = np.broadcast_to(np.asarray(sigma, dtype=float), x.shape)
    if x.size == 0:
        return np.empty(0, np.int64), np.empty(0, np.float32), np.empty(0)
    radius = np.ceil(truncate * sigma).astype(np.int64)
    idx_parts, val_parts = [], []
    peak = np.empty(x.shape)
    for R in np.unique(radius):
        sel = np.flatnonzero(radius == R)
        xs, ys, fs, ss = x[sel], y[sel], flux[sel], sigma[sel]
        k = np.arange(2 * R + 2)
        ix0 = np.floor(xs).astype(np.int64) - R
        iy0 = np.floor(ys).astype(np.int64) - R
        inv = 1.0 / (_SQRT2 * ss)[:, None]
        cx = erf((ix0[:, None] + k - xs[:, None]) * inv)
        cy = erf((iy0[:, None] + k - ys[:, None]) * inv)
        fx = 0.5 * np.diff(cx, axis=1)
        fy = 0.5 * np.diff(cy, axis=1) * fs[:, None]
        stamp = fy[:, :, None] * fx[:, None, :]  # (n, K, K) rows then columns
        peak[sel] = stamp.reshape(len(sel), -1).max(axis=1)
        cols = ix0[:, None] + k[:-1]
        rows = iy0[:, None] + k[:-1]
        ok = ((rows >= 0) & (rows < height))[:, :, None] & ((cols >= 0) & (cols < width))[:, None, :]
        flat = rows[:, :, None] * width + cols[:, None, :]
        idx_parts.append(flat[ok])
        val_parts.append(stamp[ok].astype(np.float32))
    return np.concatenate(idx_parts), np.concatenate(val_parts), peak


#: Sub-pixel phases per pixel in the tables of :func:`_pixel_integral_table`.
_PHASES = 512


@lru_cache(maxsize=8)
def _pixel_integral_table(sigma: float, R: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel integrals of a unit 1-D Gaussian of ``sigma`` over the 2R + 1 pixels around the one
    holding its centre, tabulated against the centre's phase in that pixel (0..1, ``_PHASES``
    steps), with their derivatives in the phase: ``(g, dg)`` of shape ``(_PHASES + 1, 2R + 1)``.

    ``scipy.special.erf`` costs about 35 ns a value, 50 times an ``exp``; cubic Hermite
    interpolation in this table (exact values and slopes at the nodes) is within 1e-12 of the
    erf differences (per unit flux; 4e-14 at sigma 1 px), far below the float32 the detector holds."""
    inv = 1.0 / (_SQRT2 * sigma)
    phase = np.arange(_PHASES + 1) / _PHASES
    z = (np.arange(2 * R + 2)[None, :] - R - phase[:, None]) * inv  # pixel edges, (phases, 2R + 2)
    g = 0.5 * np.diff(erf(z), axis=1)
    dg = np.diff(-inv / math.sqrt(math.pi) * np.exp(-z * z), axis=1)
    return g, dg


def _pixel_integrals(centre: np.ndarray, sigma: float, R: int) -> np.ndarray:
    """``0.5 (erf((e + 1 - c) / (sqrt 2 sigma)) - erf((e - c) / (sqrt 2 sigma)))`` for the pixels e of
    ``floor(c) - R .. floor(c) + R``: shape ``centre.shape + (2R + 1,)``, from the phase table."""
    g, dg = _pixel_integral_table(float(sigma), int(R))
    u = (centre - np.floor(centre)) * _PHASES
    i = np.minimum(u.astype(np.int64), _PHASES - 1)
    t = (u - i)[..., None]
    t2 = t * t
    t3 = t2 * t
    h = 1.0 / _PHASES
    return ((2 * t3 - 3 * t2 + 1) * g[i] + (t3 - 2 * t2 + t) * (h * dg[i])
            + (3 * t2 - 2 * t3) * g[i + 1] + (t3 - t2) * (h * dg[i + 1]))


def _path_stamps(x, y, flux, sigma: float, width: int, height: int, truncate: float = 4.0):
    """Spots of :func:`splat_gaussians` at samples ``x, y`` ``(n, k)`` along each star's path (``flux``
    (n,) per sample), summed per star on one stamp: ``(flat pixel indices, values)``, one entry per
    star and pixel (stars may share pixels). Each sample's spot is truncated exactly as there."""
    R = int(math.ceil(truncate * sigma))
    n, k = x.shape
    span = np.arange(2 * R + 1)

    def factors(centre):
        """Each sample's pixel integrals over its own 2R + 1 pixels, placed on the star's stamp."""
        first = np.floor(centre).astype(np.int64)  # (n, k) pixel holding the sample
        origin = first.min(axis=1) - R  # (n,) stamp corner
        size = int((first.max(axis=1) - first.min(axis=1)).max()) + 2 * R + 1
        out = np.zeros((n, k, size))
        start = np.arange(n * k).reshape(n, k) * size + (first - R - origin[:, None])
        out.reshape(-1)[start[:, :, None] + span] = _pixel_integrals(centre, sigma, R)
        return out, origin[:, None] + np.arange(size)

    fx, cols = factors(x)
    fy, rows = factors(y)
    stamp = np.matmul((fy * flux[:, None, None]).transpose(0, 2, 1), fx)  # (n, rows, cols)
    ok = stamp > 0.0
    if rows.min() < 0 or rows.max() >= height or cols.min() < 0 or cols.max() >= width:
        ok &= ((rows >= 0) & (rows < height))[:, :, None] & ((cols >= 0) & (cols < width))[:, None, :]
    flat = rows[:, :, None] * width + cols[:, None, :]
    return flat[ok], stamp[ok]


@dataclass
class StarsInField:
    """Stars drawn in one frame (arrays over stars, brightest first)."""

    hip: np.ndarray
    mag: np.ndarray
    d_S: np.ndarray  #: (n, 3) apparent unit directions in the tracker frame at mid-exposure
    detector_xy: np.ndarray  #: (n, 2) ideal detector pixel at mid-exposure
    screen_xy: np.ndarray  #: (n, 2) screen pixel at mid-exposure
    on_detector: np.ndarray  #: (n,) bool, the spot centre lies on the detector array
    screen_flux: np.ndarray = field(default=None)  #: (n,) relative-luminance pixel sum drawn
    screen_sigma: np.ndarray = field(default=None)
    screen_peak: np.ndarray = field(default=None)  #: (n,) peak relative luminance of the spot
    clipped: np.ndarray = field(default=None)
    mag_shown: np.ndarray = field(default=None)
    detector_flux_e: np.ndarray = field(default=None)

    def __len__(self) -> int:
        return len(self.hip)

    def as_records(self) -> list[dict]:
        out = []
        for i in range(len(self)):
            rec = {
                "hip": int(self.hip[i]),
                "mag": round(float(self.mag[i]), 4),
                "detector_xy": [round(float(v), 5) for v in self.detector_xy[i]],
                "screen_xy": [round(float(v), 5) for v in self.screen_xy[i]],
                "on_detector": bool(self.on_detector[i]),
            }
            if self.mag_shown is not None:
                rec["mag_shown"] = round(float(self.mag_shown[i]), 4)
                rec["clipped"] = bool(self.clipped[i])
            out.append(rec)
        return out


@dataclass
class Frame:
    """One rendered frame: images, the stars drawn, attitude, time tag and bright-body flags."""

    q_SN: np.ndarray
    epoch: Epoch
    time_tag_ns: int | None
    stars: StarsInField
    screen: np.ndarray | None  #: (H, W) uint8 drive codes
    detector: np.ndarray | None  #: (h, w) float32 electrons, noise-free
    aberration: bool
    bodies: dict = field(default_factory=dict)
    smear_samples: int = 1  #: spots drawn per star (1 without smear; at most Renderer.max_smear_samples)


class Renderer:
    """Render frames for one bench (tracker + collimator + screen).

    ``catalog`` defaults to the hip2 fixture cut at the tracker's limiting magnitude. The screen
    and detector arrays are persistent and updated sparsely; ``render(copy=False)`` returns views
    that the next call overwrites (what a display loop wants), ``copy=True`` (default) fresh arrays.
    ``bright_bodies`` is an optional :class:`star_screen.bodies.BrightBodies` evaluated per frame.
    """

    def __init__(
        self,
        bench: Bench | None = None,
        catalog: Catalog | None = None,
        *,
        photometry: Photometry | None = None,
        aberration: bool = True,
        bright_bodies=None,
        max_smear_px: float = MAX_SMEAR_PX,
    ):
        if not (isinstance(max_smear_px, int | float) and 0 < max_smear_px <= 4096):
            raise ValueError(f"max_smear_px = {max_smear_px!r}; allowed a number of pixels in (0, 4096].")
        self.max_smear_px = float(max_smear_px)
        self.bench = bench if bench is not None else Bench()
        t = self.bench.tracker
        self.photometry = photometry if photometry is not None else Photometry()
        if catalog is None:
            catalog = Catalog.load(mag_limit=min(t.mag_limit, 9.0))
        elif t.mag_limit > catalog.hp_limit:
            raise ValueError(
                f"tracker mag_limit = {t.mag_limit} exceeds the catalog's limit Hp {catalog.hp_limit}; "
                "load the catalog with a fainter limit or lower mag_limit."
            )
        self.catalog = catalog
        self.aberration = bool(aberration)
        self.bright_bodies = bright_bodies
        ph = self.photometry
        self.sigma_screen = float(
            np.clip(
                ph.defocus_fraction * t.psf_sigma_px * self.bench.screen_px_per_tracker_px,
                ph.min_sigma_px,
                ph.max_sigma_px,
            )
        )
        self.flux_full = 1.0 / float(centred_peak_fraction(self.sigma_screen))
        s = self.bench.screen
        self._thresholds = s.inverse_table().astype(np.float32)
        self._screen = np.zeros((s.height, s.width), np.uint8)
        self._lin = np.zeros(s.height * s.width, np.float32)
        self._screen_prev = np.empty(0, np.int64)
        self._det = np.zeros((t.height, t.width), np.float32)
        self._det_prev = np.empty(0, np.int64)
        self._cos_cull = math.cos(t.half_diagonal_rad() + _CULL_MARGIN_RAD)
        self._places_key = None
        self._places = None
        self._v_earth_key = None
        self._v_earth = None

    # ------------------------------------------------------------------ geometry
    def _places_at(self, epoch: Epoch):
        # Proper motion and parallax are evaluated on a grid of PLACES_GRID_DAYS: the fastest
        # Hipparcos star moves 1.2 mas and the largest parallax 0.6 mas per hour, a thousandth of
        # a pixel here, while recomputing the places costs ~3 ms, more than drawing a frame. The
        # sim and a display node use the same grid, so their frames stay identical.
        jd1, jd2 = epoch.jd_tt
        key = (jd1, round(jd2 / PLACES_GRID_DAYS) * PLACES_GRID_DAYS, self.aberration)
        if key != self._places_key:
            lim = self.bench.tracker.mag_limit
            self._places = self.catalog.places(key[:2], parallax=self.aberration).brighter_than(lim)
            self._places_key = key
        return self._places

    def observer_velocity(self, epoch: Epoch, v_sc_gcrs_m_s=None) -> np.ndarray:
        """Barycentric velocity of the spacecraft (m/s): Earth's (epv00) plus the orbital velocity."""
        key = epoch.jd_tt
        if key != self._v_earth_key:
            self._v_earth = earth_pv_bcrs(epoch)[1]
            self._v_earth_key = key
        v = self._v_earth
        return v + np.asarray(v_sc_gcrs_m_s, dtype=float) if v_sc_gcrs_m_s is not None else v

    def stars_in_field(self, q_SN, epoch: Epoch, v_sc_gcrs_m_s=None) -> StarsInField:
        """Stars whose spots reach the detector at attitude ``q_SN`` (apparent places unless
        ``aberration=False``), with detector and screen positions; no drawing."""
        places = self._places_at(epoch)
        C = dcm(q_SN)
        sel = places.cull(C[2], self._cos_cull)
        u = places.u_N[sel]
        if self.aberration and len(sel):
            u = aberrate(u, self.observer_velocity(epoch, v_sc_gcrs_m_s))
        d_S = u @ C.T
        t = self.bench.tracker
        det, front = t.project(d_S)
        m = 4.0 * t.psf_sigma_px
        keep = (
            front
            & (det[:, 0] > -m)
            & (det[:, 0] < t.width + m)
            & (det[:, 1] > -m)
            & (det[:, 1] < t.height + m)
        )
        sel, d_S, det = sel[keep], d_S[keep], det[keep]
        scr, _ = self.bench.direction_to_screen(d_S)
        on = (det[:, 0] >= 0) & (det[:, 0] < t.width) & (det[:, 1] >= 0) & (det[:, 1] < t.height)
        return StarsInField(places.hip[sel], places.mag[sel], d_S, det, scr, on)

    # ------------------------------------------------------------------ drawing
    @property
    def _smear_step_px(self) -> float:
        return 0.5 * min(self.sigma_screen, self.bench.tracker.psf_sigma_px)

    @property
    def _px_per_rad(self) -> float:
        return max(self.bench.k_px, self.bench.tracker.fx)

    @property
    def max_smear_samples(self) -> int:
        """Most spots drawn per star for any smear this renderer accepts."""
        return math.ceil(self.max_smear_px / self._smear_step_px) + 1

    def max_rate_rad_s(self, exposure_s: float | None = None) -> float:
        """Fastest rate whose smear over ``exposure_s`` (default: the tracker's) is drawn."""
        exposure = self.bench.tracker.exposure_s if exposure_s is None else float(exposure_s)
        return math.inf if exposure <= 0 else self.max_smear_px / (exposure * self._px_per_rad)

    def _trail(self, omega_SN_S, exposure_s: float) -> tuple[np.ndarray, float, float] | None:
        """``(omega, rate, trail_px)`` of a smeared frame, None without smear; refuses a long trail."""
        if omega_SN_S is None or exposure_s <= 0:
            return None
        w = self._rate_vector(omega_SN_S)
        rate = math.hypot(*w)  # no overflow for huge components, unlike norm's sum of squares
        if rate == 0.0:
            return None
        trail_px = rate * exposure_s * self._px_per_rad
        if not trail_px <= self.max_smear_px:
            raise SmearTooLong(
                f"omega_SN_S = {tuple(float(x) for x in w)} rad/s over a {exposure_s:g} s exposure trails the stars "
                f"{trail_px:.4g} px; this renderer draws trails up to max_smear_px = {self.max_smear_px:g} px "
                f"(a rate up to {self.max_rate_rad_s(exposure_s):.4g} rad/s)."
            )
        return w, rate, trail_px

    def _smear_offsets(self, stars: StarsInField, omega_SN_S, exposure_s: float):
        """Directions along each star's path during the exposure: (n, k, 3) and the sample count k."""
        trail = self._trail(omega_SN_S, exposure_s)
        if trail is None:
            return None
        w, rate, trail_px = trail
        k = max(2, math.ceil(trail_px / self._smear_step_px) + 1)
        ts = (np.arange(k) + 0.5) / k - 0.5  # fractions of the exposure about mid-exposure
        axis = w / rate
        ang = -rate * exposure_s * ts  # an inertial direction turns by -omega t in S
        d = stars.d_S
        c, s = np.cos(ang)[None, :, None], np.sin(ang)[None, :, None]
        kxd = np.cross(axis, d)[:, None, :]
        kdd = (d @ axis)[:, None, None] * axis
        return d[:, None, :] * c + kxd * s + kdd * (1 - c), k

    @staticmethod
    def _rate_vector(omega_SN_S) -> np.ndarray:
        w = np.asarray(omega_SN_S, dtype=float).reshape(-1)
        if w.shape != (3,) or not np.all(np.isfinite(w)):
            raise ValueError(f"omega_SN_S = {omega_SN_S!r}; it must be 3 finite numbers (rad/s).")
        return w

    def _check_velocity(self, v_sc_gcrs_m_s) -> None:
        if v_sc_gcrs_m_s is None:
            return
        v = np.asarray(v_sc_gcrs_m_s, dtype=float).reshape(-1)
        if v.shape != (3,) or not np.all(np.isfinite(v)) or not math.hypot(*v) < 0.01 * _C_LIGHT:
            raise ValueError(f"v_sc_gcrs_m_s = {v_sc_gcrs_m_s!r}; it must be 3 finite numbers (m/s) with a speed "
                             "below 1% of c (aberration is computed for a spacecraft, not a light beam).")
    def detector_signal(
        self,
        q_SN,
        epoch: Epoch,
        *,
        v_sc_gcrs_m_s=None,
        omega_SN_S=None,
        exposure_s: float | None = None,
    ) -> tuple[StarsInField, np.ndarray, np.ndarray]:
        """The ideal detector image of :meth:`render` as ``(stars, idx, e)``: the raster indices of
        the pixels that receive light (each once) and their signal in electrons (float64; the image
        holds the same values rounded to float32). Same arguments as :meth:`render`; no screen."""
        t = self.bench.tracker
        stars = self.stars_in_field(q_SN, epoch, v_sc_gcrs_m_s)
        exposure = t.exposure_s if exposure_s is None else float(exposure_s)
        path = self._smear_offsets(stars, omega_SN_S, exposure)
        det_flux = t.flux_mag0_e * 10.0 ** (-0.4 * stars.mag.astype(float))
        stars.detector_flux_e = det_flux
        n = len(stars)
        if n == 0:
            return stars, np.empty(0, np.int64), np.empty(0)
        if path is not None:
            dirs, k = path
            xy = t.project(dirs.reshape(-1, 3))[0].reshape(n, k, 2)
        else:
            k = 1
            xy = stars.detector_xy[:, None, :]
        idx, val = _path_stamps(xy[..., 0], xy[..., 1], det_flux / k, t.psf_sigma_px, t.width, t.height,
                                self.photometry.truncate_sigmas)
        return stars, *self._sum_duplicates(idx, val, t.width * t.height)

    def _sum_duplicates(self, idx: np.ndarray, val: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
        """Each raster index once with the sum of its values (where stars' stamps overlap), without
        sorting: a persistent marker array names one entry per pixel."""
        if getattr(self, "_mark", None) is None or self._mark.size != size:
            self._mark = np.zeros(size, np.int32)
        mark = self._mark
        order = np.arange(len(idx), dtype=np.int32)
        mark[idx] = order
        keep = mark[idx] == order  # one entry per pixel (the last writer's)
        u, total = idx[keep], val[keep]
        if len(u) < len(idx):
            mark[u] = np.arange(len(u), dtype=np.int32)
            rest = ~keep
            np.add.at(total, mark[idx[rest]], val[rest])
        return u, total

    def render(
        self,
        q_SN,
        epoch: Epoch,
        *,
        v_sc_gcrs_m_s=None,
        omega_SN_S=None,
        exposure_s: float | None = None,
        time_tag_ns: int | None = None,
        screen: bool = True,
        detector: bool = True,
        copy: bool = True,
        r_sc_gcrs_m=None,
    ) -> Frame:
        """Render one frame at the tracker's mid-exposure attitude ``q_SN`` and ``epoch``.

        ``v_sc_gcrs_m_s``: spacecraft velocity relative to the Earth (orbital aberration);
        ``omega_SN_S`` (rad/s) and ``exposure_s`` (default: the tracker's) smear the stars;
        ``time_tag_ns``: sim time of the frame (every displayed frame carries it);
        ``r_sc_gcrs_m``: spacecraft position (needed only for the Earth among bright bodies).
        """
        t = self.bench.tracker
        ph = self.photometry
        exposure = t.exposure_s if exposure_s is None else float(exposure_s)
        if not math.isfinite(exposure):
            raise ValueError(f"exposure_s = {exposure_s!r}; it must be a finite number of seconds.")
        self._check_velocity(v_sc_gcrs_m_s)
        self._trail(omega_SN_S, exposure)  # refuse a long trail before any work
        stars = self.stars_in_field(q_SN, epoch, v_sc_gcrs_m_s)
        path = self._smear_offsets(stars, omega_SN_S, exposure)
        n = len(stars)
        mag = stars.mag.astype(float)
        # --- screen photometry policy
        flux = self.flux_full * 10.0 ** (-0.4 * (mag - ph.mag_full))
        sigma = np.full(n, self.sigma_screen)
        bright = flux * centred_peak_fraction(self.sigma_screen) > 1.0
        clipped = np.zeros(n, bool)
        if np.any(bright):
            sig_b = 1.0 / (2.0 * _SQRT2 * erfinv(np.sqrt(1.0 / flux[bright])))
            over = sig_b > ph.max_bright_sigma_px
            sig_b = np.minimum(sig_b, ph.max_bright_sigma_px)
            fb = flux[bright]
            fb = np.where(over, 1.0 / centred_peak_fraction(ph.max_bright_sigma_px), fb)
            sigma[bright] = sig_b
            flux[bright] = fb
            clipped[np.flatnonzero(bright)[over]] = True
        mag_shown = ph.mag_full - 2.5 * np.log10(flux / self.flux_full)
        stars.screen_flux, stars.screen_sigma, stars.clipped, stars.mag_shown = (
            flux,
            sigma,
            clipped,
            mag_shown,
        )
        det_flux = t.flux_mag0_e * 10.0 ** (-0.4 * mag)
        stars.detector_flux_e = det_flux
        # --- sample positions (smear) -> spots
        if path is not None:
            dirs, k = path
            flat = dirs.reshape(-1, 3)
            s_xy = self.bench.direction_to_screen(flat)[0]
            d_xy = t.project(flat)[0]
            rep = lambda a: np.repeat(a, k) / k  # noqa: E731
            s_in = (s_xy, rep(flux), np.repeat(sigma, k))
            d_in = (d_xy, rep(det_flux))
        else:
            s_in = (stars.screen_xy, flux, sigma)
            d_in = (stars.detector_xy, det_flux)
        scr_out = det_out = None
        if screen:
            sw, sh = self.bench.screen.width, self.bench.screen.height
            idx, val, peak = splat_gaussians(
                s_in[0][:, 0], s_in[0][:, 1], s_in[1], s_in[2], sw, sh, ph.truncate_sigmas
            )
            stars.screen_peak = peak if path is None else None
            lin = self._lin
            np.add.at(lin, idx, val)
            codes = np.searchsorted(self._thresholds, lin[idx], side="right").astype(np.uint8)
            lin[idx] = 0.0
            sflat = self._screen.reshape(-1)
            sflat[self._screen_prev] = 0
            sflat[idx] = codes
            self._screen_prev = idx
            scr_out = self._screen.copy() if copy else self._screen
        if detector:
            idx, val, _ = splat_gaussians(
                d_in[0][:, 0], d_in[0][:, 1], d_in[1], t.psf_sigma_px, t.width, t.height, ph.truncate_sigmas
            )
            dflat = self._det.reshape(-1)
            dflat[self._det_prev] = 0.0
            np.add.at(dflat, idx, val)
            self._det_prev = idx
            det_out = self._det.copy() if copy else self._det
        bodies = {}
        if self.bright_bodies is not None:
            bodies = self.bright_bodies.evaluate(q_SN, epoch, r_sc_gcrs_m=r_sc_gcrs_m)
        return Frame(
            np.asarray(q_SN, float), epoch, time_tag_ns, stars, scr_out, det_out, self.aberration, bodies,
            1 if path is None else path[1],
        )
