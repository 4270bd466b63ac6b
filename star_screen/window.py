"""Fullscreen star-screen window for a bench PC (optional extra ``display``: pygame-ce).

pygame-ce bundles an SDL with the KMS/DRM backend, so a display PC without X can run it
(``SDL_VIDEODRIVER=kmsdrm``); tests use ``SDL_VIDEODRIVER=dummy``. Frames are shown as 8-bit
palette surfaces wrapping the frame's own buffer (``pygame.image.frombuffer(..., 'P')`` with a
grey palette: ~1.7 ms at 1080p, against ~30 ms for an RGB ``blit_array``; docs/benchmarks.md).

Time tags: every shown frame must carry ``time_tag_ns`` (sim time, ns). The window keeps a log of
:class:`Presented` records (present sequence number, frame time tag, and the injected clock's
reading right after the flip when a ``clock`` is given: ``star_screen`` never reads the wall clock
itself, the stand injects ``time.monotonic_ns`` or a vsync-aware clock).

Corner code (switchable, on by default): the present sequence number is drawn over the frame as
``code_bits`` square blocks of ``code_block_px`` screen pixels in a row from the top-left corner,
least significant bit first, 255 for a one and 0 for a zero. Block 0 toggles on every frame, so a
photodiode over it sees a square wave whose edges mark the frames; a camera or the tracker reads
the full counter and matches it to the log. The code overwrites whatever stars were in that
corner; keep the corner outside the collimator's field (the default 16 blocks of 8 px cover
128 x 8 px) or switch it off with ``corner_code=False``. :func:`decode_corner_code` reads it back.
"""

from __future__ import annotations

import os
import warnings
from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["ScreenWindow", "Presented", "decode_corner_code", "encode_corner_code"]


def _pygame():
    # pygame prints a banner on import unless told not to; a stand's console is not the place.
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    try:
        import pygame
    except ImportError:
        raise RuntimeError(
            "the star-screen window needs pygame-ce; install the display extra: pip install 'adcs-stand[display]'."
        ) from None
    return pygame


@dataclass(frozen=True)
class Presented:
    """One shown frame: present sequence number, the frame's sim time tag (ns), clock after flip."""

    sequence: int
    time_tag_ns: int
    clock: float | int | None


def encode_corner_code(counter: int, bits: int, block_px: int) -> list[tuple[tuple[int, int, int, int], int]]:
    """Rectangles ``(x, y, w, h)`` and drive codes (0 or 255) that encode ``counter`` modulo 2**bits."""
    return [((i * block_px, 0, block_px, block_px), 255 if (counter >> i) & 1 else 0) for i in range(bits)]


def decode_corner_code(image: np.ndarray, bits: int = 16, block_px: int = 8) -> int:
    """The counter encoded in the top-left corner of a shown (H, W) image (centre pixel of each block)."""
    c = block_px // 2
    return sum(1 << i for i in range(bits) if image[c, i * block_px + c] >= 128)


