"""Device specs: one string names a display or a camera on the command line (``--camera opencv:0``).

:data:`DEVICE_TABLE` is the one table of kinds (printed by ``--help`` and in docs/procams.md).
A spec is ``KIND`` or ``KIND:ARGUMENT``; everything after the first colon is the argument
(a ``cmd:`` template may hold colons and spaces).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

from ...errors import EdofprojError

if TYPE_CHECKING:
    from .base import Camera, Display


class DeviceKind(NamedTuple):
    role: str  # "display" or "camera"
    kind: str
    example: str
    description: str


DEVICE_TABLE: tuple[DeviceKind, ...] = (
    DeviceKind("display", "screen", "screen:1", "full-screen window on monitor N, pygame/SDL2, extra [projector]"),
    DeviceKind("display", "file", "file:shown.png", "writes every frame atomically to PATH, for other software"),
    DeviceKind("display", "memory", "memory", "keeps the frame in memory, for the Python API and a virtual camera"),
    DeviceKind("camera", "opencv", "opencv:0", "OpenCV VideoCapture: a camera index, a video, an image sequence"),
    DeviceKind(
        "camera", "cmd", "cmd:gphoto2 --capture-image-and-download --filename {out}", "runs a command writing {out}"
    ),
    DeviceKind("camera", "folder", "folder:incoming/", "waits for each new image a tethered camera writes to DIR"),
    DeviceKind("camera", "virtual", "virtual:captures/", "the virtual ProCams of a 'procams simulate' folder"),
)


def device_table_text(role: str) -> str:
    """The rows of :data:`DEVICE_TABLE` for ``role``, one ``example  description`` line each."""
    return "; ".join(f"{row.example}: {row.description}" for row in DEVICE_TABLE if row.role == role)


def _split(spec: str, role: str) -> tuple[str, str]:
    kind, _, argument = str(spec).partition(":")
    kinds = [row.kind for row in DEVICE_TABLE if row.role == role]
    if kind not in kinds:
        raise EdofprojError(f"unknown {role} '{spec}': use one of {', '.join(k + ':...' for k in kinds)}")
    return kind, argument


def open_display(spec: str) -> Display:
    """The display named by ``spec`` (:data:`DEVICE_TABLE`)."""
    # start-up: the backends load here, so that '--help' reads DEVICE_TABLE without NumPy's users
    from .displays import FileDisplay, MemoryDisplay
    from .window import PygameDisplay

    kind, argument = _split(spec, "display")
    if kind == "memory":
        return MemoryDisplay()
    if kind == "file":
        if not argument:
            raise EdofprojError("display 'file:' needs a path, e.g. file:shown.png")
        return FileDisplay(argument)

    try:
        index = int(argument or 0)
    except ValueError:
        raise EdofprojError(f"display '{spec}': the screen number must be an integer, e.g. screen:1") from None
    return PygameDisplay(index)


def open_camera(spec: str, display: Display | None = None, exposure: float | None = None, seed: int = 0) -> Camera:
    """The camera named by ``spec``; ``display`` is what a virtual camera looks at."""
    # start-up: the backends (OpenCV, the virtual ProCams) load here, not with DEVICE_TABLE
    from ..virtual import VirtualProCams
    from .cameras import CommandCamera, FolderCamera, OpenCVCamera, VirtualCamera

    kind, argument = _split(spec, "camera")
    if exposure is not None and kind != "opencv":
        raise EdofprojError(f"--exposure is set through OpenCV only; set it on the camera itself for '{kind}:'")
    if not argument:
        raise EdofprojError(
            f"camera '{kind}:' needs an argument (e.g. {[r.example for r in DEVICE_TABLE if r.kind == kind][0]})"
        )
    if kind == "opencv":
        return OpenCVCamera(argument, exposure=exposure)
    if kind == "cmd":
        return CommandCamera(argument)
    if kind == "folder":
        return FolderCamera(argument)

    if display is None:
        raise EdofprojError("a virtual camera needs the display it looks at")
    return VirtualCamera(VirtualProCams.from_capture_folder(argument), display, seed=seed, spec=f"virtual:{argument}")
