"""Frame outputs: truth dictionaries, PNG files, in-memory frames.

Display outputs are the only I/O of ``star_screen``. PNGs use OpenCV (the ``screen`` extra).
``detector_raw.png`` is 16-bit: counts = electrons / ``DETECTOR_PNG_E_PER_COUNT``, clipped to 65535
(the factor is written into the truth so the file can be read back in electrons); it is the file to
measure or solve. ``detector.png`` is the same image for a person: 8-bit, stretched by
``stretch_for_viewing`` (a star of a few hundred counts is invisible on a 0..65535 scale).
"""

from __future__ import annotations

import dataclasses
import json
import pathlib

import numpy as np

from star_screen.attitude import radec_roll_from_q_SN
from star_screen.render import Frame, Renderer

__all__ = ["frame_truth", "write_png", "write_frame", "stretch_for_viewing", "DETECTOR_PNG_E_PER_COUNT", "FrameQueue"]

DETECTOR_PNG_E_PER_COUNT = 10.0


def _cv2():
    try:
        import cv2
    except ImportError:  # pragma: no cover - depends on the installation
        raise RuntimeError(
            "writing PNG files needs OpenCV; it is part of the base install (pip install adcs-stand)."
        ) from None
    return cv2


def write_png(path, image: np.ndarray) -> pathlib.Path:
    """Write a uint8 or uint16 single-channel image as PNG; returns the path."""
    path = pathlib.Path(path)
    if image.dtype not in (np.uint8, np.uint16) or image.ndim != 2:
        raise ValueError(
            f"PNG output takes a 2-D uint8 or uint16 array; got {image.dtype} with shape {image.shape}."
        )
    if not _cv2().imwrite(str(path), image):
        raise OSError(f"could not write PNG file {str(path)!r}.")
    return path


def detector_counts(detector_e: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(detector_e / DETECTOR_PNG_E_PER_COUNT), 0, 65535).astype(np.uint16)


def stretch_for_viewing(image: np.ndarray, *, pedestal: float = 0.12, white_percentile: float = 99.99,
                        soft_sigmas: float = 3.0) -> np.ndarray:
    """An 8-bit picture of a detector image (counts or electrons) that a person can look at.

    An asinh stretch, as astronomers use for star fields: linear near the sky level, logarithmic
    for bright stars, so stars from the limiting magnitude to the brightest are all visible. The sky
    level (the median) maps to ``pedestal`` of full scale, so the frame reads as a dark grey sky and
    its noise stays visible instead of being clipped to black; the ``white_percentile`` of the image
    maps to white. The linear range is ``soft_sigmas`` times the sky noise (robust: from the median
    absolute deviation) and at least 0.3 % of the range up to white (all of a noise-free image's
    sky is one level).
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2 or img.size == 0:
        raise ValueError(f"stretch_for_viewing takes a 2-D image; got shape {img.shape}.")
    if not np.all(np.isfinite(img)):
        raise ValueError("stretch_for_viewing takes finite pixel values; the image holds NaN or infinity.")
    if not 0.0 <= pedestal < 1.0:
        raise ValueError(f"pedestal = {pedestal}; it is a fraction of full scale in [0, 1).")
    sky = float(np.median(img))
    sigma = 1.4826 * float(np.median(np.abs(img - sky)))
    span = float(np.percentile(img, white_percentile)) - sky
    if span <= 0.0:
        span = float(img.max()) - sky
    if span <= 0.0:  # a flat image: nothing brighter than the sky
        return np.full(img.shape, round(255 * pedestal), dtype=np.uint8)
    soft = min(max(soft_sigmas * sigma, 3e-3 * span), span)
    level = np.arcsinh((img - sky) / soft) / np.arcsinh(span / soft)
    out = pedestal + (1.0 - pedestal) * level
    return np.clip(np.rint(255.0 * out), 0, 255).astype(np.uint8)


def frame_truth(frame: Frame, renderer: Renderer) -> dict:
    """JSON-ready truth of a frame: attitude, time tag, optics, every star drawn, bright-body flags."""
    b = renderer.bench
    ra, dec, roll = radec_roll_from_q_SN(frame.q_SN)
    tracker = dataclasses.asdict(b.tracker)
    tracker["distortion"] = b.tracker.distortion.as_opencv().tolist()
    tracker["fov_deg"] = list(b.tracker.fov_deg)
    screen = dataclasses.asdict(b.screen)
    screen.pop("luminance")
    return {
        "q_SN": [float(v) for v in frame.q_SN],
        "q_convention": "scalar-first [w, x, y, z]; v_S = dcm(q_SN) @ v_N; S: +z boresight, +x image right, "
        "+y image down; N: GCRS",
        "pointing_deg": {"ra": float(ra), "dec": float(dec), "roll": float(roll)},
        "epoch_utc": frame.epoch.iso,
        "time_tag_ns": frame.time_tag_ns,
        "aberration": frame.aberration,
        "pixel_convention": "(0.5, 0.5) is the centre of the top-left pixel; x right, y down",
        "magnitude_band": "Hipparcos Hp",
        "tracker": tracker,
        "screen": screen,
        "collimator": {
            "focal_length_m": b.collimator.focal_length_m,
            "distortion": b.collimator.distortion.as_opencv().tolist(),
        },
        "screen_axis_px": [b.sx0, b.sy0],
        "screen_spot_sigma_px": renderer.sigma_screen,
        "photometry": dataclasses.asdict(renderer.photometry),
        "detector_raw_png_e_per_count": DETECTOR_PNG_E_PER_COUNT,
        "bodies": frame.bodies,
        "n_stars": len(frame.stars),
        "stars": frame.stars.as_records(),
    }


def write_frame(out_dir, frame: Frame, renderer: Renderer) -> dict:
    """Write ``screen.png``, ``detector_raw.png`` (16-bit counts), ``detector.png`` (8-bit, stretched
    for viewing) and ``truth.json`` into ``out_dir``; returns the truth."""
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if frame.screen is not None:
        write_png(out / "screen.png", frame.screen)
    if frame.detector is not None:
        counts = detector_counts(frame.detector)
        write_png(out / "detector_raw.png", counts)
        write_png(out / "detector.png", stretch_for_viewing(counts))
    truth = frame_truth(frame, renderer)
    (out / "truth.json").write_text(json.dumps(truth, indent=1))
    return truth


class FrameQueue:
    """In-memory output for emulated trackers: keeps the last ``maxlen`` frames (copies), time-tagged."""

    def __init__(self, maxlen: int = 4):
        if maxlen < 1:
            raise ValueError(f"maxlen = {maxlen}; keep at least one frame.")
        self.maxlen = int(maxlen)
        self._frames: list[Frame] = []

    def push(self, frame: Frame) -> None:
        if frame.time_tag_ns is None:
            raise ValueError("every frame handed to an output must carry time_tag_ns (sim time in ns).")
        self._frames.append(frame)
        del self._frames[: -self.maxlen]

    def latest(self) -> Frame | None:
        return self._frames[-1] if self._frames else None

    def __len__(self) -> int:
        return len(self._frames)
