"""``edofproj compensate``: a run's compensation method on image files -> the image to send to the projector.

    edofproj compensate RUN --image TARGET --capture CAPTURED --out PROJ.png
    edofproj compensate RUN --image TARGET --depth-mm Z --out PROJ.png [--preview SHOWN.png]
    edofproj compensate RUN --image TARGET --capture RAW --calib calib.npz --out PROJ.png
    edofproj compensate RUN (--images DIR | --video FILE) (--depth-mm Z | --depth-map MAP.npy)
                        --out (FOLDER | VIDEO.avi | VIDEO.mp4) [--calib calib.npz]

``--method NAME`` chooses the method, built from the run exactly as ``edofproj evaluate`` builds
and scores it (:mod:`edofproj.methods`); the default is the run's own network (``doe+net``),
behind its display guard where the run has one. The network computes ``x = net(I, I*)`` from the
desired image ``I`` and the uncompensated
projection ``I*``: either a camera capture already warped into projector space (``--capture``,
same size as the target) or the simulated capture ``I* = project(I, p_z)`` of the run's DOE on a
flat screen at ``--depth-mm``. ``x`` is clamped to ``[0, 1]`` (what a projector can emit) and
written as an 8- or 16-bit image. Any image size. With ``--depth-mm``, ``--preview`` also writes
the simulated projection of ``x``, and the command prints the SSIM and PSNR against the target of
that projection and of the uncompensated projection ``I*`` (what the network gains there).

With ``--calib`` (from ``edofproj procams calibrate``) the capture is a *raw* camera frame: it is
rectified into projector output light per projector pixel, and the output is the projector
*input* ``u = f^-1(x)`` that emits the light ``x`` (the inverse of the measured response).
The target is then projector output light (full primary = 1); see docs/procams.md.

On a coloured, textured object whose surface the calibration holds (``procams calibrate
--surface-captures``), the target is first scaled into what the surface can show (the goal ``g``)
and the uncompensated image is the photometric correction ``D = clip((g - a) / s, 0, 1)``:

    edofproj compensate RUN --image TARGET --calib calib.npz --surface-from-calib --out U0.png
    (project U0.png, capture it: RAW)
    edofproj compensate RUN --image TARGET --capture RAW --calib calib.npz --out PROJ.png

The first writes ``u0 = f^-1(D)`` (the photometric-only compensation; the network is not run).
The second, for a run trained with ``net.surface_input``, gives the network the measured surface
(:mod:`edofproj.application.surface_frames`); for another network it needs
``--surface-from-calib`` and runs it in cascade after the photometric correction. A calibration
without the surface is refused in one line.

With ``--images DIR`` or ``--video FILE`` a whole show is compensated offline for a flat screen at
``--depth-mm`` or a screen of per-pixel depth ``--depth-map`` (``edofproj render``'s depth
layers), in batches of ``--batch`` frames, on the network path of ``edofproj live``
(:mod:`edofproj.application.offline`): the output is a folder of PNG images or a video (by the
extension of ``--out``: .avi, .mp4), with ``--calib`` the projector input at the projector's size.
A progress bar runs while it works; frames per second are printed at the end. A video that
cannot be decoded to its end or an output that cannot be written completely ends in one line,
and no partial output is left. On the calibration's surface (a run with ``net.surface_input``, or
``--surface-from-calib``) the screen simulated is the object under each frame's photometric
correction, ``s ⊙ A(D) + a``.
"""

from __future__ import annotations

import math
from pathlib import Path

