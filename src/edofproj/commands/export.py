"""``edofproj export``: export the compensation network of a trained run (ONNX or TorchScript).

The export itself (formats, verification, fixed-size ONNX for Fourier networks) is
:mod:`edofproj.compensation.export`.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import EdofprojError
from ._common import RUN_HELP_SUFFIX, refuse_output_over, run_directory

EXPORT_FORMATS = ("onnx", "torchscript")
"""= ``compensation.export.EXPORT_FORMATS`` (tests/test_cli_help.py checks): not imported, so that
``edofproj export --help`` does not load torch."""


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export", help="export a run's compensation network to ONNX or TorchScript", description=__doc__.split("\n")[0]
    )
    p.add_argument("run", metavar="RUN", type=run_directory, help="a training run directory" + RUN_HELP_SUFFIX)
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
    from ..runs import last_checkpoint_path, load_run

    run_dir = Path(args.run)
    if not run_dir.is_dir():
        raise EdofprojError(f"run directory '{run_dir}' does not exist")
    if not last_checkpoint_path(run_dir).is_file():
        raise EdofprojError(f"run '{run_dir}' has no checkpoint ({last_checkpoint_path(run_dir)}): train it first")
    if args.format == "onnx":
        require_onnx()
    if not args.out:
        require_output_outside(run_dir, "--out")
    out = Path(args.out) if args.out else run_dir / DEFAULT_FILE_NAMES[args.format]
    refuse_output_over(str(out), "--out", runs=[("RUN", args.run)], file_output=True)
    trained = load_run(run_dir)
    worst = export_network(trained.net, out, args.format, args.height, args.width, verify=not args.no_verify)
    fixed_size = args.format == "onnx" and fixed_size_onnx(trained.net)
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
    print(f"wrote {out} ({args.format}, {dynamic}, step {trained.step}{checked})")
    return 0
