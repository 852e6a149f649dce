"""A lab's own capture folder, made with other software, described by a small manifest (``lab.json``).

The manifest names, for each sequence of captures, the pattern kind, its parameters and the order
of its files, and the projector's size, so that the structured-light commands (``procams decode``,
``procams psf-map``, ``procams predict``) read the folder as it is::

    {"format": "edofproj-lab-captures", "version": 1,
     "projector": {"height": 1140, "width": 912},
     "channel": "mean",                         # grey = mean of R, G, B (or "red", "green", "blue")
     "sequences": [
       {"name": "columns", "kind": "phase-shift", "axis": "x", "periods": [1, 4, 16, 48], "steps": 4,
        "order": "period-major", "files": {"folder": "RE1", "glob": "*.bmp"}},
       {"name": "gray", "kind": "gray-code", "axis": "x", "planes": 10,
        "files": {"folder": "CAPTURED/normal-projection", "glob": "*.bmp"}},
       {"name": "dots", "kind": "dots", "spacing_px": [12, 12], "origin_px": [0, 0],
        "files": {"list": ["DOT2/dot_white.bmp"]}}]}

* ``files``: ``{"list": [...]}`` in capture order, or ``{"folder": F, "glob": G}``: the matches
  sorted by name (time-stamped names sort in capture order). Paths are relative to the
  manifest's folder (or the folder given as ``root``) and may not leave it (no ``..``, not absolute).
* ``phase-shift``: ``I_(f,k) = 1/2 + 1/2 cos(2 pi f c / L + 2 pi k / N)`` (:mod:`.structured_light`);
  ``order`` ``"period-major"`` (all steps of the first period count, then the next) or
  ``"step-major"`` (step 0 of every period count, then step 1 ...).
* ``gray-code``: ``planes`` captures, most significant plane first; ``inverse`` (optional, bool):
  each plane followed by its inverse.
* ``dots``: single lit pixels every ``spacing_px`` ``[along y, along x]`` from ``origin_px`` ``[y, x]``.
* ``channel`` (any sequence, optional): the channel its captures are read in, instead of the
  manifest's; a ``dots`` sequence of red, green or blue dots says so with ``"channel": "red"`` ...,
  and ``procams psf-map`` fits that colour's map from it.
"""

from __future__ import annotations

import json
import math
import stat
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import numpy as np

from ..errors import EdofprojError
from .capture_io import read_rgb
from .structured_light import axis_length, check_phase_plan, gray_code_bits

LAB_FORMAT = "edofproj-lab-captures"
LAB_MANIFEST_NAME = "lab.json"
MAX_MANIFEST_BYTES = 16 * 2**20
"""Largest lab manifest read (a manifest lists files; it is kilobytes)."""
KINDS = ("phase-shift", "gray-code", "dots", "black", "white")
CHANNELS = {"mean": None, "red": 0, "green": 1, "blue": 2}


@dataclass
class Sequence:
    """One sequence of the manifest (module docstring); ``files`` resolved to relative paths in order."""

    name: str
    kind: str
    files: list[str]
    axis: str | None = None
    periods: list[int] = field(default_factory=list)
    steps: int = 0
    order: str = "period-major"
    planes: int = 0
    inverse: bool = False
    spacing_px: tuple[int, int] = (0, 0)
    origin_px: tuple[float, float] = (0.0, 0.0)
    channel: str | None = None

    def to_json(self) -> dict:
        item: dict = {"name": self.name, "kind": self.kind}
        if self.axis is not None:
            item["axis"] = self.axis
        if self.channel is not None:
            item["channel"] = self.channel
        if self.kind == "phase-shift":
            item.update(periods=list(self.periods), steps=self.steps, order=self.order)
        if self.kind == "gray-code":
            item.update(planes=self.planes, inverse=self.inverse)
        if self.kind == "dots":
            item.update(spacing_px=list(self.spacing_px), origin_px=list(self.origin_px))
        item["files"] = {"list": list(self.files)}
        return item


def _relative(path: str, what: str) -> str:
    p = PurePosixPath(str(path).replace("\\", "/"))
    if p.is_absolute() or ".." in p.parts or not p.parts:
        raise ValueError(f"{what} '{path}' must be a relative path inside the manifest's folder")
    return str(p)


def _whole(value, what: str) -> int:
    """``value`` as an int: a JSON integer, or a number with no fractional part; one line otherwise
    (``7.5``, ``NaN``, ``true``, a string)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{what} must be a whole number, got {json.dumps(value)}")
    if isinstance(value, float) and not (math.isfinite(value) and value.is_integer()):
        raise ValueError(f"{what} must be a whole number, got {value}")
    return int(value)


def _finite(value, what: str) -> float:
    """``value`` as a finite float; one line otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{what} must be a finite number, got {json.dumps(value)}")
    return float(value)