from ..errors import EdofprojError
from ._common import RUN_HELP_SUFFIX, add_method_options, refuse_output_over, run_directory
from ._compensate_psf_map import MAP_METHODS, add_psf_map_options, refuse_map_options, run_psf_map


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "compensate",
        help="compute the projector image for a target with a run's compensation method",
        description=__doc__.split("\n")[0],
    )
    p.add_argument(
        "run",
        metavar="RUN",
        type=run_directory,
        nargs="?",
        default=None,
        help="trained run directory" + RUN_HELP_SUFFIX + " (none with --psf-map, except for --method net)",
    )
    add_method_options(p)
    add_psf_map_options(p)
    targets = p.add_mutually_exclusive_group(required=True)
    targets.add_argument("--image", default=None, metavar="TARGET", help="the desired image (PNG/JPEG/TIFF)")
    targets.add_argument("--images", default=None, metavar="DIR", help="a folder of target images (with --depth-mm)")
    targets.add_argument("--video", default=None, metavar="FILE", help="a target video (with --depth-mm)")
    source = p.add_mutually_exclusive_group()
    source.add_argument(
        "--capture",
        default=None,
        metavar="CAPTURED",
        help="the uncompensated projection captured by a camera, warped to projector space",
    )
    source.add_argument(
        "--depth-mm",
        type=float,
        default=None,
        help="simulate the capture on a flat screen at this depth (mm) with the run's DOE",
    )
    source.add_argument(
        "--depth-map",
        default=None,
        metavar="MAP.npy",
        help="with --images/--video: simulate the capture on a screen of this per-pixel depth, a .npy float "
        "array (H, W) in mm at the frames' size (NaN: nothing hit)",
    )
    p.add_argument(
        "--calib",
        default=None,
        metavar="calib.npz",
        help="with --capture: the capture is a raw camera frame; rectify it and invert the projector's response; "
        "with --images/--video: frames at the projector's size, output the projector input",
    )
    p.add_argument(
        "--surface-from-calib",
        action="store_true",
        help="with --calib: compensate for the surface measured in the calibration (its colour and texture): without "
        "--capture write the photometric correction to project and capture; with --capture run the network after it "
        "(implied for a run trained with net.surface_input)",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="PROJ",
        help="output image: the projector input; with --images/--video a folder or a video (.avi, .mp4)",
    )
    p.add_argument(
        "--preview",
        default=None,
        metavar="SHOWN",
        help="with --depth-mm: also write the simulated projection of the output",
    )
    p.add_argument("--bits", type=int, choices=(8, 16), default=8, help="bits per channel of the outputs")
    p.add_argument(
        "--batch",
        type=int,
        default=None,
        help="with --images/--video: frames per batch (default 1: on a CPU one frame at a time is the fastest)",
    )
    p.add_argument(
        "--fps", type=float, default=None, help="frame rate of a video output (default: the input video's, or 30)"
    )
    p.add_argument("--overwrite", action="store_true", help="with --images/--video: replace an existing output")
    p.set_defaults(func=run)


