"""``edofproj tune-classic``: sweep a classic EDOF element's parameters for a projector and a range.

    edofproj tune-classic --element cubic [--values 2.5,5,10,20] [--config cpu] --out DIR

The projector, spectrum, PSF sampling and scored range are the configuration's (default: the
``cpu`` preset).

Each candidate (cubic strength, axicon focal-line ends, multifocal foci) is scored by its blind
depth-ensemble Wiener filter (``X+ensemble``) on the validation images, never the test images
(:mod:`edofproj.evaluation.classic_optics`). Writes ``classic_sweep.csv``, ``classic_sweep.md`` (the
table and the chosen value) and ``classic_sweep.png`` (mean and worst-depth SSIM against the
parameter) into ``--out``, and prints the chosen value as the ``--set`` options that select it.
"""

from __future__ import annotations

import math
import shlex
import sys

from ._common import add_config_options, config_from_args, parse_number_list

ELEMENTS = ("cubic", "axicon", "multifocal")  # = methods.catalogue.CLASSIC_ELEMENTS; not imported: --help stays fast


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "tune-classic",
        help="sweep a classic EDOF element's parameters, scored by its blind linear filter on validation images",
        description=__doc__.split("\n")[0],
    )
    p.add_argument("--element", required=True, choices=ELEMENTS, help="the classic element to tune")
    p.add_argument(
        "--values",
        default=None,
        help="candidates: cubic alpha in waves '5,10,20'; axicon NEAR:FAR mm '300:800,250:900'; multifocal foci "
        "'350/500/700;300/450/800' (default: a sweep around the configuration's value)",
    )
    p.add_argument(
        "--depths-mm",
        default="300,400,500,600,700,800",
        help="depths scored, mm (default 300-800 every 100 mm)",
    )
    p.add_argument("--max-images", type=int, default=0, help="score only the first N validation images (0: all)")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the table, the summary and the plot")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    add_config_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..errors import EdofprojError
    from ..evaluation.classic_optics import (
        CANDIDATE_SYNTAX,
        DEFAULT_CANDIDATES,
        current_candidate,
        parse_candidates,
        sweep_classic_element,
    )
    from ..progress import StageProgress
    from ..reporting.classic_optics import write_sweep

    if args.max_images < 0:
        raise EdofprojError(f"--max-images {args.max_images} must be >= 0")
    if args.config is None:
        args.config = "cpu"  # the preset the demo and the reference model are trained with
    cfg = config_from_args(args)
    if args.values is not None and not args.values.strip():
        raise EdofprojError(
            f"--values is empty: give the {args.element} candidates ({CANDIDATE_SYNTAX[args.element]}), or leave "
            "--values out for the default sweep"
        )
    candidates = parse_candidates(args.element, args.values or DEFAULT_CANDIDATES[args.element])
    refuse_unresolvable(cfg, args.element, candidates)
    depths = parse_number_list(args.depths_mm, "--depths-mm")
    sweep = sweep_classic_element(
        cfg,
        args.element,
        candidates,
        depths,
        StageProgress("tune-classic", enabled=not args.quiet),
        args.max_images,
    )
    current = current_candidate(cfg, args.element)
    command = "edofproj " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:] else "edofproj tune-classic"
    files = write_sweep(sweep, args.out, current, command)
    for candidate in sweep.candidates:
        mean, worst, depth = sweep.summary[candidate.label]
        print(f"{candidate.label}: mean SSIM {mean:.4f}, worst {worst:.4f} at {depth:g} mm")
    chosen = sweep.chosen
    print(
        f"chosen: {chosen.label} ("
        + " ".join(f"--set {o}" for o in chosen.overrides)
        + f"); configuration's: {current}"
    )
    if sweep.chosen_at_edge:
        print("note: the chosen candidate lies at an end of the swept parameter; extend --values beyond it")
    print(f"wrote {files['summary']}, {files['table']} and {files['figure']}")
    return 0


def _unresolved(cfg, kind: str, overrides) -> bool:
    """Whether the element ``kind`` of ``cfg`` with ``overrides`` changes phase too fast for every pupil sampling
    (its own rule, ``DOE.check_sampling``, at the finest sampling the search names)."""
    from ..config import apply_overrides
    from ..doe import build_doe
    from ..errors import SamplingError
    from ..optics.sampling import MAX_PUPIL_SAMPLES

    doe = build_doe(apply_overrides(cfg, list(overrides)), kind)
    try:
        doe.check_sampling(cfg.optics.aperture_m / MAX_PUPIL_SAMPLES)
    except SamplingError:
        return True
    return False


def refuse_unresolvable(cfg, kind: str, candidates) -> None:
    """One line, before any candidate is scored, for a candidate no pupil sampling resolves: for the
    cubic plate, the largest strength that one does (bisection on alpha with the plate's own rule,
    whose phase step grows with alpha); for the others, the candidate to change."""
    from ..errors import EdofprojError
    from ..optics.sampling import MAX_PUPIL_SAMPLES

    for candidate in candidates:
        if not _unresolved(cfg, kind, candidate.overrides):
            continue
        if kind != "cubic":
            raise EdofprojError(
                f"--values: the {kind} {candidate.label} changes phase faster than any pupil sampling up to "
                f"{MAX_PUPIL_SAMPLES} resolves: bring its depths closer to the focus ({cfg.optics.focus_m * 1e3:g} mm)"
            )
        low, high = 0.0, float(candidate.value)
        for _ in range(60):
            middle = (low + high) / 2
            low, high = (low, middle) if _unresolved(cfg, kind, (f"doe.cubic_waves={middle!r}",)) else (middle, high)
        raise EdofprojError(
            f"--values: a cubic alpha of {candidate.label} is more than any pupil sampling resolves (up to "
            f"pupil_samples={MAX_PUPIL_SAMPLES}): the largest usable alpha is {math.floor(low * 100) / 100:g} waves; give values up to it"
        )
