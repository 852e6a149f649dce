"""A PSF map of measured kernels: each dot's rank profile, averaged over the dots around a node.

The Gaussian PSF map (:mod:`.psf_map`) fits a shape to every dot; this map fits none. Around each dot
of a capture brought into projector space (:func:`.lab_kernels.capture_to_projector`, 8-bit counts,
the background subtracted) it takes the ``(2h + 1) x (2h + 1)`` window and its **rank profile**
(:func:`.lab_kernels.rank_kernel`): the window's distinct levels in descending order placed on the
kernel's rings, centre first, normalized to 1 -- the kernel estimator of Li et al. (IEEE TII 2020),
whose scoring protocol blurs with it. One dot's profile depends on how many distinct grey levels its
window holds, so single dots scatter; the map keeps, at each node ``g`` of a regular grid, the mean of
the profiles of the seen dots within a box of ``smooth_px`` around it,

    w_g = mean_{d : |y_d - y_g|, |x_d - x_g| <= smooth_px / 2,  window_d != 0} rank_profile(window_d),

(a mean of descending profiles is descending, and normalized, so ``w_g`` is a kernel of the same
kind). The box's side is chosen by **leave-one-out**: among boxes of 3 to 15 dot spacings, the one
whose mean of the *other* dots predicts each dot's profile best (:func:`choose_smooth_px`; a surface
whose blur changes fast gets a small box, a smooth one a large box). The blur of a projector image interpolates the nodes' kernels bilinearly in the source
form of :class:`edofproj.imaging.field_varying.FieldVaryingBlur` (:meth:`KernelMap.blur`).

**What it is for, and what it is not.** A rank profile is not a fit of the PSF's shape: a dot
exposed past saturation gives one level for its whole core, and the profile spreads over as many
rings as the window has levels (module docstring of :mod:`.lab_kernels`). It is the model under which
that lab scores compensations, and the one its own compensation uses; with it, edofproj's solvers can
be compared with theirs on the same knowledge of the blur. Which model predicts a projector's
captures better is measured, not assumed (the experiment records; ``procams predict`` takes the
Gaussian map).

**The offset.** The decoded map may see the projector shifted by a constant ``o`` (a 1-based phase
origin). It is estimated as the median, over the seen dots, of the window's intensity centroid less
the dot's position in a projection at ``o = 0``, corrected once by the same median in a projection at
that estimate (a window cut by a whole-pixel misplacement pulls the first centroid towards the dot);
the capture is then projected at ``o``. The projection rounds to whole pixels, so ``o`` is known to
the pixel it rounds to, not finer.

**Colours.** A white dot capture gives one map per camera channel (``red``, ``green``, ``blue``: the
light of each primary as the camera's channel of that colour sees it); a colour's dot capture (its
``channel`` in the lab manifest) gives that colour's map from the camera's channel of that colour.
Saved as ``.npz``, format ``edofproj-procams-kernel-map``: ``kernels`` ``(C, Gy, Gx, K, K)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import EdofprojError
from ..fileio import read_tagged_arrays, save_npz_atomic
from ..imaging.field_varying import node_centres_px
from .lab_kernels import DEFAULT_HALF_PX, capture_to_projector, dot_windows, orbit_sizes, orbit_window, rank_kernel
from .psf_map import KERNEL_MAP_FORMAT, DotGrid
from .structured_light import CorrespondenceMap

KERNEL_MAP_CHANNELS = ("mean", "red", "green", "blue")
DEFAULT_KERNEL_NODE_SPACING_PX = 36
"""Spacing (projector px) of the map's nodes."""
_CAMERA_CHANNEL = {"red": 0, "green": 1, "blue": 2}


