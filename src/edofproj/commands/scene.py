"""``edofproj scene``: projection mapping onto 3-D objects.

    edofproj scene list
    edofproj scene render --scene S --doe D --image I --out O [--depth-out D.npy] [--figure F.png]
    edofproj scene render --scene S --run RUN --image I --out O [--projector-out X.png]

``S`` is a built-in scene (``scene list``), a YAML scene file or a mesh file (OBJ, PLY, STL,
GLB) in metres in the projector's frame (+z the optical axis, +x right, +y down). One ray per
projector pixel gives the depth each pixel lands on; the projection goes through the
depth-layer renderer, each source pixel carrying the PSF of the surface it lands on; light
that misses the objects is lost. ``--depth-out`` writes the depth map as ``float32 (H, W)``
in millimetres, NaN where nothing is hit: the array ``edofproj render --depth-map`` reads.

``--run RUN`` compensates the projection with a trained run (its DOE, its configuration and its
network): the scene's rendered uncompensated projection ``I* = R(I)`` is the network's capture,
``x = net(I, I*)`` the projector input (``--projector-out``), and ``--out`` what the objects
show, ``R(clamp(x, 0, 1))``. It prints the SSIM and PSNR over the objects' pixels of both
projections against the image, as ``evaluate --scene`` scores them.
"""

from __future__ import annotations

from ._common import RUN_HELP_SUFFIX, add_config_options, config_from_args, refuse_output_over, run_directory


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "scene",
        help="projection mapping onto 3-D objects (meshes, built-in scenes)",
        description=__doc__.split("\n")[0],
    )
    actions = p.add_subparsers(dest="scene_action", metavar="ACTION", required=True)
    listing = actions.add_parser("list", help="the built-in scenes and the depths they span")
    add_config_options(listing)
    listing.set_defaults(func=run_list)

    r = actions.add_parser("render", help="simulate the projection of an image onto a scene")
    r.add_argument("--scene", required=True, help="built-in scene name, YAML scene file, or .obj/.ply/.stl/.glb mesh")
    design = r.add_mutually_exclusive_group(required=True)
    design.add_argument(
        "--doe",
        help="the design: lens, mlp, free, cubic, axicon, multifocal, a DOE .npz file or a run directory",
    )
    design.add_argument(
        "--run",
        type=run_directory,
        default=None,
        help="a trained run" + RUN_HELP_SUFFIX + ": its DOE, configuration and network compensate the projection",
    )
    r.add_argument(
        "--projector-out",
        default=None,
        help="with --run: also write the compensated projector input (the image to project)",
    )
    r.add_argument(
        "--image",
        required=True,
        help="projector image (PNG/JPEG), used at its size: one ray per pixel (smaller than the panel: the view's centre)",
    )
    r.add_argument("--out", required=True, help="simulated projection (.png, .tif, .jpg, .bmp)")
    r.add_argument(
        "--depth-out", default=None, help="also write the depth map: .npy float32 (H, W) in mm, NaN = no hit"
    )
    r.add_argument("--figure", default=None, help="also write a figure (.png): image, depth, incidence, projection")
    r.add_argument(
        "--falloff",
        action="store_true",
        help="apply the irradiance falloff cos(theta) (v/d)^2 relative to the focus distance v (off by default)",
    )
    r.add_argument("--bits", type=int, choices=(8, 16), default=8, help="bits per channel of the output")
    add_config_options(r)
    r.set_defaults(func=run_render)


