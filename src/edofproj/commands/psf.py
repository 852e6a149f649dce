"""``edofproj psf``: simulate the RGB (or monochromatic) PSFs of a design across depth.

Writes the ``.npz`` contract of docs/formats.md (``psf``, ``depths_m``, ``pixel_pitch_m``,
``energy_in_window``) and optionally a comparison figure against the bare lens.
"""

from __future__ import annotations

import numpy as np

from ..errors import EdofprojError
from ._common import add_config_options, parse_number_list, refuse_output_over


def add_optics_options(parser) -> None:
    """The optics overrides shared by PSF-producing commands."""
    parser.add_argument("--aperture-mm", type=float, help="aperture (lens) diameter, mm")
    parser.add_argument("--focus-mm", type=float, help="in-focus projection distance v, mm")
    parser.add_argument("--throw-ratio", type=float, help="projection distance / image width")
    parser.add_argument("--width-px", type=int, help="projector image width, pixels")


def psf_overrides(args) -> list[str]:
    """Config overrides from the optics options and, where the command has them, ``--window``,
    ``--pupil-samples`` and ``--engine``."""
    pairs = (
        ("optics.aperture_mm", "aperture_mm"),
        ("optics.focus_mm", "focus_mm"),
        ("optics.throw_ratio", "throw_ratio"),
        ("optics.width_px", "width_px"),
        ("psf.window", "window"),
        ("psf.pupil_samples", "pupil_samples"),
        ("psf.engine", "engine"),
    )
    values = ((key, getattr(args, attr, None)) for key, attr in pairs)
    return [f"{key}={value}" for key, value in values if value is not None]


def depths_from_args(depth_specs, cfg) -> np.ndarray:
    """Depths in metres from repeatable ``--depth-mm`` values (lists or start:stop:step ranges)."""
    if depth_specs:
        values = [v for spec in depth_specs for v in parse_number_list(spec, "--depth-mm")]
    else:
        values = list(np.linspace(cfg.psf.depth_min_mm, cfg.psf.depth_max_mm, 11))
    from ..optics.geometry import check_screen_depths_mm

    return check_screen_depths_mm(values, "--depth-mm") * 1e-3


def design_config(args, specs):
    """The configuration that simulates the designs ``specs``: a run's own projector
    (:func:`edofproj.runs.projector.config_for_designs`), with the optics options and ``--set`` on top."""
    from ..runs.projector import config_for_designs

    overrides = psf_overrides(args) + list(getattr(args, "overrides", []) or [])
    return config_for_designs(args.config, overrides, specs)


def build_design(cfg, spec, config_arg=None):
    """:func:`edofproj.doe.build_doe`, refusing a design file made for another aperture than ``cfg``'s and
    saying so when a design file is simulated without ``--config`` (``config_arg``)."""
    from ..doe import build_doe
    from ..runs.projector import check_design_aperture, warn_default_projector

    doe = build_doe(cfg, spec)
    if spec is not None and doe.name == "file":
        check_design_aperture(doe, cfg, spec)
        warn_default_projector(spec, config_arg)
    return doe


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "psf", help="simulate PSFs across depth and write them as .npz", description=__doc__.split("\n")[0]
    )
    add_config_options(p)
    p.add_argument(
        "--doe",
        default=None,
        help="lens, mlp, free, cubic, axicon, multifocal, a DOE .npz file, or a run directory (default: config)",
    )
    p.add_argument(
        "--depth-mm",
        action="append",
        default=[],
        help="screen depth(s) in mm: repeatable, comma-separated, or start:stop:step",
    )
    p.add_argument(
        "--wavelength-nm",
        type=float,
        default=None,
        help="one wavelength (nm) instead of the RGB primaries: writes one channel",
    )
    p.add_argument("--window", type=int, default=None, help="PSF window K in pixels (odd)")
    p.add_argument("--engine", choices=("radial", "2d"), default=None, help="propagation engine")
    p.add_argument("--pupil-samples", type=int, default=None, help="pupil samples across the diameter")
    add_optics_options(p)
    p.add_argument("--out", required=True, help="output .npz")
    p.add_argument("--plot", default=None, help="also write a PNG comparing the design with the bare lens")
    p.set_defaults(func=run)


def run(args) -> int:
    import torch

    from ..doe import build_doe
    from ..doe.factory import design_label
    from ..optics.psf_bank import simulator_from_config
    from ..optics.spectra import check_wavelengths_nm

    cfg = design_config(args, [args.doe])
    if args.wavelength_nm is not None:
        check_wavelengths_nm([args.wavelength_nm])
    depths_m = depths_from_args(args.depth_mm, cfg)
    if not str(args.out).endswith(".npz"):
        raise EdofprojError(f"--out '{args.out}' must end in .npz")
    for option in ("--out", "--plot"):
        output = getattr(args, option[2:])
        refuse_output_over(output, option, [("--config", args.config)], runs=[("--doe", args.doe)], file_output=True)
    doe = build_design(cfg, args.doe, args.config)
    engine = cfg.psf.engine
    if not doe.radially_symmetric and engine == "radial":
        if args.engine == "radial":
            raise EdofprojError(f"the {doe.name} DOE is not radially symmetric: use --engine 2d")
        engine = "2d"
    sim = simulator_from_config(cfg, wavelength_nm=args.wavelength_nm, engine=engine)
    bank = sim.bank(doe, depths_m)
    panels = None
    if args.plot:  # the bare lens in the command's engine and optics, simulated before anything is written
        label = doe.name if args.doe is None else design_label(args.doe)  # builtin:NAME, not "file"
        panels = [(label, doe, bank)]
        if doe.name != "lens":  # the bare lens beside the design (not the lens beside itself)
            lens = build_doe(cfg, "lens")
            with torch.no_grad():
                sim = simulator_from_config(cfg, wavelength_nm=args.wavelength_nm, engine=engine)
                panels.insert(0, ("lens", lens, sim.bank(lens, depths_m)))
    bank.save(args.out)
    energy = bank.energy_in_window.numpy()
    print(
        f"wrote {args.out}: {len(depths_m)} depths x {bank.psf.shape[1]} channel(s), window {bank.window} px, "
        f"{doe.describe()}"
    )
    for z, e in zip(depths_m, energy):
        print(f"  {z * 1e3:7.1f} mm  energy in window " + " ".join(f"{v:.4f}" for v in e))
    if panels is not None:
        from ..reporting.psf_plots import plot_psf_comparison

        plot_psf_comparison(panels, args.plot)
        print(f"wrote {args.plot}")
    return 0
