"""``edofproj procams simulate``: capture a pattern folder with a virtual projector-camera system.

    edofproj procams simulate --patterns PATTERNS --out CAPTURES --depth-mm Z [--doe D | --psf FILE]

The virtual ProCams plays projector and camera: the patterns blurred by the PSF of ``--doe`` (or
of ``--psf``) at the screen distance, seen by a camera of a random pose with gamma and noise.

With ``--surface TEXTURE`` (a built-in texture of ``edofproj evaluate --surface`` or a reflectance
file at the projector's size) the screen is that coloured, textured object, lit by
``--surface-ambient``: simulated with the same ``--seed`` (the same camera pose) as the white
screen's captures, its folder holds the black and white fields that ``procams calibrate
--surface-captures`` measures the surface from (``ground_truth.npz`` holds the closed-form truth).
"""

from __future__ import annotations

import numpy as np

from ...errors import EdofprojError
from .._common import add_config_options, refuse_output_over
from ..psf import add_optics_options, psf_overrides
from ._common import note_width


def register(subparsers) -> None:
    """Add ``procams simulate`` to the ``procams`` subcommands."""
    p = subparsers.add_parser("simulate", help="capture a pattern folder with a virtual projector-camera system")
    add_config_options(p)
    p.add_argument("--patterns", required=True, help="pattern folder (from 'procams patterns')")
    p.add_argument("--out", required=True, help="output capture folder")
    p.add_argument("--depth-mm", type=float, required=True, help="screen distance, mm")
    p.add_argument("--doe", default=None, help="design whose PSF to simulate (lens, mlp, ..., a DOE file or run dir)")
    p.add_argument("--psf", default=None, help="use this PSF file (edofproj psf .npz) instead of simulating one")
    p.add_argument("--window", type=int, default=None, help="window K of the simulated PSF (default: config)")
    add_optics_options(p)
    p.add_argument("--gamma", type=float, nargs="+", default=[2.2], help="projector gamma, one or three values (2.2)")
    p.add_argument("--noise-sigma", type=float, default=0.005, help="camera noise, std in [0, 1] units (0.005)")
    p.add_argument(
        "--camera-scale",
        type=float,
        default=3.0,
        help="camera pixels per projector pixel (3); the camera is 4/3 of that times the projector",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the camera pose and the noise (0)")
    p.add_argument(
        "--surface",
        default=None,
        metavar="TEXTURE",
        help="the screen is a textured object: a built-in texture (leaves, field, checker, brick, gravel, white) "
        "or a reflectance image/.npy in [0, 1] at the projector's size (default: a white screen)",
    )
    p.add_argument(
        "--surface-ambient",
        type=float,
        default=0.0,
        help="with --surface: ambient illuminance on the object, a fraction of the projector's white (0)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    p.set_defaults(func=run)


def _simulated_psf(args, cfg, depth_m: float) -> np.ndarray:
    """The RGB PSF ``(3, K, K)`` at ``depth_m``: from ``--psf`` or simulated for ``--doe``."""
    from ...optics.psf_bank import PSFBank, simulator_from_config

    if args.psf is not None:
        if args.doe is not None:
            raise EdofprojError("give --doe or --psf, not both")
        bank = PSFBank.load(args.psf)
        index = int(np.argmin(np.abs(bank.depths_m - depth_m)))
        if abs(bank.depths_m[index] - depth_m) > 0.5e-3:
            raise EdofprojError(
                f"PSF file '{args.psf}' has no depth within 0.5 mm of {depth_m * 1e3:g} mm "
                f"(it has {', '.join(f'{z * 1e3:g}' for z in bank.depths_m)} mm)"
            )
        if bank.psf.shape[1] != 3:
            raise EdofprojError(
                f"PSF file '{args.psf}' has {bank.psf.shape[1]} channel(s); the virtual ProCams needs RGB"
            )
        return bank.psf[index].double().numpy()
    import torch

    from ...optics.psf_bank import design_engine
    from ..psf import build_design

    doe = build_design(cfg, args.doe, args.config)
    with torch.no_grad():
        return (
            simulator_from_config(cfg, engine=design_engine(doe, cfg.psf.engine))(doe, np.array([depth_m]))[0]
            .double()
            .numpy()
        )


def run(args) -> int:
    from ...optics.geometry import ProjectorGeometry
    from ...procams.patterns import PatternManifest
    from ...procams.virtual import VirtualProCams, simulate_captures

    inputs = [
        ("--patterns", args.patterns),
        ("--psf", args.psf),
        ("--surface", args.surface),
        ("--config", args.config),
    ]
    refuse_output_over(args.out, "--out", inputs, runs=[("--doe", args.doe)])
    from ...runs.projector import config_for_designs

    cfg = config_for_designs(args.config, psf_overrides(args) + list(args.overrides), [args.doe])  # a run's own
    from ...optics.geometry import check_screen_depths_mm

    check_screen_depths_mm(args.depth_mm, "--depth-mm")
    if len(args.gamma) not in (1, 3) or any(not (0.1 <= g <= 10) for g in args.gamma):
        raise EdofprojError("--gamma takes one or three values in 0.1-10")
    if args.noise_sigma < 0 or not (1.0 <= args.camera_scale <= 10.0):
        raise EdofprojError("--noise-sigma must be >= 0 and --camera-scale in 1-10")
    from ...imaging.surfaces import check_illuminance

    check_illuminance(args.surface_ambient, "--surface-ambient")
    if args.surface is None and args.surface_ambient != 0.0:
        raise EdofprojError("--surface-ambient goes with --surface")
    manifest = PatternManifest.load(args.patterns)
    reflectance = None
    if args.surface is not None:
        from ...data.textures import surface_reflectance

        hw = (manifest.height, manifest.width)
        reflectance = surface_reflectance(args.surface, hw)[0].permute(1, 2, 0).double().numpy()
    depth_m = args.depth_mm * 1e-3
    psf = _simulated_psf(args, cfg, depth_m)
    gamma = tuple(args.gamma) * (3 // len(args.gamma))
    note_width(manifest, cfg)
    rig = VirtualProCams.example(
        (manifest.height, manifest.width),
        psf,
        seed=args.seed,
        camera_scale=args.camera_scale,
        gamma=gamma,
        noise_sigma=args.noise_sigma,
        depth_m=depth_m,
        pixel_pitch_m=float(ProjectorGeometry.from_config(cfg.optics).pixel_pitch_m(depth_m)),
        reflectance=reflectance,
        surface_ambient=args.surface_ambient,
    )
    print(
        f"simulating {len(manifest.entries)} captures with a {rig.camera_hw[0]}x{rig.camera_hw[1]} (height x width) camera "
        f"({rig.camera_pixels_per_projector_pixel():.2f} camera px per projector px), PSF window {psf.shape[-1]} px, "
        f"in-window energy {np.round(psf.sum(axis=(-1, -2)), 4).tolist()}"
    )
    simulate_captures(rig, args.patterns, args.out, seed=args.seed, overwrite=args.overwrite, log=print)
    if reflectance is not None:
        print(
            f"the screen is the textured surface '{args.surface}' (reflectance "
            f"{reflectance.min():.3f}-{reflectance.max():.3f}), ambient {args.surface_ambient:g}"
        )
    print(f"wrote {args.out} (captures, ground_truth.json/.npz, true_psf.npz, captures.json)")
    return 0
