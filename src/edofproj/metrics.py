"""Image-quality metrics for batches of RGB images ``(B, 3, H, W)`` in ``[0, 1]``.

All functions return one value per image, a tensor of shape ``(B,)``; the data range is 1.
They are differentiable (the training losses reuse them).

* :func:`psnr` - ``10 log10(1 / MSE)``, the MSE over all channels and pixels
  (= ``skimage.metrics.peak_signal_noise_ratio(..., data_range=1)``).
* :func:`ssim` - SSIM (Wang et al. 2004) with an 11×11 Gaussian window (sigma 1.5),
  population (co)variances, ``K1 = 0.01, K2 = 0.03``, averaged over the positions where the
  window lies inside the image and over the channels; this is exactly
  ``skimage.metrics.structural_similarity(..., channel_axis, data_range=1,
  gaussian_weights=True, sigma=1.5, use_sample_covariance=False)``.
* :func:`ms_ssim` - multi-scale SSIM (Wang, Simoncelli, Bovik 2003), see its docstring.
* :func:`delta_e2000` - colour fidelity: the CIEDE2000 difference per pixel (scikit-image),
  its mean and 95th percentile per image; :func:`ssim_per_channel` - SSIM of each colour
  channel ``(B, C)`` (these two are measured, not trained on).
* :func:`dists`, :func:`lpips` - perceptual metric objects with pretrained networks; they raise
  :class:`~edofproj.perceptual.PerceptualWeightsMissing` when the weights are not on this
  machine (report such a metric as unavailable, never as 0).
  :func:`available_perceptual_metrics` tells which ones can be built.
"""

from __future__ import annotations

import os
from typing import Optional

import numpy as np
import torch
from torch.nn import functional as F

from .errors import EdofprojError
from .perceptual import DISTS, LPIPS, PerceptualWeightsMissing
from .perceptual.lpips import LPIPS_BACKBONES
from .perceptual.weights import backbone_weights_path, metric_weights_path

__all__ = [
    "MS_SSIM_WEIGHTS",
    "PERCEPTUAL_METRICS",
    "PerceptualWeightsMissing",
    "available_perceptual_metrics",
    "delta_e2000",
    "dists",
    "lpips",
    "ms_ssim",
    "ms_ssim_scales",
    "perceptual_metric",
    "psnr",
    "ssim",
    "ssim_per_channel",
]

SSIM_SIGMA = 1.5
SSIM_TRUNCATE = 3.5  # scipy/skimage: window radius = int(3.5 * sigma + 0.5) = 5, i.e. 11 taps
SSIM_K1 = 0.01
SSIM_K2 = 0.03
#: Exponents of the five MS-SSIM scales, finest first (Wang et al. 2003).
MS_SSIM_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)
#: Names accepted by :func:`perceptual_metric`.
PERCEPTUAL_METRICS = ("dists", "lpips-alex", "lpips-vgg")

PathLike = str | os.PathLike


def _check_pair(pred: torch.Tensor, target: torch.Tensor, name: str) -> None:
    if pred.dim() != 4 or pred.shape != target.shape:
        raise EdofprojError(
            f"{name} needs two (B, C, H, W) batches of the same shape, got "
            f"{tuple(pred.shape)} and {tuple(target.shape)}"
        )


