"""Displays without a screen: in memory (the Python API, tests) and ``file:PATH`` (other software).

``file:PATH`` writes every shown frame atomically to ``PATH`` (8-bit PNG, or any format
:func:`edofproj.imaging.image_io.write_image` writes), so another program -- a projector's
own player, a remote screen -- can pick it up, and a reader never sees half a file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...imaging.image_io import check_output_path, write_image
from .base import Display


class MemoryDisplay(Display):
    """Keeps the shown frame in :attr:`shown` and counts frames; ``size_hw`` fixes its size if given."""

    def __init__(self, size_hw: tuple[int, int] | None = None) -> None:
        super().__init__()
        self.spec = "memory"
        self._size_hw = None if size_hw is None else (int(size_hw[0]), int(size_hw[1]))
        self.frames_shown = 0

    @property
    def size_hw(self) -> tuple[int, int] | None:
        return self._size_hw

    def _present(self, frame: np.ndarray) -> None:
        self.frames_shown += 1


class FileDisplay(Display):
    """Writes every shown frame atomically to ``path``."""

    def __init__(self, path: str | Path) -> None:
        super().__init__()
        self.path = Path(path)
        self.spec = f"file:{self.path}"
        check_output_path(self.path, 8)

    def _present(self, frame: np.ndarray) -> None:
        write_image(self.path, np.ascontiguousarray(frame.transpose(2, 0, 1)), bits=8)

    def settings(self) -> dict:
        return {"spec": self.spec, "path": str(self.path.resolve())}
