"""``edofproj compensate --psf-map``: the projector image for a blur measured by ``procams psf-map``.

    edofproj compensate --psf-map MAP.npz --image TARGET --method {wiener,cls} --out PROJ.png
    edofproj compensate --psf-map MAP.npz --images DIR --method cls --out FOLDER
    edofproj compensate --psf-map MAP.npz --image TARGET --method net --run RUN --out PROJ.png

The blur is the map's (:func:`edofproj.procams.measured_blur.map_file_blur`: a Gaussian of the measured
covariance at every node of the projector image, or a kernel map's measured kernels, interpolated
between nodes; each colour its own map where the file has one); the methods are :mod:`edofproj.procams.map_compensation`'s (``wiener``: the
field-varying Wiener filter, NSR tuned on training crops unless ``--nsr``; ``cls``: box-constrained
least squares with the exact blur, ``--iterations`` steps of ``--solver`` from the Wiener estimate)
and ``net``: the
network of a run fine-tuned on the map (``edofproj finetune RUN --psf-map MAP``), given the target and
the map's simulated projection of it. Images are at the map's projector size (height x width);
outputs 8- or 16-bit PNG/TIFF, written atomically; a folder of outputs appears only when complete.
"""

from __future__ import annotations

import time
from pathlib import Path

from ..errors import EdofprojError
from ._common import refuse_output_over, run_directory

MAP_METHODS = ("wiener", "cls", "net")
"""``--method`` values that go with ``--psf-map``."""
DEFAULT_MAP_METHOD = "cls"
CLS_SOLVERS = ("lbfgs", "fista")
"""``--solver`` values (:data:`edofproj.compensation.field_varying.CLS_METHODS` less ``pgd``)."""
DEFAULT_CLS_ITERATIONS = 20
"""``--iterations`` by default: :data:`edofproj.compensation.field_varying.DEFAULT_CLS_ITERATIONS` (a test
holds them equal; this module imports no torch before it must)."""


def add_psf_map_options(parser) -> None:
    """``--psf-map``, ``--run``, ``--nsr``, ``--iterations``; ``--method`` also takes :data:`MAP_METHODS`."""
    for action in parser._actions:
        if action.dest == "method":
            action.choices = list(action.choices) + list(MAP_METHODS)
            action.default = None
            action.help = (
                action.help or ""
            ) + f"; with --psf-map one of {', '.join(MAP_METHODS)} (default {DEFAULT_MAP_METHOD})"
    parser.add_argument(
        "--psf-map",
        default=None,
        metavar="PSF_MAP",
        help="compensate the blur of this PSF map (edofproj procams psf-map) instead of a run's simulated optics",
    )
    parser.add_argument(
        "--run",
        dest="run_option",
        default=None,
        metavar="RUN",
        type=run_directory,
        help="with --psf-map --method net: the run fine-tuned on the map (or give it as RUN)",
    )
    parser.add_argument(
        "--nsr",
        type=float,
        default=None,
        help="with --psf-map: the Wiener NSR (wiener, and cls's start; default: tuned)",
    )
    parser.add_argument(
        "--rank-tolerance",
        type=float,
        default=None,
        help="with --psf-map: relative error allowed in the blur's and the Wiener filter's node kernels, written in "
        "a few basis kernels (default 0.01; larger: fewer FFTs per step, faster)",
    )
    parser.add_argument(
        "--iterations",
        type=int,
        default=None,
        help=f"with --psf-map --method cls: solver iterations (default {DEFAULT_CLS_ITERATIONS})",
    )
    parser.add_argument(
        "--solver",
        choices=CLS_SOLVERS,
        default=None,
        help="with --psf-map --method cls: lbfgs (projected quasi-Newton, default: the lower objective under "
        "the map in as many steps) or fista (monotone FISTA)",
    )


def refuse_other_options(args) -> None:
    """The options of the run path that mean nothing with a PSF map, refused in one line."""
    other = {
        "--capture": args.capture,
        "--depth-mm": args.depth_mm,
        "--depth-map": args.depth_map,
        "--calib": args.calib,
        "--video": args.video,
        "--preview": args.preview,
        "--fps": args.fps,
        "--baselines": args.baselines,
    }
    given = [name for name, value in other.items() if value is not None]
    if args.surface_from_calib:
        given.append("--surface-from-calib")
    if given:
        raise EdofprojError(f"{', '.join(given)} do(es) not go with --psf-map (its blur is the measured one)")
    if args.psf_map is None:
        raise EdofprojError(f"--method {args.method} goes with --psf-map PSF_MAP")
    if args.method not in MAP_METHODS:
        raise EdofprojError(f"--method {args.method} does not go with --psf-map (one of {', '.join(MAP_METHODS)})")
    if args.method != "net" and (args.run is not None or args.run_option is not None):
        raise EdofprojError(f"--method {args.method} computes from the PSF map alone: drop RUN/--run (it is for net)")
    if args.method != "cls" and args.iterations is not None:
        raise EdofprojError("--iterations goes with --method cls")
    if args.method != "cls" and args.solver is not None:
        raise EdofprojError("--solver goes with --method cls")
    if args.run is not None and args.run_option is not None:
        raise EdofprojError("give the run once: as RUN or as --run")
    if args.batch is not None and args.images is None:
        raise EdofprojError("--batch goes with --images")


