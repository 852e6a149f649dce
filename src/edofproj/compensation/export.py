"""Export of a compensation network to ONNX or TorchScript, verified against PyTorch.

The exported model takes ``target`` and ``captured`` (1, 3, H, W) float32 images and returns
``projector_input`` (unclamped, as the PyTorch network). ONNX uses the TorchScript-based
exporter (``dynamo=False``, opset 17) with dynamic batch, height and width; TorchScript is a
trace. Before the file is moved into place, the export is run on two frame sizes (the
requested one and a smaller odd one) and compared with PyTorch: a maximum absolute
difference above 1e-4 is an error and nothing is written.

Networks with a radial Fourier filter (``net.prefilter_bins > 0``: the real-time network), a
linear base filter (``net.linear_base: ensemble``, the ``cpu`` preset's) or a display guard go
through ``torch.export`` instead (``dynamo=True``; needs the ``onnxscript`` package). Their padding
and FFT sizes follow the frame size in Python, so the file is for *one* frame size
(``--height``/``--width``, 1 x 3 x H x W) and is verified at that size only. In the file:

* the FFTs are float32 matrix products (:mod:`edofproj.imaging.matrix_dft`), not ONNX ``DFT``
  nodes: ONNX Runtime's ``DFT`` runs lengths that are not powers of two by Bluestein's algorithm in
  scalar code (with it ONNX Runtime took 1.7-3.0x PyTorch's time per 600x800 frame on one thread),
  and in float32 it left errors of 1e-3 after the demo's network (2e-6 in double, at the same
  cost). With the matrix products ONNX Runtime takes 0.7-1.0x PyTorch's time, and the files differ
  from PyTorch by at most 4e-6 after the reference network (docs/experiments/2026-11-27-onnx-speed.md);
* what is computed from the weights alone is folded into constants (initializers) when the file
  is written (:func:`fold_weight_constants`) only up to :data:`FOLD_SIZE_LIMIT` elements: a
  transfer function on a small grid (the display guard's tiles), the radial filter's gains on a
  small frame. A transfer function on the frame's grid (``3 x 2 x Gw x (Gh/2 + 1)`` values, the
  linear filter's at 1080x1920: 27 MB; with the guard's former whole-frame projections, 117 MB) is
  not stored: the graph computes it from the kernel (``K x K`` values) with the same matrix DFT as
  the frame's, one more forward transform of three channels per frame. The file holds the weights,
  the kernels and the DFT matrices (``O(N sqrt N)`` values per axis of length ``N``): its size does
  not grow with the frame's area.

TorchScript (``torch.jit``) is deprecated in recent PyTorch releases in favour of
``torch.export``; it is kept because C++/LibTorch deployments still load it. Loading the
file with ``torch.jit.load`` may print PyTorch's deprecation warning.
"""

from __future__ import annotations

import copy
import importlib
import logging
import warnings
from pathlib import Path

import numpy as np
import torch

from ..errors import EdofprojError
from ..fileio import atomic_path
from .registry import check_frame_memory

EXPORT_FORMATS = ("onnx", "torchscript")
ONNX_OPSET = 17
TOLERANCE = 1e-4
INPUT_NAMES = ("target", "captured")
OUTPUT_NAME = "projector_input"
DEFAULT_FILE_NAMES = {"onnx": "net.onnx", "torchscript": "net.torchscript.pt"}


#: The packages of the ``export`` extra (``pip install "edofproj[export]"``).
ONNX_PACKAGES = ("onnx", "onnxruntime", "onnxscript")


def require_onnx(fourier: bool = False) -> None:
    """Raise a one-line error naming every missing package of the ``export`` extra (``onnxscript``
    only matters for networks with a Fourier filter, ``fourier=True``)."""
    missing = []
    for name in ONNX_PACKAGES if fourier else ONNX_PACKAGES[:2]:
        try:
            importlib.import_module(name)
        except ImportError:
            missing.append(name)
    if missing:
        raise EdofprojError(f'ONNX export needs {", ".join(missing)} (not installed): pip install "edofproj[export]"')