@dataclass
class KernelMap:
    """Kernels ``(C, Gy, Gx, K, K)`` (each summing to 1) at nodes ``ys`` x ``xs`` (projector px) for the
    colours ``channels`` (``C`` of them); ``dots`` ``(C, Gy, Gx)`` how many dots each node averaged;
    ``offset_px`` ``(x, y)`` the decoded map's offset used; ``smooth_px`` the averaging box."""

    xs: np.ndarray
    ys: np.ndarray
    kernels: np.ndarray
    channels: tuple[str, ...]
    dots: np.ndarray
    offset_px: np.ndarray
    projector_hw: tuple[int, int]
    smooth_px: float
    #: the leave-one-out error of every box side tried (px -> error) when the box was chosen; not saved
    leave_one_out: dict = field(default_factory=dict)

    def blur(self, rank_tolerance: float = 0.0):
        """The operator ``A`` on ``(B, 3, H, W)`` projector images: :class:`FieldVaryingBlur` of the nodes'
        kernels, each colour its own map where the file has R, G and B, else one for every colour."""
        import torch

        from ..imaging.field_varying import FieldVaryingBlur

        if set(self.channels) >= {"red", "green", "blue"}:
            order = [self.channels.index(c) for c in ("red", "green", "blue")]
        else:
            order = [self.channels.index("mean") if "mean" in self.channels else 0]
        kernels = np.moveaxis(self.kernels[order], 0, 2)  # (Gy, Gx, C, K, K)
        return FieldVaryingBlur(torch.from_numpy(np.ascontiguousarray(kernels)), self.ys, self.xs,
                                self.projector_hw, rank_tolerance)  # fmt: skip

    def save(self, path) -> None:
        """Write the map to ``path`` (``.npz``), atomically."""
        save_npz_atomic(
            path,
            format=np.array(KERNEL_MAP_FORMAT),
            projector_hw=np.array(self.projector_hw),
            channels=np.array(self.channels),
            xs=self.xs,
            ys=self.ys,
            kernels=self.kernels,
            dots=self.dots,
            offset_px=self.offset_px,
            smooth_px=np.array(self.smooth_px),
        )

    @classmethod
    def load(cls, path) -> "KernelMap":
        """Read a map :meth:`save` wrote; one line for anything else or anything inconsistent."""
        keys = ("projector_hw", "channels", "xs", "ys", "kernels", "dots", "offset_px", "smooth_px")
        data = read_tagged_arrays(path, "kernel map", KERNEL_MAP_FORMAT, keys,
                                  "make one with 'edofproj procams psf-map --model rank-profile'")  # fmt: skip
        source = f"kernel map '{path}'"
        channels = tuple(str(c) for c in np.atleast_1d(data["channels"]))
        xs, ys, kernels = data["xs"].astype(np.float64), data["ys"].astype(np.float64), data["kernels"]
        hw = data["projector_hw"]
        if hw.shape != (2,) or not np.all(hw >= 2):
            raise EdofprojError(f"{source} has a projector size of {hw.tolist()}")
        if not channels or len(set(channels)) != len(channels) or any(c not in KERNEL_MAP_CHANNELS for c in channels):
            raise EdofprojError(
                f"{source} lists channels {list(channels)}: each one of {', '.join(KERNEL_MAP_CHANNELS)}"
            )
        if (
            xs.ndim != 1
            or ys.ndim != 1
            or len(xs) < 2
            or len(ys) < 2
            or np.any(np.diff(xs) <= 0)
            or np.any(np.diff(ys) <= 0)
        ):
            raise EdofprojError(f"{source} has node centres that are not two increasing lists")
        k = kernels.shape[-1] if kernels.ndim == 5 else 0
        if kernels.shape != (len(channels), len(ys), len(xs), k, k) or k % 2 == 0:
            raise EdofprojError(f"{source} has kernels of shape {kernels.shape} for {len(channels)} colours and "
                                f"{len(ys)}x{len(xs)} nodes (odd square kernels)")  # fmt: skip
        if not np.all(np.isfinite(kernels)) or np.any(kernels < 0) or not np.allclose(kernels.sum((-1, -2)), 1.0):
            raise EdofprojError(f"{source} has kernels that are not non-negative and normalized to 1")
        return cls(xs, ys, kernels.astype(np.float64), channels, data["dots"].astype(np.int64),
                   data["offset_px"].astype(np.float64), (int(hw[0]), int(hw[1])), float(data["smooth_px"]))  # fmt: skip


def grid_windows(image: np.ndarray, grid: DotGrid, half_px: int = DEFAULT_HALF_PX) -> np.ndarray:
    """:func:`.lab_kernels.dot_windows` at the dots of ``grid`` (rounded to whole pixels)."""
    return dot_windows(image, np.round(grid.ys), np.round(grid.xs), half_px)


def centroid_offset_px(windows: np.ndarray) -> np.ndarray:
    """``(x, y)``: the median over the seen dots of the window's intensity centroid less its centre."""
    half = windows.shape[-1] // 2
    total = windows.sum(axis=(-1, -2))
    seen = total > 0
    if not seen.any():
        raise EdofprojError("no dot is seen in the capture (every window is black): check the map and the capture")
    d = np.arange(-half, half + 1, dtype=np.float64)
    cx = (windows.sum(axis=-2) @ d)[seen] / total[seen]
    cy = (windows.sum(axis=-1) @ d)[seen] / total[seen]
    return np.array([np.median(cx), np.median(cy)])


