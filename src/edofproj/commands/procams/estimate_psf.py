"""``edofproj procams estimate-psf``: measure the PSF from captured Bernoulli patterns (paper Eq. 13).

    edofproj procams estimate-psf --patterns PATTERNS --captures CAPTURES --calib calib.npz --out psf.npz

The captures of the Bernoulli noise patterns, brought into projector space with the calibration,
are deconvolved by the patterns (Tikhonov-regularized, ``--eps``), over the whole image or per
``--patch``; the result is a PSF file in the format of ``edofproj psf``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ...errors import EdofprojError
from .._common import add_config_options, config_from_args, refuse_output_over
from ..psf import add_optics_options, psf_overrides
from ._common import note_width


def register(subparsers) -> None:
    """Add ``procams estimate-psf`` to the ``procams`` subcommands."""
    p = subparsers.add_parser("estimate-psf", help="measure the PSF from captured Bernoulli patterns (paper Eq. 13)")
    add_config_options(p)
    p.add_argument("--patterns", required=True, help="pattern folder")
    p.add_argument("--captures", required=True, help="capture folder")
    p.add_argument("--calib", required=True, help="calibration .npz (from 'procams calibrate')")
    p.add_argument("--out", required=True, help="output PSF .npz (the 'edofproj psf' format)")
    p.add_argument("--window", type=int, default=None, help="PSF window K, odd (default: config psf.window)")
    p.add_argument(
        "--patch",
        type=int,
        default=0,
        metavar="N",
        help="estimate per N x N patch and write their mean (0: the whole image at once)",
    )
    p.add_argument(
        "--depth-mm",
        type=float,
        default=None,
        help="screen distance, mm (default: depth_mm in the capture folder's captures.json)",
    )
    add_optics_options(p)
    p.add_argument("--eps", type=float, default=None, help="Tikhonov epsilon relative to the mean pattern power (1e-4)")
    p.add_argument(
        "--iterations",
        type=int,
        default=None,
        help="passes removing the light that enters each region from outside it (8)",
    )
    p.add_argument(
        "--patch-psfs", default=None, metavar="FILE", help="also write the per-patch PSFs and patch centres (.npz)"
    )
    p.set_defaults(func=run)


def _depth_mm(args) -> float:
    if args.depth_mm is not None:
        depth = args.depth_mm
    else:
        info = Path(args.captures) / "captures.json"
        try:
            depth = json.loads(info.read_text(encoding="utf-8"))["depth_mm"]
        except (OSError, ValueError, KeyError, TypeError):
            depth = None
        if depth is None:
            raise EdofprojError(f"give --depth-mm (the screen distance): '{info}' does not record depth_mm")
    if not (np.isfinite(depth) and depth > 0):
        raise EdofprojError(f"--depth-mm {depth} must be a positive number")
    return float(depth)


def run(args) -> int:
    from ...fileio import save_npz_atomic
    from ...optics.geometry import ProjectorGeometry
    from ...procams.calibration import ProCamsCalibration
    from ...procams.capture_io import read_captures
    from ...procams.patterns import PatternManifest, read_pattern
    from ...procams.psf_estimation import DEFAULT_EPS_REL, DEFAULT_ITERATIONS, bernoulli_files, measure_psf

    for flag, path in (("--out", args.out), ("--patch-psfs", args.patch_psfs)):
        if path is not None and not str(path).endswith(".npz"):
            raise EdofprojError(f"{flag} '{path}' must end in .npz")
    inputs = [("--patterns", args.patterns), ("--captures", args.captures), ("--calib", args.calib)]
    for option in ("--out", "--patch-psfs"):
        output = getattr(args, option[2:].replace("-", "_"))
        refuse_output_over(output, option, inputs + [("--config", args.config)], file_output=True)
    cfg = config_from_args(args, psf_overrides(args))
    depth_mm = _depth_mm(args)
    manifest = PatternManifest.load(args.patterns)
    calibration = ProCamsCalibration.load(args.calib)
    files = bernoulli_files(manifest)
    entries = {e.file: e for e in manifest.entries}
    patterns = {f: read_pattern(args.patterns, entries[f], manifest) for f in files}
    captures = read_captures(args.captures, files, expected_hw=calibration.camera_map.camera_hw)
    estimate = measure_psf(
        manifest,
        patterns,
        captures,
        calibration,
        cfg.psf.window,
        patch=args.patch,
        eps_rel=args.eps if args.eps is not None else DEFAULT_EPS_REL,
        iterations=args.iterations if args.iterations is not None else DEFAULT_ITERATIONS,
    )
    note_width(manifest, cfg)
    pitch = float(ProjectorGeometry.from_config(cfg.optics).pixel_pitch_m(depth_mm * 1e-3))
    where = "whole image" if args.patch <= 0 else f"mean of {len(estimate.patch_boxes)} patches of {args.patch} px"
    bank = estimate.to_bank(
        depth_mm * 1e-3, pitch, description=f"measured (edofproj procams, {len(files)} Bernoulli patterns, {where})"
    )
    bank.save(args.out)
    if args.patch_psfs:
        save_npz_atomic(
            args.patch_psfs,
            psf=estimate.patch_psfs.astype(np.float32),
            patch_boxes=estimate.patch_boxes,
            patch_centers_px=estimate.patch_centers_px,
            depths_m=np.array([depth_mm * 1e-3]),
        )
    print(
        f"wrote {args.out}: PSF at {depth_mm:g} mm, window {cfg.psf.window} px, {where}; in-window energy "
        f"{np.round(estimate.energy_in_window, 4).tolist()} (R, G, B)"
    )
    return 0
