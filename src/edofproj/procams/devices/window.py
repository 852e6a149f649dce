"""``screen:N``: a borderless full-screen window on monitor ``N``, drawn with pygame (SDL2).

Why pygame/SDL2: SDL2 places a full-screen window on a chosen monitor
(``set_mode(..., display=N)``) at the desktop's resolution, blits an RGB array to it without
resampling (``pygame.surfarray``), and has headless drivers (``SDL_VIDEODRIVER=dummy`` or
``offscreen``) so the same code runs in tests and read back its pixels. pyglet and glfw go
through OpenGL, which a headless machine often lacks, and need a textured quad for a plain
image. pygame ships wheels with SDL2 inside for Linux, macOS and Windows: ``pip install
'edofproj[projector]'``.

:meth:`PygameDisplay.show` returns after ``pygame.display.flip()`` and the event queue is
pumped; projectors add their own latency (a frame or more), which the capture's settle delay
(``--settle-s``) covers. Closing the window or pressing Escape raises ``KeyboardInterrupt``:
the session stops as on Ctrl-C.
"""

from __future__ import annotations

import os

import numpy as np

from ...errors import EdofprojError
from .base import Display


def _pygame():
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    try:
        import pygame  # optional: the projector extra
    except ImportError:
        raise EdofprojError(
            "display 'screen:N' needs pygame: pip install 'edofproj[projector]' (or use --display file:PATH)"
        ) from None
    return pygame


def list_screens() -> list[tuple[int, int]]:
    """``(width, height)`` of each monitor SDL sees (initializes pygame's display module)."""
    pygame = _pygame()
    try:
        pygame.display.init()
        return [tuple(size) for size in pygame.display.get_desktop_sizes()]
    except pygame.error as exc:
        raise EdofprojError(f"no screen found: SDL says '{exc}' (no display server? set DISPLAY)") from None


class PygameDisplay(Display):
    """A full-screen window on monitor ``index`` at its desktop resolution."""

    def __init__(self, index: int = 0) -> None:
        super().__init__()
        self.spec = f"screen:{index}"
        screens = list_screens()
        if not screens:
            raise EdofprojError("no screen found (SDL lists no monitor)")
        if not (0 <= index < len(screens)):
            found = ", ".join(f"screen:{i} ({h}x{w}, height x width)" for i, (w, h) in enumerate(screens))
            raise EdofprojError(f"display 'screen:{index}' does not exist; found {found}")
        pygame = self._pg = _pygame()
        self.index = index
        self.surface = pygame.display.set_mode((0, 0), pygame.FULLSCREEN | pygame.NOFRAME, display=index)
        pygame.display.set_caption("edofproj")
        pygame.mouse.set_visible(False)
        width, height = self.surface.get_size()
        self._size = (height, width)

    @property
    def size_hw(self) -> tuple[int, int]:
        return self._size

    def _present(self, frame: np.ndarray) -> None:
        pygame = self._pg
        pixels = np.round(frame * 255.0).astype(np.uint8).transpose(1, 0, 2)  # surfarray is (W, H, 3)
        pygame.surfarray.blit_array(self.surface, pixels)
        pygame.display.flip()
        for event in pygame.event.get():
            if event.type == pygame.QUIT or (event.type == pygame.KEYDOWN and event.key == pygame.K_ESCAPE):
                raise KeyboardInterrupt

    def read_back(self) -> np.ndarray:
        """The window's pixels ``(H, W, 3)`` uint8, as drawn."""
        return self._pg.surfarray.array3d(self._pg.display.get_surface()).transpose(1, 0, 2).copy()

    def close(self) -> None:
        self._pg.display.quit()

    def settings(self) -> dict:
        return {"spec": self.spec, "backend": "pygame", "size_hw": list(self._size)}
