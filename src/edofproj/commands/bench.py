"""``edofproj bench``: milliseconds per compensated 3-channel frame (the paper's Table 1).

Methods: ``wiener`` (non-blind Wiener with a cached filter: SciPy FFT and PyTorch), ``unet``
(the compensation network: PyTorch with channels_last in inference mode, and ONNX Runtime),
``onlineprodeb`` (the baseline re-implementation, PyTorch and ONNX Runtime) and ``cls``
(box-constrained least squares, 100 iterations, PyTorch). With ``--run``, ``unet`` times what
``compensate`` and ``live`` run for that run's ``--method`` (default: its own network, behind its
display guard where it has one, built as ``edofproj evaluate`` scores it) and, when a guard is
part of it, the bare network beside it; without ``--run`` an untrained network of ``--widths``
(the cost does not depend on the weights). The header names the CPU's instruction sets
(:mod:`edofproj.machine`). Each case runs on the CPU, and on CUDA when available (timed with CUDA events,
and each PyTorch case also replayed as a CUDA graph, ``torch+graph``). The median over
``--repeats`` timed frames after ``--warmup`` frames is reported.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

from ..errors import EdofprojError
from ._common import RUN_HELP_SUFFIX, add_method_options, parse_name_list, refuse_output_over, run_directory

METHODS = ("wiener", "unet", "onlineprodeb", "cls")
DEFAULT_SIZES = "256x256,600x800,768x1024"


def devices(requested: str) -> list[str]:
    import torch  # start-up: commands import their libraries when they run (edofproj --help stays fast)

    if requested == "auto":
        return ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    if requested == "cuda" and not torch.cuda.is_available():
        raise EdofprojError("--device cuda: no CUDA device is available to PyTorch")
    return [requested]


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "bench", help="time the compensation methods per frame (paper Table 1)", description=__doc__.split("\n")[0]
    )
    p.add_argument("--sizes", default=DEFAULT_SIZES, help=f"frame sizes HxW, comma-separated (default {DEFAULT_SIZES})")
    p.add_argument("--repeats", type=int, default=10, help="timed frames per case and size (median reported)")
    p.add_argument("--warmup", type=int, default=2, help="untimed frames before timing")
    p.add_argument(
        "--run",
        default=None,
        type=run_directory,
        help="time what compensate runs for this run directory (its --method)" + RUN_HELP_SUFFIX,
    )
    add_method_options(p)
    p.add_argument(
        "--widths",
        default=None,
        help="U-Net width preset (default, fast, paper) or channel counts, e.g. 8,16,32 (without --run)",
    )
    p.add_argument(
        "--space-to-depth",
        type=int,
        default=1,
        help="run the untrained U-Net of --widths on s x s pixel blocks (without --run)",
    )
    p.add_argument(
        "--prefilter-bins",
        type=int,
        default=0,
        help="add the radial Fourier pre-filter to the untrained U-Net of --widths (without --run)",
    )
    p.add_argument(
        "--architecture",
        choices=("unet", "multirate"),
        default="unet",
        help="untrained network of --widths: the U-Net, or the multi-rate real-time network "
        "(needs --space-to-depth >= 2 and --prefilter-bins >= 2)",
    )
    p.add_argument(
        "--methods",
        default="wiener,unet",
        help=f"comma-separated subset of {', '.join(METHODS)} (default: wiener,unet)",
    )
    p.add_argument(
        "--device", choices=("auto", "cpu", "cuda"), default="auto", help="auto: the CPU, and CUDA when available"
    )
    p.add_argument("--threads", type=int, default=None, help="CPU threads for PyTorch, SciPy and ONNX Runtime")
    p.add_argument("--window", type=int, default=None, help="PSF window K for Wiener/CLS (default: config psf.window)")
    p.add_argument("--nsr", type=float, default=1e-3, help="Wiener noise-to-signal ratio (does not change the time)")
    p.add_argument("--cls-iterations", type=int, default=100, help="iterations of the constrained solver")
    p.add_argument("--no-onnx", action="store_true", help="skip the ONNX Runtime cases")
    p.add_argument(
        "--no-cuda-graphs",
        action="store_true",
        help="on CUDA, do not also time each PyTorch case replayed as a CUDA graph (torch+graph)",
    )
    p.add_argument(
        "--compile",
        action="store_true",
        help="also time each network compiled by torch.compile (torch+compile; compiled once per frame size "
        "before it is timed, not replayed as a CUDA graph; on the CPU it needs a C++ compiler)",
    )
    p.add_argument("--csv", default=None, help="also write the timings as CSV")
    p.set_defaults(func=run)


def run(args) -> int:
    import torch

    from ..compensation.registry import check_frame_memory, network_from_widths
    from ..config import Config
    from ..evaluation import timing
    from ..evaluation.timing import disk_psf
    from ..fileio import write_text_atomic
    from ..machine import instruction_sets

    refuse_output_over(
        args.csv, "--csv", [("--baselines", args.baselines)], runs=[("--run", args.run)], file_output=True
    )
    sizes = timing.parse_sizes(args.sizes)
    for height, width in sizes:  # every size is refused before the first is timed
        check_frame_memory(height, width, f"a {height}x{width} frame", "use smaller --sizes")
    methods = parse_name_list(args.methods)
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise EdofprojError(
            f"--methods: unknown method '{unknown[0] if unknown else ''}' (known: {', '.join(METHODS)})"
        )
    if args.repeats < 1 or args.warmup < 0:
        raise EdofprojError("--repeats must be >= 1 and --warmup >= 0")
    if args.threads is not None:
        if args.threads < 1:
            raise EdofprojError("--threads must be >= 1")
        torch.set_num_threads(args.threads)
    if args.run and (args.widths or args.space_to_depth != 1 or args.prefilter_bins or args.architecture != "unet"):
        raise EdofprojError(
            "--widths/--architecture/--space-to-depth/--prefilter-bins and --run exclude each other "
            "(a run has its own network)"
        )

    if args.architecture == "multirate" and (args.space_to_depth < 2 or args.prefilter_bins < 2):
        raise EdofprojError(
            "--architecture multirate needs --space-to-depth >= 2 (block size) and "
            "--prefilter-bins >= 2 (filter nodes), e.g. --space-to-depth 4 --prefilter-bins 48"
        )

    cfg = Config()
    net = None
    net_label = "unet"
    networks = []
    if "unet" in methods:
        if args.run:
            from ..methods.builder import build_method

            shipped = build_method(args.run, args.method, args.baselines)
            if shipped.module is None:
                raise EdofprojError(f"--method {shipped.name} has no network to time (the linear filter is 'wiener')")
            cfg, net, net_label = shipped.design.cfg, shipped.module, shipped.name
            if shipped.network is not None and shipped.network is not shipped.module:
                networks.append((f"{shipped.name} without guard", shipped.network))
        else:
            net = network_from_widths(
                args.widths or "default", args.space_to_depth, args.prefilter_bins, args.architecture
            )
            net_label = args.architecture
    psf = disk_psf(args.window if args.window is not None else cfg.psf.window)

    if net is not None:
        networks.insert(0, (net_label, net))
    if "onlineprodeb" in methods:
        from ..compensation.onlineprodeb import OnlineProDebNet

        networks.append(("onlineprodeb", OnlineProDebNet.from_preset("default")))

    with tempfile.TemporaryDirectory(prefix="edofproj-bench-") as tmp:
        onnx_files: dict[int, Path] = {}
        cases = []
        for device in devices(args.device):
            if "wiener" in methods:
                if device == "cpu":
                    cases.append(timing.wiener_scipy_case(psf, args.nsr, workers=args.threads))
                cases.append(timing.wiener_torch_case(psf, args.nsr, device))
            for index, (label, network) in enumerate(networks):
                cases.append(timing.network_torch_case(network, label, device))
                if args.compile:
                    cases.append(timing.network_torch_case(network, label, device, compile_network=True))
                if args.no_onnx:
                    continue
                if not timing.onnx_available(device):
                    print(
                        f"edofproj: note: no ONNX Runtime for {device}: skipping {label}/onnxruntime", file=sys.stderr
                    )
                    continue
                from ..compensation.export import export_network, fixed_size_onnx, require_onnx

                if fixed_size_onnx(network):  # a Fourier filter: one export per frame size
                    try:
                        require_onnx(fourier=True)
                    except EdofprojError as missing:
                        print(f"edofproj: note: {missing}: skipping {label}/onnxruntime", file=sys.stderr)
                        continue

                    def path_for(height: int, width: int, network=network, index=index) -> Path:
                        path = Path(tmp) / f"net{index}-{height}x{width}.onnx"
                        if not path.exists():
                            export_network(network, path, "onnx", height, width)
                        return path

                    cases.append(timing.network_onnx_case(path_for, label, device, args.threads))
                    continue
                if index not in onnx_files:
                    onnx_files[index] = Path(tmp) / f"net{index}.onnx"
                    export_network(network, onnx_files[index], "onnx", *sizes[0])
                cases.append(timing.network_onnx_case(str(onnx_files[index]), label, device, args.threads))
            if "cls" in methods:
                cases.append(timing.cls_torch_case(psf, args.cls_iterations, device))
        if not args.no_cuda_graphs:
            cases += [
                timing.cuda_graph_case(case)
                for case in cases
                if case.device.startswith("cuda") and case.backend == "torch"
            ]

        def progress(t: timing.Timing) -> None:
            print(
                f"  {t.method}/{t.backend}/{t.device} {t.height}x{t.width}: {t.median_ms:.1f} ms",
                file=sys.stderr,
                flush=True,
            )

        results = timing.time_cases(cases, sizes, args.repeats, args.warmup, progress)

    threads = args.threads or torch.get_num_threads()
    gpu = f", GPU {torch.cuda.get_device_name()}" if any(t.device.startswith("cuda") for t in results) else ""
    print(
        f"edofproj bench: torch {torch.__version__}, {threads} CPU thread(s) of {os.cpu_count()} "
        f"[{instruction_sets()}]{gpu}, "
        f"PSF window {psf.shape[-1]}, median of {args.repeats} frames (ms per 3-channel frame; "
        f"CUDA: CUDA events)"
    )
    print(timing.format_table(results))
    if args.csv:
        write_text_atomic(args.csv, timing.timings_csv(results))
        print(f"wrote {args.csv}")
    return 0
