"""The differentiable projector of the joint training (paper Fig. 2, Eq. 9).

For a target image ``I`` and a screen depth ``z`` per sample:

    P     = PSF_DOE(z)                                  RGB PSF of the (quantized) DOE at depth z
    I*    = camera( project(I, P) )                     uncompensated projection, as observed
                                                        (on a textured surface s ⊙ project(·) + a)
    Î     = net(I, I*)                                  compensated projector input (unclamped)
    Î*    = project(Î, P)                               what the screen shows

the closed loop of :mod:`edofproj.compensation.closed_loop` on a flat screen (for depth maps
``(B, H, W)``, ``project`` is the depth-layer renderer), where
``project(x, P) = clamp(x, 0, 1) ⊛ P + (1 - ΣP) mean(clamp(x, 0, 1))`` (:func:`edofproj.imaging.projection.project`):
the projector emits only light in [0, 1], and light outside the PSF window is a uniform haze.
The loss ``L(Î*, I)`` (Eq. 12) is taken by the caller. Everything is differentiable with
respect to the network and, through ``P`` (the PSF simulator with the straight-through
quantizer), the DOE's parameters.

With ``mixed_precision="bf16"`` the network runs under bfloat16 autocast (its convolutions in
bf16, its Fourier filter in float32) and its output is returned to float32; the PSFs, both
projections and the camera stay in float32. ``"auto"`` is resolved by
:func:`resolve_mixed_precision` to ``bf16`` on hardware with native bfloat16 arithmetic.

PSFs come from a *PSF source*, a module ``source(depths_m) -> (B, C, K, K)``:
:class:`SimulatedPSF` (the DOE simulated every step, one call for the whole batch) or a
:class:`~edofproj.training.psf_table.DepthPSFTable` (a fixed DOE, precomputed).
"""

from __future__ import annotations

import torch
from torch import nn

from .. import machine
from ..compensation.closed_loop import ForwardModel, LoopImages, closed_loop, flat_screen
from ..compensation.photometric import photometric_compensation
from ..imaging.depth_layers import render_depth_map
from .camera import camera_capture


def native_bf16(device: torch.device) -> bool:
    """Whether ``device`` computes bfloat16 natively: a CUDA GPU with bf16 support, or a CPU with
    AVX512-BF16 or AMX instructions that the environment does not forbid
    (:func:`edofproj.machine.usable_flags`; elsewhere oneDNN emulates bf16, slower than float32)."""
    if device.type == "cuda":
        return bool(torch.cuda.is_bf16_supported())
    if device.type == "cpu":
        hardware = bool(torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported())
        return hardware and (not machine.isa_limits() or machine.native_bf16())
    return False


def resolve_mixed_precision(setting: str, device: torch.device) -> str:
    """``train.mixed_precision`` on ``device``: ``none`` and ``bf16`` as given, ``auto`` -> ``bf16``
    where :func:`native_bf16`, else ``none``."""
    if setting == "auto":
        return "bf16" if native_bf16(device) else "none"
    return setting


class SimulatedPSF(nn.Module):
    """PSFs of ``doe`` simulated at each call: ``simulator(doe, depths_m)`` as float32 ``(B, C, K, K)``."""

    def __init__(self, doe: nn.Module, simulator) -> None:
        super().__init__()
        self.doe = doe
        self.simulator = simulator

    def forward(self, depths_m) -> torch.Tensor:
        return self.simulator(self.doe, depths_m).float()


class EndToEndProjector(nn.Module):
    """PSF source + compensation network + image formation, as one module (one DDP wrapper)."""

    def __init__(
        self,
        psf_source: nn.Module,
        net: nn.Module,
        noise_sigma: float = 0.0,
        quantize_capture: bool = False,
        mixed_precision: str = "none",
        layers_m=None,
    ) -> None:
        super().__init__()
        if mixed_precision not in ("none", "bf16"):
            raise ValueError(f"mixed_precision={mixed_precision!r} is not one of none, bf16")
        self.psf_source = psf_source
        self.net = net
        self.noise_sigma = float(noise_sigma)
        self.quantize_capture = bool(quantize_capture)
        self.mixed_precision = mixed_precision
        self.layers_m = layers_m  # depth layers for depth-varying screens (train.screens: varying)

    def _compensate(self, target: torch.Tensor, captured: torch.Tensor, *surface: torch.Tensor) -> torch.Tensor:
        with torch.autocast(target.device.type, dtype=torch.bfloat16, enabled=self.mixed_precision == "bf16"):
            compensated = self.net(target, captured, *surface)
        return compensated.float()

    def forward(
        self,
        target: torch.Tensor,
        depths_m,
        noise: torch.Tensor | None = None,
        reflectance: torch.Tensor | None = None,
        ambient: torch.Tensor | None = None,
    ) -> LoopImages:
        """``target`` (B, 3, H, W) in [0, 1], ``depths_m`` (B,) flat screens or (B, H, W) depth maps
        (rendered by depth layers at ``layers_m``), ``noise`` standard normal like ``target``.
        ``reflectance`` (B, 3, H, W) and ``ambient`` (B, 3, H|1, W|1): a textured surface
        (:mod:`edofproj.imaging.surfaces`: the screen shows ``s ⊙ A(x) + a``; the network, one
        that takes the surface, gets both, and its capture ``I*`` is of the photometric correction
        ``clip((G - a) / s, 0, 1)`` projected, :mod:`edofproj.compensation.surface_net`); ``target``
        is then the goal appearance (:func:`edofproj.compensation.achievable.achievable_goal`).

        Returns the loop's images ``(captured I*, compensated Î, projected Î*)``.
        """
        if getattr(depths_m, "ndim", 1) == 3:
            if self.layers_m is None:
                raise ValueError("depth-map screens need the projector's layers_m")
            layers, maps = self.layers_m, depths_m
            layer_psf = self.psf_source(layers).to(target.device)
            forward: ForwardModel = lambda image: render_depth_map(image, maps, layer_psf, layers=layers)  # noqa: E731
        else:
            forward = flat_screen(self.psf_source(depths_m).to(target.device))

        def observe(image: torch.Tensor) -> torch.Tensor:
            return camera_capture(image, noise, self.noise_sigma, self.quantize_capture)

        if reflectance is None:
            return closed_loop(target, forward, self._compensate, observe)
        if ambient is None:
            raise ValueError("a textured surface needs its ambient light too (zeros for none)")
        rho, amb = reflectance.to(target.device), ambient.to(target.device)
        screen = forward

        def textured(image: torch.Tensor) -> torch.Tensor:
            return rho * screen(image) + amb

        # the capture a surface-aware network takes: its photometric first stage projected (surface_net.py)
        captured = observe(textured(photometric_compensation(target, rho, amb)))
        return closed_loop(
            target, textured, lambda goal, seen: self._compensate(goal, seen, rho, amb), observe, captured=captured
        )