def run_list(args) -> int:
    from ..optics.geometry import ProjectorGeometry
    from ..scenes import BUILTIN_SCENES, builtin_scene, cast_scene

    cfg = config_from_args(args)
    geometry = ProjectorGeometry.from_config(cfg.optics)
    stride = max(1, min(geometry.width_px, geometry.height_px) // 60)
    print(
        f"built-in scenes, as seen at {geometry.height_px}x{geometry.width_px} px (throw ratio {geometry.throw_ratio:g}):"
    )
    for name in BUILTIN_SCENES:
        scene = builtin_scene(name, geometry)
        cast = cast_scene(scene, geometry.height_px, geometry.width_px, geometry, stride=stride)
        lo, hi = cast.depth_range_m()
        print(
            f"  {name:<12} {lo * 1e3:5.0f}-{hi * 1e3:4.0f} mm, {cast.hit_fraction:4.0%} of pixels hit: {scene.description}"
        )
    return 0


def _check_image_memory(path: str, cfg) -> None:
    """One line, before ``--image`` is decoded, when rendering it would not fit in memory: its size from
    the header, the projection on ``imaging.depth_layers`` layers
    (:func:`edofproj.imaging.projection.projection_bytes`, a lower bound), as ``render`` checks."""
    from ..imaging.image_io import image_file_size
    from ..imaging.projection import projection_bytes
    from ..limits import check_memory

    size = image_file_size(path)
    if size is not None:
        check_memory(
            projection_bytes(size[0], size[1], cfg.psf.window, int(cfg.imaging.depth_layers)),
            f"rendering the {size[0]}x{size[1]} (height x width) image '{path}' on the scene",
            "scale the image down first",
        )


def run_render(args) -> int:
    from pathlib import Path

    import numpy as np
    import torch

    from ..errors import EdofprojError
    from ..fileio import atomic_path
    from ..imaging import read_image, write_image
    from ..imaging.image_io import check_output_path
    from ..optics.geometry import ProjectorGeometry
    from ..scenes import cast_scene, check_scene_depth_range, load_scene, render_scene
    from .psf import build_design
    from .render import simulator_for

    check_output_path(args.out, args.bits)
    if args.depth_out is not None and Path(args.depth_out).suffix.lower() != ".npy":
        raise EdofprojError(f"--depth-out '{args.depth_out}' must end in .npy")
    if args.figure is not None and Path(args.figure).suffix.lower() != ".png":
        raise EdofprojError(f"--figure '{args.figure}' must end in .png")
    if args.projector_out is not None:
        if args.run is None:
            raise EdofprojError("--projector-out goes with --run (a trained network to compensate with)")
        check_output_path(args.projector_out, args.bits)
    inputs = [("--image", args.image), ("--scene", args.scene), ("--config", args.config)]
    for option in ("--out", "--projector-out", "--depth-out", "--figure"):
        output = getattr(args, option[2:].replace("-", "_"))
        refuse_output_over(output, option, inputs, runs=[("--doe", args.doe), ("--run", args.run)], file_output=True)
    trained = None
    if args.run is not None:
        from ..config import apply_overrides
        from ..methods.builder import require_trained_run
        from ..runs import load_run

        if args.config is not None:
            raise EdofprojError("--run renders with the run's own configuration: change a key with --set, not --config")
        trained = load_run(require_trained_run(args.run))
        cfg = apply_overrides(trained.cfg, args.overrides) if args.overrides else trained.cfg
    else:
        from ..runs.projector import config_for_designs

        cfg = config_for_designs(args.config, args.overrides, [args.doe])  # a run's --doe: its own projector
    geometry = ProjectorGeometry.from_config(cfg.optics)
    scene = load_scene(args.scene, geometry)
    _check_image_memory(args.image, cfg)
    image = read_image(args.image)[None]
    height, width = image.shape[-2:]
    cast = cast_scene(scene, height, width, geometry)
    check_scene_depth_range(
        cast, cfg.psf.depth_min_m, cfg.psf.depth_max_m, "the PSFs (psf.depth_min_mm-psf.depth_max_mm)"
    )
    doe = build_design(cfg, args.doe, args.config) if trained is None else trained.doe
    simulator = simulator_for(cfg, doe)
    reference = cfg.optics.focus_mm * 1e-3 if args.falloff else None
    psf_for_depths = lambda depths: simulator(doe, depths)  # noqa: E731
    loop = None
    with torch.inference_mode():
        if trained is None:
            result = render_scene(image, cast, psf_for_depths, int(cfg.imaging.depth_layers), reference)
        else:
            from ..compensation.closed_loop import closed_loop, scene_screen
            from ..scenes.render import scene_layers_m

            # the layers' PSFs once, for the capture and for the compensated projection
            layers = scene_layers_m(cast, int(cfg.imaging.depth_layers))
            loop = closed_loop(image, scene_screen(cast, psf_for_depths(layers), layers, reference), trained.net)
            result = loop.projected

    write_image(args.out, result[0], bits=args.bits)
    written = [args.out]
    if loop is not None and args.projector_out is not None:
        write_image(args.projector_out, loop.emitted[0], bits=args.bits)
        written.append(args.projector_out)
    if args.depth_out is not None:
        with atomic_path(args.depth_out, suffix=".npy") as tmp:
            np.save(tmp, (cast.depth_m * 1e3).astype(np.float32))
        written.append(args.depth_out)
    if args.figure is not None:
        from ..scenes.figures import plot_scene_render

        plot_scene_render(
            image[0].permute(1, 2, 0).numpy(),
            cast,
            result[0].permute(1, 2, 0).numpy(),
            args.figure,
            f"{scene.name} with {doe.describe()}" + (", compensated by its network" if loop is not None else ""),
        )
        written.append(args.figure)
    lo, hi = cast.depth_range_m()
    print(
        f"wrote {', '.join(written)} ({height}x{width} px): scene '{scene.name}' at {lo * 1e3:.1f}-{hi * 1e3:.1f} mm, "
        f"{cast.hit_fraction:.0%} of pixels hit ({cast.engine} ray casting {cast.seconds:.2f} s); {doe.describe()}"
        + ("; falloff cos(theta) (v/d)^2" if args.falloff else "")
    )
    if loop is not None:
        from ..evaluation.scenes import masked_scores

        hit = torch.as_tensor(cast.hit)
        shown, _ = masked_scores(loop.projected, image, hit)
        plain, _ = masked_scores(loop.captured, image, hit)
        print(
            "over the objects' pixels against the image: compensated "
            f"SSIM {shown[0]['ssim']:.4f}, PSNR {shown[0]['psnr']:.2f} dB; "
            f"uncompensated SSIM {plain[0]['ssim']:.4f}, PSNR {plain[0]['psnr']:.2f} dB"
        )
    return 0