class ScreenWindow:
    """A window that shows 8-bit star-screen frames, time-tagged and optionally corner-coded.

    ``size`` = (width, height) in screen pixels: the bench screen's resolution, and every frame
    must have exactly that shape (H, W). ``display``: index of the monitor for fullscreen.
    ``fullscreen=False`` opens a plain window for debugging. ``vsync``: ask SDL to sync flips to
    the display refresh; ``self.vsync`` tells whether it was granted (SDL refuses it on the dummy
    driver and where no accelerated renderer exists; the window then flips immediately).
    """

    def __init__(
        self,
        size: tuple[int, int],
        *,
        display: int = 0,
        fullscreen: bool = True,
        vsync: bool = True,
        corner_code: bool = True,
        code_bits: int = 16,
        code_block_px: int = 8,
        clock=None,
        log_length: int = 100_000,
        title: str = "star screen",
    ):
        w, h = (int(v) for v in size)
        if w < 1 or h < 1:
            raise ValueError(f"window size = {tuple(size)}; width and height must be positive pixel counts.")
        if not 1 <= code_bits <= 32:
            raise ValueError(f"code_bits = {code_bits}; allowed 1 to 32.")
        if code_block_px < 1 or code_bits * code_block_px > w or code_block_px > h:
            raise ValueError(f"code_block_px = {code_block_px} with code_bits = {code_bits} does not fit a "
                             f"{w} x {h} screen; use blocks of at least 1 px whose row fits the width.")
        pg = _pygame()
        self._pg = pg
        pg.display.init()
        n = pg.display.get_num_displays()
        if not 0 <= display < n:
            pg.display.quit()
            raise ValueError(f"display = {display}; this machine has displays 0 to {n - 1}.")
        self.size = (w, h)
        self.display_index = int(display)
        self.corner_code = bool(corner_code)
        self.code_bits = int(code_bits)
        self.code_block_px = int(code_block_px)
        self.clock = clock
        self.log: deque[Presented] = deque(maxlen=int(log_length))
        self.presented = 0
        self.vsync = False
        self.vsync_note = "not requested"
        flags = pg.FULLSCREEN if fullscreen else 0
        pg.display.set_caption(title)
        surface = None
        if vsync:
            # pygame-ce honours vsync only through SDL's renderer (SCALED); at the native size
            # SCALED is 1:1. A missing accelerated renderer comes back as a warning, not an error.
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                try:
                    surface = pg.display.set_mode((w, h), flags | pg.SCALED, display=display, vsync=1)
                except pg.error as exc:
                    self.vsync_note = f"refused by SDL: {exc}"
            if surface is not None and caught:
                self.vsync_note = "refused by SDL: " + "; ".join(str(c.message) for c in caught)
                surface = None
            elif surface is not None:
                self.vsync, self.vsync_note = True, "granted"
        if surface is None:
            surface = pg.display.set_mode((w, h), flags, display=display)
        if surface.get_size() != (w, h):
            got = surface.get_size()
            pg.display.quit()
            raise ValueError(f"window size = {(w, h)} but the display gave {got}; set the screen's resolution "
                             "to the display's native mode.")
        self._surface = surface
        self._palette = [(i, i, i) for i in range(256)]
        self._closed = False

    # ------------------------------------------------------------------ showing
    def show(self, frame=None, *, image: np.ndarray | None = None, time_tag_ns: int | None = None) -> Presented:
        """Show a rendered :class:`~star_screen.render.Frame` (its ``screen`` and ``time_tag_ns``),
        or a bare ``image`` (H, W) uint8 with an explicit ``time_tag_ns``. Returns the log record."""
        if self._closed:
            raise RuntimeError("the window is closed; open a new ScreenWindow to show frames.")
        if frame is not None:
            image, time_tag_ns = frame.screen, frame.time_tag_ns
        if time_tag_ns is None:
            raise ValueError("time_tag_ns = None; every displayed frame must carry its sim time in ns.")
        if image is None:
            raise ValueError("the frame has no screen image (rendered with screen=False); render the screen.")
        w, h = self.size
        if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.shape != (h, w):
            got = (getattr(image, "dtype", type(image).__name__), getattr(image, "shape", None))
            raise ValueError(f"frame image is {got[0]} with shape {got[1]}; this window shows uint8 frames of "
                             f"shape ({h}, {w}).")
        if not image.flags.c_contiguous:
            image = np.ascontiguousarray(image)
        pg = self._pg
        src = pg.image.frombuffer(image.data, (w, h), "P")
        src.set_palette(self._palette)
        self._surface.blit(src, (0, 0))
        seq = self.presented
        if self.corner_code:
            for rect, code in encode_corner_code(seq, self.code_bits, self.code_block_px):
                self._surface.fill((code, code, code), rect)
        pg.display.flip()
        # SDL needs its event queue pumped or the OS declares the window unresponsive.
        pg.event.pump()
        rec = Presented(seq, int(time_tag_ns), self.clock() if self.clock is not None else None)
        self.log.append(rec)
        self.presented += 1
        return rec

    #: Outputs share one method name (``FrameQueue.push``), so a display node can feed either.
    push = show

    def read_back(self) -> np.ndarray:
        """What the window's surface holds now, as an (H, W) uint8 grey image (red channel)."""
        return np.ascontiguousarray(self._pg.surfarray.array_red(self._surface).T)

    def quit_requested(self) -> bool:
        """True when the operator closed the window or pressed Escape."""
        pg = self._pg
        for ev in pg.event.get((pg.QUIT, pg.KEYDOWN)):
            if ev.type == pg.QUIT or getattr(ev, "key", None) == pg.K_ESCAPE:
                return True
        return False

    def close(self) -> None:
        """Close the window (idempotent)."""
        if not self._closed:
            self._closed = True
            self._pg.display.quit()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
