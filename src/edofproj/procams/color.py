"""Colour calibration of a projector-camera pair (paper Sec. 5.2): mixing matrix and projector response.

Three colour spaces:

* projector **input** ``u`` in ``[0, 1]^3``: the pattern values sent to the projector;
* projector **output** ``o``: linear light of each primary above the black level, normalized so
  that a full primary is 1 (the paper: "let the outputs of the three single-color images be
  (1,0,0), (0,1,0), (0,0,1)"). Screen light, and so the PSF, acts in this space;
* **camera** ``c``: linear camera RGB (a RAW capture).

Linear part (colour mixing): ``c - c_black = M o``. Column ``j`` of ``M`` is the mean capture of
the full primary ``j`` minus the black capture over the illuminated region, so
``o = M^-1 (c - c_black)``.

Non-linear part (the projector's 3-D response ``o = f(u)``): sampled at the colour samples
``u_k``, with ``o_k = M^-1 (c_k - c_black)``, and evaluated anywhere by local linear
interpolation over the ``k`` nearest samples -- the reconstruction weights of locally linear
embedding (Roweis & Saul 2000; paper ref. [26]):

    w = argmin || u - sum_j w_j u_j ||^2 + lambda ||w||^2   subject to   sum_j w_j = 1,
    f(u) ~= sum_j w_j o_j,

solved in closed form as ``w ~ (G + lambda I)^-1 1`` with the local Gram matrix
``G_jl = (u - u_j) . (u - u_l)`` and ``lambda = 1e-3 trace(G)``. The same interpolation with the
roles of ``u`` and ``o`` swapped gives the inverse ``u = f^-1(o)``. A query that coincides with a
sample returns that sample exactly. ``k = 6`` by default: on 6 levels per channel of a
gamma-2.2 projector (virtual ProCams) it gave a mean response error of 0.009, against 0.012
for ``k = 8`` and, for ``k = 4``, 0.011 with a 0.15 maximum where the 4 neighbours are coplanar.
The inverse is less accurate (mean 0.03 there): the samples form an uneven grid in output
space, so a query's neighbours are lopsided.

Means are taken over the *interior* of each warped capture (:func:`interior_mean`): the
full field minus an inset of 15 % of each side, where the PSF's blur of the image border does
not reach.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from ..errors import EdofprojError

RESPONSE_LUT_SIZE = 65
"""Grid points per channel of :class:`ResponseLUT` (65^3 colours, 3.3 MB as float32)."""
INTERIOR_INSET_FRACTION = 0.15
LLE_REGULARIZATION = 1e-3
EXACT_MATCH_DISTANCE = 1e-9


def interior_mean(image: np.ndarray, inset_fraction: float = INTERIOR_INSET_FRACTION) -> np.ndarray:
    """Per-channel mean of ``image (H, W, C)`` without a border of ``inset_fraction`` of each side."""
    H, W = image.shape[:2]
    dy, dx = int(round(H * inset_fraction)), int(round(W * inset_fraction))
    return np.asarray(image[dy : H - dy, dx : W - dx], dtype=np.float64).reshape(-1, image.shape[-1]).mean(axis=0)


def mixing_matrix_from_primaries(red: np.ndarray, green: np.ndarray, blue: np.ndarray, black: np.ndarray) -> np.ndarray:
    """``M`` (3x3): column ``j`` = interior mean of the capture of full primary ``j`` minus black."""
    black_mean = interior_mean(black)
    matrix = np.stack([interior_mean(capture) - black_mean for capture in (red, green, blue)], axis=1)
    condition = np.linalg.cond(matrix)
    if not np.isfinite(condition) or condition > 1e4:
        raise EdofprojError(
            f"the colour-mixing matrix is singular (condition number {condition:.3g}): are the red, green and "
            "blue captures really of the three primaries, above the black level?"
        )
    return matrix


def locally_linear_weights(queries: np.ndarray, samples: np.ndarray, neighbours: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(n, k)`` of the ``k`` nearest samples of each query and their LLE weights ``(n, k)``
    (module docstring); each row of weights sums to 1."""
    k = min(int(neighbours), len(samples))
    distance, index = cKDTree(samples).query(queries, k=k)
    distance, index = distance.reshape(len(queries), k), index.reshape(len(queries), k)
    offsets = queries[:, None, :] - samples[index]  # (n, k, 3)
    gram = offsets @ offsets.transpose(0, 2, 1)  # (n, k, k)
    trace = np.trace(gram, axis1=1, axis2=2)
    gram += (LLE_REGULARIZATION * np.maximum(trace, 1e-12))[:, None, None] * np.eye(k)
    weights = np.linalg.solve(gram, np.ones((len(queries), k, 1)))[..., 0]
    weights /= weights.sum(axis=1, keepdims=True)
    exact = distance[:, 0] <= EXACT_MATCH_DISTANCE
    weights[exact] = 0.0
    weights[exact, 0] = 1.0
    return index, weights


def _interpolate(values: np.ndarray, keys: np.ndarray, targets: np.ndarray, neighbours: int) -> np.ndarray:
    """LLE interpolation of ``targets`` (sampled at ``keys``) at ``values (..., 3)``; works on unique colours."""
    flat = np.asarray(values, dtype=np.float64).reshape(-1, 3)
    unique, inverse = np.unique(flat, axis=0, return_inverse=True)
    index, weights = locally_linear_weights(unique, keys, neighbours)
    result = np.einsum("nk,nkc->nc", weights, targets[index])
    return result[inverse.ravel()].reshape(np.shape(values))


