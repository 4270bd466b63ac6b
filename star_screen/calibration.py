"""Calibration of the screen-plus-collimator map from camera images of a ChArUco pattern.

Procedure on a bench:

1. show :func:`charuco_screen_image` on the screen (a ChArUco board from OpenCV's contrib ``aruco``
   module, placed so every chessboard corner has a known screen pixel position);
2. photograph it through the collimator with the tracker in raw-image mode (or any camera whose
   intrinsics are known, given as a :class:`TrackerOptics`);
3. :func:`calibrate_screen` detects the ChArUco corners (``cv2.aruco.CharucoDetector``), turns each
   camera pixel into a direction with the camera's intrinsics, and fits the bench model
   ``screen = (sx0, sy0) + k * D(x, y)`` (``D`` is OpenCV's 5-term Brown-Conrady distortion, ``k`` =
   collimator focal length / pixel pitch) by least squares. The result is a calibrated
   :class:`~star_screen.geometry.Bench` to store with the bench configuration.

A residual rotation between camera and collimator shows up mostly as a shift of ``(sx0, sy0)``;
the camera must be focused at infinity. :func:`simulate_camera_view` renders what a camera sees of
a screen image through a (distorted) collimator, for tests and for planning a calibration.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from star_screen.geometry import Bench, BrownConrady, Collimator, TrackerOptics

__all__ = [
    "CharucoPattern",
    "charuco_screen_image",
    "simulate_camera_view",
    "calibrate_screen",
    "Calibration",
]


def _cv2():
    try:
        import cv2
    except ImportError:  # pragma: no cover
        raise RuntimeError(
            "calibration needs opencv-contrib-python-headless (part of the base install: pip install adcs-stand)."
        ) from None
    if not hasattr(cv2, "aruco"):  # pragma: no cover
        raise RuntimeError(
            "calibration needs OpenCV's contrib module aruco; install opencv-contrib-python-headless."
        )
    return cv2


@dataclass(frozen=True)
class CharucoPattern:
    """A ChArUco board drawn on the screen: squares, square size in screen pixels, top-left corner."""

    squares_x: int = 14
    squares_y: int = 10
    square_px: int = 64
    marker_fraction: float = 0.7
    dictionary: int = 11  #: cv2.aruco.DICT_6X6_1000
    x0_px: int = 0
    y0_px: int = 0

    def board(self):
        cv2 = _cv2()
        d = cv2.aruco.getPredefinedDictionary(self.dictionary)
        return cv2.aruco.CharucoBoard(
            (self.squares_x, self.squares_y), float(self.square_px), self.square_px * self.marker_fraction, d
        )

    def corner_screen_px(self) -> np.ndarray:
        """Screen pixel positions (docs/conventions.md) of the inner chessboard corners, by corner id."""
        c = np.asarray(self.board().getChessboardCorners(), float)[:, :2]
        return c + [self.x0_px, self.y0_px]


def charuco_screen_image(bench: Bench, squares_x: int = 14, squares_y: int = 10, square_px: int = 64):
    """A screen image (uint8) with a ChArUco board centred on the collimator axis, and its pattern."""
    w = squares_x * square_px
    h = squares_y * square_px
    x0 = int(round(bench.sx0 - w / 2))
    y0 = int(round(bench.sy0 - h / 2))
    pat = CharucoPattern(squares_x, squares_y, square_px, x0_px=x0, y0_px=y0)
    s = bench.screen
    if x0 < 0 or y0 < 0 or x0 + w > s.width or y0 + h > s.height:
        raise ValueError(
            f"a {squares_x} x {squares_y} board of {square_px}-px squares does not fit the "
            f"{s.width} x {s.height} screen; use fewer or smaller squares."
        )
    img = np.zeros((s.height, s.width), np.uint8)
    img[y0 : y0 + h, x0 : x0 + w] = pat.board().generateImage((w, h), marginSize=0, borderBits=1)
    return img, pat


def simulate_camera_view(
    screen_image: np.ndarray, bench: Bench, camera: TrackerOptics | None = None
) -> np.ndarray:
    """What a camera (default: the bench's tracker) focused at infinity sees of ``screen_image``
    through the bench's collimator, sampled bilinearly at each camera pixel centre."""
    cv2 = _cv2()
    cam = camera if camera is not None else bench.tracker
    jj, ii = np.mgrid[0 : cam.height, 0 : cam.width]
    px = np.stack((ii + 0.5, jj + 0.5), axis=-1).reshape(-1, 2)
    s, _ = bench.direction_to_screen(cam.unproject(px))
    mx = (s[:, 0] - 0.5).reshape(cam.height, cam.width).astype(np.float32)  # OpenCV: integer = centre
    my = (s[:, 1] - 0.5).reshape(cam.height, cam.width).astype(np.float32)
    return cv2.remap(screen_image, mx, my, interpolation=cv2.INTER_LINEAR, borderValue=0)


@dataclass(frozen=True)
class Calibration:
    bench: Bench  #: the calibrated bench (collimator focal length and distortion, screen axis)
    n_points: int
    rms_px: float  #: fit residual, screen px
    max_px: float


def calibrate_screen(
    camera_images,
    pattern: CharucoPattern,
    bench: Bench,
    camera: TrackerOptics | None = None,
    fit_tangential: bool = True,
    fit_k3: bool = False,
) -> Calibration:
    """Fit the screen-plus-collimator model to ChArUco corners detected in ``camera_images``."""
    cv2 = _cv2()
    cam = camera if camera is not None else bench.tracker
    detector = cv2.aruco.CharucoDetector(pattern.board())
    corners_screen = pattern.corner_screen_px()
    xy_list, scr_list = [], []
    for img in camera_images:
        ch_corners, ch_ids, _, _ = detector.detectBoard(img)
        if ch_ids is None or len(ch_ids) < 12:
            continue
        cam_px = ch_corners.reshape(-1, 2).astype(float) + 0.5  # OpenCV -> our pixel convention
        d = cam.unproject(cam_px)
        xy_list.append(d[:, :2] / d[:, 2:3])
        scr_list.append(corners_screen[ch_ids.ravel()])
    if not xy_list:
        raise ValueError(
            "no ChArUco board was found in the camera images (need at least 12 corners per image)."
        )
    xy = np.concatenate(xy_list)
    scr = np.concatenate(scr_list)
    k0 = bench.k_px

    def _dist(p):
        t = 1.0 if fit_tangential else 0.0
        return BrownConrady(p[3], p[4], p[5] * t, p[6] * t, p[7] if fit_k3 else 0.0)

    def model(p):
        dist = _dist(p)
        return np.array([p[1], p[2]]) + p[0] * dist.distort(xy)

    p0 = np.array([k0, bench.sx0, bench.sy0, 0, 0, 0, 0, 0], float)
    sol = least_squares(
        lambda p: (model(p) - scr).ravel(), p0, x_scale=[k0 * 1e-3, 1, 1, 1e-3, 1e-3, 1e-4, 1e-4, 1e-3]
    )
    p = sol.x
    res = np.linalg.norm(model(p) - scr, axis=1)
    dist = _dist(p)
    col = Collimator(focal_length_m=p[0] * bench.screen.pitch_m, distortion=dist)
    new = dataclasses.replace(bench, collimator=col, sx0=float(p[1]), sy0=float(p[2]))
    return Calibration(new, len(xy), float(np.sqrt(np.mean(res**2))), float(res.max()))
