"""``edofproj render``: simulate what a screen shows when the projector emits an image.

The PSFs come from a PSF file (``--psf``, written by ``edofproj psf``) or are simulated for
a design (``--doe``). The screen is a plane at one depth, a tilted plane (``--tilt-deg``,
``--near-mm`` [``--far-mm``]) or any per-pixel depth map (``--depth-map``, a ``.npy`` array
``(H, W)`` in millimetres, NaN where the light meets nothing and is lost, as ``edofproj scene
render --depth-out`` writes); non-planar screens are rendered by depth layers
(:mod:`edofproj.imaging.depth_layers`). With ``--surface`` the screen is coloured and textured
(a built-in texture or a reflectance image/``.npy`` in projector space, the image's size) and
``--ambient`` adds reflected ambient light: the output is ``s ⊙ render + s E``
(:mod:`edofproj.imaging.surfaces`). The output has the input's size.
"""

from __future__ import annotations

import numpy as np

from ..errors import EdofprojError
from ._common import add_config_options, refuse_output_over


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "render", help="simulate the projection of an image (defocus blur + haze)", description=__doc__.split("\n")[0]
    )
    p.add_argument("--image", required=True, help="input image (PNG/JPEG, 8 or 16 bit)")
    p.add_argument("--out", required=True, help="output image (.png, .tif, .jpg, .bmp)")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--psf", default=None, help="PSF file (.npz from 'edofproj psf')")
    source.add_argument(
        "--doe",
        default=None,
        help="simulate the PSFs of a design: lens, mlp, free, cubic, axicon, multifocal, "
        "a DOE .npz file or a run directory",
    )
    p.add_argument(
        "--depth-index",
        type=int,
        default=None,
        help="with --psf: which depth of the PSF file (needed when it holds several)",
    )
    p.add_argument("--depth-mm", type=float, default=None, help="with --doe: the screen depth in mm")
    p.add_argument(
        "--depth-map", default=None, help="per-pixel screen depth: a .npy float array (H, W) in mm, the image's size"
    )
    p.add_argument(
        "--tilt-deg",
        type=float,
        default=None,
        help="a plane screen turned by this angle about the vertical axis (>0: near side on the left)",
    )
    p.add_argument("--near-mm", type=float, default=None, help="with --tilt-deg: depth seen by the near image edge, mm")
    p.add_argument(
        "--far-mm",
        type=float,
        default=None,
        help="with --tilt-deg: depth seen by the far image edge, mm (default: from the tilt and throw ratio)",
    )
    p.add_argument(
        "--surface",
        default=None,
        metavar="TEXTURE",
        help="a coloured, textured screen: a built-in texture (white, leaves, field, checker, brick, gravel) or a "
        "reflectance image/.npy in projector space, the image's size, values in [0, 1]",
    )
    p.add_argument(
        "--ambient",
        type=float,
        default=0.0,
        help="with --surface: ambient illuminance reflected by the surface, a fraction of the projector's white",
    )
    p.add_argument("--bits", type=int, choices=(8, 16), default=8, help="bits per channel of the output")
    add_config_options(p)
    p.set_defaults(func=run)


def check_arguments(args) -> None:
    """Reject option combinations that do not make sense, before any work is done."""
    tilt_options = [name for name in ("near_mm", "far_mm") if getattr(args, name) is not None]
    if args.tilt_deg is None and tilt_options:
        raise EdofprojError(f"--{tilt_options[0].replace('_', '-')} needs --tilt-deg (a tilted plane screen)")
    if args.tilt_deg is not None and args.near_mm is None:
        raise EdofprojError("--tilt-deg needs --near-mm (and optionally --far-mm)")
    if args.tilt_deg is not None and args.depth_map is not None:
        raise EdofprojError("give either --depth-map or --tilt-deg, not both")
    non_planar = args.depth_map is not None or args.tilt_deg is not None
    if args.psf is not None:
        if args.depth_mm is not None:
            raise EdofprojError("--depth-mm goes with --doe; with --psf choose the depth with --depth-index")
        if non_planar and args.depth_index is not None:
            raise EdofprojError(
                "--depth-index picks one plane; a depth map or tilted screen uses the PSF file's depths"
            )
    else:
        if args.depth_index is not None:
            raise EdofprojError("--depth-index goes with --psf; with --doe give --depth-mm")
        if non_planar and args.depth_mm is not None:
            raise EdofprojError(
                "--depth-mm is a flat screen; with --depth-map or --tilt-deg the depths come from the map"
            )
        if not non_planar and args.depth_mm is None:
            raise EdofprojError("--doe needs the screen depth: --depth-mm Z (or --depth-map / --tilt-deg)")
    if args.surface is None and args.ambient != 0.0:
        raise EdofprojError("--ambient goes with --surface (ambient light reflected by a textured screen)")
    from ..imaging.surfaces import check_illuminance

    check_illuminance(args.ambient, "--ambient")
    from ..optics.geometry import check_screen_depths_mm

    for name in ("depth_mm", "near_mm", "far_mm"):
        value = getattr(args, name)
        if value is not None:
            check_screen_depths_mm(value, f"--{name.replace('_', '-')}")