def _box_sums(profiles: np.ndarray, seen: np.ndarray, grid: DotGrid, ys_px: np.ndarray, xs_px: np.ndarray,
              box_px: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """``(sum (Gy, Gx, n), count (Gy, Gx))`` of the seen dots' ``profiles`` ``(rows, cols, n)`` within a square
    of side ``box_px`` around each point ``ys_px`` x ``xs_px`` (running sums over the dot grid)."""
    weights = seen.astype(np.float64)
    sums = np.pad(np.cumsum(np.cumsum(profiles * weights[..., None], 0), 1), ((1, 0), (1, 0), (0, 0)))
    counts = np.pad(np.cumsum(np.cumsum(weights, 0), 1), ((1, 0), (1, 0)))
    half = box_px / 2.0
    r0, r1 = np.searchsorted(grid.ys, ys_px - half, "left"), np.searchsorted(grid.ys, ys_px + half, "right")
    c0, c1 = np.searchsorted(grid.xs, xs_px - half, "left"), np.searchsorted(grid.xs, xs_px + half, "right")

    def box(table: np.ndarray) -> np.ndarray:
        R0, R1, C0, C1 = r0[:, None], r1[:, None], c0[None, :], c1[None, :]
        return table[R1, C1] - table[R0, C1] - table[R1, C0] + table[R0, C0]

    return box(sums), np.rint(box(counts))


def box_mean_profiles(profiles: np.ndarray, seen: np.ndarray, grid: DotGrid, ys_px: np.ndarray,
                      xs_px: np.ndarray, box_px: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """``(mean (Gy, Gx, n), count (Gy, Gx))``: the mean of the seen dots' ``profiles`` ``(rows, cols, n)``
    within ``box_px`` (a square of that side) around each node; a node with none takes the mean of all."""
    total, count = _box_sums(profiles, seen, grid, ys_px, xs_px, box_px)
    overall = profiles[seen].mean(axis=0)
    mean = np.where(count[..., None] > 0, total / np.maximum(count, 1)[..., None], overall)
    return np.maximum(mean, 0.0), count.astype(np.int64)  # the running sums' differences round below 0


def leave_one_out_error(
    profiles: np.ndarray, seen: np.ndarray, grid: DotGrid, box_px: float, half_px: int = DEFAULT_HALF_PX
) -> float:
    """How well a box of side ``box_px`` predicts a dot it has not seen: the mean over the seen dots (with
    another seen dot in their box) of ``||k_d - mean_{d' != d in the box} k_d'||^2``, the kernels' squared
    difference summed over the window (each ring's value counts once per offset on it)."""
    total, count = _box_sums(profiles, seen, grid, grid.ys, grid.xs, box_px)
    usable = seen & (count > 1)
    if not usable.any():
        return float("inf")
    others = (total[usable] - profiles[usable]) / (count[usable] - 1)[:, None]
    return float(((others - profiles[usable]) ** 2 @ orbit_sizes(half_px)).mean())


SMOOTH_CANDIDATE_DOTS = (1, 2, 3, 4, 5, 7)
"""Half-widths ``h`` (in dots) of the boxes :func:`choose_smooth_px` tries: sides of ``(2h + 1)`` dot spacings."""


def choose_smooth_px(
    profiles: list[np.ndarray], seen: list[np.ndarray], grid: DotGrid, half_px: int = DEFAULT_HALF_PX
) -> tuple[float, dict]:
    """The box side (px) of :data:`SMOOTH_CANDIDATE_DOTS` with the least leave-one-out error summed over the
    colours (:func:`leave_one_out_error`), and every candidate's error: the smoothing is chosen by how well
    the map predicts the dots it leaves out, never by a compensation's score."""
    step = float(max(grid.spacing_px))
    errors = {
        (2 * h + 1) * step: sum(
            leave_one_out_error(p, s, grid, (2 * h + 1) * step, half_px) for p, s in zip(profiles, seen)
        )
        for h in SMOOTH_CANDIDATE_DOTS
    }
    return min(errors, key=lambda side: errors[side]), errors


def measure_kernel_map(
    captures: list[tuple[np.ndarray, str]],
    corr: CorrespondenceMap,
    grid: DotGrid,
    background: np.ndarray | None = None,
    smooth_px: float | None = None,
    node_spacing_px: float | None = None,
    half_px: int = DEFAULT_HALF_PX,
) -> KernelMap:
    """The kernel map (module docstring) from 8-bit dot captures ``(Hc, Wc, 3)``, each with its colour
    (``mean``: a white capture, one map per camera channel; ``red``/``green``/``blue``: that colour's),
    all of the same grid and camera pose, and the decoded map ``corr`` of that pose. ``smooth_px``: the
    averaging box's side (default: chosen by :func:`choose_smooth_px`); ``node_spacing_px``: the nodes'
    (default half the box, at least the dots' spacing, at most :data:`DEFAULT_KERNEL_NODE_SPACING_PX`)."""
    if (smooth_px is not None and not smooth_px > 0) or (node_spacing_px is not None and not node_spacing_px >= 1):
        raise EdofprojError(
            f"the averaging box ({smooth_px} px) must be > 0 and the node spacing ({node_spacing_px}) >= 1"
        )
    H, W = corr.projector_hw
    names: list[str] = []
    planes: list[np.ndarray] = []
    for capture, colour in captures:
        capture = np.asarray(capture)
        if capture.dtype != np.uint8 or capture.ndim != 3 or capture.shape[-1] != 3:
            raise EdofprojError("a rank profile is defined on 8-bit RGB captures; this dot capture is not one")
        for name in ("red", "green", "blue") if colour == "mean" else (colour,):
            if name in names:
                raise EdofprojError(f"two dot captures give the '{name}' map: give one capture per colour")
            names.append(name)
            planes.append(capture[..., _CAMERA_CHANNEL[name]])
    stack = np.stack(planes, axis=-1)
    back = (
        None
        if background is None
        else np.asarray(background, dtype=np.float64)[..., [_CAMERA_CHANNEL[n] for n in names]]
    )
    offset = np.zeros(2)
    for _ in range(2):  # a window cut by a whole-pixel misplacement biases the centroid: once more from there
        shifted = capture_to_projector(stack, corr, (float(offset[0]), float(offset[1])), back)
        offset = offset + centroid_offset_px(grid_windows(shifted.sum(-1), grid, half_px))
    image = capture_to_projector(stack, corr, (float(offset[0]), float(offset[1])), back) / 255.0
    profiles, seen = [], []
    for c in range(len(names)):
        windows = grid_windows(image[..., c], grid, half_px)
        seen.append(windows.sum(axis=(-1, -2)) > 0)
        if not seen[-1].any():
            raise EdofprojError(f"no dot is seen in the '{names[c]}' channel: check the capture and the map")
        profiles.append(rank_kernel(windows.reshape(-1, *windows.shape[-2:])).reshape(*windows.shape[:2], -1))
    errors: dict[float, float] = {}
    if smooth_px is None:
        smooth_px, errors = choose_smooth_px(profiles, seen, grid, half_px)
    if node_spacing_px is None:
        node_spacing_px = min(max(smooth_px / 2.0, float(max(grid.spacing_px))), DEFAULT_KERNEL_NODE_SPACING_PX)
    ys, xs = node_centres_px(H, node_spacing_px), node_centres_px(W, node_spacing_px)
    kernels, counts = [], []
    for p, s in zip(profiles, seen):
        mean, count = box_mean_profiles(p, s, grid, ys, xs, smooth_px)
        window = orbit_window(mean, half_px)
        kernels.append(window / window.sum(axis=(-1, -2), keepdims=True))
        counts.append(count)
    return KernelMap(
        xs, ys, np.stack(kernels), tuple(names), np.stack(counts), offset, (H, W), float(smooth_px), errors
    )


def summary(kernel_map: KernelMap) -> str:
    """One line: per colour, the kernels' median RMS width ``sqrt(sum k r^2 / 2)`` (px) over the nodes."""
    half = kernel_map.kernels.shape[-1] // 2
    d = np.arange(-half, half + 1, dtype=np.float64)
    r2 = d[:, None] ** 2 + d[None, :] ** 2
    parts = []
    for name, k in zip(kernel_map.channels, kernel_map.kernels):
        width = np.sqrt((k * r2).sum((-1, -2)) / 2.0)
        parts.append(f"{name} {np.median(width):.2f} px")
    nodes = f"{len(kernel_map.ys)}x{len(kernel_map.xs)} nodes"
    return f"{nodes}, each the mean of the dots within {kernel_map.smooth_px:g} px; RMS width per axis: " + ", ".join(
        parts
    )
