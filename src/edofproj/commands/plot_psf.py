"""``edofproj plot-psf``: RGB PSFs across depth for two designs side by side, their radial
profiles, and their height profiles."""

from __future__ import annotations

from ..errors import EdofprojError
from ._common import add_config_options, config_from_args
from .psf import add_optics_options, depths_from_args, psf_overrides


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "plot-psf", help="plot PSFs across depth for two designs", description=__doc__.split("\n")[0]
    )
    add_config_options(p)
    p.add_argument(
        "--doe",
        action="append",
        default=[],
        help="a design (lens, mlp, cubic, axicon, multifocal, file, run dir); give one or two "
        "(default: lens and the config's design)",
    )
    p.add_argument("--depth-mm", action="append", default=[], help="depths in mm (list or start:stop:step)")
    p.add_argument("--window", type=int, default=None, help="PSF window K in pixels (odd)")
    add_optics_options(p)
    p.add_argument("--out", required=True, help="output PNG")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..doe import build_doe
    from ..doe.factory import design_label
    from ..optics.psf_bank import design_engine, simulator_from_config
    from ..reporting.psf_plots import plot_psf_comparison

    cfg = config_from_args(args, psf_overrides(args))
    specs = list(args.doe) or ["lens", cfg.doe.kind]
    if len(specs) == 1:
        specs = ["lens"] + specs
    if len(specs) > 2:
        raise EdofprojError(f"give at most two --doe designs, got {len(specs)}")
    if not str(args.out).lower().endswith(".png"):
        raise EdofprojError(f"--out '{args.out}' must end in .png")
    depths_m = depths_from_args(args.depth_mm, cfg)
    panels = []
    for spec in specs:
        doe = build_doe(cfg, spec)
        sim = simulator_from_config(cfg, engine=design_engine(doe, cfg.psf.engine))
        panels.append((design_label(spec), doe, sim.bank(doe, depths_m)))
    plot_psf_comparison(panels, args.out)
    print(f"wrote {args.out}")
    return 0
