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
  not grow with the frame's area;
* a module with :func:`export_parts` (a network behind its display guard) is one graph with a
  branch: the guard's decision on the whole frame is the ``then`` graph of an ONNX ``If`` node, run
  only for a frame whose tiled decision is too close to call, as in PyTorch. The verification runs
  the file, and a copy of it with the ``If``'s branches swapped, on the same frame: both branches are
  checked against PyTorch.

The verification's ONNX Runtime session plans no reuse of buffers and folds no constants (with
them the check of a 1080x1920 guarded file needed 3.3 GB; without, ``export`` at that size peaks
at 1.9 GB, docs/experiments/2026-11-29-export-1080p.md).

TorchScript (``torch.jit``) is deprecated in recent PyTorch releases in favour of
``torch.export``; it is kept because C++/LibTorch deployments still load it. Loading the
file with ``torch.jit.load`` may print PyTorch's deprecation warning.
"""

from __future__ import annotations

import copy
import importlib
import logging
import tempfile
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
    """``torch.export`` -> ONNX (the FFTs as matrix products) for one ``height x width`` frame; a
    module with :func:`export_parts` as one graph with its branch in an ``If`` node."""
    parts = export_parts(net, height, width)
    if parts is not None:
        import onnx  # optional: the export extra

        onnx.save(_conditional_model(parts, height, width), str(path))
        return
    _exported_program(net, _example_inputs(height, width, 0), INPUT_NAMES, (OUTPUT_NAME,)).save(str(path))


def export_parts(net: torch.nn.Module, height: int, width: int):
    """``(head, branch, tail)`` of a module exported with a branch (``net.export_parts(height, width)``,
    e.g. a network behind its display guard: :meth:`GuardedNetwork.export_parts`), else None."""
    parts = getattr(net, "export_parts", None)
    return parts(height, width) if callable(parts) else None


def _exported_program(module: torch.nn.Module, inputs: tuple, input_names, output_names):
    """``torch.onnx.export(dynamo=True)`` of ``module`` on ``inputs``, constants folded within
    :data:`FOLD_SIZE_LIMIT` (:func:`fold_weight_constants`): the ``ONNXProgram``."""
    torch_logger = logging.getLogger("torch")
    level = torch_logger.level
    torch_logger.setLevel(logging.ERROR)  # notes about unrelated operator libraries (e.g. torchvision)
    try:
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")
            program = torch.onnx.export(
                module,
                inputs,
                dynamo=True,
                opset_version=FIXED_SIZE_OPSET,
                input_names=list(input_names),
                output_names=list(output_names),
                verbose=False,
                optimize=False,  # folded here, within FOLD_SIZE_LIMIT (the exporter's own limit is 512 x 512)
            )
            if program is None:
                raise EdofprojError("torch.onnx.export returned no ONNX program")
            fold_weight_constants(program.model)
            return program
    except EdofprojError:
        raise
    except Exception as exc:  # noqa: BLE001 - the exporter's errors are many and long
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise EdofprojError(f"ONNX export through torch.export failed: {first}") from None
    finally:
        torch_logger.setLevel(level)


FIXED_SIZE_OPSET = max(ONNX_OPSET, 18)

#: The values a conditional export's three parts share (graph inputs and outputs keep these names).
HEAD_OUTPUTS = ("network_input", "filter_input", "margin", "take_branch")
BRANCH_INPUTS = ("target", "network_input", "filter_input")
TAIL_INPUTS = ("network_input", "filter_input", "chosen_margin")


def _conditional_model(parts, height: int, width: int):
    """One ONNX model of ``(head, branch, tail)`` (:func:`export_parts`) at ``height x width``:

        x, e, m, take = head(target, captured);  m' = branch(target, x, e) if take else m;  tail(x, e, m')

    Each part is exported on its own (:func:`_exported_program`); the branch's nodes become the
    ``then`` graph of an ``If`` node (ONNX Runtime runs them only when ``take``), its weights the
    outer graph's, and initializers equal in value across the parts are stored once."""
    import onnx  # optional: the export extra

    head, branch, tail = parts
    target, captured = _example_inputs(height, width, 0)
    with torch.no_grad():
        x, e, margin, _ = head(target, captured)
    protos = [
        _exported_program(head, (target, captured), INPUT_NAMES, HEAD_OUTPUTS).model_proto,
        _exported_program(branch, (target, x, e), BRANCH_INPUTS, ("whole_margin",)).model_proto,
        _exported_program(tail, (x, e, margin), TAIL_INPUTS, (OUTPUT_NAME,)).model_proto,
    ]
    shared = {*INPUT_NAMES, *HEAD_OUTPUTS, *TAIL_INPUTS, OUTPUT_NAME}
    seen: dict[tuple, str] = {}
    initializers: list = []
    parts_nodes: list[list] = []
    value_info: list = []
    for prefix, proto in zip(("head/", "branch/", "tail/"), protos, strict=True):
        graph = proto.graph
        alias: dict[str, str] = {}
        for tensor in graph.initializer:
            key = (tensor.data_type, tuple(tensor.dims), onnx.numpy_helper.to_array(tensor).tobytes())
            if key in seen:
                alias[tensor.name] = seen[key]
                continue
            seen[key] = alias[tensor.name] = prefix + tensor.name
            tensor.name = alias[tensor.name]
            initializers.append(tensor)

        def rename(name: str, prefix=prefix, alias=alias) -> str:
            return name if not name or name in shared else alias.get(name, prefix + name)

        for node in graph.node:
            if any(a.type in (onnx.AttributeProto.GRAPH, onnx.AttributeProto.GRAPHS) for a in node.attribute):
                raise EdofprojError(f"conditional export: part {prefix[:-1]} has a subgraph node ({node.op_type})")
            node.input[:] = [rename(n) for n in node.input]
            node.output[:] = [rename(n) for n in node.output]
            node.name = prefix + node.name
        for info in graph.value_info:
            info.name = rename(info.name)
        parts_nodes.append(list(graph.node))
        value_info.extend(graph.value_info if prefix != "branch/" else [])
    head_graph, branch_graph, tail_graph = (p.graph for p in protos)
    branch_output = onnx.ValueInfoProto()
    branch_output.CopyFrom(branch_graph.output[0])
    branch_output.name = "branch/whole_margin"
    then_graph = onnx.helper.make_graph(parts_nodes[1], "whole_frame", [], [branch_output])
    else_output = onnx.ValueInfoProto()
    else_output.CopyFrom(branch_graph.output[0])
    else_output.name = "margin_kept"
    else_graph = onnx.helper.make_graph(
        [onnx.helper.make_node("Identity", ["margin"], ["margin_kept"])], "tiles", [], [else_output]
    )
    choose = onnx.helper.make_node(
        "If", ["take_branch"], ["chosen_margin"], name="branch", then_branch=then_graph, else_branch=else_graph
    )
    graph = onnx.helper.make_graph(
        [*parts_nodes[0], choose, *parts_nodes[2]],
        "conditional",
        list(head_graph.input),
        list(tail_graph.output),
        initializer=initializers,
        value_info=value_info,
    )
    model = onnx.helper.make_model(graph, opset_imports=list(protos[0].opset_import))
    model.ir_version = protos[0].ir_version
    return model


