"""``edofproj evaluate``: score a trained run and its baselines on held-out images across depth.

    edofproj evaluate RUN [--images DIR] [--depths-mm 300,350,...] [--methods a,b,...] [--baselines DIR]
    edofproj evaluate RUN --scene S [--scene S2 ...] [--images DIR] [--methods a,b,...]

Writes into RUN (or ``--out``): ``metrics.csv`` (method, depth_mm, image, psnr, ssim, ms_ssim,
de2000, de2000_p95, ssim_r, ssim_g, ssim_b[, lpips, dists]), ``tilted_metrics.csv``, ``summary.md``, ``report.md`` + ``report.html`` and
``figures/eval_*.png``. Methods: lens, lens+wiener, lens+cls, lens+net, lens+onlineprodeb, doe,
doe+wiener, doe+cls (only when named), doe+net, cubic+net, axicon+net; those needing a separate run are looked up in
``--baselines`` (default: RUN's parent directory) as lens_net/, lens_onlineprodeb/, cubic_net/,
axicon_net/ and skipped with a note when absent (an error when named in ``--methods``).

With ``--scene`` (a built-in scene, ``builtin`` for all of them, a YAML scene file or a mesh
file; repeatable) the methods are scored on 3-D scenes instead, over the objects' pixels:
``scene_metrics.csv``, ``scene_summary.md``, ``figures/eval_scenes.png`` and
``figures/eval_scene_ssim.png`` (:mod:`edofproj.evaluation.scenes`).

With ``--surface`` (a built-in texture -- white, leaves, field, checker, brick, gravel; ``builtin``
for all of them -- or a reflectance file the size of the evaluation images; repeatable) the
methods are scored over depth on coloured, textured surfaces, with photometric variants and the
surface-aware network: ``surface_metrics.csv``, ``surface_summary.md`` and
``figures/eval_surfaces.png`` (:mod:`edofproj.evaluation.surfaces`, :mod:`edofproj.reporting.surfaces`).

Each evaluation replaces the previous one in its output folder as a whole: the files of an earlier
evaluation of any kind that the new one does not write are removed
(:mod:`edofproj.evaluation.output_set`). ``--out`` may not be, contain or lie inside an input
(``--images``, a ``--surface`` or ``--scene`` file, the run's configuration, DOE and checkpoints).
"""

from __future__ import annotations

import contextlib
import sys
import time
from pathlib import Path

