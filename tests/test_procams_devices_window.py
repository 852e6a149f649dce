"""The ``screen:N`` display (pygame/SDL2) under SDL's dummy video driver, read back pixel by pixel."""

import numpy as np
import pytest

pytest.importorskip("pygame", reason="the screen: display needs pygame (pip install 'edofproj[projector]')")

from edofproj.errors import EdofprojError  # noqa: E402
from edofproj.procams.devices import open_display  # noqa: E402


@pytest.fixture
def dummy_video(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    import pygame

    pygame.display.quit()  # a fresh display module picks the driver up
    yield
    pygame.display.quit()


def test_screen_shows_the_exact_pixels(dummy_video):
    with open_display("screen:0") as display:
        height, width = display.size_hw
        image = np.random.default_rng(0).integers(0, 256, (height, width, 3)) / 255.0
        display.show(image)
        np.testing.assert_array_equal(display.read_back(), np.round(image * 255).astype(np.uint8))
        with pytest.raises(EdofprojError, match=f"but display 'screen:0' is {height}x{width}"):
            display.show(image[:-1])


def test_missing_screen_lists_the_screens_found(dummy_video):
    with pytest.raises(EdofprojError, match=r"'screen:3' does not exist; found screen:0 \(\d+x\d+, height x width\)"):
        open_display("screen:3")
    with pytest.raises(EdofprojError, match="must be an integer"):
        open_display("screen:left")
