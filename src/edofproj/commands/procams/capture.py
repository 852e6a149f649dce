"""``edofproj procams capture``: show every pattern on a display and capture it with a camera (resumable).

    edofproj procams capture --patterns PATTERNS --out CAPTURES --camera SPEC --display SPEC [--depth-mm Z]

An interrupted session is resumed: patterns already captured are kept.
"""

from __future__ import annotations

import numpy as np

from ...errors import EdofprojError
from .._common import refuse_output_over
from .devices import add_device_options, open_devices


def register(subparsers) -> None:
    """Add ``procams capture`` to the ``procams`` subcommands."""
    p = subparsers.add_parser(
        "capture", help="show every pattern on a display and capture it with a camera (resumable)"
    )
    p.add_argument("--patterns", required=True, help="pattern folder (from 'procams patterns')")
    p.add_argument("--out", required=True, help="capture folder (an interrupted session is resumed)")
    add_device_options(p)
    p.add_argument("--depth-mm", type=float, default=None, help="screen distance, mm (recorded in captures.json)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ...procams.session import capture_patterns

    if args.depth_mm is not None and not (np.isfinite(args.depth_mm) and args.depth_mm > 0):
        raise EdofprojError(f"--depth-mm {args.depth_mm:g} must be positive")
    refuse_output_over(args.out, "--out", [("--patterns", args.patterns)])
    display, camera, grab = open_devices(args)
    with display, camera:
        print(f"capturing with camera '{camera.spec}' and display '{display.spec}' into {args.out}")
        try:
            result = capture_patterns(args.patterns, args.out, display, camera, grab, depth_mm=args.depth_mm, log=print)
        except KeyboardInterrupt:
            print(f"interrupted: the captures so far are kept in {args.out}; run the same command again to resume")
            raise
    hw = result.camera_hw
    print(
        f"captured {result.captured} patterns ({result.skipped} already there) of {result.total} into {args.out}"
        + (f", camera {hw[0]}x{hw[1]} (height x width)" if hw else "")
    )
    return 0
