"""Frame outputs: truth dictionaries, PNG files, in-memory frames.

Display outputs are the only I/O of ``star_screen``. PNGs use OpenCV (the ``screen`` extra).
``detector.png`` is 16-bit: counts = electrons / ``DETECTOR_PNG_E_PER_COUNT``, clipped to 65535
(the factor is written into the truth so the file can be read back in electrons).
"""

from __future__ import annotations

import dataclasses
import json
import pathlib

import numpy as np

from star_screen.attitude import radec_roll_from_q_SN
from star_screen.render import Frame, Renderer

__all__ = ["frame_truth", "write_png", "write_frame", "DETECTOR_PNG_E_PER_COUNT", "FrameQueue"]

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
        "detector_png_e_per_count": DETECTOR_PNG_E_PER_COUNT,
        "bodies": frame.bodies,
        "n_stars": len(frame.stars),
        "stars": frame.stars.as_records(),
    }


def write_frame(out_dir, frame: Frame, renderer: Renderer) -> dict:
    """Write ``screen.png``, ``detector.png`` and ``truth.json`` into ``out_dir``; returns the truth."""
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if frame.screen is not None:
        write_png(out / "screen.png", frame.screen)
    if frame.detector is not None:
        write_png(out / "detector.png", detector_counts(frame.detector))
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
