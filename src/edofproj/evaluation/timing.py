"""Wall-clock time per compensated frame (the paper's Table 1).

A *case* is one way of compensating a 3-channel frame: a method (``wiener``, ``unet``,
``onlineprodeb``, ``cls``) run by one backend (``scipy``, ``torch``, ``onnxruntime``) on one
device (``cpu``, ``cuda``). :func:`time_cases` builds each case's frame function for each
frame size, calls it ``warmup`` times (caches such as the Wiener filter for that size are
filled then, as they would be for a video), then ``repeats`` times, and reports the median
in milliseconds. On the CPU each call is timed by the wall clock; on CUDA by a pair of CUDA
events recorded around it on the current stream (the GPU's own clock, read after the events
complete), so launch overhead counts but no host synchronization does.

On CUDA a case can also be replayed as a CUDA graph (:func:`cuda_graph_case`, backend
``<backend>+graph``): the frame's kernels are captured once after warm-up and each frame is one
``graph.replay()``, which removes the per-kernel launch cost of the host. A network can also be
compiled by :func:`torch.compile` (TorchInductor, backend ``torch+compile``: fused kernels, one
compilation per frame size, made when the case is built and not timed).

Inputs are random images: the cost of these methods does not depend on the content.
"""

from __future__ import annotations

import csv
import io
import statistics
import time
from dataclasses import asdict, dataclass
from typing import Callable, Iterable, Sequence

import numpy as np
import torch

from ..compensation.constrained import box_constrained_deconvolution
from ..compensation.wiener import TorchWienerCompensator, WienerCompensator
from ..errors import EdofprojError
from ..imaging.projection import project

FrameFunction = Callable[[], object]


@dataclass(frozen=True)
class Case:
    """One compensator to time: ``build(height, width)`` returns a zero-argument frame function."""

    method: str
    backend: str
    device: str
    build: Callable[[int, int], FrameFunction]


@dataclass(frozen=True)
class Timing:
    """Median time of one case at one frame size."""

    method: str
    backend: str
    device: str
    height: int
    width: int
    median_ms: float
    repeats: int


def measure_ms(
    frame: FrameFunction,
    repeats: int = 10,
    warmup: int = 2,
    synchronize: Callable[[], None] | None = None,
    budget_s: float | None = None,
) -> list[float]:
    """Wall-clock milliseconds of each of ``repeats`` calls of ``frame`` after ``warmup`` untimed
    calls (``synchronize`` is called after each, e.g. to wait for a device). With ``budget_s``, fewer
    calls (at least one) once the timed ones add up to ``budget_s`` seconds: a frame of several
    seconds is timed once or twice, not ``repeats`` times."""
    if repeats < 1 or warmup < 0:
        raise EdofprojError(f"repeats={repeats} must be >= 1 and warmup={warmup} >= 0")
    sync = synchronize or (lambda: None)
    for _ in range(warmup):
        frame()
    sync()
    times: list[float] = []
    for _ in range(repeats):
        start = time.perf_counter()
        frame()
        sync()
        times.append((time.perf_counter() - start) * 1e3)
        if budget_s is not None and sum(times) >= budget_s * 1e3:
            break
    return times


def measure_cuda_ms(frame: FrameFunction, repeats: int = 10, warmup: int = 2) -> list[float]:
    """Milliseconds of each of ``repeats`` calls of ``frame`` between two CUDA events on the current
    stream, after ``warmup`` untimed calls (module docstring)."""
    if repeats < 1 or warmup < 0:
        raise EdofprojError(f"repeats={repeats} must be >= 1 and warmup={warmup} >= 0")
    for _ in range(warmup):
        frame()
    torch.cuda.synchronize()
    events = [(torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)) for _ in range(repeats)]
    for start, end in events:
        start.record()
        frame()
        end.record()
    torch.cuda.synchronize()
    return [start.elapsed_time(end) for start, end in events]