def _inside(root: Path, relative: str, what: str) -> str:
    """``relative`` unless ``root / relative``, its links followed, leaves ``root`` (a symbolic link
    inside the folder that points outside it)."""
    base = root.resolve()
    target = (root / relative).resolve()
    if target != base and base not in target.parents:
        raise ValueError(f"{what} '{relative}' leads outside the manifest's folder (a link to '{target}'): "
                         "copy the capture into the folder")  # fmt: skip
    return relative


def _files(item: dict, root: Path) -> list[str]:
    spec = item.get("files")
    name = item.get("name")
    if not isinstance(spec, dict):
        raise ValueError(f"sequence '{name}' needs 'files': {{'list': [...]}} or {{'folder', 'glob'}}")
    if "list" in spec:
        if not isinstance(spec["list"], list):
            raise ValueError(f"sequence '{name}': 'files': {{'list': ...}} must be a list of file names")
        files = [_inside(root, _relative(f, "file"), "file") for f in spec["list"]]
    else:
        folder = _relative(spec.get("folder", "."), "folder") if spec.get("folder", ".") != "." else "."
        pattern = str(spec.get("glob", "*"))
        if "/" in pattern or ".." in pattern:
            raise ValueError(f"glob '{pattern}' must match names inside its folder")
        base = root / folder
        if not base.is_dir():
            raise ValueError(f"folder '{folder}' of sequence '{name}' does not exist under '{root}'")
        _inside(root, folder, "folder")
        files = [str(PurePosixPath(folder) / p.name) for p in sorted(base.glob(pattern)) if p.is_file()]
        files = [_inside(root, f, "file") for f in files]
    repeated = sorted({f for f in files if files.count(f) > 1})
    if repeated:
        raise ValueError(f"sequence '{name}' lists {', '.join(repeated)} more than once: each capture is one frame")
    return files


@dataclass
class LabManifest:
    """A lab capture folder (module docstring): the projector size, the grey channel and the sequences."""

    projector_hw: tuple[int, int]
    sequences: list[Sequence]
    channel: str = "mean"
    root: Path = Path(".")

    def sequence(self, name: str) -> Sequence:
        for s in self.sequences:
            if s.name == name:
                return s
        names = ", ".join(s.name for s in self.sequences)
        raise EdofprojError(f"the lab manifest has no sequence '{name}' (it has: {names})")

    def channel_of(self, seq: Sequence) -> str:
        """The channel ``seq``'s captures are read in: its own ``channel``, else the manifest's."""
        return seq.channel if seq.channel is not None else self.channel

    def read_grey(self, relative: str, channel: str | None = None) -> np.ndarray:
        """One capture as grey ``(Hc, Wc)`` float64 in ``[0, 1]`` (``channel``, default the manifest's)."""
        return to_grey(read_rgb(self.root / relative, what="capture"), channel or self.channel)

    def read_rgb(self, relative: str) -> np.ndarray:
        """One capture ``(Hc, Wc, 3)`` float32 in ``[0, 1]``."""
        return read_rgb(self.root / relative, what="capture")

    def to_json(self) -> dict:
        H, W = self.projector_hw
        return {
            "format": LAB_FORMAT,
            "version": 1,
            "projector": {"height": H, "width": W},
            "channel": self.channel,
            "sequences": [s.to_json() for s in self.sequences],
        }

    @classmethod
    def load(cls, path: str | Path, root: str | Path | None = None) -> "LabManifest":
        """Read and check ``path``; files are found under ``root`` (default: the manifest's folder)."""
        path = Path(path)
        base = Path(root) if root is not None else path.parent
        try:
            mode = path.stat().st_mode
        except FileNotFoundError:
            raise EdofprojError(f"lab manifest '{path}' does not exist") from None
        except OSError as exc:
            raise EdofprojError(f"cannot read lab manifest '{path}': {exc.strerror or exc}") from None
        if stat.S_ISDIR(mode):
            raise EdofprojError(
                f"lab manifest '{path}' is a folder: give the manifest file in it (e.g. {path / LAB_MANIFEST_NAME})"
            )
        if not stat.S_ISREG(mode):
            raise EdofprojError(
                f"lab manifest '{path}' is not a regular file (a FIFO, a socket or a device): give a lab.json file"
            )
        if path.stat().st_size > MAX_MANIFEST_BYTES:
            raise EdofprojError(f"lab manifest '{path}' is {path.stat().st_size} bytes: a manifest is a small "
                                f"JSON file (at most {MAX_MANIFEST_BYTES // 2**20} MiB)")  # fmt: skip
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            if not isinstance(data, dict) or data.get("format") != LAB_FORMAT:
                raise ValueError(f"not a lab manifest (format '{LAB_FORMAT}')")
            version = data.get("version", 1)
            if isinstance(version, bool) or version != 1:
                raise ValueError(f"version {json.dumps(version)} is not one this edofproj reads (1)")
            H = _whole(data["projector"]["height"], "projector height")
            W = _whole(data["projector"]["width"], "projector width")
            if not (2 <= H <= 32768 and 2 <= W <= 32768):
                raise ValueError(f"projector size {W}x{H} is not 2..32768 px per side")
            channel = str(data.get("channel", "mean"))
            if channel not in CHANNELS:
                raise ValueError(f"channel '{channel}' is not one of {', '.join(CHANNELS)}")
            sequences = [_sequence(item, base, (H, W)) for item in data["sequences"]]
            names = [s.name for s in sequences]
            if len(set(names)) != len(names):
                raise ValueError("sequence names repeat")
        except FileNotFoundError:
            raise EdofprojError(f"lab manifest '{path}' does not exist") from None
        except RecursionError:
            raise EdofprojError(f"cannot read lab manifest '{path}': it is nested too deeply to be one") from None
        except KeyError as exc:
            raise EdofprojError(f"cannot read lab manifest '{path}': it lacks {exc}") from None
        except (OSError, ValueError, TypeError, EdofprojError) as exc:
            raise EdofprojError(f"cannot read lab manifest '{path}': {exc}") from None
        return cls(projector_hw=(H, W), sequences=sequences, channel=channel, root=base)