def fixed_size_onnx(net: torch.nn.Module) -> bool:
    """Whether an ONNX export of ``net`` is for one frame size only: it holds a radial Fourier
    filter or a linear base filter (an FFT convolution; module docstring), or says so itself
    (``fixed_size_export``: a network behind its display guard, whose projections are FFTs)."""
    return (
        getattr(net, "prefilter", None) is not None
        or getattr(net, "linear_base", None) is not None
        or bool(getattr(net, "fixed_size_export", False))
    )


def verification_sizes(height: int, width: int, fixed_size: bool = False) -> list[tuple[int, int]]:
    """The export size and a second, smaller odd size (checks that H and W are really dynamic);
    only the export size for a fixed-size export."""
    if fixed_size:
        return [(height, width)]
    return [(height, width), ((height // 2 + 3) | 1, (width // 2 + 5) | 1)]


def _example_inputs(height: int, width: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    target = torch.rand(1, 3, height, width, generator=generator)
    return target, (0.8 * target + 0.1).clamp(0, 1)


def _write_onnx(net: torch.nn.Module, path: Path, height: int, width: int) -> None:
    if fixed_size_onnx(net):
        _write_onnx_fixed_size(net, path, height, width)
        return
    dynamic = {0: "batch", 2: "height", 3: "width"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # tracer warnings about Python-int shape arithmetic
        torch.onnx.export(
            net,
            _example_inputs(height, width, 0),
            str(path),
            dynamo=False,
            opset_version=ONNX_OPSET,
            input_names=list(INPUT_NAMES),
            output_names=[OUTPUT_NAME],
            dynamic_axes={name: dynamic for name in (*INPUT_NAMES, OUTPUT_NAME)},
        )


def _write_onnx_fixed_size(net: torch.nn.Module, path: Path, height: int, width: int) -> None:
    """``torch.export`` -> ONNX (the FFTs become ``DFT`` nodes) for one ``height x width`` frame."""
    torch_logger = logging.getLogger("torch")
    level = torch_logger.level
    torch_logger.setLevel(logging.ERROR)  # notes about unrelated operator libraries (e.g. torchvision)
    try:
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")
            program = torch.onnx.export(
                net,
                _example_inputs(height, width, 0),
                dynamo=True,
                opset_version=max(ONNX_OPSET, 18),
                input_names=list(INPUT_NAMES),
                output_names=[OUTPUT_NAME],
                verbose=False,
                optimize=False,  # folded here, within FOLD_SIZE_LIMIT (the exporter's own limit is 512 x 512)
            )
            if program is None:
                raise EdofprojError("torch.onnx.export returned no ONNX program")
            fold_weight_constants(program.model)
            program.save(str(path))
    except Exception as exc:  # noqa: BLE001 - the exporter's errors are many and long
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise EdofprojError(f"ONNX export through torch.export failed: {first}") from None
    finally:
        torch_logger.setLevel(level)


#: Elements of the largest tensor folded into a constant: a transfer function on a display guard's
#: tile grid fits (3 PSFs x 3 colours x 2 x 75 x 38 = 51,300 values), one on a frame's grid does not
#: (module docstring): the file stays small, and its size independent of the frame's area.
FOLD_SIZE_LIMIT = 1 << 16


#: Operators left unfolded: they fill a tensor of a given shape (``torch.empty`` and broadcasts), whose
#: value would only make the file larger.
UNFOLDED_OPERATORS = ("ConstantOfShape", "Expand")


def fold_weight_constants(model) -> None:
    """Simplify the ONNX IR ``model`` (``onnx_ir.Model``, as ``torch.onnx.export`` returns it) in place.

    Equal constants become one, and equal computations on the same inputs one (the guard's linear
    filter of the target is the network's; the projections at the guard's depths share the
    transform of their input). Then every node whose inputs are all constants and whose output has
    at most :data:`FOLD_SIZE_LIMIT` elements is replaced by its value (onnxscript's constant
    folding), except tensors filled from a shape (:data:`UNFOLDED_OPERATORS`): a larger tensor
    computed from the weights (a transfer function on the frame's grid) stays a computation."""
    import onnx_ir  # optional: the export extra (a dependency of onnxscript)
    from onnx_ir.passes.common import (
        CommonSubexpressionEliminationPass,
        DeduplicateHashedInitializersPass,
        RemoveUnusedNodesPass,
    )
    from onnxscript.optimizer import fold_constants

    for value in model.graph.initializers.values():  # hashing needs C-ordered arrays (not channels-last weights)
        array = value.const_value.numpy()
        if not array.flags.c_contiguous:
            value.const_value = onnx_ir.Tensor(np.ascontiguousarray(array), name=value.name)
    DeduplicateHashedInitializersPass()(model)
    CommonSubexpressionEliminationPass()(model)
    fold_constants(
        model,
        input_size_limit=FOLD_SIZE_LIMIT,
        output_size_limit=FOLD_SIZE_LIMIT,
        should_fold=lambda node: False if node.op_type in UNFOLDED_OPERATORS else None,
    )
    RemoveUnusedNodesPass()(model)


def _write_torchscript(net: torch.nn.Module, path: Path, height: int, width: int) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # tracer warnings; torch.jit's own deprecation notice
        traced = torch.jit.trace(net, _example_inputs(height, width, 0), check_trace=False)
        torch.jit.save(traced, str(path))


def _run_onnx(path: Path):
    import onnxruntime  # optional: the export extra

    options = onnxruntime.SessionOptions()
    # no arena and no pre-planned memory pattern: a 1080x1920 frame's intermediates are freed as they die
    options.enable_cpu_mem_arena = False
    options.enable_mem_pattern = False
    session = onnxruntime.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    declared = {i.name for i in session.get_inputs()}  # an input the network ignores is pruned

    def run(target, captured):
        feed = {"target": target.numpy(), "captured": captured.numpy()}
        return session.run(None, {name: value for name, value in feed.items() if name in declared})[0]

    return run


def _run_torchscript(path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        module = torch.jit.load(str(path), map_location="cpu")

    def run(target, captured):
        with torch.inference_mode():
            return module(target, captured).numpy()

    return run


def export_network(
    net: torch.nn.Module,
    path: str | Path,
    format: str = "onnx",
    height: int = 256,
    width: int = 256,
    verify: bool = True,
) -> float:
    """Export ``net(target, captured)`` to ``path`` (atomically); return the max |export − PyTorch|.

    ``format``: ``onnx`` or ``torchscript``; ``height``/``width``: the example frame used for
    tracing (ONNX keeps batch, height and width dynamic, except for networks with a Fourier
    filter: :func:`fixed_size_onnx`). With ``verify`` the exported file
    is run on :func:`verification_sizes` and must match PyTorch within 1e-4, else an
    :class:`EdofprojError` is raised and no file is written. Returns NaN when not verified.
    """
    if format not in EXPORT_FORMATS:
        raise EdofprojError(f"unknown export format '{format}' (known: {', '.join(EXPORT_FORMATS)})")
    if height < 1 or width < 1:
        raise EdofprojError(f"export size {height}x{width} must be positive")
    check_frame_memory(height, width, f"exporting at {height}x{width} px", "use a smaller --height/--width")
    if format == "onnx":
        require_onnx(fourier=fixed_size_onnx(net))
    fixed_size = format == "onnx" and fixed_size_onnx(net)
    net = copy.deepcopy(net).cpu().float().eval()
    worst = float("nan")
    with atomic_path(path) as tmp:
        writer, runner = (_write_onnx, _run_onnx) if format == "onnx" else (_write_torchscript, _run_torchscript)
        writer(net, tmp, height, width)
        if verify:
            run_exported = runner(tmp)
            worst = 0.0
            for seed, (h, w) in enumerate(verification_sizes(height, width, fixed_size), start=1):
                target, captured = _example_inputs(h, w, seed)
                with torch.inference_mode():
                    reference = net(target, captured).numpy()
                difference = float(np.max(np.abs(run_exported(target, captured) - reference)))
                worst = max(worst, difference)
                if not difference <= TOLERANCE:
                    raise EdofprojError(
                        f"the {format} export differs from PyTorch by {difference:.3g} (> {TOLERANCE:g}) "
                        f"at {h}x{w}; nothing written"
                    )
    return worst
