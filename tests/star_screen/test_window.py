"""The fullscreen star-screen window, on SDL's dummy video driver (no display needed)."""

import numpy as np
import pytest

from star_screen.attitude import q_SN_from_radec_roll
from star_screen.geometry import default_bench
from star_screen.render import Renderer
from star_screen.window import ScreenWindow, decode_corner_code, encode_corner_code
from tests.oracles import require

require("pygame", "the display extra (pygame-ce)")

W, H = 640, 360


@pytest.fixture
def dummy_video(monkeypatch):
    # SDL reads the driver when the video subsystem starts, so this must precede ScreenWindow().
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    monkeypatch.setenv("PYGAME_HIDE_SUPPORT_PROMPT", "1")


@pytest.fixture(scope="module")
def frames(catalog, epoch):
    r = Renderer(default_bench(W, H), catalog)
    qs = q_SN_from_radec_roll(np.array([83.8, 10.0, 250.0]), np.array([-5.4, 60.0, -30.0]), np.zeros(3))
    return [r.render(q, epoch, time_tag_ns=1_000_000 * (i + 1), detector=False) for i, q in enumerate(qs)]


def test_shown_surface_equals_the_frame(dummy_video, frames):
    assert frames[0].screen.max() > 0 and len(frames[0].stars) > 0  # a real sky, not a blank
    with ScreenWindow((W, H), fullscreen=False, corner_code=False) as win:
        for f in frames:
            win.show(f)
            np.testing.assert_array_equal(win.read_back(), f.screen)
        assert [(p.sequence, p.time_tag_ns) for p in win.log] == [(i, f.time_tag_ns) for i, f in enumerate(frames)]
        assert win.log[0].clock is None  # no clock injected: star_screen never reads the wall clock


def test_corner_code_decodes_to_the_frame_counter_and_spares_the_rest(dummy_video, frames):
    ticks = iter(range(100, 200))
    with ScreenWindow((W, H), fullscreen=False, code_bits=12, code_block_px=6, clock=lambda: next(ticks)) as win:
        for n in range(7):
            f = frames[n % len(frames)]
            rec = win.show(f)
            shown = win.read_back()
            assert decode_corner_code(shown, bits=12, block_px=6) == n == rec.sequence
            np.testing.assert_array_equal(shown[6:], f.screen[6:])
            np.testing.assert_array_equal(shown[:6, 72:], f.screen[:6, 72:])
        assert [p.clock for p in win.log] == list(range(100, 107))


def test_corner_code_wraps_modulo_its_bits():
    img = np.zeros((8, 40), np.uint8)
    for (x, y, w, h), code in encode_corner_code(2**5 + 19, 5, 8):
        img[y : y + h, x : x + w] = code
    assert decode_corner_code(img, bits=5, block_px=8) == 19


def test_refuses_wrong_size_missing_time_tag_and_wrong_dtype(dummy_video, frames):
    with ScreenWindow((W, H), fullscreen=False) as win:
        with pytest.raises(ValueError, match=r"shape \(360, 640\)"):
            win.show(image=np.zeros((H, W + 1), np.uint8), time_tag_ns=0)
        with pytest.raises(ValueError, match="uint8"):
            win.show(image=np.zeros((H, W), np.uint16), time_tag_ns=0)
        untagged = frames[0].__class__(**{**frames[0].__dict__, "time_tag_ns": None})
        with pytest.raises(ValueError, match="time_tag_ns"):
            win.show(untagged)
        with pytest.raises(ValueError, match="time_tag_ns"):
            win.show(image=frames[0].screen)
        assert win.presented == 0 and len(win.log) == 0


def test_fullscreen_opens_on_the_display_and_checks_index_and_size(dummy_video):
    import pygame

    pygame.display.init()
    size = pygame.display.get_desktop_sizes()[0]
    pygame.display.quit()
    with ScreenWindow(size, display=0) as win:
        assert win.vsync in (True, False) and win.vsync_note  # dummy driver: refused, and says why
        win.show(image=np.full(size[::-1], 7, np.uint8), time_tag_ns=3)
        assert win.read_back()[-1, -1] == 7
    with pytest.raises(ValueError, match="display = 5"):
        ScreenWindow(size, display=5)
    with pytest.raises(ValueError, match="native mode"):
        ScreenWindow((size[0] // 2, size[1] // 2))
    with pytest.raises(ValueError, match="code_bits"):
        ScreenWindow((W, H), code_bits=0)


def test_closed_window_refuses_frames(dummy_video):
    win = ScreenWindow((W, H), fullscreen=False)
    win.close()
    win.close()  # idempotent
    with pytest.raises(RuntimeError, match="closed"):
        win.show(image=np.zeros((H, W), np.uint8), time_tag_ns=0)