def _measure(
    case: "Case", frame: FrameFunction, repeats: int, warmup: int, budget_s: float | None = None
) -> list[float]:
    if case.device.startswith("cuda") and case.backend != "onnxruntime":
        return measure_cuda_ms(frame, repeats, warmup)
    synchronize = torch.cuda.synchronize if case.device.startswith("cuda") else None
    return measure_ms(frame, repeats, warmup, synchronize, budget_s)


def time_cases(
    cases: Iterable[Case],
    sizes: Sequence[tuple[int, int]],
    repeats: int = 10,
    warmup: int = 2,
    progress: Callable[[Timing], None] | None = None,
    budget_s: float | None = None,
) -> list[Timing]:
    """Median milliseconds per frame of every case at every ``(height, width)``; ``budget_s``: on the CPU,
    the seconds of timed calls after which a case stops repeating (:func:`measure_ms`; each
    :class:`Timing` gives the calls timed)."""
    results = []
    for case in cases:
        for height, width in sizes:
            frame = case.build(height, width)
            times = _measure(case, frame, repeats, warmup, budget_s)
            timing = Timing(case.method, case.backend, case.device, height, width, statistics.median(times), len(times))
            results.append(timing)
            if progress is not None:
                progress(timing)
            del frame
    return results


# --------------------------------------------------------------------------- cases


def disk_psf(window: int, channels: int = 3, energy: float = 0.95) -> np.ndarray:
    """A defocus-like PSF (C, K, K): a uniform disk filling the window, summing to ``energy``."""
    if window < 1 or window % 2 == 0:
        raise EdofprojError(f"--window={window} must be odd and >= 1")
    radius = window // 2
    y, x = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    disk = (x**2 + y**2 <= radius**2 + 0.5).astype(np.float64)
    return np.repeat((energy * disk / disk.sum())[None], channels, axis=0)


def _random_frame(height: int, width: int, device: str, seed: int = 0) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return torch.rand(1, 3, height, width, generator=generator).to(device)


def wiener_scipy_case(psf, nsr: float = 1e-3, workers: int | None = None) -> Case:
    """:class:`WienerCompensator` (SciPy FFT, cached filter) on the CPU."""
    compensator = WienerCompensator(psf, nsr, workers=workers)

    def build(height: int, width: int) -> FrameFunction:
        image = _random_frame(height, width, "cpu")[0].numpy()
        return lambda: compensator(image)

    return Case("wiener", "scipy", "cpu", build)


def wiener_torch_case(psf, nsr: float = 1e-3, device: str = "cpu") -> Case:
    """:class:`TorchWienerCompensator` (cached filter) on ``device``."""
    compensator = TorchWienerCompensator(psf, nsr)

    def build(height: int, width: int) -> FrameFunction:
        image = _random_frame(height, width, device)

        def frame():
            with torch.inference_mode():
                return compensator(image)

        return frame

    return Case("wiener", "torch", device, build)


def cls_torch_case(psf, iterations: int = 100, device: str = "cpu") -> Case:
    """Box-constrained least squares (:mod:`edofproj.compensation.constrained`) on ``device``."""
    psf = torch.as_tensor(np.asarray(psf), dtype=torch.float32)

    def build(height: int, width: int) -> FrameFunction:
        image = _random_frame(height, width, device)
        return lambda: box_constrained_deconvolution(image, psf.to(device), iterations=iterations)

    return Case("cls", "torch", device, build)