def _swapped_branches(model):
    """A copy of a conditional ``model`` (:func:`_conditional_model`) whose ``If`` takes the other branch:
    the verification runs both."""
    import onnx

    swapped = onnx.ModelProto()
    swapped.CopyFrom(model)
    for node in swapped.graph.node:
        if node.op_type == "If":
            graphs = {a.name: a for a in node.attribute}
            then_graph, else_graph = onnx.GraphProto(), onnx.GraphProto()
            then_graph.CopyFrom(graphs["then_branch"].g)
            else_graph.CopyFrom(graphs["else_branch"].g)
            graphs["then_branch"].g.CopyFrom(else_graph)
            graphs["else_branch"].g.CopyFrom(then_graph)
    return swapped


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
    # no arena, no pre-planned memory pattern and no planned reuse of a dead tensor's buffer by a later
    # one of its size (which holds the buffer in between: 2.6 GB instead of 1.05 GB for the guarded
    # network at 1080x1920): a frame's intermediates are freed as they die; no constant folding: ONNX
    # Runtime would compute the transfer functions on the frame's grid when the session is made
    # (2.3 GB more at 1080x1920), which only pays off over many frames
    options.enable_cpu_mem_arena = False
    options.enable_mem_pattern = False
    options.enable_mem_reuse = False
    session = onnxruntime.InferenceSession(
        str(path), options, providers=["CPUExecutionProvider"], disabled_optimizers=["ConstantFolding"]
    )
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
            worst = 0.0
            checks = [(tmp, net, size) for size in verification_sizes(height, width, fixed_size)]
            parts = export_parts(net, height, width) if fixed_size else None
            with tempfile.TemporaryDirectory(prefix="edofproj-export-") as folder:
                if parts is not None:  # the file's other branch, checked on the same frame
                    import onnx

                    swapped = Path(folder) / "swapped.onnx"
                    onnx.save(_swapped_branches(onnx.load(str(tmp))), str(swapped))
                    checks.append((swapped, _OtherBranch(parts), (height, width)))
                for file, reference_module, (h, w) in checks:
                    run_exported = runner(file)
                    target, captured = _example_inputs(h, w, 1)
                    with torch.inference_mode():
                        reference = reference_module(target, captured).numpy()
                    difference = float(np.max(np.abs(run_exported(target, captured) - reference)))
                    del run_exported, reference
                    worst = max(worst, difference)
                    if not difference <= TOLERANCE:
                        branch = " (the branch the frame does not take)" if file != tmp else ""
                        raise EdofprojError(
                            f"the {format} export differs from PyTorch by {difference:.3g} (> {TOLERANCE:g}) "
                            f"at {h}x{w}{branch}; nothing written"
                        )
    return worst


class _OtherBranch(torch.nn.Module):
    """PyTorch's result of :func:`export_parts` with the branch *not* taken where the module takes it
    and taken where it does not: the reference of :func:`_swapped_branches`' file."""

    def __init__(self, parts) -> None:
        super().__init__()
        self.head, self.branch, self.tail = parts

    def forward(self, target: torch.Tensor, captured: torch.Tensor) -> torch.Tensor:
        network_input, filter_input, margin, take = self.head(target, captured)
        if bool(take):
            chosen = margin
        else:
            chosen = self.branch(target, network_input, filter_input)
        return self.tail(network_input, filter_input, chosen)
