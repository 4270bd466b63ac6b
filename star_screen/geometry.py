"""Geometry of a star-tracker bench: tracker optics, screen, collimator, and the maps between them.

Frames and pixels (the project's conventions):

* Tracker frame S: +z is the boresight, +x is image x (right), +y is image y (down).
* Pixel coordinates are continuous, with (0.5, 0.5) the *centre* of the top-left pixel, so pixel
  (column i, row j) covers [i, i+1) x [j, j+1). The principal point defaults to (W/2, H/2), the
  centre of the array.
* A direction ``d_S`` has normalised coordinates ``(x, y) = (d_x / d_z, d_y / d_z)``.

Distortion uses OpenCV's Brown-Conrady model (``k1, k2, p1, p2, k3``), applied to normalised
coordinates exactly as ``cv2.projectPoints`` does, so calibrations from ``cv2.calibrateCamera``
plug in directly.

* Tracker: ``pixel = (cx + fx * xd, cy + fy * yd)`` with ``(xd, yd) = distort(x, y)``.
* Screen seen through the collimator: the screen sits in the collimator's focal plane, so a screen
  point at ``f_c * (xd, yd)`` from the collimator axis appears to the tracker in the direction
  ``(x, y)`` (a magnifier: upright, no mirror). In screen pixels:
  ``screen = (sx0 + k * xd, sy0 + k * yd)`` with ``k = f_c / pitch`` and the collimator's own
  distortion. ``flip_x`` / ``flip_y`` describe a fold mirror in the light path.
  The tracker frame is assumed aligned with the collimator axis (a bench calibration absorbs a
  residual misalignment into ``sx0, sy0``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["BrownConrady", "TrackerOptics", "Screen", "Collimator", "Bench", "default_bench"]


@dataclass(frozen=True)
class BrownConrady:
    """OpenCV's radial-tangential distortion of normalised coordinates (all zero: none)."""

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    @classmethod
    def from_opencv(cls, coeffs) -> BrownConrady:
        c = np.ravel(np.asarray(coeffs, dtype=float))
        c = np.concatenate((c, np.zeros(max(0, 5 - c.size))))
        if np.any(c[5:] != 0.0):
            raise ValueError(
                "only the 5-term OpenCV model (k1, k2, p1, p2, k3) is supported; got more terms."
            )
        return cls(*(float(v) for v in c[:5]))

    def as_opencv(self) -> np.ndarray:
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])

    @property
    def is_zero(self) -> bool:
        return not any((self.k1, self.k2, self.p1, self.p2, self.k3))

    def distort(self, xy) -> np.ndarray:
        """Distorted normalised coordinates ``(..., 2)`` of ideal ones."""
        xy = np.asarray(xy, dtype=float)
        if self.is_zero:
            return xy
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
        return np.stack((xd, yd), axis=-1)

    def undistort(self, xyd, iterations: int = 30, tol: float = 1e-14) -> np.ndarray:
        """Ideal normalised coordinates of distorted ones (Newton iteration with a numerical Jacobian)."""
        xyd = np.asarray(xyd, dtype=float)
        if self.is_zero:
            return xyd
        xy = xyd.copy()
        h = 1e-7
        for _ in range(iterations):
            f = self.distort(xy) - xyd
            if np.max(np.abs(f), initial=0.0) < tol:
                break
            jx = (self.distort(xy + [h, 0.0]) - self.distort(xy - [h, 0.0])) / (2 * h)
            jy = (self.distort(xy + [0.0, h]) - self.distort(xy - [0.0, h])) / (2 * h)
            a, c = jx[..., 0], jx[..., 1]
            b, d = jy[..., 0], jy[..., 1]
            det = a * d - b * c
            dx = (d * f[..., 0] - b * f[..., 1]) / det
            dy = (-c * f[..., 0] + a * f[..., 1]) / det
            xy = xy - np.stack((dx, dy), axis=-1)
        return xy


def _check_pixel_size(owner: str, width, height) -> None:
    """Refuse a detector or panel size that is not a whole number of pixels, at least 8 each way."""
    for key, v in (("width", width), ("height", height)):
        if int(v) != v or v < 8:
            raise ValueError(f"{owner} {key} = {v!r}; it must be a whole number of pixels >= 8.")


