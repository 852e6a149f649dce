"""``edofproj procams``: projector-camera tools -- patterns, a virtual ProCams, calibration, PSF measurement.

    edofproj procams patterns --width W --height H --out PATTERNS
    edofproj procams simulate --patterns PATTERNS --out CAPTURES --depth-mm Z [--doe D | --psf FILE] [--surface T]
    edofproj procams calibrate --patterns PATTERNS --captures CAPTURES --out calib.npz [--surface-captures DIR]
    edofproj procams estimate-psf --patterns PATTERNS --captures CAPTURES --calib calib.npz --out psf.npz
    edofproj procams capture --patterns PATTERNS --out CAPTURES --camera SPEC --display SPEC [--depth-mm Z]
    edofproj procams rectify CAPTURE --calib calib.npz --out OUT
    edofproj procams evaluate --targets DIR --captures DIR --calib calib.npz --out REPORT_DIR
    edofproj procams decode --lab lab.json --x SEQ [--y SEQ] --out map.npz
    edofproj procams psf-map --lab lab.json --dots SEQ --map map.npz --out psf_map.npz
    edofproj procams predict --map map.npz [--psf-map psf_map.npz] --image PROJ --capture CAP
    edofproj procams score (--psf-map psf_map.npz | --lab lab.json --dots SEQ --map map.npz) --image ORIG --compensation COMP

Project every pattern, capture it with a camera (linear/RAW, fixed exposure, the whole
projected image in view) into a folder under the pattern's file name (``capture`` does it
with the devices named by --camera/--display, resumably), calibrate, then measure the PSF
(paper Sec. 5.1-5.2); ``simulate`` plays projector and camera. ``rectify`` brings raw captures
into projector space; ``evaluate`` scores captured projections against their targets. A rig with structured light (its
own captures described by a lab manifest, or ``patterns --structured-light``) is read by
``decode`` (camera -> projector map), ``psf-map`` (PSFs from single-pixel dots) and ``predict``
(a projector image's capture predicted and scored); ``score`` scores compensations in simulation
under the measured blur, as Li et al. (IEEE TII 2020) do.

Each step is one module of this package defining ``register(subparsers)``, as each command is one
module of :mod:`edofproj.commands`; :data:`STEPS` lists them in the order ``--help`` shows them.
The device options that ``capture`` shares with ``live`` are in :mod:`.devices`.
"""

from __future__ import annotations

from . import calibrate, capture, decode, estimate_psf, evaluate, patterns, predict, psf_map, rectify, score, simulate

#: The ``procams`` steps, in the order of a measurement (and of ``edofproj procams --help``).
STEPS = (patterns, simulate, calibrate, estimate_psf, capture, rectify, evaluate, decode, psf_map, predict, score)


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "procams", help="projector-camera patterns, calibration and PSF measurement", description=__doc__.split("\n")[0]
    )
    sub = parser.add_subparsers(dest="procams_command", metavar="STEP")
    sub.required = True
    for step in STEPS:
        step.register(sub)
