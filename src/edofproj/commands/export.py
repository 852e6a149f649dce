"""``edofproj export``: export what ``compensate`` runs for a trained run (ONNX or TorchScript).

``--method NAME`` (default: the run's own network, behind its display guard where the run has one)
is built exactly as ``edofproj evaluate`` scores it and ``compensate`` runs it; its module -- the
network, or the network and its guard as one graph -- is what is written. Methods without a
network (the linear filters) have nothing to export.

The export itself (formats, verification, fixed-size ONNX for Fourier networks) is
:mod:`edofproj.compensation.export`. The output is written atomically by its one writer
(:func:`edofproj.locking.sole_file_writer`): a second export of the same file at the same time is
refused, and the temporary file ``.NAME.tmp-*`` of an export that was killed is removed by the
next. ``--out`` may not lie in the run's ``checkpoints/`` (only training writes there).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import EdofprojError
from ._common import RUN_HELP_SUFFIX, add_method_options, refuse_output_over, run_directory

EXPORT_FORMATS = ("onnx", "torchscript")
"""= ``compensation.export.EXPORT_FORMATS`` (tests/test_cli_help.py checks): not imported, so that
``edofproj export --help`` does not load torch."""


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export", help="export a run's compensation network to ONNX or TorchScript", description=__doc__.split("\n")[0]
    )
    p.add_argument("run", metavar="RUN", type=run_directory, help="a training run directory" + RUN_HELP_SUFFIX)
    add_method_options(p)
    p.add_argument("--format", choices=EXPORT_FORMATS, default="onnx", help="output format (default: onnx)")
    p.add_argument("--out", default=None, help="output file (default: RUN/net.onnx or RUN/net.torchscript.pt)")
    p.add_argument("--height", type=int, default=256, help="example frame height for tracing (default 256)")
    p.add_argument("--width", type=int, default=256, help="example frame width for tracing (default 256)")
    p.add_argument("--no-verify", action="store_true", help="skip the comparison with PyTorch")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..builtin_runs import require_output_outside
    from ..compensation.export import (
        DEFAULT_FILE_NAMES,
        ONNX_OPSET,
        export_network,
        fixed_size_onnx,
        require_onnx,
        verification_sizes,
    )
    from ..locking import sole_file_writer
    from ..methods.builder import build_method, require_trained_run
    from ..runs import load_run

    run_dir = require_trained_run(args.run)
    if args.format == "onnx":
        require_onnx()
    if not args.out:
        require_output_outside(run_dir, "--out")
    out = Path(args.out) if args.out else run_dir / DEFAULT_FILE_NAMES[args.format]
    refuse_output_over(str(out), "--out", runs=[("RUN", args.run)], file_output=True)
    method = build_method(run_dir, args.method, args.baselines)
    module = method.module
    if module is None:
        raise EdofprojError(f"method {method.name} has no network to export (a linear filter: nothing trained)")
    step = load_run(run_dir).step if method.spec.run_dir is None else None
    with sole_file_writer(out, "edofproj export"):  # one writer; a killed one's temporary files are removed
        worst = export_network(module, out, args.format, args.height, args.width, verify=not args.no_verify)
    fixed_size = args.format == "onnx" and fixed_size_onnx(module)
    checked = (
        ""
        if args.no_verify
        else (
            f"; max |{args.format} - PyTorch| = {worst:.2g} at "
            + " and ".join(f"{h}x{w}" for h, w in verification_sizes(args.height, args.width, fixed_size))
        )
    )
    if args.format == "torchscript":
        dynamic = "traced"
    elif fixed_size:
        dynamic = f"torch.export, for 1x3x{args.height}x{args.width} frames only (Fourier filter)"
    else:
        dynamic = f"opset {ONNX_OPSET}, dynamic batch/height/width"
    what = f"method {method.name}" + (", display guard in the graph" if module is not method.network else "")
    print(
        f"wrote {out} ({args.format}, {what}, {dynamic}"
        + (f", step {step}" if step is not None else "")
        + f"{checked})"
    )
    return 0