def psnr(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Peak signal-to-noise ratio in dB per image: ``10 log10(1 / mean((pred - target)^2))``.

    Identical images give ``inf``.
    """
    _check_pair(pred, target, "psnr")
    mse = (pred - target).pow(2).flatten(1).mean(1)
    return 10 * torch.log10(1.0 / mse)


def gaussian_window(
    sigma: float = SSIM_SIGMA, truncate: float = SSIM_TRUNCATE, dtype: torch.dtype = torch.float32, device=None
) -> torch.Tensor:
    """1-D Gaussian ``exp(-x^2 / (2 sigma^2))`` for ``|x| <= int(truncate sigma + 0.5)``, sum 1
    (the window of ``scipy.ndimage.gaussian_filter``)."""
    radius = int(truncate * sigma + 0.5)
    x = torch.arange(-radius, radius + 1, dtype=dtype, device=device)
    window = torch.exp(-0.5 * (x / sigma) ** 2)
    return window / window.sum()


def _filter_layout(device: torch.device) -> torch.memory_format:
    """The layout the Gaussian filter runs in: channels-last on the CPU (oneDNN's depthwise kernels
    are written for it: about 12x faster at 600x800), contiguous elsewhere (on a CUDA GPU the
    contiguous depthwise convolution is about 3x faster; measured on an H200)."""
    return torch.channels_last if device.type == "cpu" else torch.contiguous_format


def _filter_valid(
    images: torch.Tensor, window: torch.Tensor, layout: torch.memory_format | None = None
) -> torch.Tensor:
    """Separable Gaussian filter of every channel, only where the window fits ("valid"), in ``layout``
    (default :func:`_filter_layout`; a copy when ``images`` is in another); the result is contiguous."""
    images = images.contiguous(memory_format=layout or _filter_layout(images.device))
    channels = images.shape[1]
    size = window.numel()
    rows = window.view(1, 1, 1, size).expand(channels, 1, 1, size)
    cols = window.view(1, 1, size, 1).expand(channels, 1, size, 1)
    return F.conv2d(F.conv2d(images, rows, groups=channels), cols, groups=channels).contiguous()


def _ssim_maps(pred: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Local SSIM and contrast-structure maps ``(B, C, H - 2r, W - 2r)`` (``r`` the window's radius).

    With local Gaussian-weighted means ``mu``, variances ``sigma^2`` and covariance
    ``sigma_xy``, ``C1 = (K1 L)^2``, ``C2 = (K2 L)^2``, ``L = 1``:

        cs   = (2 sigma_xy + C2) / (sigma_x^2 + sigma_y^2 + C2)
        SSIM = (2 mu_x mu_y + C1) / (mu_x^2 + mu_y^2 + C1) * cs
    """
    return SSIMReference(target).maps(pred)


class SSIMReference:
    """SSIM against one fixed ``target`` ``(B, C, H, W)``: its local mean and second moment are
    filtered once, so that scoring many images against it (:meth:`ssim`, e.g. a display guard's
    candidates at several depths) filters only ``x``, ``x^2`` and ``x y`` of each (the same values as
    :func:`ssim`; the channels are filtered independently). ``pred`` may hold ``k B`` images, the
    target's batch repeated ``k`` times."""

    def __init__(self, target: torch.Tensor) -> None:
        self.target = target
        self.window = gaussian_window(dtype=target.dtype, device=target.device)
        if min(target.shape[-2:]) < self.window.numel():
            raise EdofprojError(
                f"SSIM needs images of at least {self.window.numel()}x{self.window.numel()} pixels, got "
                f"{target.shape[-2]}x{target.shape[-1]}"
            )
        channels = target.shape[1]
        self.mu_y, self.yy = torch.split(
            _filter_valid(torch.cat([target, target * target], dim=1), self.window), channels, dim=1
        )

    def maps(self, pred: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Local SSIM and contrast-structure maps of ``pred`` (as :func:`_ssim_maps`).

        Without gradients (scores: the evaluation, a display guard) the same arithmetic runs in
        place, in buffers of its own (:meth:`_maps_in_place`: the same values to the last bit); not
        in an export (``torch.export`` or a trace), where writes into a buffer become ONNX
        ``ScatterND`` copies and ``torch.cond`` refuses them."""
        batch = self.target.shape[0]
        repeats = pred.shape[0] // batch
        if pred.shape[1:] != self.target.shape[1:] or repeats * batch != pred.shape[0]:
            raise EdofprojError(
                f"ssim needs two (B, C, H, W) batches of the same shape, got {tuple(pred.shape)} and "
                f"{tuple(self.target.shape)}"
            )
        exporting = torch.jit.is_tracing() or torch.compiler.is_compiling()
        if not (exporting or (torch.is_grad_enabled() and (pred.requires_grad or self.target.requires_grad))):
            return self._maps_in_place(pred, repeats)
        channels = pred.shape[1]
        # (k, B, C, H, W) against the target's (B, C, H, W): broadcast, never copied k times
        cross = (pred.view(repeats, batch, *pred.shape[1:]) * self.target).view(pred.shape)
        stacked = torch.cat([pred, pred * pred, cross], dim=1)
        filtered = _filter_valid(stacked, self.window.to(pred.dtype))
        mu_x, xx, xy = (m.view(repeats, batch, channels, *m.shape[-2:]) for m in torch.split(filtered, channels, dim=1))
        mu_y, var_y, mu_y2 = self._target_terms()
        c1, c2 = SSIM_K1**2, SSIM_K2**2
        mu_x2 = mu_x * mu_x
        mu_xy = mu_x * mu_y
        contrast_structure = (2 * (xy - mu_xy) + c2) / ((xx - mu_x2) + var_y + c2)
        luminance = (2 * mu_xy + c1) / (mu_x2 + mu_y2 + c1)
        shape = (pred.shape[0], channels, *filtered.shape[-2:])
        return (luminance * contrast_structure).view(shape), contrast_structure.view(shape)

    def _maps_in_place(self, pred: torch.Tensor, repeats: int) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`maps` without autograd: ``x``, ``x^2`` and ``x y`` are written straight into the
        filter's input (in its layout: no concatenation and no layout copy) and every later term
        overwrites a filtered plane it no longer needs, so that per call only the filter's output
        and ``mu_x^2`` are allocated. Each element sees the same operations in the same order as
        in :meth:`maps`, so the maps are equal to the last bit (memory traffic, not arithmetic, is
        what this saves: about 30 % of an SSIM at 600x800 on two CPU cores)."""
        batch, channels = self.target.shape[0], pred.shape[1]
        stacked = torch.empty(
            (pred.shape[0], 3 * channels, *pred.shape[-2:]),
            dtype=pred.dtype,
            device=pred.device,
            memory_format=_filter_layout(pred.device),
        )
        stacked[:, :channels] = pred
        torch.mul(pred, pred, out=stacked[:, channels : 2 * channels])
        by_target = stacked[:, 2 * channels :].unflatten(0, (repeats, batch))
        torch.mul(pred.unflatten(0, (repeats, batch)), self.target, out=by_target)
        filtered = _filter_valid(stacked, self.window.to(pred.dtype))
        mu_x, xx, xy = (m.unflatten(0, (repeats, batch)) for m in torch.split(filtered, channels, dim=1))
        mu_y, var_y, mu_y2 = self._target_terms()
        c1, c2 = SSIM_K1**2, SSIM_K2**2
        mu_x2 = mu_x * mu_x
        mu_xy = mu_x.mul_(mu_y)  # mu_x is not needed again
        contrast_structure = xy.sub_(mu_xy).mul_(2).add_(c2)  # 2 (xy - mu_xy) + c2
        contrast_structure.div_(xx.sub_(mu_x2).add_(var_y).add_(c2))  # / ((xx - mu_x2) + var_y + c2)
        luminance = mu_xy.mul_(2).add_(c1).div_(mu_x2.add_(mu_y2).add_(c1))  # (2 mu_xy + c1) / (mu_x2 + mu_y2 + c1)
        ssim_map = luminance.mul_(contrast_structure)
        return ssim_map.flatten(0, 1), contrast_structure.flatten(0, 1)

    def _target_terms(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``mu_y``, ``sigma_y^2`` and ``mu_y^2`` of the target (computed on first use, then kept)."""
        if not hasattr(self, "_terms"):
            mu_y2 = self.mu_y * self.mu_y
            self._terms = (self.mu_y, self.yy - mu_y2, mu_y2)
        return self._terms

    def ssim(self, pred: torch.Tensor) -> torch.Tensor:
        """SSIM per image of ``pred`` against the target, ``(len(pred),)``."""
        return self.maps(pred)[0].mean(dim=(1, 2, 3))


def _ssim_and_contrast_structure(pred: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean SSIM and mean contrast-structure term per image, both ``(B,)`` (:func:`_ssim_maps`)."""
    ssim_values, contrast_structure = _ssim_maps(pred, target)
    return ssim_values.flatten(1).mean(1), contrast_structure.flatten(1).mean(1)


def ssim_map(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Local SSIM ``(B, H, W)`` averaged over the colours, NaN within the window's radius of the border
    (where the window does not fit); its mean over the finite pixels is :func:`ssim`."""
    _check_pair(pred, target, "ssim")
    local = _ssim_maps(pred, target)[0].mean(1)
    radius = (pred.shape[-2] - local.shape[-2]) // 2
    out = torch.full((pred.shape[0], *pred.shape[-2:]), float("nan"), dtype=local.dtype, device=local.device)
    out[:, radius : radius + local.shape[-2], radius : radius + local.shape[-1]] = local
    return out


def ssim(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Structural similarity per image (see the module docstring); images >= 11×11 pixels."""
    _check_pair(pred, target, "ssim")
    return _ssim_and_contrast_structure(pred, target)[0]


def ms_ssim_scales(height: int, width: int, max_scales: int = len(MS_SSIM_WEIGHTS)) -> int:
    """Number of MS-SSIM scales for an image: at most ``max_scales``, and the coarsest scale
    (``floor(size / 2^(scales-1))``) must still hold the 11-pixel Gaussian window."""
    window = gaussian_window().numel()
    scales = 0
    while scales < max_scales and min(height, width) // 2**scales >= window:
        scales += 1
    return scales


def ms_ssim(
    pred: torch.Tensor, target: torch.Tensor, finest: tuple[torch.Tensor, torch.Tensor] | None = None
) -> torch.Tensor:
    """Multi-scale SSIM per image (Wang, Simoncelli, Bovik 2003):

        MS-SSIM = SSIM_M^{w_M} * prod_{j<M} cs_j^{w_j}

    where scale ``j + 1`` is scale ``j`` average-pooled 2×2, ``cs_j`` / ``SSIM_M`` are the mean
    contrast-structure term / the mean SSIM (as in :func:`ssim`) and ``w`` =
    :data:`MS_SSIM_WEIGHTS`. Negative ``cs``/``SSIM`` values are set to 0 before the powers
    (as in torchmetrics' ``normalize="relu"``).

    Small images: the number of scales ``M`` is reduced (:func:`ms_ssim_scales`) so the
    coarsest scale still holds the 11×11 window, and the first ``M`` weights are rescaled to
    sum to 1 (e.g. 128×128 crops use 4 scales, 128 → 16 pixels). Images below 11×11 raise.
    ``finest``: the mean SSIM and contrast-structure term of the first scale when already computed
    (:class:`ImageScorer`), each ``(B,)``.
    """
    _check_pair(pred, target, "ms_ssim")
    scales = ms_ssim_scales(pred.shape[-2], pred.shape[-1])
    if scales == 0:
        raise EdofprojError(f"MS-SSIM needs images of at least 11x11 pixels, got {pred.shape[-2]}x{pred.shape[-1]}")
    weights = torch.tensor(MS_SSIM_WEIGHTS[:scales], dtype=pred.dtype, device=pred.device)
    weights = weights / weights.sum()
    result = pred.new_ones(pred.shape[0])
    for scale in range(scales):
        if scale > 0:
            pred, target = F.avg_pool2d(pred, 2), F.avg_pool2d(target, 2)
        if scale == 0 and finest is not None:
            full, contrast_structure = finest
        else:
            full, contrast_structure = _ssim_and_contrast_structure(pred, target)
        term = full if scale == scales - 1 else contrast_structure
        result = result * F.relu(term) ** weights[scale]
    return result


# --------------------------------------------------------------------------- colour fidelity

#: Percentile of the per-pixel colour difference reported beside its mean.
DELTA_E_PERCENTILE = 95.0


def delta_e2000_map(pred: torch.Tensor, target: torch.Tensor) -> np.ndarray:
    """Per-pixel CIEDE2000 difference ``(B, H, W)`` (float64) of two batches read as sRGB in [0, 1]
    (values outside are clipped first, as a display would)."""
    _check_pair(pred, target, "delta_e2000")
    return _delta_e2000_map_to_lab(pred, cielab(target))


def cielab(images: torch.Tensor) -> np.ndarray:
    """CIELAB (D65) of a batch ``(B, 3, H, W)`` read as sRGB in ``[0, 1]`` (clipped first): ``(B, H, W, 3)``
    float64 (scikit-image's ``rgb2lab``)."""
    from skimage.color import rgb2lab  # start-up: scikit-image's colour module is slow to import

    rgb = images.detach().float().clamp(0, 1).permute(0, 2, 3, 1).cpu().numpy().astype(np.float64)
    return np.stack([rgb2lab(image) for image in rgb])


def _delta_e2000_map_to_lab(pred: torch.Tensor, target_lab: np.ndarray) -> np.ndarray:
    """Per-pixel CIEDE2000 difference ``(B, H, W)`` of ``pred`` from a target given in CIELAB."""
    from skimage.color import deltaE_ciede2000

    return np.stack([deltaE_ciede2000(lab, pred_lab) for lab, pred_lab in zip(target_lab, cielab(pred))])


def delta_e2000(
    pred: torch.Tensor, target: torch.Tensor, target_lab: np.ndarray | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(mean, p95)`` of the per-pixel CIEDE2000 difference, each ``(B,)`` float32 (module docstring).
    ``target_lab``: :func:`cielab` of ``target`` when already computed."""
    _check_pair(pred, target, "delta_e2000")
    lab = cielab(target) if target_lab is None else target_lab
    maps = _delta_e2000_map_to_lab(pred, lab).reshape(pred.shape[0], -1)
    mean = torch.from_numpy(maps.mean(axis=1)).float()
    p95 = torch.from_numpy(np.percentile(maps, DELTA_E_PERCENTILE, axis=1)).float()
    return mean, p95


def ssim_per_channel(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """SSIM of each channel ``(B, C)``: the local SSIM map of :func:`edofproj.metrics.ssim` averaged
    over the positions only (not over the channels)."""
    _check_pair(pred, target, "ssim_per_channel")
    return _ssim_maps(pred, target)[0].flatten(2).mean(2)


class ImageScorer:
    """The scores of many images against one fixed ``target`` ``(B, 3, H, W)`` (e.g. every method's
    display at every depth): the target's local SSIM statistics (:class:`SSIMReference`) and its CIELAB
    values are computed once, and one SSIM map per image gives its SSIM, the SSIM of each channel and
    MS-SSIM's finest scale. The values equal :func:`psnr`, :func:`ssim`, :func:`ms_ssim`,
    :func:`delta_e2000` and :func:`ssim_per_channel` to the last bit."""

    def __init__(self, target: torch.Tensor) -> None:
        self.target = target
        self.reference = SSIMReference(target)
        self.reference._target_terms()  # computed now: a scorer may be shared by threads
        self.target_lab = cielab(target)

    def scores(self, pred: torch.Tensor) -> dict[str, torch.Tensor]:
        """``{psnr, ssim, ms_ssim, de2000, de2000_p95, ssim_r, ssim_g, ssim_b}``, each ``(B,)``."""
        _check_pair(pred, self.target, "ImageScorer")
        ssim_values, contrast_structure = self.reference.maps(pred)
        finest = (ssim_values.flatten(1).mean(1), contrast_structure.flatten(1).mean(1))
        channels = ssim_values.flatten(2).mean(2)
        de_mean, de_p95 = delta_e2000(pred, self.target, self.target_lab)
        return {
            "psnr": psnr(pred, self.target),
            "ssim": finest[0],
            "ms_ssim": ms_ssim(pred, self.target, finest),
            "de2000": de_mean,
            "de2000_p95": de_p95,
            "ssim_r": channels[:, 0],
            "ssim_g": channels[:, 1],
            "ssim_b": channels[:, 2],
        }


# --------------------------------------------------------------------------- perceptual


def dists(weights_dir: Optional[PathLike] = None) -> DISTS:
    """The DISTS metric object: ``metric(pred, target) -> (B,)``, lower is better.

    Raises :class:`PerceptualWeightsMissing` when its weight files are absent.
    """
    return DISTS.load(weights_dir)


def lpips(net: str = "alex", weights_dir: Optional[PathLike] = None) -> LPIPS:
    """The LPIPS metric object (``net``: ``alex`` or ``vgg``): ``metric(pred, target) -> (B,)``.

    Raises :class:`PerceptualWeightsMissing` when its weight files are absent.
    """
    return LPIPS.load(net, weights_dir)


def perceptual_metric(name: str, weights_dir: Optional[PathLike] = None) -> DISTS | LPIPS:
    """Metric object by name: one of :data:`PERCEPTUAL_METRICS`."""
    if name == "dists":
        return dists(weights_dir)
    if name.startswith("lpips-") and name[len("lpips-") :] in LPIPS_BACKBONES:
        return lpips(name[len("lpips-") :], weights_dir)
    raise EdofprojError(f"unknown perceptual metric '{name}' (allowed: {', '.join(PERCEPTUAL_METRICS)})")


def available_perceptual_metrics(weights_dir: Optional[PathLike] = None) -> dict[str, bool]:
    """For each name in :data:`PERCEPTUAL_METRICS`: are all its weight files present?

    Only checks that the files exist (cheap); loading can still fail on a corrupt file.
    """
    needs = {"dists": ("dists", "vgg16")}
    for net, (backbone, _) in LPIPS_BACKBONES.items():
        needs[f"lpips-{net}"] = (f"lpips-{net}", backbone)
    available = {}
    for name in PERCEPTUAL_METRICS:
        metric_file, backbone = needs[name]
        try:
            metric_weights_path(metric_file, weights_dir)
            backbone_weights_path(backbone, weights_dir)
        except PerceptualWeightsMissing:
            available[name] = False
        else:
            available[name] = True
    return available