def network_torch_case(
    net: torch.nn.Module, method: str, device: str = "cpu", channels_last: bool = True, compile_network: bool = False
) -> Case:
    """``net(target, captured)`` in ``torch.inference_mode`` (``channels_last`` memory format for the
    weights, and for the images unless the network says ``channels_last_inputs = False``);
    ``compile_network``: through :func:`torch.compile` (static shapes: compiled at the first call of
    each frame size)."""
    net = net.eval().to(device)
    memory_format = torch.channels_last if channels_last else torch.contiguous_format
    net = net.to(memory_format=memory_format)  # type: ignore[call-overload]  # documented; missing from torch's stubs
    if not getattr(net, "channels_last_inputs", True):
        memory_format = torch.contiguous_format
    run: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] = (
        torch.compile(net, dynamic=False) if compile_network else net
    )

    def build(height: int, width: int) -> FrameFunction:
        target = _random_frame(height, width, device, 0).contiguous(memory_format=memory_format)
        captured = _random_frame(height, width, device, 1).contiguous(memory_format=memory_format)

        def frame():
            with torch.inference_mode():
                return run(target, captured)

        if compile_network:  # compile for this size now: a compiler that fails is one line, not a traceback
            try:
                frame()
            except Exception as error:
                reason = (str(error).strip().splitlines() or [type(error).__name__])[0]
                raise EdofprojError(
                    f"torch.compile of {method} failed at {height}x{width} ({reason}); leave out --compile"
                ) from error
        return frame

    return Case(method, "torch+compile" if compile_network else "torch", device, build)


def cuda_graph_case(case: Case, warmup: int = 3) -> Case:
    """``case`` replayed as a CUDA graph: its frame function is run ``warmup`` times on a side stream
    (filling caches such as the Wiener filter), captured once, and each frame is a replay writing
    the same output buffer. Only for torch cases on CUDA whose frame has no host synchronization."""
    if not case.device.startswith("cuda") or case.backend != "torch":
        raise EdofprojError(f"a CUDA graph needs a torch case on CUDA, not {case.backend} on {case.device}")

    def build(height: int, width: int) -> FrameFunction:
        frame = case.build(height, width)
        stream = torch.cuda.Stream()
        stream.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(stream):
            for _ in range(max(int(warmup), 1)):
                frame()
        torch.cuda.current_stream().wait_stream(stream)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            output = frame()

        def replay():
            graph.replay()
            return output  # the captured output buffer, rewritten by every replay

        return replay

    return Case(case.method, f"{case.backend}+graph", case.device, build)


def onnx_available(device: str) -> bool:
    """Whether ONNX Runtime is installed and can run on ``device`` (``cpu`` or ``cuda``)."""
    try:
        import onnxruntime  # optional: the export extra
    except ImportError:
        return False
    return device == "cpu" or "CUDAExecutionProvider" in onnxruntime.get_available_providers()


def onnx_providers(device: str) -> list[str]:
    """ONNX Runtime execution providers for ``device`` (raises if CUDA is not available)."""
    import onnxruntime  # optional: the export extra

    if device == "cpu":
        return ["CPUExecutionProvider"]
    if "CUDAExecutionProvider" not in onnxruntime.get_available_providers():
        raise EdofprojError("ONNX Runtime has no CUDAExecutionProvider (install onnxruntime-gpu)")
    return ["CUDAExecutionProvider", "CPUExecutionProvider"]


def network_onnx_case(onnx_path, method: str, device: str = "cpu", threads: int | None = None) -> Case:
    """An exported network (inputs ``target``, ``captured``) run by ONNX Runtime. ``onnx_path``:
    one file for every frame size, or ``path_for(height, width)`` for exports made for one frame
    size (networks with a Fourier filter, :func:`edofproj.compensation.export.fixed_size_onnx`)."""
    import onnxruntime  # optional: the export extra

    options = onnxruntime.SessionOptions()
    if threads:
        options.intra_op_num_threads = int(threads)

    def session_for(path):
        return onnxruntime.InferenceSession(str(path), options, providers=onnx_providers(device))

    shared = None if callable(onnx_path) else session_for(onnx_path)

    def build(height: int, width: int) -> FrameFunction:
        session = shared if shared is not None else session_for(onnx_path(height, width))
        feed = {
            "target": _random_frame(height, width, "cpu", 0).numpy(),
            "captured": _random_frame(height, width, "cpu", 1).numpy(),
        }
        return lambda: session.run(None, feed)

    return Case(method, "onnxruntime", device, build)