def _sequence(item: dict, root: Path, projector_hw: tuple[int, int]) -> Sequence:
    kind = item["kind"]
    if kind not in KINDS:
        raise ValueError(f"sequence '{item.get('name')}' has unknown kind '{kind}' (one of {', '.join(KINDS)})")
    seq = Sequence(name=str(item["name"]), kind=kind, files=_files(item, root), axis=item.get("axis"))
    if "channel" in item:
        seq.channel = str(item["channel"])
        if seq.channel not in CHANNELS:
            raise ValueError(f"sequence '{seq.name}' has channel '{seq.channel}', not one of {', '.join(CHANNELS)}")
    if not seq.files:
        raise ValueError(f"sequence '{seq.name}' lists no files")
    want = 1
    if kind in ("phase-shift", "gray-code"):
        if seq.axis is None:
            raise ValueError(f"sequence '{seq.name}' needs 'axis' ('x' or 'y')")
        length = axis_length(projector_hw, seq.axis)
    if kind == "phase-shift":
        if not isinstance(item["periods"], list):
            raise ValueError(f"sequence '{seq.name}': 'periods' must be a list of whole numbers")
        seq.periods = [_whole(p, f"sequence '{seq.name}': a period count") for p in item["periods"]]
        seq.steps = _whole(item["steps"], f"sequence '{seq.name}': 'steps'")
        seq.order = str(item.get("order", "period-major"))
        if seq.order not in ("period-major", "step-major"):
            raise ValueError(f"order '{seq.order}' is not 'period-major' or 'step-major'")
        check_phase_plan(length, seq.periods, seq.steps)
        want = len(seq.periods) * seq.steps
    elif kind == "gray-code":
        seq.planes = _whole(item.get("planes", gray_code_bits(length)), f"sequence '{seq.name}': 'planes'")
        if not isinstance(item.get("inverse", False), bool):
            raise ValueError(f"sequence '{seq.name}': 'inverse' must be true or false")
        seq.inverse = bool(item.get("inverse", False))
        if not 1 <= seq.planes <= gray_code_bits(length):
            raise ValueError(f"'{seq.name}' gives {seq.planes} planes; a {length}-px axis has {gray_code_bits(length)}")
        want = seq.planes * (2 if seq.inverse else 1)
    elif kind == "dots":
        spacing, origin = item["spacing_px"], item.get("origin_px", [0, 0])
        if not (isinstance(spacing, list) and len(spacing) == 2 and isinstance(origin, list) and len(origin) == 2):
            raise ValueError(f"sequence '{seq.name}': 'spacing_px' and 'origin_px' are [along y, along x] pairs")
        sy, sx = (_whole(v, f"sequence '{seq.name}': 'spacing_px'") for v in spacing)
        oy, ox = (_finite(v, f"sequence '{seq.name}': 'origin_px'") for v in origin)
        H, W = projector_hw
        if not (0 <= oy <= H - 1 and 0 <= ox <= W - 1):
            raise ValueError(f"sequence '{seq.name}': the first dot, origin_px [{oy:g}, {ox:g}] ([y, x]), is "
                             f"outside the {W}x{H} projector: it is a pixel [0..{H - 1}, 0..{W - 1}]")  # fmt: skip
        if sy < 1 or sx < 1:
            raise ValueError(f"sequence '{seq.name}': 'spacing_px' {[sy, sx]} must be at least 1 px")
        seq.spacing_px, seq.origin_px = (sy, sx), (oy, ox)
        want = len(seq.files)
    if len(seq.files) != want:
        raise ValueError(f"sequence '{seq.name}' needs {want} files, found {len(seq.files)}")
    return seq