@dataclass
class ColorCalibration:
    """Mixing matrix, black level and the sampled projector response (module docstring).

    ``black_level`` (3,): camera value of the black field (interior mean); ``sample_inputs`` /
    ``sample_outputs`` ``(N, 3)``: the colour samples in input and output space.
    """

    mixing_matrix: np.ndarray
    black_level: np.ndarray
    sample_inputs: np.ndarray
    sample_outputs: np.ndarray
    neighbours: int = 6

    def camera_to_output(self, camera: np.ndarray, black: np.ndarray | None = None) -> np.ndarray:
        """``o = M^-1 (c - c_black)`` per pixel; ``black``: a black image of the same shape, or the level."""
        black = self.black_level if black is None else black
        difference = np.asarray(camera, dtype=np.float64) - black
        return difference @ np.linalg.inv(self.mixing_matrix).T

    def input_to_output(self, inputs: np.ndarray) -> np.ndarray:
        """The projector's response ``o = f(u)`` at inputs ``(..., 3)``."""
        return _interpolate(inputs, self.sample_inputs, self.sample_outputs, self.neighbours)

    def output_to_input(self, outputs: np.ndarray) -> np.ndarray:
        """The inverse response ``u = f^-1(o)`` at outputs ``(..., 3)`` (not clamped)."""
        return _interpolate(outputs, self.sample_outputs, self.sample_inputs, self.neighbours)

    def inverse_response_lut(self, size: int = RESPONSE_LUT_SIZE) -> "ResponseLUT":
        """:meth:`output_to_input` tabulated over outputs in ``[0, 1]^3``, clamped to ``[0, 1]``
        (what a projector accepts): turns light the network asks for into projector input."""
        return ResponseLUT.from_function(lambda o: np.clip(self.output_to_input(o), 0.0, 1.0), size)


class ResponseLUT:
    """A colour map ``[0, 1]^3 -> R^3`` tabulated on a ``S x S x S`` grid, read by trilinear interpolation.

    ``table[i, j, k]`` is the map at ``(r, g, b) = (i, j, k) / (S - 1)``. Evaluating the local
    linear interpolation of :class:`ColorCalibration` per pixel costs a nearest-neighbour search
    and a ``k x k`` solve per distinct colour (seconds for a frame); the table costs that once
    and then a frame is one :func:`torch.nn.functional.grid_sample` (milliseconds). Inputs are
    clamped to ``[0, 1]`` first. Between grid points the error is that of linear interpolation,
    ``h^2 |f''| / 8`` with ``h = 1 / (S - 1)``.
    """

    def __init__(self, table: np.ndarray) -> None:
        table = np.asarray(table, dtype=np.float32)
        if table.ndim != 4 or table.shape[-1] != 3 or len(set(table.shape[:3])) != 1:
            raise EdofprojError(f"a response table must be (S, S, S, 3), got {table.shape}")
        self.table = table
        # grid_sample's 5-D input is (N, C, D, H, W) with grid (x, y, z) indexing (W, H, D): D = r, H = g, W = b
        self._volume = torch.from_numpy(np.ascontiguousarray(table.transpose(3, 0, 1, 2)))[None]

    @classmethod
    def from_function(cls, function, size: int = RESPONSE_LUT_SIZE) -> "ResponseLUT":
        """Tabulate ``function(values (..., 3)) -> (..., 3)`` on the grid."""
        axis = np.linspace(0.0, 1.0, size)
        grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1)
        return cls(function(grid.reshape(-1, 3)).reshape(size, size, size, 3))

    def __call__(self, images: torch.Tensor) -> torch.Tensor:
        """The map at every pixel of ``images (B, 3, H, W)`` (float), same shape."""
        B, C, H, W = images.shape
        if C != 3:
            raise EdofprojError(f"a colour map takes RGB images (B, 3, H, W), got {tuple(images.shape)}")
        grid = images.detach().float().clamp(0.0, 1.0).permute(0, 2, 3, 1).flip(-1) * 2.0 - 1.0  # (B, H, W, [b, g, r])
        volume = self._volume.to(images.device)
        out = torch.nn.functional.grid_sample(
            volume, grid.reshape(1, B, H, W, 3), mode="bilinear", padding_mode="border", align_corners=True
        )  # (1, 3, B, H, W)
        return out[0].permute(1, 0, 2, 3).to(images.dtype)


def calibrate_color(
    primaries: dict[str, np.ndarray], black: np.ndarray, samples: list[tuple[tuple, np.ndarray]], neighbours: int = 6
) -> ColorCalibration:
    """Colour calibration from captures warped into projector pixels.

    ``primaries``: ``{"red"|"green"|"blue": capture}``; ``black``: the black capture;
    ``samples``: ``[(input colour, capture), ...]`` of the colour-sampling fields.
    """
    if neighbours < 4:
        raise EdofprojError(f"--neighbours {neighbours} must be >= 4 (a 3-D local linear interpolation)")
    if len(samples) < neighbours:
        raise EdofprojError(f"{len(samples)} colour samples are fewer than --neighbours {neighbours}")
    matrix = mixing_matrix_from_primaries(primaries["red"], primaries["green"], primaries["blue"], black)
    calibration = ColorCalibration(
        mixing_matrix=matrix,
        black_level=interior_mean(black),
        sample_inputs=np.zeros((0, 3)),
        sample_outputs=np.zeros((0, 3)),
        neighbours=neighbours,
    )
    inputs = np.asarray([color for color, _ in samples], dtype=np.float64)
    outputs = np.stack([calibration.camera_to_output(interior_mean(capture)) for _, capture in samples])
    calibration.sample_inputs, calibration.sample_outputs = inputs, outputs
    return calibration