# --------------------------------------------------------------------------- evaluated methods


def time_methods(
    methods: Sequence, image: torch.Tensor, depth_m: float, repeats: int = 3, slow_ms: float = 2000.0
) -> dict[str, float]:
    """Median milliseconds of each evaluated method's compensation of one frame, as evaluated.

    ``methods``: :class:`~edofproj.methods.builder.PreparedMethod` objects; ``image`` ``(3, H, W)``
    (or ``(1, 3, H, W)``), the frame; ``depth_m``: the depth whose PSF the method is given (the
    simulated capture ``I*`` is made with it and is not timed). Each method runs once untimed
    (caches, lazy initialization), then ``repeats`` times; a method whose first timed frame takes
    longer than ``slow_ms`` is timed on that frame alone. Every compensation is called exactly as
    the sweep calls it: a non-blind Wiener filter is computed for each frame (its PSF follows the
    depth), the depth-ensemble filter and the networks are fixed.
    """
    target = image if image.ndim == 4 else image.unsqueeze(0)
    sync = torch.cuda.synchronize if target.is_cuda else None
    times: dict[str, float] = {}
    for method in methods:
        psf = method.design.psf([depth_m]).to(target.device)
        with torch.inference_mode():
            captured = project(target, psf)

            def frame(method=method, captured=captured, psf=psf):
                return method.compensate(target, captured, psf)

            first = measure_ms(frame, repeats=1, warmup=1, synchronize=sync)
            slow = first[0] >= slow_ms
            more = (
                measure_ms(frame, repeats=repeats - 1, warmup=0, synchronize=sync) if repeats > 1 and not slow else []
            )
        times[method.name] = statistics.median(first + more)
    return times


# --------------------------------------------------------------------------- reporting


def parse_sizes(text: str) -> list[tuple[int, int]]:
    """``"256x256,600x800"`` → ``[(256, 256), (600, 800)]`` (height × width)."""
    sizes = []
    for part in str(text).split(","):
        part = part.strip().lower()
        if not part:
            continue
        try:
            height, width = (int(v) for v in part.split("x"))
        except ValueError:
            raise EdofprojError(f"frame size '{part}' must look like HEIGHTxWIDTH, e.g. 600x800") from None
        if height < 1 or width < 1:
            raise EdofprojError(f"frame size '{part}' must be positive pixel counts HEIGHTxWIDTH, e.g. 600x800")
        sizes.append((height, width))
    if not sizes:
        raise EdofprojError("no frame sizes given (e.g. --sizes 256x256,600x800)")
    return sizes


def format_table(timings: Sequence[Timing]) -> str:
    """A Markdown table: one row per (method, backend, device), one column per frame size (ms)."""
    sizes = list(dict.fromkeys((t.height, t.width) for t in timings))
    rows = list(dict.fromkeys((t.method, t.backend, t.device) for t in timings))
    value = {(t.method, t.backend, t.device, t.height, t.width): t.median_ms for t in timings}
    header = ["method", "backend", "device"] + [f"{h}x{w} (ms)" for h, w in sizes]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        cells = [_milliseconds(value[row + size]) if row + size in value else "n/a" for size in sizes]
        lines.append("| " + " | ".join(list(row) + cells) + " |")
    return "\n".join(lines)


def _milliseconds(ms: float) -> str:
    """One decimal, two below 10 ms (GPU timings)."""
    return f"{ms:.2f}" if ms < 10 else f"{ms:.1f}"


def timings_csv(timings: Sequence[Timing]) -> str:
    """CSV text with one line per timing (columns of :class:`Timing`)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(Timing.__dataclass_fields__), lineterminator="\n")
    writer.writeheader()
    for timing in timings:
        row = asdict(timing)
        row["median_ms"] = f"{timing.median_ms:.3f}"
        writer.writerow(row)
    return buffer.getvalue()