def run_psf_map(args) -> int:
    """``compensate --psf-map`` (module docstring)."""
    args.method = args.method or DEFAULT_MAP_METHOD
    refuse_other_options(args)
    run = args.run_option or args.run
    if args.method == "net" and run is None:
        raise EdofprojError(
            "--method net needs the run fine-tuned on the map: --run RUN (edofproj finetune RUN --psf-map)"
        )
    inputs = [("--image", args.image), ("--images", args.images), ("--psf-map", args.psf_map)]
    refuse_output_over(args.out, "--out", inputs, runs=[("--run", run)], file_output=args.image is not None)
    if args.images is not None and Path(args.out).suffix:
        raise EdofprojError(f"--out '{args.out}': with --images the output is a folder (no extension)")
    if args.image is not None:
        from ..imaging.image_io import check_output_path

        check_output_path(args.out, args.bits)
    compensator = MapCompensator(args, run)
    if args.image is not None:
        return compensator.one_image()
    return compensator.folder()


class MapCompensator:
    """The map's blur and the method, set up once for every image."""

    def __init__(self, args, run) -> None:
        from ..procams.measured_blur import DEFAULT_RANK_TOLERANCE, map_file_blur

        self.args = args
        tolerance = DEFAULT_RANK_TOLERANCE if args.rank_tolerance is None else float(args.rank_tolerance)
        self.op = map_file_blur(args.psf_map, rank_tolerance=tolerance)
        self.hw = (self.op.height, self.op.width)
        self.colours = "per colour" if self.op.channels == 3 else "one map for every colour"
        self.network = None
        self.wiener = None
        self.nsr = args.nsr
        if args.method == "net":
            from ..methods.map_network import MapNetwork

            self.network = MapNetwork(run, self.op)
        else:
            from ..compensation.field_varying import FieldVaryingWiener
            from ..procams.map_compensation import tune_map_nsr

            if self.nsr is None:
                self.nsr = tune_map_nsr(self.op)
            self.wiener = FieldVaryingWiener(self.op, self.nsr, rank_tolerance=tolerance)

    def compensate(self, target):
        """``(x (1, 3, H, W), note)`` for one target ``(1, 3, H, W)``."""
        import torch

        from ..procams.map_compensation import compensate_with_map

        if self.network is not None:
            start = time.perf_counter()
            with torch.inference_mode():
                x = self.network(target)
            return x, f"{time.perf_counter() - start:.2f} s"
        result = compensate_with_map(
            target,
            self.op,
            self.args.method,
            iterations=self.args.iterations,
            wiener=self.wiener,
            solver=self.args.solver,
        )
        note = f"NSR {result.nsr:.3g}, {result.seconds:.2f} s"
        if self.args.method == "cls":
            note += f"; {result.convergence()}"
        return result.image, note

    def one_image(self) -> int:
        import torch

        from ..imaging.image_io import read_image, write_image

        target = read_image(self.args.image).unsqueeze(0).to(torch.float32)
        if tuple(target.shape[-2:]) != self.hw:
            raise EdofprojError(
                f"--image '{self.args.image}' is {target.shape[-2]}x{target.shape[-1]} px but the PSF map's projector "
                f"{self.hw[0]}x{self.hw[1]} (height x width)"
            )
        x, note = self.compensate(target)
        write_image(self.args.out, x[0], bits=self.args.bits)
        print(
            f"wrote {self.args.out} ({self.hw[0]}x{self.hw[1]} px, height x width; method {self.args.method} for the "
            f"blur of {self.args.psf_map}, {self.colours}; {note})"
        )
        return 0

    def folder(self) -> int:
        import numpy as np
        import torch

        from ..application.offline import FolderSink, open_frames

        source = open_frames(self.args.images, None, self.hw)
        start = time.perf_counter()
        with FolderSink(self.args.out, bits=self.args.bits, overwrite=self.args.overwrite) as sink:
            for name, frame in source.frames:
                target = torch.from_numpy(np.ascontiguousarray(frame.transpose(2, 0, 1)))[None]
                x, _ = self.compensate(target)
                sink.write(name, x[0].numpy().transpose(1, 2, 0))
        wall = time.perf_counter() - start
        print(
            f"wrote {self.args.out}: {sink.written} images ({self.hw[0]}x{self.hw[1]} px, height x width; method "
            f"{self.args.method} for the blur of {self.args.psf_map}, {self.colours}) in {wall:.1f} s"
        )
        return 0


def refuse_map_options(args) -> None:
    """On the run path: ``--run``, ``--nsr``, ``--iterations``, ``--rank-tolerance`` belong to ``--psf-map``;
    the default method is the run's."""
    from ..methods.catalogue import OURS  # no torch: plain data

    options = [("--run", args.run_option), ("--nsr", args.nsr), ("--iterations", args.iterations)]
    options.append(("--rank-tolerance", args.rank_tolerance))
    options.append(("--solver", args.solver))
    given = [o for o, v in options if v is not None]
    if given:
        raise EdofprojError(f"{', '.join(given)} go(es) with --psf-map")
    args.method = args.method or OURS