def run(args) -> int:
    if args.psf_map is not None or args.method in MAP_METHODS:
        return run_psf_map(args)  # the blur a PSF map measured (_compensate_psf_map.py)
    if args.run is None:
        raise EdofprojError("give RUN (a trained run directory), or --psf-map PSF_MAP for a measured blur")
    refuse_map_options(args)
    refuse_outputs_over_inputs(args)
    if args.capture is None and args.depth_mm is None and args.depth_map is None:
        if args.surface_from_calib and args.image is not None:
            return run_photometric(args)
        raise EdofprojError(
            "give one of --capture, --depth-mm or --depth-map (or --calib with --surface-from-calib and no capture: "
            "the photometric correction to project first)"
        )
    if args.surface_from_calib and (args.calib is None or (args.capture is None and args.image is not None)):
        raise EdofprojError(
            "--surface-from-calib goes with --calib: with --image and --capture, or none for the photometric "
            "correction; or with --images/--video"
        )
    if args.images is not None or args.video is not None:
        return run_batch(args)
    if args.batch is not None or args.fps is not None or args.overwrite:
        raise EdofprojError("--batch, --fps and --overwrite go with --images or --video")
    if args.depth_map is not None:
        raise EdofprojError("--depth-map goes with --images or --video ('edofproj render --depth-map' for one image)")
    import torch

    from ..compensation.closed_loop import closed_loop, flat_screen
    from ..imaging.image_io import check_output_path, read_image, write_image

    if args.calib is not None and args.capture is None:
        raise EdofprojError("--calib goes with --capture (a raw camera frame to rectify)")
    if args.preview is not None and args.depth_mm is None:
        raise EdofprojError("--preview needs --depth-mm (a simulated screen to show the result on)")
    if args.depth_mm is not None:
        from ..optics.geometry import check_screen_depths_mm

        check_screen_depths_mm(args.depth_mm, "--depth-mm")
    check_output_path(args.out, args.bits)
    if args.preview is not None:
        check_output_path(args.preview, args.bits)
    method = _build_method(args)
    _check_image_memory(args.image, method.design.cfg.psf.window)
    target = read_image(args.image).unsqueeze(0)
    psf = None
    calibration = None
    if args.calib is not None:
        from ..compensation.surface_net import SurfaceAwareNet
        from ..procams.calibration import ProCamsCalibration
        from ..procams.capture_io import read_rgb

        calibration = ProCamsCalibration.load(args.calib)
        calibration.check_projector_hw((target.shape[-2], target.shape[-1]), what=f"--image '{args.image}'")
        if args.surface_from_calib or isinstance(method.network, SurfaceAwareNet):
            return _compensate_on_surface(
                args, _surface_network(method), target, calibration, read_rgb(args.capture, what="capture")
            )
        light = calibration.to_output_space(read_rgb(args.capture, what="capture"))
        captured = torch.from_numpy(light.astype("float32").transpose(2, 0, 1).copy())[None]
    elif args.capture is not None:
        captured = read_image(args.capture).unsqueeze(0)
        if captured.shape != target.shape:
            raise EdofprojError(
                f"--image is {target.shape[-2]}x{target.shape[-1]} px but --capture is "
                f"{captured.shape[-2]}x{captured.shape[-1]} px (height x width): warp the capture to projector space"
            )
    else:
        psf = method.design.psf([args.depth_mm * 1e-3])
        _note_untrained_depths([args.depth_mm], method.design.cfg)
    compensate = method.frame_function(psf)  # a non-blind method without a simulated screen: refused here
    with torch.inference_mode():
        # a simulated screen runs the whole loop (its projection is the preview); a capture, the method alone
        loop = closed_loop(target, flat_screen(psf), compensate) if psf is not None else None
        emitted = loop.emitted if loop is not None else compensate(target, captured).clamp(0.0, 1.0)
    if calibration is not None:
        write_image(args.out, calibration.to_projector_input(emitted)[0], bits=args.bits)
        print(
            f"wrote {args.out} ({target.shape[-2]}x{target.shape[-1]} px): projector input (measured response inverted)"
        )
        return 0
    write_image(args.out, emitted[0], bits=args.bits)
    print(f"wrote {args.out} ({target.shape[-2]}x{target.shape[-1]} px, height x width; method {method.name})")
    if args.preview is not None:
        if loop is None:  # refused above: --preview needs --depth-mm, which excludes --capture
            raise EdofprojError("--preview needs --depth-mm (a simulated screen to show the result on)")
        write_image(args.preview, loop.projected[0], bits=args.bits)
        print(f"wrote {args.preview}: simulated projection at {args.depth_mm:g} mm")
    if loop is not None:
        compensated, uncompensated = _quality([loop.projected, loop.captured], target)
        print(
            f"against the target at {args.depth_mm:g} mm: compensated (the preview) {compensated}; "
            f"uncompensated projection {uncompensated}"
        )
    return 0


