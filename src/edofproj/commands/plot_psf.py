"""``edofproj plot-psf``: RGB PSFs across depth for two designs side by side, their radial
profiles, and their height profiles."""

from __future__ import annotations

from ..errors import EdofprojError
from ._common import add_config_options
from .psf import add_optics_options, build_design, depths_from_args, design_config


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "plot-psf",
        help="plot PSFs across depth for two designs",
        description=" ".join(__doc__.split("\n\n")[0].split()),
    )
    add_config_options(p)
    p.add_argument(
        "--doe",
        action="append",
        default=[],
        help="a design (lens, mlp, cubic, axicon, multifocal, a DOE .npz file or a run directory); give one or two "
        "(default: the config's design beside the bare lens; one design other than the lens is shown beside the "
        "lens); a run's own projector simulates it",
    )
    p.add_argument("--depth-mm", action="append", default=[], help="depths in mm (list or start:stop:step)")
    p.add_argument("--window", type=int, default=None, help="PSF window K in pixels (odd)")
    add_optics_options(p)
    p.add_argument("--out", required=True, help="output PNG")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..doe.factory import design_label
    from ..optics.psf_bank import design_engine, simulator_from_config
    from ..reporting.psf_plots import plot_psf_comparison

    if len(args.doe) > 2:
        raise EdofprojError(f"give at most two --doe designs, got {len(args.doe)}")
    cfg = design_config(args, list(args.doe))
    specs = list(args.doe) or [cfg.doe.kind]
    if len(specs) == 1 and specs[0] != "lens":
        specs = ["lens"] + specs  # the design beside the bare lens, not the lens beside itself
    if not str(args.out).lower().endswith(".png"):
        raise EdofprojError(f"--out '{args.out}' must end in .png")
    depths_m = depths_from_args(args.depth_mm, cfg)
    panels = []
    for spec in specs:
        doe = build_design(cfg, spec, args.config)
        sim = simulator_from_config(cfg, engine=design_engine(doe, cfg.psf.engine))
        panels.append((design_label(spec), doe, sim.bank(doe, depths_m)))
    plot_psf_comparison(panels, args.out)
    print(f"wrote {args.out}")
    return 0
