"""Device options of the commands that drive a display and a camera: ``procams capture`` and ``live``."""

from __future__ import annotations


def add_device_options(p) -> None:
    """``--camera``, ``--display`` (device specs), ``--settle-s``, ``--average``, ``--exposure``, ``--seed``."""
    from ...procams.devices.spec import device_table_text

    p.add_argument(
        "--camera", required=True, metavar="SPEC", help="camera: " + device_table_text("camera").replace("%", "%%")
    )
    p.add_argument("--display", required=True, metavar="SPEC", help="display: " + device_table_text("display"))
    p.add_argument("--settle-s", type=float, default=0.0, help="wait after showing an image before capturing, s (0)")
    p.add_argument("--average", type=int, default=1, metavar="N", help="frames averaged per capture (1)")
    p.add_argument("--exposure", type=float, default=None, help="exposure (OpenCV cameras that have it; driver units)")
    p.add_argument("--seed", type=int, default=0, help="noise seed of a virtual camera (0)")


def open_devices(args):
    """``(display, camera, grab settings)`` from :func:`add_device_options`' options; close both after use."""
    from ...procams.devices import GrabSettings, open_camera, open_display

    grab = GrabSettings(settle_s=args.settle_s, average=args.average)
    display = open_display(args.display)
    try:
        camera = open_camera(args.camera, display=display, exposure=args.exposure, seed=args.seed)
    except BaseException:
        display.close()
        raise
    return display, camera, grab