def load_depth_map_m(path: str, image_hw: tuple[int, int]) -> np.ndarray:
    """A ``.npy`` depth map in mm (NaN: nothing hit), checked against the image size; returned in metres."""
    from ..fileio import read_arrays
    from ..optics.geometry import check_screen_depths_mm

    arrays = read_arrays(path, what="depth map")
    if list(arrays) != [""]:
        raise EdofprojError(f"depth map '{path}' must be one .npy array in mm, not an .npz archive")
    depth_mm = arrays[""]
    if depth_mm.dtype.kind not in "fiu":
        raise EdofprojError(f"depth map '{path}' must hold numbers (depth in mm), got dtype {depth_mm.dtype}")
    if depth_mm.shape != tuple(image_hw):
        raise EdofprojError(
            f"depth map '{path}' has shape {depth_mm.shape}, expected the image's (H, W) = {tuple(image_hw)}"
        )
    depth_mm = depth_mm.astype(np.float64)
    if np.all(np.isnan(depth_mm)):
        raise EdofprojError(f"depth map '{path}' is all NaN: the light meets nothing")
    check_screen_depths_mm(depth_mm[~np.isnan(depth_mm)], f"depth map '{path}'")
    return depth_mm * 1e-3


def simulator_for(cfg, doe):
    """The PSF simulator for ``doe``: the 2-D engine when the design is not radially symmetric."""
    from ..optics.psf_bank import simulator_from_config

    engine = cfg.psf.engine
    if not doe.radially_symmetric:
        engine = "2d"
    try:
        return simulator_from_config(cfg, engine=engine)
    except ImportError:
        raise EdofprojError(
            f"the '{doe.name}' DOE is not radially symmetric and needs the 2-D PSF engine, "
            "which is not available in this installation"
        ) from None