def _check_image_memory(path: str, window: int) -> None:
    """One line, before ``--image`` is decoded, when compensating it would not fit in memory: its size
    from the header (:func:`edofproj.imaging.image_io.image_file_size`; unreadable: ``read_image`` says
    why), the simulated screen (:func:`edofproj.imaging.projection.projection_bytes`) plus the network
    (:data:`edofproj.compensation.registry.NETWORK_FRAME_BYTES_PER_PIXEL`)."""
    from ..compensation.registry import NETWORK_FRAME_BYTES_PER_PIXEL
    from ..imaging.image_io import image_file_size
    from ..imaging.projection import projection_bytes
    from ..limits import check_memory

    size = image_file_size(path)
    if size is not None:
        H, W = size
        check_memory(
            projection_bytes(H, W, window) + NETWORK_FRAME_BYTES_PER_PIXEL * H * W,
            f"compensating the {H}x{W} (height x width) image '{path}'",
            "scale the image down to the projector's resolution first",
        )


def _build_method(args):
    """The method ``--method`` of the run, built as ``evaluate`` builds it (:func:`edofproj.methods.builder.build_method`)."""
    from ..methods.builder import build_method

    return build_method(args.run, args.method, args.baselines)


def _surface_network(method):
    """What compensates on the calibration's surface: a surface-aware network itself (given the
    surface, as ``evaluate --surface`` scores ``doe+surface-net``); any other method in cascade after
    the photometric correction, as the method ``M+photometric`` is scored."""
    from ..compensation.surface_net import SurfaceAwareNet

    if isinstance(method.network, SurfaceAwareNet):
        return method.network.eval()
    return method.frame_function()


def refuse_outputs_over_inputs(args) -> None:
    """``--out`` and ``--preview`` are none of the inputs, contain none, lie inside none (the run's
    own files included; :func:`edofproj.outputs.refuse_output_over_inputs`)."""
    inputs = [("--image", args.image), ("--images", args.images), ("--video", args.video), ("--capture", args.capture)]
    inputs += [("--depth-map", args.depth_map), ("--calib", args.calib), ("--baselines", args.baselines)]
    for option in ("--out", "--preview"):
        value = getattr(args, option[2:])  # a file (an image, a video) or, without a suffix, a folder of frames
        refuse_output_over(
            value, option, inputs, runs=[("RUN", args.run)], file_output=bool(value and Path(value).suffix)
        )


def _note_untrained_depths(depths_mm, cfg) -> None:
    """A note (stderr) when the screen lies outside the depths the run was trained on."""
    import sys

    from ..methods.depth_ranges import depth_notes, trained_range_mm

    for note in depth_notes([float(z) for z in depths_mm], trained_range_mm(cfg)):
        print(f"note: {note}", file=sys.stderr)


def _compensate_on_surface(args, net, target, calibration, capture) -> int:
    """``--capture RAW --calib`` on the calibration's surface (:mod:`edofproj.application.surface_frames`)."""
    from ..application.surface_frames import compensate_on_surface, measured_surface
    from ..compensation.surface_net import SurfaceAwareNet
    from ..imaging.image_io import write_image

    aware = isinstance(net, SurfaceAwareNet)
    what = "the run's surface-aware network (net.surface_input)" if aware else "--surface-from-calib"
    surface = measured_surface(calibration, what)
    u = compensate_on_surface(net, target, capture, calibration, surface, what=f"--image '{args.image}'")
    write_image(args.out, u[0], bits=args.bits)
    how = "the network given the surface" if aware else "photometric correction, then the network"
    print(
        f"wrote {args.out} ({target.shape[-2]}x{target.shape[-1]} px): projector input on the calibration's surface "
        f"({how}; measured response inverted)"
    )
    return 0


