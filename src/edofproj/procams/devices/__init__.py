"""Projector and camera devices behind two small interfaces (:class:`Display`, :class:`Camera`).

* :mod:`.base` -- the interfaces and :func:`grab_frame` (settle delay, averaging, saturation);
* :mod:`.displays` -- ``memory`` and ``file:PATH`` displays;
* :mod:`.window` -- ``screen:N``, a full-screen pygame (SDL2) window;
* :mod:`.cameras` -- ``opencv:``, ``cmd:``, ``folder:`` and ``virtual:`` cameras;
* :mod:`.spec` -- device spec strings and their table.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .base import Camera, Display, GrabSettings, grab_frame  # noqa: F401
    from .spec import DEVICE_TABLE, open_camera, open_display  # noqa: F401

_EXPORTS = {
    **dict.fromkeys(("Camera", "Display", "GrabSettings", "grab_frame"), ".base"),
    **dict.fromkeys(("DEVICE_TABLE", "open_camera", "open_display"), ".spec"),
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    # start-up: loaded on first use (PEP 562); '--help' reads spec.DEVICE_TABLE alone
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