def run(args) -> int:
    import torch

    from ..imaging import bank_layers, project, read_image, write_image
    from ..imaging.image_io import check_output_path, image_file_size
    from ..imaging.projection import projection_bytes
    from ..imaging.screens import tilted_plane_depth_map, tilted_plane_far_m, tilted_plane_tilt_deg
    from ..limits import check_memory
    from ..optics.geometry import ProjectorGeometry
    from ..scenes.render import filled_depth_m, render_masked_depth_map

    check_arguments(args)
    check_output_path(args.out, args.bits)
    inputs = [("--image", args.image), ("--psf", args.psf), ("--depth-map", args.depth_map)]
    inputs += [("--surface", args.surface), ("--config", args.config)]
    refuse_output_over(args.out, "--out", inputs, runs=[("--doe", args.doe)], file_output=True)
    from ..runs.projector import config_for_designs

    cfg = config_for_designs(args.config, args.overrides, [args.doe])  # a run's --doe: the run's own projector
    size = image_file_size(args.image)
    if size is not None:
        layers = 1 if args.depth_map is None and args.tilt_deg is None else int(cfg.imaging.depth_layers)
        check_memory(
            projection_bytes(size[0], size[1], cfg.psf.window, layers),
            f"rendering the {size[0]}x{size[1]} (height x width) image '{args.image}'",
            "scale the image down first",
        )
    image = read_image(args.image)[None]
    height, width = image.shape[-2:]
    surface = None
    if args.surface is not None:
        from ..data.textures import surface_reflectance
        from ..imaging.surfaces import Surface

        reflectance = surface_reflectance(args.surface, (height, width))
        surface = Surface.from_arrays(reflectance, reflectance * args.ambient)

    depth_map_m = None
    screen = ""
    if args.depth_map is not None:
        depth_map_m = load_depth_map_m(args.depth_map, (height, width))
        screen = f"depth map {np.nanmin(depth_map_m) * 1e3:.1f}-{np.nanmax(depth_map_m) * 1e3:.1f} mm"
        if np.isnan(depth_map_m).any():
            screen += f", {np.isnan(depth_map_m).mean():.0%} of pixels hit nothing"
    elif args.tilt_deg is not None:
        geometry = ProjectorGeometry.from_config(cfg.optics)
        if args.psf is not None:
            # the PSF file's pixel pitch q(z) = z / (T W) fixes the throw the file was simulated for
            from dataclasses import replace

            from ..optics.psf_bank import PSFBank

            bank_for_throw = PSFBank.load(args.psf)
            throw_width = float(bank_for_throw.depths_m[0]) / float(bank_for_throw.pixel_pitch_m[0])
            geometry = replace(geometry, throw_ratio=throw_width / geometry.width_px)
        near_m = args.near_mm * 1e-3
        far_m = (
            args.far_mm * 1e-3
            if args.far_mm is not None
            else tilted_plane_far_m(near_m, args.tilt_deg, width, geometry)
        )
        depth_map_m = tilted_plane_depth_map(height, width, args.tilt_deg, near_m, far_m)
        implied = tilted_plane_tilt_deg(near_m, far_m, width, geometry)
        throw = (
            f"the PSF file's pitch, T W = {geometry.throw_width_m:.0f} px"
            if args.psf is not None
            else f"throw ratio {geometry.throw_ratio:g}"
        )
        screen = (
            f"plane tilted {args.tilt_deg:g} deg, {near_m * 1e3:.1f}-{far_m * 1e3:.1f} mm "
            f"(with {throw}, these depths mean a tilt of {implied:.1f} deg)"
        )

    with torch.no_grad():
        if args.psf is not None:
            from ..optics.psf_bank import PSFBank

            bank = PSFBank.load(args.psf)
            if depth_map_m is not None:
                depths, psf = bank_layers(bank, filled_depth_m(depth_map_m))
                result = render_masked_depth_map(image, depth_map_m, psf, depths)
                source = f"{len(depths)} PSF layers from '{args.psf}'"
            else:
                index = pick_depth_index(bank, args.depth_index, args.psf)
                result = project(image, bank.psf[index : index + 1])
                screen = f"flat screen at {bank.depths_m[index] * 1e3:.1f} mm"
                source = f"'{args.psf}' depth index {index}"
        else:
            from .psf import build_design

            doe = build_design(cfg, args.doe, args.config)
            simulator = simulator_for(cfg, doe)
            if depth_map_m is not None:
                layers = int(cfg.imaging.depth_layers)
                result = render_masked_depth_map(image, depth_map_m, lambda depths: simulator(doe, depths), layers)
                source = f"{doe.describe()}, up to {layers} depth layers"
            else:
                result = project(image, simulator(doe, np.array([args.depth_mm * 1e-3])))
                screen = f"flat screen at {args.depth_mm:g} mm"
                source = doe.describe()

    if surface is not None:
        result = surface.appearance(result)
        screen += f", surface {args.surface}" + (f" under ambient {args.ambient:g}" if args.ambient else "")
    write_image(args.out, result[0], bits=args.bits)
    print(f"wrote {args.out} ({height}x{width} px, height x width, {args.bits}-bit): {screen}; {source}")
    return 0


def pick_depth_index(bank, depth_index: int | None, path: str) -> int:
    """The PSF file's depth to use for a flat screen (required when the file holds several)."""
    count = len(bank.depths_m)
    listing = ", ".join(f"{i}: {z * 1e3:g} mm" for i, z in enumerate(bank.depths_m[:12]))
    listing += ", ..." if count > 12 else ""
    if depth_index is None:
        if count == 1:
            return 0
        raise EdofprojError(f"PSF file '{path}' holds {count} depths; choose one with --depth-index ({listing})")
    if not 0 <= depth_index < count:
        raise EdofprojError(
            f"--depth-index {depth_index} is out of range: '{path}' holds {count} depths, 0..{count - 1} ({listing})"
        )
    return depth_index