def to_grey(image: np.ndarray, channel: str = "mean") -> np.ndarray:
    """``(Hc, Wc)`` float64: the mean of R, G, B, or one channel."""
    image = np.asarray(image, dtype=np.float64)
    if image.ndim == 2:
        return image
    index = CHANNELS[channel]
    return image.mean(axis=-1) if index is None else image[..., index]


def censored_samples(image: np.ndarray, channel: str = "mean") -> tuple[np.ndarray, np.ndarray]:
    """``(saturated, clipped)`` ``(Hc, Wc)`` bool for :func:`to_grey` of ``image`` ``(Hc, Wc, 3)`` in
    ``channel``: its grey value is only a lower bound where a channel it averages is saturated, and
    only an upper bound where every channel it averages is clipped to black."""
    from .structured_light import CLIPPED_BLACK, SATURATED

    image = np.asarray(image)
    if image.ndim == 2:
        return image >= SATURATED, image <= CLIPPED_BLACK
    index = CHANNELS[channel]
    used = image if index is None else image[..., index : index + 1]
    return np.asarray((used >= SATURATED).any(axis=-1)), np.asarray((used <= CLIPPED_BLACK).all(axis=-1))


def phase_frames_in_profile_order(seq: Sequence) -> list[str]:
    """The sequence's files in :func:`.structured_light.phase_shift_profiles` order (period-major)."""
    if seq.order == "period-major":
        return list(seq.files)
    n_periods = len(seq.periods)
    return [seq.files[k * n_periods + j] for j in range(n_periods) for k in range(seq.steps)]


def decode_sequence(manifest: LabManifest, name: str, planes: int | None = None, periods: int | None = None):
    """Decode sequence ``name`` (phase shift or Gray code) into an :class:`.structured_light.AxisDecoding`;
    ``planes``: decode only the first ``planes`` Gray-code planes, ``periods``: only the first
    ``periods`` period counts of a phase shift (the others held out). Each is refused for the other kind."""
    from .structured_light import check_decoding_memory, decode_gray_code, decode_phase_shift

    seq = manifest.sequence(name)
    if seq.axis is None or seq.kind not in ("phase-shift", "gray-code"):
        raise EdofprojError(f"sequence '{name}' is of kind '{seq.kind}', not a phase shift or a Gray code")
    length = axis_length(manifest.projector_hw, seq.axis)
    if seq.kind == "phase-shift":
        if planes is not None:
            raise EdofprojError(
                f"--planes counts Gray-code planes; '{name}' is a phase shift: hold its finest period counts "
                f"out with --periods N (it has {len(seq.periods)}: {seq.periods})"
            )
        use = len(seq.periods) if periods is None else int(periods)
        if not 1 <= use <= len(seq.periods):
            raise EdofprojError(f"--periods {use} must be 1..{len(seq.periods)} (the period counts of '{name}')")
        files = phase_frames_in_profile_order(seq)[: use * seq.steps]
        channel = manifest.channel_of(seq)
        first = manifest.read_grey(files[0], channel)
        check_decoding_memory(first.shape, len(files))
        frames = [first] + [manifest.read_grey(f, channel) for f in files[1:]]
        _same_size(frames, name)
        return _enough_valid(decode_phase_shift(frames, seq.periods[:use], seq.steps, length), name)
    if periods is not None:
        raise EdofprojError(
            f"--periods counts a phase shift's period counts; '{name}' is a Gray code: hold planes out with --planes N"
        )
    frames, inverse = read_gray_code(manifest, name, planes)
    return _enough_valid(decode_gray_code(frames, length, inverse_frames=inverse), name)


