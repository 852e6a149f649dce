"""Projector and camera devices behind two small interfaces (:class:`Display`, :class:`Camera`).

* :mod:`.base` -- the interfaces and :func:`grab_frame` (settle delay, averaging, saturation);
* :mod:`.displays` -- ``memory`` and ``file:PATH`` displays;
* :mod:`.window` -- ``screen:N``, a full-screen pygame (SDL2) window;
* :mod:`.cameras` -- ``opencv:``, ``cmd:``, ``folder:`` and ``virtual:`` cameras;
* :mod:`.spec` -- device spec strings and their table.
"""

from .base import Camera, Display, GrabSettings, grab_frame  # noqa: F401
from .spec import DEVICE_TABLE, open_camera, open_display  # noqa: F401
