"""The detector frames of image-source star trackers, live on the operator page.

A tracker whose source is ``image`` renders, noises and solves a detector image at every exposure
(the kind's image solver, which offers an ``on_frame`` hook). The page shows the newest of them, at most ``FRAME_HZ``
a second (wall time), and only while a page is open:

1. the live feed's sender thread (:class:`stand.view.state.LiveFeed`, ten times a second) *arms* a
   :class:`FrameTap` when a page is open and the tap's last frame is at least ``1 / FRAME_HZ`` old: it sets the
   solver's ``on_frame``;
2. at the tracker's next exposure the loop's thread calls it once (:meth:`FrameTap.take`): one copy of the exposure
   (:meth:`SparseExposure.image`, under 1 ms of CPU for 1024 x 768), and ``on_frame`` is unset again. Without a page, or
   between two frames, the exposure pays one attribute test and nothing else; no tick pays anything;
3. the sender thread shrinks the copy (:func:`shrink`: 2 x 2 maximum, so a star of one pixel stays, and an asinh
   stretch to 8 bits) and sends it through the pipe with its header (:meth:`FrameTap.collect`);
4. the server's process encodes it as PNG (:func:`encode_png`), keeps the newest per tracker for ``GET
   /api/frame?device=NAME``, and tells the pages over the websocket (``{"type": "frame", ...}``), which then load it.

The exposure is the one the tracker's extractor read (:mod:`star_screen.tracking.exposure`): pixels it never read
hold the background level, so the sky between stars is flat but for the noisy background grid (every 8th pixel of
every 8th row) the extractor measures the background from.
"""

from __future__ import annotations

import logging
import math
import threading
import time

import numpy as np

log = logging.getLogger(__name__)

#: Most frames per second (wall time) the page is sent of each tracker.
FRAME_HZ = 2.0
#: Frames are shrunk by this factor in each direction (1024 x 768 -> 512 x 384) before they leave the run's process.
SHRINK = 2
#: The stretch to 8 bits: black at the background plus ``BLACK_SIGMA`` noise sigmas, asinh with its knee at
#: ``KNEE_SIGMA`` sigmas above that, white at ``WHITE_E`` electrons above it (a magnitude-3 star's peak pixel).
BLACK_SIGMA = 1.0
KNEE_SIGMA = 3.0
WHITE_E = 20000.0


def shrink(image: np.ndarray, background_e: float, sigma_e: float, factor: int = SHRINK) -> np.ndarray:
    """A detector image (electrons, float) as 8 bits, ``factor`` times smaller each way: the maximum of each
    ``factor`` x ``factor`` block (a faint star's peak pixel survives), stretched by asinh from the background plus
    ``BLACK_SIGMA`` sigmas (black) to ``WHITE_E`` electrons above it (white)."""
    import cv2  # its dilation releases the interpreter lock: the run's loop goes on meanwhile

    # The maximum over each block: a dilation whose kernel starts at the pixel, then every factor-th pixel.
    block = np.ones((factor, factor), np.uint8)
    small = cv2.dilate(np.asarray(image, np.float32), block, anchor=(0, 0))[::factor, ::factor]
    h, w = image.shape[0] // factor, image.shape[1] // factor
    knee = np.float32(max(KNEE_SIGMA * sigma_e, 1.0))
    above = np.maximum(small[:h, :w] - np.float32(background_e + BLACK_SIGMA * sigma_e), np.float32(0.0))
    level = np.arcsinh(above / knee) * np.float32(255.0 / math.asinh(WHITE_E / knee))
    return np.minimum(level + np.float32(0.5), np.float32(255.0)).astype(np.uint8)  # rounded


def encode_png(header: dict, pixels: bytes) -> bytes:
    """The 8-bit frame ``pixels`` (``header["size_px"]`` = [width, height]) as PNG (in the server's process)."""
    import cv2

    w, h = header["size_px"]
    ok, png = cv2.imencode(".png", np.frombuffer(pixels, np.uint8).reshape(h, w))
    if not ok:
        raise ValueError(f"the frame of {header.get('device')!r} could not be encoded as PNG")
    return png.tobytes()


class FrameTap:
    """One image tracker's frames, from the loop's thread (:meth:`take`) to the feed's sender thread
    (:meth:`arm`, :meth:`collect`). Only the loop's thread unsets the solver's ``on_frame`` and only the sender sets
    it (when unset), so the loop never sees it change between its test and its call."""

    def __init__(self, name: str, solver, frame_hz: float = FRAME_HZ, clock=time.monotonic):
        self.name, self.solver = name, solver
        self.period_s = 1.0 / frame_hz
        self.clock = clock
        self._next_s = -math.inf
        self._frame = None  # (t_s, image, fields), taken in the loop's thread, collected by the sender
        self._lock = threading.Lock()
        self.taken = 0  # frames copied in the loop's thread
        self.take_s = 0.0  # the CPU time the loop's thread spent copying them
        self.error: str | None = None

    def arm(self) -> bool:
        """Ask for the next exposure's image, unless one was asked for less than a period ago or is on its way."""
        now = self.clock()
        if now < self._next_s or self.solver.on_frame is not None or self._frame is not None:
            return False
        self._next_s = now + self.period_s
        self.solver.on_frame = self.take
        return True

    def take(self, t_s: float, fields: dict) -> None:
        """The loop's thread, right after the exposure's solve: copy the image the extractor read. Whatever goes
        wrong here costs the page its frame, never the tracker its measurement (``error`` says what, once)."""
        c0 = time.thread_time()
        self.solver.on_frame = None
        try:
            exposure = self.solver.exposure
            frame = (t_s, exposure.image(), float(exposure.background_e), float(exposure.sigma_e), dict(fields))
        except Exception as exc:  # noqa: BLE001 - the run goes on without this frame
            if self.error is None:
                self.error = f"{self.name}: no frame for the page: {type(exc).__name__}: {exc}"
                log.warning("%s", self.error)
            return
        with self._lock:
            self._frame = frame
        self.taken += 1
        self.take_s += time.thread_time() - c0

    def collect(self) -> tuple[dict, bytes] | None:
        """The newest frame taken, shrunk to 8 bits, as ``(header, pixels)``; None when none was taken since."""
        with self._lock:
            frame, self._frame = self._frame, None
        if frame is None:
            return None
        t_s, image, background_e, sigma_e, fields = frame
        small = shrink(image, background_e, sigma_e)
        matched = int(fields.get("stars_matched") or 0)
        header = {"device": self.name, "t_s": float(t_s), "size_px": [small.shape[1], small.shape[0]],
                  "full_px": [image.shape[1], image.shape[0]], "stars_extracted": fields.get("stars_in_field"),
                  "stars_matched": matched, "solved": matched > 0,
                  "stretch": {"black_e": background_e + BLACK_SIGMA * sigma_e, "white_e": WHITE_E}}
        return header, small.tobytes()


def taps(devices: dict, frame_hz: float = FRAME_HZ) -> list[FrameTap]:
    """A tap for every device of a scene that renders an image (its ``image`` is a solver taking ``on_frame``)."""
    return [FrameTap(name, dev.image, frame_hz) for name, dev in devices.items()
            if hasattr(getattr(dev, "image", None), "on_frame")]