def _on_surface(args, net, forward, calibration):
    """The offline show on the calibration's surface: ``(network, simulated capture)`` on the targets.

    The simulated capture is what the object shows of the photometric correction ``D`` of each
    frame's goal, ``s ⊙ A(D) + a`` (absolute light); the network is given it as ``compensate``
    gives a real capture (:class:`edofproj.application.surface_frames.SurfaceLoop`)."""
    from ..application.live import network_memory_format
    from ..application.surface_frames import SurfaceLoop

    what = "--surface-from-calib" if args.surface_from_calib else "the run's surface-aware network (net.surface_input)"
    loop = SurfaceLoop(calibration, net, what)
    network_memory_format(net)  # its weights in the memory format the frames come in
    rho, ambient = loop.surface

    def simulated(images):
        _, light = loop.prepare(images, what="a frame")
        return rho.to(light) * forward(light) + ambient.to(light)

    def compensate(images, captured):
        first, _ = loop.prepare(images, warn=False)
        return loop.compensate_absolute(net, first, captured)

    return compensate, simulated


def run_photometric(args) -> int:
    """``--image T --calib C --surface-from-calib`` without a capture: the photometric correction's projector input."""
    from ..application.surface_frames import measured_surface, photometric_input
    from ..imaging.image_io import check_output_path, read_image, write_image
    from ..procams.calibration import ProCamsCalibration

    if args.calib is None:
        raise EdofprojError("--surface-from-calib needs --calib (the calibration that holds the surface)")
    if args.preview is not None or args.batch is not None or args.fps is not None or args.overwrite:
        raise EdofprojError("--preview, --batch, --fps and --overwrite do not go with the photometric correction")
    check_output_path(args.out, args.bits)
    calibration = ProCamsCalibration.load(args.calib)
    surface = measured_surface(calibration, "--surface-from-calib")
    target = read_image(args.image).unsqueeze(0)
    calibration.check_projector_hw((target.shape[-2], target.shape[-1]), what=f"--image '{args.image}'")
    u0 = photometric_input(target, calibration, surface, what=f"--image '{args.image}'")
    write_image(args.out, u0[0], bits=args.bits)
    print(
        f"wrote {args.out} ({target.shape[-2]}x{target.shape[-1]} px): projector input of the photometric correction "
        "(project and capture it for --capture)"
    )
    return 0


def _quality(shown: list, target) -> list[str]:
    """``SSIM s, PSNR p dB`` of each simulated projection of ``shown`` (each ``(1, 3, H, W)``) against the
    target (PSNR alone below SSIM's window); the target's local moments are filtered once for all."""
    from ..metrics import SSIMReference, gaussian_window, psnr

    texts = [f"PSNR {float(psnr(image, target)[0]):.2f} dB" for image in shown]
    if min(target.shape[-2:]) >= gaussian_window().numel():
        reference = SSIMReference(target)  # then one image at a time: a batch of both takes 0.2 GB more at 1080p
        texts = [f"SSIM {float(reference.ssim(image)[0]):.4f}, {text}" for image, text in zip(shown, texts)]
    return texts