from ._common import (
    RUN_HELP_SUFFIX,
    add_device_option,
    add_set_option,
    parse_name_list,
    parse_number_list,
    run_directory,
)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "evaluate",
        help="score a trained run and its baselines across depth (metrics, report)",
        description=__doc__.split("\n")[0],
    )
    p.add_argument(
        "run",
        metavar="RUN",
        type=run_directory,
        help="trained run directory (config.yaml, checkpoints/last.pt)" + RUN_HELP_SUFFIX,
    )
    p.add_argument(
        "--images",
        default=None,
        metavar="DIR",
        help="score the PNG/JPEG images below DIR instead of the run's held-out test images",
    )
    p.add_argument(
        "--validation",
        action="store_true",
        help="score the built-in validation set (varied content, never training or test images) instead",
    )
    p.add_argument(
        "--depths-mm",
        default=None,
        help="flat-screen depths, comma-separated or start:stop:step (default: 300-800 every 50, plus 250 and 900)",
    )
    p.add_argument("--methods", default=None, help="comma-separated methods (default: all whose runs exist)")
    p.add_argument(
        "--baselines",
        default=None,
        metavar="DIR",
        help="directory holding the baseline runs lens_net/, lens_onlineprodeb/, cubic_net/, axicon_net/ "
        "(default: RUN's parent)",
    )
    p.add_argument("--out", default=None, metavar="DIR", help="write the results here instead of into RUN")
    add_set_option(p, help="override an evaluation key, e.g. --set evaluation.image_size=[384,512] (repeatable)")
    add_device_option(p, "run images, PSFs and networks (the scores agree to float32 rounding)")
    p.add_argument(
        "--scene",
        dest="scenes",
        action="append",
        default=None,
        metavar="S",
        help="score on a 3-D scene instead of flat screens: a built-in scene ('builtin': all), a YAML scene "
        "file or a mesh file (repeatable)",
    )
    p.add_argument(
        "--surface",
        dest="surfaces",
        action="append",
        default=None,
        metavar="TEXTURE",
        help="score on a coloured, textured flat surface: a built-in texture ('builtin': all) or a reflectance "
        "image/.npy the size of the evaluation images (repeatable)",
    )
    p.add_argument(
        "--ambient",
        type=float,
        default=0.0,
        help="with --surface: ambient illuminance reflected by the surface, as a fraction of the projector's white "
        "(default 0)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.set_defaults(func=run)


def _checked_methods(args) -> list[str] | None:
    """``--methods`` as a list of names (None: the default methods); an unknown name fails before any work."""
    from ..methods.catalogue import method_spec

    methods = parse_name_list(args.methods) if args.methods is not None else None
    for name in methods or ():
        method_spec(name)
    return methods


def _output_lock(args):
    """The lock of the output directory (``--out``, or the run itself), after checking that the run is
    trained and that the output may be written there: one writer per output directory, so a run being
    trained, or evaluated by another process, is refused."""
    from ..builtin_runs import require_output_outside
    from ..locking import directory_lock
    from ..methods.builder import require_trained_run
    from ..runs import run_inputs
    from ._common import refuse_output_over

    require_trained_run(args.run)
    if not args.out:
        require_output_outside(args.run, "--out")
    # evaluate writes its own files into the folder (never replaces it): the run may hold them, its files may not be them
    named = [("--images", args.images), *(("--surface", s) for s in args.surfaces or ())]
    named += [("--scene", s) for s in args.scenes or ()]
    refuse_output_over(args.out, "--out", named + run_inputs(args.run))
    return directory_lock(args.out or args.run, "edofproj evaluate", "--out" if args.out else "RUN")


@contextlib.contextmanager
def _staged_set(args):
    """``(stage, settle)``: the evaluation is written into ``stage`` and replaces the output folder's
    previous evaluation as a whole (:func:`edofproj.evaluation.output_set.staged_output_set`);
    ``settle(evaluation)``, after the swap, points its paths at their final places."""
    from ..builtin_runs import resolve_run_dir
    from ..evaluation.output_set import moved_path, staged_output_set

    out = Path(args.out or resolve_run_dir(args.run))
    with staged_output_set(out) as stage:

        def settle(evaluation) -> None:
            evaluation.files = {key: moved_path(path, stage, out) for key, path in evaluation.files.items()}
            evaluation.out_dir = out

        yield stage, settle


def _print_notes_and_files(evaluation, seconds: float) -> None:
    """The evaluation's notes (on stderr), then the summary, table and figure it wrote."""
    for note in evaluation.notes:
        print(f"note: {note}", file=sys.stderr)
    print(
        f"wrote {evaluation.files['summary']}, {evaluation.files['metrics']} and {evaluation.files['figure']} "
        f"({seconds:.0f} s)"
    )


def run_scenes(args) -> int:
    from ..evaluation.scenes import evaluate_scenes
    from ..progress import StageProgress
    from ..reporting.scenes import scene_summary_table, write_scene_report
    from ..reporting.tables import format_text_table
    from ..training.distributed import choose_device

    if args.depths_mm is not None:
        from ..errors import EdofprojError

        raise EdofprojError("--depths-mm is for flat screens; with --scene the depths come from the scenes")
    methods = _checked_methods(args)
    clock = time.perf_counter()
    device = choose_device(args.device, option="--device")
    with _output_lock(args), _staged_set(args) as (stage, settle):
        evaluation = evaluate_scenes(
            args.run,
            [item for text in args.scenes for item in parse_name_list(text)],
            out_dir=stage,
            images_dir=args.images,
            methods=methods,
            baselines_dir=args.baselines,
            overrides=args.overrides,
            progress=StageProgress("evaluate", enabled=not args.quiet),
            device=device,
        )
        write_scene_report(evaluation)
    settle(evaluation)
    print("SSIM over the objects' pixels:")
    print(format_text_table(scene_summary_table(evaluation, "ssim")))
    _print_notes_and_files(evaluation, time.perf_counter() - clock)
    return 0


def run_surfaces(args) -> int:
    from ..data.textures import builtin_texture_names
    from ..errors import EdofprojError
    from ..evaluation.surfaces import evaluate_surfaces
    from ..progress import StageProgress
    from ..reporting.surfaces import format_table, surface_summary_table, write_surface_report
    from ..training.distributed import choose_device

    if args.scenes:
        raise EdofprojError("give --surface or --scene, not both (the surfaces are flat screens)")
    if args.validation:
        raise EdofprojError(
            "--validation goes with flat white screens; with --surface use --images DIR or the test images"
        )
    methods = _checked_methods(args)
    surfaces: list[str] = []
    for text in args.surfaces:
        for item in builtin_texture_names() if text == "builtin" else [text]:
            if item not in surfaces:
                surfaces.append(item)
    depths = parse_number_list(args.depths_mm, "--depths-mm") if args.depths_mm is not None else None
    device = choose_device(args.device, option="--device")
    with _output_lock(args), _staged_set(args) as (stage, settle):
        evaluation = evaluate_surfaces(
            args.run,
            surfaces,
            out_dir=stage,
            images_dir=args.images,
            methods=methods,
            depths_mm=depths,
            ambient=args.ambient,
            baselines_dir=args.baselines,
            overrides=args.overrides,
            progress=StageProgress("evaluate", enabled=not args.quiet),
            device=device,
        )
        write_surface_report(evaluation)
    settle(evaluation)
    for surface in evaluation.surfaces:
        print(f"surface {surface}:")
        print(format_table(surface_summary_table(evaluation, surface)))
    _print_notes_and_files(evaluation, evaluation.seconds)
    return 0


def run(args) -> int:
    if args.surfaces:
        return run_surfaces(args)
    if args.ambient != 0.0:
        from ..errors import EdofprojError

        raise EdofprojError("--ambient goes with --surface (the ambient light on a textured surface)")
    if args.scenes:
        return run_scenes(args)
    from ..progress import StageProgress
    from ..training.distributed import choose_device

    methods = _checked_methods(args)
    depths = parse_number_list(args.depths_mm, "--depths-mm") if args.depths_mm is not None else None
    device = choose_device(args.device, option="--device")
    progress = StageProgress("evaluate", enabled=not args.quiet)
    with _output_lock(args):
        return _evaluate_locked(args, methods, depths, device, progress)


def _evaluate_locked(args, methods, depths, device, progress) -> int:
    from ..builtin_runs import resolve_run_dir
    from ..evaluation.image_checks import behind_linear_filter
    from ..evaluation.output_set import moved_path, staged_output_set
    from ..evaluation.pipeline import evaluate_run
    from ..reporting.claims import ssim_claims
    from ..reporting.tables import format_text_table, range_table
    from ..reporting.writeup import claims_section, write_documents

    clock = time.perf_counter()
    out = Path(args.out or resolve_run_dir(args.run))
    # the whole set (tables, figures, reports) is written aside, then swapped in: never a mix of two
    with staged_output_set(out) as stage:
        evaluation = evaluate_run(
            args.run,
            out_dir=stage,
            images_dir=args.images,
            validation=args.validation,
            depths_mm=depths,
            methods=methods,
            baselines_dir=args.baselines,
            overrides=args.overrides,
            progress=progress,
            device=device,
        )
        claims = ssim_claims(evaluation.table, evaluation.range_mm)
        paths = write_documents(
            evaluation,
            title=f"edofproj evaluation of {evaluation.run.run_dir}",
            preface=claims_section(claims),
            progress=progress,
        )
    evaluation.files = {key: moved_path(path, stage, out) for key, path in evaluation.files.items()}
    paths = {key: moved_path(path, stage, out) for key, path in paths.items()}
    evaluation.out_dir = out
    shown = [m for m in ("ssim", "psnr", "de2000") if m in evaluation.table.metrics]
    print(format_text_table(range_table(evaluation.table, evaluation.range_mm, shown, evaluation.frame_ms)))
    behind = [c for c in behind_linear_filter(evaluation.table, evaluation.range_mm) if c.behind]
    if behind:
        names = ", ".join(f"{c.image} ({c.ssim_net - c.ssim_linear:+.4f})" for c in behind)
        print(f"warning: doe+net is behind doe+ensemble (its DOE's linear filter) on {len(behind)} image(s): {names}")
    for note in evaluation.notes:
        print(f"note: {note}", file=sys.stderr)
    if evaluation.perceptual_missing:
        print(
            f"note: {', '.join(evaluation.perceptual_missing)} unavailable (no pretrained weights): columns omitted",
            file=sys.stderr,
        )
    print(
        f"wrote {paths['summary']}, {evaluation.files['metrics']} and {paths['report_html']} "
        f"({time.perf_counter() - clock:.0f} s)"
    )
    return 0