@dataclass(frozen=True)
class TrackerOptics:
    """A star tracker's camera: pixels, focal length in pixels (per axis), distortion, PSF, band.

    ``psf_sigma_px`` is the Gaussian sigma of the tracker's (deliberately defocused) spot in its own
    pixels; ``mag_limit`` the faintest magnitude it detects (fainter stars are not drawn);
    ``flux_mag0_e`` the signal of a magnitude-0 star in one exposure (electrons, detector product).
    """

    width: int = 1024
    height: int = 768
    fx: float = 512.0 / math.tan(math.radians(10.0))
    fy: float = 384.0 / math.tan(math.radians(7.5))
    cx: float | None = None
    cy: float | None = None
    distortion: BrownConrady = field(default_factory=BrownConrady)
    psf_sigma_px: float = 1.0
    mag_limit: float = 8.0
    exposure_s: float = 0.1
    flux_mag0_e: float = 2.0e6
    name: str = "default"

    def __post_init__(self):
        _check_pixel_size("tracker", self.width, self.height)
        for key in ("fx", "fy", "psf_sigma_px", "flux_mag0_e"):
            v = getattr(self, key)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"tracker {key} = {v!r}; it must be a positive finite number.")
        if self.exposure_s < 0:
            raise ValueError(f"tracker exposure_s = {self.exposure_s!r}; it must be >= 0 s.")
        if self.cx is None:
            object.__setattr__(self, "cx", self.width / 2.0)
        if self.cy is None:
            object.__setattr__(self, "cy", self.height / 2.0)

    @classmethod
    def from_fov(cls, fov_x_deg: float, fov_y_deg: float, width: int, height: int, **kw) -> TrackerOptics:
        """Optics whose undistorted full field is ``fov_x_deg`` x ``fov_y_deg`` on ``width`` x ``height``."""
        for key, v, hi in (("fov_x_deg", fov_x_deg, 170.0), ("fov_y_deg", fov_y_deg, 170.0)):
            if not (0.0 < v < hi):
                raise ValueError(f"tracker {key} = {v!r}; it must be between 0 and {hi} deg.")
        fx = (width / 2.0) / math.tan(math.radians(fov_x_deg) / 2.0)
        fy = (height / 2.0) / math.tan(math.radians(fov_y_deg) / 2.0)
        return cls(width=width, height=height, fx=fx, fy=fy, **kw)

    @property
    def fov_deg(self) -> tuple[float, float]:
        """Full field of view (undistorted) along x and y, degrees."""
        return (
            math.degrees(math.atan(self.cx / self.fx) + math.atan((self.width - self.cx) / self.fx)),
            math.degrees(math.atan(self.cy / self.fy) + math.atan((self.height - self.cy) / self.fy)),
        )

    @property
    def camera_matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def arcsec_per_px(self) -> float:
        return math.degrees(1.0 / self.fx) * 3600.0

    def project(self, d_S) -> tuple[np.ndarray, np.ndarray]:
        """Detector pixel ``(..., 2)`` of tracker-frame directions, and a mask of those in front (z > 0)."""
        d = np.asarray(d_S, dtype=float)
        z = d[..., 2]
        front = z > 1e-9
        zs = np.where(front, z, 1.0)
        xy = self.distortion.distort(np.stack((d[..., 0] / zs, d[..., 1] / zs), axis=-1))
        px = np.stack((self.cx + self.fx * xy[..., 0], self.cy + self.fy * xy[..., 1]), axis=-1)
        return px, front

    def unproject(self, px) -> np.ndarray:
        """Unit tracker-frame directions of detector pixels ``(..., 2)``."""
        px = np.asarray(px, dtype=float)
        xy = self.distortion.undistort(
            np.stack(((px[..., 0] - self.cx) / self.fx, (px[..., 1] - self.cy) / self.fy), axis=-1)
        )
        d = np.concatenate((xy, np.ones(xy.shape[:-1] + (1,))), axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def half_diagonal_rad(self) -> float:
        """Largest angle between the boresight and any detector corner."""
        corners = np.array([[0, 0], [self.width, 0], [0, self.height], [self.width, self.height]], float)
        return float(np.max(np.arccos(np.clip(self.unproject(corners)[:, 2], -1.0, 1.0))))


@dataclass(frozen=True)
class Screen:
    """The display panel: pixels, pitch, and its code -> relative luminance response.

    Response is a power law ``L = (code / max_code) ** gamma`` unless a measured table
    ``luminance`` (one relative luminance per code, increasing, 0 .. 1) is given.
    """

    width: int = 1920
    height: int = 1080
    pitch_m: float = 0.2768e-3
    gamma: float = 2.2
    bits: int = 8
    luminance: tuple | None = None
    name: str = "screen"

    def __post_init__(self):
        _check_pixel_size("screen", self.width, self.height)
        if not (self.pitch_m > 0 and math.isfinite(self.pitch_m)):
            raise ValueError(f"screen pitch_m = {self.pitch_m!r}; it must be a positive length in metres.")
        if self.bits != 8:
            raise ValueError(f"screen bits = {self.bits!r}; only 8-bit panels are supported.")
        if not (0.5 <= self.gamma <= 4.0):
            raise ValueError(f"screen gamma = {self.gamma!r}; it must lie in [0.5, 4].")
        if self.luminance is not None:
            lum = np.asarray(self.luminance, float)
            if lum.shape != (256,) or np.any(np.diff(lum) <= 0) or lum[0] < 0 or lum[-1] > 1.0 + 1e-12:
                raise ValueError("screen luminance must hold 256 strictly increasing values in [0, 1].")

    def response(self) -> np.ndarray:
        """Relative luminance of every drive code (256,)."""
        if self.luminance is not None:
            return np.asarray(self.luminance, dtype=float)
        return (np.arange(256) / 255.0) ** self.gamma

    def inverse_table(self) -> np.ndarray:
        """Luminance thresholds (255,): code ``c`` is chosen for L in [t[c-1], t[c]) (nearest luminance)."""
        lum = self.response()
        return 0.5 * (lum[1:] + lum[:-1])

    def encode(self, lum) -> np.ndarray:
        """Drive codes (uint8) whose emitted luminance is nearest to relative luminance ``lum``."""
        return np.searchsorted(self.inverse_table(), np.asarray(lum), side="right").astype(np.uint8)


@dataclass(frozen=True)
class Collimator:
    """Collimating lens: focal length (m) and its distortion (of the screen seen through it)."""

    focal_length_m: float = 1.1
    distortion: BrownConrady = field(default_factory=BrownConrady)

    def __post_init__(self):
        if not (self.focal_length_m > 0 and math.isfinite(self.focal_length_m)):
            raise ValueError(f"collimator focal_length_m = {self.focal_length_m!r}; it must be > 0 m.")


@dataclass(frozen=True)
class Bench:
    """One tracker in front of one collimated screen."""

    tracker: TrackerOptics = field(default_factory=TrackerOptics)
    screen: Screen = field(default_factory=Screen)
    collimator: Collimator = field(default_factory=Collimator)
    sx0: float | None = None  #: screen pixel on the collimator axis (default: screen centre)
    sy0: float | None = None
    flip_x: bool = False
    flip_y: bool = False

    def __post_init__(self):
        if self.sx0 is None:
            object.__setattr__(self, "sx0", self.screen.width / 2.0)
        if self.sy0 is None:
            object.__setattr__(self, "sy0", self.screen.height / 2.0)

    @property
    def k_px(self) -> float:
        """Screen pixels per unit of normalised coordinate (``f_c / pitch``)."""
        return self.collimator.focal_length_m / self.screen.pitch_m

    @property
    def screen_px_per_tracker_px(self) -> float:
        return self.k_px / self.tracker.fx

    def normalized_to_screen(self, xy) -> np.ndarray:
        xyd = self.collimator.distortion.distort(xy)
        sx = -1.0 if self.flip_x else 1.0
        sy = -1.0 if self.flip_y else 1.0
        return np.stack(
            (self.sx0 + sx * self.k_px * xyd[..., 0], self.sy0 + sy * self.k_px * xyd[..., 1]), axis=-1
        )

    def direction_to_screen(self, d_S) -> tuple[np.ndarray, np.ndarray]:
        """Screen pixel ``(..., 2)`` the tracker sees in direction ``d_S``, and the in-front mask."""
        d = np.asarray(d_S, dtype=float)
        front = d[..., 2] > 1e-9
        z = np.where(front, d[..., 2], 1.0)
        return self.normalized_to_screen(np.stack((d[..., 0] / z, d[..., 1] / z), axis=-1)), front

    def screen_to_direction(self, px) -> np.ndarray:
        """Unit tracker-frame direction in which the tracker sees screen pixel ``px`` ``(..., 2)``."""
        px = np.asarray(px, dtype=float)
        sx = -1.0 if self.flip_x else 1.0
        sy = -1.0 if self.flip_y else 1.0
        xyd = np.stack(
            ((px[..., 0] - self.sx0) * sx / self.k_px, (px[..., 1] - self.sy0) * sy / self.k_px), axis=-1
        )
        xy = self.collimator.distortion.undistort(xyd)
        d = np.concatenate((xy, np.ones(xy.shape[:-1] + (1,))), axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def check_fits(self) -> list[str]:
        """Problems (empty if none): detector corners that the screen cannot show."""
        t = self.tracker
        corners = np.array([[0, 0], [t.width, 0], [0, t.height], [t.width, t.height]], float)
        s, _ = self.direction_to_screen(t.unproject(corners))
        bad = (s[:, 0] < 0) | (s[:, 0] > self.screen.width) | (s[:, 1] < 0) | (s[:, 1] > self.screen.height)
        return [
            f"tracker corner {corners[i].tolist()} maps to screen pixel {np.round(s[i], 1).tolist()}, "
            f"outside the {self.screen.width} x {self.screen.height} screen"
            for i in np.flatnonzero(bad)
        ]


def default_bench(screen_width: int = 1920, screen_height: int = 1080, **kw) -> Bench:
    """The default bench: 20 x 15 deg tracker on 1024 x 768 px; a screen whose 1920-px-wide
    equivalent pitch is 0.2768 mm (24-inch FHD) behind a 1.1 m collimator. Other resolutions keep
    the panel size (the pitch scales), so the tracker field covers the same part of the panel."""
    pitch = 0.2768e-3 * 1920.0 / screen_width
    screen = Screen(width=screen_width, height=screen_height, pitch_m=pitch)
    return Bench(tracker=kw.pop("tracker", TrackerOptics()), screen=screen, **kw)