def run_batch(args) -> int:
    """``--images`` / ``--video``: the show compensated offline (module docstring)."""
    import sys

    import numpy as np
    from tqdm import tqdm

    from ..application.offline import FolderSink, VideoSink, compensate_frames, is_video_path, open_frames
    from ..compensation.closed_loop import flat_screen
    from ..compensation.registry import NETWORK_FRAME_BYTES_PER_PIXEL
    from ..compensation.surface_net import SurfaceAwareNet
    from ..imaging.projection import projection_bytes
    from ..limits import check_memory

    if args.depth_mm is None and args.depth_map is None:  # the parser's group asks for one of them or --capture
        raise EdofprojError(
            "--images/--video need --depth-mm or --depth-map, the screen of the show (--capture is one frame)"
        )
    if args.depth_mm is not None:
        from ..optics.geometry import check_screen_depths_mm

        check_screen_depths_mm(args.depth_mm, "--depth-mm")
    if args.preview is not None:
        raise EdofprojError("--preview goes with --image")
    batch = 1 if args.batch is None else args.batch
    if batch < 1:
        raise EdofprojError(f"--batch {batch} must be >= 1")
    if args.fps is not None and not (math.isfinite(args.fps) and args.fps > 0):
        raise EdofprojError(f"--fps {args.fps:g} must be > 0")
    video_out = is_video_path(args.out)
    if video_out and args.bits != 8:
        raise EdofprojError(f"videos hold 8-bit frames, not --bits {args.bits} (write a folder for 16 bits)")
    if not video_out and args.fps is not None:
        raise EdofprojError(f"--fps goes with a video output (.avi, .mp4); --out '{args.out}' is a folder of images")
    if not video_out and Path(args.out).suffix:
        raise EdofprojError(
            f"--out '{args.out}': with --images/--video the output is a folder (no extension) or a video (.avi, .mp4)"
        )
    method = _build_method(args)
    if not method.blind and args.depth_map is not None:
        raise EdofprojError(
            f"method {method.name} is not blind: it needs one PSF, which only a flat screen (--depth-mm) gives"
        )
    surface_aware = isinstance(method.network, SurfaceAwareNet)
    calibration = None
    if args.calib is not None:
        from ..procams.calibration import ProCamsCalibration

        calibration = ProCamsCalibration.load(args.calib)
        if calibration.has_surface and not (args.surface_from_calib or surface_aware):
            print(
                f"note: the surface measured in {args.calib} is not used (--surface-from-calib compensates for it)",
                file=sys.stderr,
            )
    source = open_frames(args.images, args.video, calibration.projector_hw if calibration is not None else None)
    H, W = source.size_hw
    design = method.design
    cfg = method.design.cfg
    psf = None
    if args.depth_map is not None:
        from ..scenes.render import render_masked_depth_map
        from .render import load_depth_map_m

        depth_map_m = load_depth_map_m(args.depth_map, (H, W))
        layers = int(cfg.imaging.depth_layers)

        def forward(images):
            return render_masked_depth_map(images, depth_map_m, design.psf, layers)

        screen = f"depth map {np.nanmin(depth_map_m) * 1e3:.0f}-{np.nanmax(depth_map_m) * 1e3:.0f} mm"
        _note_untrained_depths([np.nanmin(depth_map_m) * 1e3, np.nanmax(depth_map_m) * 1e3], cfg)
    else:
        layers = 1
        psf = design.psf([args.depth_mm * 1e-3])
        forward = flat_screen(psf)
        screen = f"flat screen at {args.depth_mm:g} mm"
        _note_untrained_depths([args.depth_mm], cfg)
    check_memory(
        batch * (projection_bytes(H, W, cfg.psf.window, layers) + NETWORK_FRAME_BYTES_PER_PIXEL * H * W),
        f"compensating batches of {batch} frames of {H}x{W} (height x width)",
        "lower --batch" if batch > 1 else "scale the frames down to the projector's resolution first",
    )
    sink = (
        VideoSink(args.out, args.fps or source.fps, source.size_hw, overwrite=args.overwrite)
        if video_out
        else FolderSink(args.out, bits=args.bits, overwrite=args.overwrite)
    )
    to_input = calibration.inverse_table.apply if calibration is not None else None
    net = method.frame_function(psf)
    if calibration is not None and (args.surface_from_calib or surface_aware):
        net, forward = _on_surface(args, _surface_network(method), forward, calibration)
        screen = f"{screen} on the surface measured in {args.calib}"
    count = source.count or "unknown number of"
    print(
        f"compensating the {source.description} with {method.name}: {count} frames of {H}x{W} (height x width), for a {screen}"
    )
    with sink, tqdm(total=source.count or None, unit="frame", file=sys.stderr, disable=None) as bar:
        summary = compensate_frames(net, source, forward, sink, batch=batch, to_input=to_input, on_batch=bar.update)
    output = "projector input (measured response inverted)" if calibration is not None else "light"
    print(
        f"wrote {args.out}: {summary.frames} frames ({output}) in {summary.wall_s:.1f} s, {summary.fps:.2f} frames/s "
        f"(network {summary.network_ms_per_frame():.1f} ms per frame in batches of {batch})"
    )
    return 0
