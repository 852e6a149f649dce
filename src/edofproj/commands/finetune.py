"""``edofproj finetune``: fine-tune a run's compensation network on measured PSFs (DOE fixed), or on a PSF map."""

from __future__ import annotations

from ._common import RUN_HELP_SUFFIX, refuse_output_over, run_directory


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "finetune", help="fine-tune the network on measured PSFs (paper Sec. 5.3)", description=__doc__.split("\n")[0]
    )
    p.add_argument("run", type=run_directory, help="a trained run directory" + RUN_HELP_SUFFIX)
    p.add_argument(
        "--psfs",
        nargs="+",
        default=None,
        metavar="PSF.npz",
        help="measured PSF files (edofproj psf format, e.g. from 'edofproj procams estimate-psf')",
    )
    p.add_argument(
        "--patch-psfs",
        nargs="+",
        default=None,
        metavar="PATCHES.npz",
        help="per-patch PSF files ('estimate-psf --patch-psfs'), one per depth, instead of --psfs: "
        "each training sample draws a patch (field point)",
    )
    p.add_argument(
        "--psf-map",
        default=None,
        metavar="PSF_MAP",
        help="a PSF map ('edofproj procams psf-map') instead of --psfs: each training sample draws one of the map's "
        "node kernels (each colour its own where the map has one); then 'compensate --psf-map MAP --method net --run OUT'",
    )
    p.add_argument("--steps", type=int, default=20, help="fine-tuning iterations (paper: 20)")
    p.add_argument(
        "--out", default=None, help="new run directory (default: RUN-finetuned; runs/NAME-finetuned for builtin:NAME)"
    )
    p.add_argument("--lr", type=float, default=None, help="learning rate (default: where the run's schedule ended)")
    p.add_argument("--batch-size", type=int, default=None)
    p.add_argument("--seed", type=int, default=None)
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from ..builtin_runs import is_builtin_run_dir
    from ..errors import EdofprojError
    from ..training.finetune import finetune

    if sum(x is not None for x in (args.psfs, args.patch_psfs, args.psf_map)) != 1:
        raise EdofprojError("give --psfs, --patch-psfs or --psf-map (one of them)")
    run_path = Path(args.run.rstrip("/"))
    default_parent = Path("runs") if is_builtin_run_dir(run_path) else run_path.parent
    out = args.out or str(default_parent / (run_path.name + "-finetuned"))
    psfs = [("--psfs", path) for path in args.psfs or args.patch_psfs or []] + [("--psf-map", args.psf_map)]
    refuse_output_over(out, "--out", psfs, runs=[("RUN", args.run)])
    result = finetune(
        args.run,
        args.psfs or args.patch_psfs,
        out,
        steps=args.steps,
        lr=args.lr,
        batch_size=args.batch_size,
        seed=args.seed,
        per_patch=args.patch_psfs is not None,
        psf_map=args.psf_map,
    )
    lo, hi = result.depth_range_m
    if args.psf_map is not None:
        print(
            f"fine-tuned {result.steps} steps on the node kernels of the PSF map {args.psf_map}: "
            f"loss {result.first_loss:.4g} -> {result.last_loss:.4g}; wrote {result.run_dir} "
            f"(edofproj compensate --psf-map {args.psf_map} --method net --run {result.run_dir})"
        )
        return 0
    print(
        f"fine-tuned {result.steps} steps on measured PSFs at {lo * 1e3:.0f}-{hi * 1e3:.0f} mm: "
        f"loss {result.first_loss:.4g} -> {result.last_loss:.4g}; wrote {result.run_dir}"
    )
    return 0