MIN_VALID_FRACTION = 0.01
"""Smallest fraction of the camera's pixels a decoded sequence must give a valid coordinate."""


def _enough_valid(decoding, name: str):
    """``decoding``, or one line when fewer than ``MIN_VALID_FRACTION`` of its pixels are valid: the
    captures do not hold the sequence's pattern (noise, other files, another order)."""
    fraction = float(np.mean(decoding.valid))
    if fraction < MIN_VALID_FRACTION:
        raise EdofprojError(
            f"only {fraction:.2%} of the camera's pixels decode '{name}' to a coordinate that agrees with their "
            f"neighbours' (at least {MIN_VALID_FRACTION:.0%} needed): the captures do not show the sequence's "
            "pattern -- check its files, their order and its kind, periods or planes in the lab manifest"
        )
    return decoding


def read_gray_code(
    manifest: LabManifest, name: str, planes: int | None = None
) -> tuple[list[np.ndarray], list[np.ndarray] | None]:
    """The grey captures of Gray-code sequence ``name``'s first ``planes`` planes (default all), and
    their inverses' (None without inverse patterns)."""
    seq = manifest.sequence(name)
    if seq.kind != "gray-code":
        raise EdofprojError(f"sequence '{name}' is of kind '{seq.kind}', not a Gray code")
    use = seq.planes if planes is None else int(planes)
    if not 2 <= use <= seq.planes:
        raise EdofprojError(f"--planes {use} must be 2..{seq.planes} (the planes of '{name}')")
    step = 2 if seq.inverse else 1
    channel = manifest.channel_of(seq)
    frames = [manifest.read_grey(seq.files[step * b], channel) for b in range(use)]
    inverse = [manifest.read_grey(seq.files[step * b + 1], channel) for b in range(use)] if seq.inverse else None
    _same_size(frames + (inverse or []), name)
    return frames, inverse


def _same_size(frames: list[np.ndarray], name: str) -> None:
    sizes = {f.shape for f in frames}
    if len(sizes) != 1:
        raise EdofprojError(f"the captures of '{name}' differ in size: {sorted(sizes)}")


def default_periods(length_px: int, ratio: int = 4, min_period_px: int = 8) -> list[int]:
    """``1, ratio, ratio^2, ...`` periods across ``length_px`` while a period is at least ``min_period_px``."""
    periods = [1]
    while periods[-1] * ratio * min_period_px <= length_px:
        periods.append(periods[-1] * ratio)
    return periods


def structured_light_set(
    projector_hw: tuple[int, int], steps: int = 4, dot_spacing_px: int = 12
) -> tuple[LabManifest, dict[str, np.ndarray]]:
    """Gray codes and phase shifts along both axes, and one dot grid, as ``{file: (H, W) image in [0, 1]}``
    with the lab manifest that describes them (files in capture order, names ``gray_x_00.png``,
    ``phase_y_f004_k1.png``, ``dots_12px.png``, ``black_sl.png``, ``white_sl.png``)."""
    from .structured_light import gray_code_profiles, phase_shift_profiles, profiles_to_images

    H, W = projector_hw
    images: dict[str, np.ndarray] = {}
    sequences = []
    for axis in ("x", "y"):
        length = axis_length(projector_hw, axis)
        gray = profiles_to_images(gray_code_profiles(length), projector_hw, axis)
        names = [f"gray_{axis}_{b:02d}.png" for b in range(len(gray))]
        images.update(zip(names, gray))
        sequences.append(Sequence(f"gray_{axis}", "gray-code", names, axis=axis, planes=len(gray)))
        periods = default_periods(length)
        phase = profiles_to_images(phase_shift_profiles(length, periods, steps), projector_hw, axis)
        names = [f"phase_{axis}_f{f:03d}_k{k}.png" for f in periods for k in range(steps)]
        images.update(zip(names, phase))
        sequences.append(Sequence(f"phase_{axis}", "phase-shift", names, axis=axis, periods=periods, steps=steps))
    dots = np.zeros((H, W))
    dots[::dot_spacing_px, ::dot_spacing_px] = 1.0
    name = f"dots_{dot_spacing_px}px.png"
    images[name] = dots
    sequences.append(Sequence("dots", "dots", [name], spacing_px=(dot_spacing_px, dot_spacing_px)))
    images["black_sl.png"], images["white_sl.png"] = np.zeros((H, W)), np.ones((H, W))
    sequences.append(Sequence("black", "black", ["black_sl.png"]))
    sequences.append(Sequence("white", "white", ["white_sl.png"]))
    return LabManifest(projector_hw=(H, W), sequences=sequences), images
