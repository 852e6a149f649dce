"""``edofproj procams``: projector-camera tools -- patterns, a virtual ProCams, calibration, PSF measurement.

    edofproj procams patterns --width W --height H --out PATTERNS
    edofproj procams simulate --patterns PATTERNS --out CAPTURES --depth-mm Z [--doe D | --psf FILE]
    edofproj procams calibrate --patterns PATTERNS --captures CAPTURES --out calib.npz
    edofproj procams estimate-psf --patterns PATTERNS --captures CAPTURES --calib calib.npz --out psf.npz
    edofproj procams capture --patterns PATTERNS --out CAPTURES --camera SPEC --display SPEC [--depth-mm Z]
    edofproj procams rectify CAPTURE --calib calib.npz --out OUT
    edofproj procams evaluate --targets DIR --captures DIR --calib calib.npz --out REPORT_DIR

Project every pattern, capture it with a camera (linear/RAW, fixed exposure, the whole
projected image in view) into a folder under the pattern's file name (``capture`` does it
with the devices named by --camera/--display, resumably), calibrate, then measure the PSF
(paper Sec. 5.1-5.2); ``simulate`` plays projector and camera. ``rectify`` brings raw captures
into projector space; ``evaluate`` scores captured projections against their targets.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import EdofprojError
from ._common import add_config_options, config_from_args
from .psf import add_optics_options, psf_overrides


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "procams", help="projector-camera patterns, calibration and PSF measurement", description=__doc__.split("\n")[0]
    )
    sub = parser.add_subparsers(dest="procams_command", metavar="STEP")
    sub.required = True

    p = sub.add_parser("patterns", help="write the calibration and PSF-measurement patterns with manifest.json")
    p.add_argument("--width", type=int, required=True, help="projector width, pixels")
    p.add_argument("--height", type=int, required=True, help="projector height, pixels")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--bernoulli", type=int, default=5, metavar="N", help="number of Bernoulli noise patterns (5)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the noise patterns (0)")
    p.add_argument("--dots", default="16x32", metavar="ROWSxCOLS", help="dot grid (16x32, as in the paper)")
    p.add_argument(
        "--dot-radius",
        type=int,
        default=None,
        metavar="PX",
        help="dot radius in pixels (default: 1/8 of the smaller dot spacing)",
    )
    p.add_argument(
        "--color-levels",
        type=int,
        default=6,
        metavar="L",
        help="levels per channel of the colour samples: L^3 uniform fields (6)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    p.set_defaults(func=run_patterns)

    p = sub.add_parser("simulate", help="capture a pattern folder with a virtual projector-camera system")
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
    p.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    p.set_defaults(func=run_simulate)

    p = sub.add_parser("calibrate", help="geometric and colour calibration from captured patterns")
    p.add_argument("--patterns", required=True, help="pattern folder")
    p.add_argument("--captures", required=True, help="capture folder (one capture per pattern, same names)")
    p.add_argument("--out", required=True, help="output calibration .npz")
    p.add_argument(
        "--neighbours",
        type=int,
        default=6,
        metavar="K",
        help="nearest colour samples in the local linear response interpolation (6)",
    )
    p.set_defaults(func=run_calibrate)

    p = sub.add_parser("estimate-psf", help="measure the PSF from captured Bernoulli patterns (paper Eq. 13)")
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
    p.set_defaults(func=run_estimate_psf)

    p = sub.add_parser("capture", help="show every pattern on a display and capture it with a camera (resumable)")
    p.add_argument("--patterns", required=True, help="pattern folder (from 'procams patterns')")
    p.add_argument("--out", required=True, help="capture folder (an interrupted session is resumed)")
    add_device_options(p)
    p.add_argument("--depth-mm", type=float, default=None, help="screen distance, mm (recorded in captures.json)")
    p.set_defaults(func=run_capture)

    p = sub.add_parser("rectify", help="raw camera captures -> projector output light per projector pixel")
    p.add_argument("capture", metavar="CAPTURE", help="a raw capture (image file) or a folder of them")
    p.add_argument("--calib", required=True, help="calibration .npz (from 'procams calibrate')")
    p.add_argument("--out", required=True, help="output image (for one capture) or folder (for a folder)")
    p.add_argument("--bits", type=int, choices=(8, 16), default=16, help="bits per channel of the output PNGs (16)")
    p.set_defaults(func=run_rectify)

    p = sub.add_parser("evaluate", help="score captured projections against their targets (paper Table 2)")
    p.add_argument("--targets", required=True, help="folder of target images (projector output light)")
    p.add_argument(
        "--captures",
        required=True,
        help="folder with one sub-folder of raw captures per method (e.g. lens, lens+net, doe+net), named like the targets",
    )
    p.add_argument("--calib", required=True, help="calibration .npz (from 'procams calibrate')")
    p.add_argument("--out", required=True, help="report folder (report.md, report.html, comparison figure, scores)")
    p.add_argument("--weights-dir", default=None, help="folder of LPIPS/DISTS weights (default: the usual places)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing report folder")
    p.set_defaults(func=run_evaluate)


# --------------------------------------------------------------------------- devices (shared with 'live')


def add_device_options(p) -> None:
    """``--camera``, ``--display`` (device specs), ``--settle-s``, ``--average``, ``--exposure``, ``--seed``."""
    from ..procams.devices.spec import device_table_text

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
    from ..procams.devices import GrabSettings, open_camera, open_display

    grab = GrabSettings(settle_s=args.settle_s, average=args.average)
    display = open_display(args.display)
    try:
        camera = open_camera(args.camera, display=display, exposure=args.exposure, seed=args.seed)
    except BaseException:
        display.close()
        raise
    return display, camera, grab


# --------------------------------------------------------------------------- patterns


def run_patterns(args) -> int:
    from ..procams.capture_io import atomic_folder, write_rgb_png
    from ..procams.patterns import MANIFEST_NAME, PatternSpec, build_pattern_set, manifest_json_text, parse_grid

    spec = PatternSpec(
        width=args.width,
        height=args.height,
        bernoulli_count=args.bernoulli,
        seed=args.seed,
        dot_grid=parse_grid(args.dots),
        dot_radius_px=args.dot_radius,
        color_levels=args.color_levels,
    )
    manifest, images = build_pattern_set(spec)
    with atomic_folder(args.out, overwrite=args.overwrite) as tmp:
        for name, image in images.items():
            write_rgb_png(tmp / name, image)
        (tmp / MANIFEST_NAME).write_text(manifest_json_text(manifest), encoding="utf-8")
    counts = {role: len(manifest.with_role(role)) for role in ("bernoulli", "color_sample")}
    print(
        f"wrote {len(images)} patterns of {args.width}x{args.height} to {args.out}: {counts['bernoulli']} Bernoulli, "
        f"{spec.dot_grid[0]}x{spec.dot_grid[1]} dots, 5 full fields, {counts['color_sample']} colour samples"
    )
    return 0


# --------------------------------------------------------------------------- simulate


def _note_width(manifest, cfg) -> None:
    """Say so when the patterns are not as wide as the projector the optics config describes."""
    if manifest.width != cfg.optics.width_px:
        print(
            f"note: the patterns are {manifest.width} px wide but optics.width_px is {cfg.optics.width_px}: "
            "PSFs and pixel pitch are for the latter (patterns = a crop of its image; else pass --width-px)"
        )


def _simulated_psf(args, cfg, depth_m: float) -> np.ndarray:
    """The RGB PSF ``(3, K, K)`` at ``depth_m``: from ``--psf`` or simulated for ``--doe``."""
    from ..optics.psf_bank import PSFBank, simulator_from_config

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

    from ..doe import build_doe
    from ..optics.psf_bank import design_engine

    doe = build_doe(cfg, args.doe)
    with torch.no_grad():
        return (
            simulator_from_config(cfg, engine=design_engine(doe, cfg.psf.engine))(doe, np.array([depth_m]))[0]
            .double()
            .numpy()
        )


def run_simulate(args) -> int:
    from ..optics.geometry import ProjectorGeometry
    from ..procams.patterns import PatternManifest
    from ..procams.virtual import VirtualProCams, simulate_captures

    cfg = config_from_args(args, psf_overrides(args))
    if args.depth_mm <= 0:
        raise EdofprojError(f"--depth-mm {args.depth_mm:g} must be positive")
    if len(args.gamma) not in (1, 3) or any(not (0.1 <= g <= 10) for g in args.gamma):
        raise EdofprojError("--gamma takes one or three values in 0.1-10")
    if args.noise_sigma < 0 or not (1.0 <= args.camera_scale <= 10.0):
        raise EdofprojError("--noise-sigma must be >= 0 and --camera-scale in 1-10")
    manifest = PatternManifest.load(args.patterns)
    depth_m = args.depth_mm * 1e-3
    psf = _simulated_psf(args, cfg, depth_m)
    gamma = tuple(args.gamma) * (3 // len(args.gamma))
    _note_width(manifest, cfg)
    rig = VirtualProCams.example(
        (manifest.height, manifest.width),
        psf,
        seed=args.seed,
        camera_scale=args.camera_scale,
        gamma=gamma,
        noise_sigma=args.noise_sigma,
        depth_m=depth_m,
        pixel_pitch_m=float(ProjectorGeometry.from_config(cfg.optics).pixel_pitch_m(depth_m)),
    )
    print(
        f"simulating {len(manifest.entries)} captures with a {rig.camera_hw[1]}x{rig.camera_hw[0]} camera "
        f"({rig.camera_pixels_per_projector_pixel():.2f} camera px per projector px), PSF window {psf.shape[-1]} px, "
        f"in-window energy {np.round(psf.sum(axis=(-1, -2)), 4).tolist()}"
    )
    simulate_captures(rig, args.patterns, args.out, seed=args.seed, overwrite=args.overwrite, log=print)
    print(f"wrote {args.out} (captures, ground_truth.json/.npz, true_psf.npz, captures.json)")
    return 0


# --------------------------------------------------------------------------- calibrate


def run_calibrate(args) -> int:
    from ..procams.calibration import calibrate_folders

    if not str(args.out).endswith(".npz"):
        raise EdofprojError(f"--out '{args.out}' must end in .npz")
    manifest, calibration = calibrate_folders(args.patterns, args.captures, neighbours=args.neighbours)
    calibration.save(args.out)
    cm = calibration.camera_map
    print(
        f"wrote {args.out}: {len(cm.dots_proj)} dots matched, camera {cm.camera_hw[1]}x{cm.camera_hw[0]}, "
        f"{cm.camera_pixels_per_projector_pixel():.2f} camera px per projector px, lens distortion up to "
        f"{cm.homography_residual_px().max():.2f} camera px beyond the homography"
    )
    print("colour-mixing matrix (camera RGB per unit projector output):")
    for row in calibration.color.mixing_matrix:
        print("  " + " ".join(f"{v:8.4f}" for v in row))
    print(
        f"{len(calibration.color.sample_inputs)} colour samples, black level "
        f"{np.round(calibration.color.black_level, 4).tolist()}"
    )
    return 0


# --------------------------------------------------------------------------- estimate-psf


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


def run_estimate_psf(args) -> int:
    from ..fileio import save_npz_atomic
    from ..optics.geometry import ProjectorGeometry
    from ..procams.calibration import ProCamsCalibration
    from ..procams.capture_io import read_captures
    from ..procams.patterns import PatternManifest, read_pattern
    from ..procams.psf_estimation import DEFAULT_EPS_REL, DEFAULT_ITERATIONS, bernoulli_files, measure_psf

    for flag, path in (("--out", args.out), ("--patch-psfs", args.patch_psfs)):
        if path is not None and not str(path).endswith(".npz"):
            raise EdofprojError(f"{flag} '{path}' must end in .npz")
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
    _note_width(manifest, cfg)
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


# --------------------------------------------------------------------------- capture


def run_capture(args) -> int:
    from ..procams.session import capture_patterns

    if args.depth_mm is not None and not (np.isfinite(args.depth_mm) and args.depth_mm > 0):
        raise EdofprojError(f"--depth-mm {args.depth_mm:g} must be positive")
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
        + (f", camera {hw[1]}x{hw[0]}" if hw else "")
    )
    return 0


# --------------------------------------------------------------------------- rectify


def run_rectify(args) -> int:
    from ..imaging.image_io import IMAGE_EXTENSIONS, check_output_path, write_image
    from ..procams.calibration import ProCamsCalibration
    from ..procams.capture_io import atomic_folder, read_rgb

    calibration = ProCamsCalibration.load(args.calib)
    source = Path(args.capture)

    def rectified(path: Path) -> np.ndarray:
        light = calibration.to_output_space(read_rgb(path, what="capture"))
        return np.ascontiguousarray(light.transpose(2, 0, 1))

    if source.is_dir():
        files = sorted(p for p in source.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file())
        if not files:
            raise EdofprojError(f"capture folder '{source}' holds no image")
        with atomic_folder(args.out) as tmp:
            for path in files:
                write_image(tmp / (path.stem + ".png"), rectified(path), bits=args.bits)
        print(f"wrote {len(files)} rectified captures to {args.out}")
    else:
        check_output_path(args.out, args.bits)
        write_image(args.out, rectified(source), bits=args.bits)
        print(f"wrote {args.out}")
    H, W = calibration.projector_hw
    print(f"projector space: {W}x{H}, projector output light (full primary = 1; clipped to [0, 1] in the file)")
    return 0


# --------------------------------------------------------------------------- evaluate


def run_evaluate(args) -> int:
    from ..evaluation.captures import evaluate_captures

    result = evaluate_captures(
        args.targets, args.captures, args.calib, args.out, weights_dir=args.weights_dir, overwrite=args.overwrite
    )
    for line in result.summary_lines():
        print(line)
    print(f"wrote {args.out} (report.md, report.html, comparison.png, scores.csv)")
    return 0
