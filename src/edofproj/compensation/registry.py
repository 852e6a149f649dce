"""The compensation networks by architecture name: one table that builds, describes and lists them.

Every network maps ``net(target, captured) -> projector input`` (unclamped, same size as the
target). ``net.architecture`` in a config names one of :data:`NETWORKS`; the rest of the ``net``
section is that network's configuration, a class of :mod:`edofproj.net_config` that declares its
options (their meaning, unit and range) and is validated when the config is read:

* ``unet`` -- :class:`~edofproj.compensation.unet.CompensationUNet` (the paper's U-Net; with a
  learned radial Fourier pre-filter or the safe linear base in front of it), configured by
  :class:`~edofproj.net_config.UNetConfig`;
* ``multirate`` -- :class:`~edofproj.compensation.multirate.MultirateCompensationNet` (the
  real-time network), configured by :class:`~edofproj.net_config.MultirateConfig`;
* ``onlineprodeb`` -- :class:`~edofproj.compensation.onlineprodeb.OnlineProDebNet` (the baseline
  re-implementation, its default preset), configured by :class:`~edofproj.net_config.OnlineProDebConfig`.

The names are the configuration classes' own (``UNetConfig.architecture``): the configuration layer
reads a ``net`` section without importing any network, and this table pairs each of its classes
(:data:`edofproj.net_config.NET_CONFIGS`) with the network it builds.

:func:`build_network` builds a config's network, :func:`describe_network` names it in one line
(reports, ``bench``), :func:`network_from_widths` builds an untrained one from a width spec
(``bench --widths``).
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

from torch import nn

from ..errors import EdofprojError
from ..limits import check_memory
from ..net_config import NET_CONFIGS, MultirateConfig, NetConfig, OnlineProDebConfig, UNetConfig
from .multirate import MultirateCompensationNet
from .onlineprodeb import OnlineProDebNet
from .surface_net import SurfaceAwareNet
from .unet import CompensationUNet, width_preset

#: Least bytes per pixel of one frame through a compensation network (inference): peak RSS at
#: 512x512 of the smallest network, the multi-rate one of widths 8,16, was 184 B/px (the default
#: U-Net 713; docs/experiments/2026-11-25-hostile-inputs.md) -- a lower bound.
NETWORK_FRAME_BYTES_PER_PIXEL = 128


def check_frame_memory(height: int, width: int, what: str, change: str) -> None:
    """Refuse a ``height x width`` frame through a network that cannot fit in memory, before any
    allocation (:func:`edofproj.limits.check_memory` of :data:`NETWORK_FRAME_BYTES_PER_PIXEL`)."""
    check_memory(float(NETWORK_FRAME_BYTES_PER_PIXEL) * height * width, what, change)


def _describe_unet(net_cfg) -> str:
    widths = [int(w) for w in net_cfg.widths]
    text = f"U-Net {min(widths)}-{max(widths)} ({len(widths)} scales)"
    if net_cfg.space_to_depth > 1:
        text += f" on {net_cfg.space_to_depth}x{net_cfg.space_to_depth} pixel blocks"
    if net_cfg.prefilter_bins:
        text += f" + radial pre-filter ({net_cfg.prefilter_bins} nodes)"
    if net_cfg.linear_base == "ensemble":
        # the same network serves every optics (lens+net, axicon+net, doe+net): the filter is its optics'
        text += f" as a correction of at most {net_cfg.correction_bound:g} on its optics' depth-ensemble linear filter"
    return text


def _describe_multirate(net_cfg) -> str:
    widths = [int(w) for w in net_cfg.widths]
    s = net_cfg.block_px
    return (
        f"multi-rate network: U-Net {min(widths)}-{max(widths)} ({len(widths)} scales) at 1/{s} resolution"
        f" + radial Fourier filter at 1/{s} ({net_cfg.filter_bins} nodes)"
    )


class Architecture(NamedTuple):
    """A network's configuration class, the network class, how a config builds it, and how it is
    named in one line."""

    config: type[NetConfig]
    network: type
    build: Callable[[Any], nn.Module]
    describe: Callable[[Any], str]


_ARCHITECTURES = (
    Architecture(UNetConfig, CompensationUNet, CompensationUNet.from_config, _describe_unet),
    Architecture(MultirateConfig, MultirateCompensationNet, MultirateCompensationNet.from_config, _describe_multirate),
    Architecture(
        OnlineProDebConfig,
        OnlineProDebNet,
        lambda net_cfg: OnlineProDebNet.from_preset("default", leaky_slope=net_cfg.leaky_slope),
        lambda net_cfg: "onlineprodeb",
    ),
)
#: Each architecture of :data:`edofproj.net_config.NET_CONFIGS` (in its order) with its network.
NETWORKS: dict[str, Architecture] = {
    name: next(a for a in _ARCHITECTURES if a.config is config) for name, config in NET_CONFIGS.items()
}


def _architecture(name: str) -> Architecture:
    if name not in NETWORKS:
        raise EdofprojError(f"unknown network architecture '{name}' (known: {', '.join(NETWORKS)})")
    return NETWORKS[name]


def build_network(net_cfg) -> nn.Module:
    """The compensation network of a :class:`~edofproj.config.NetConfig` (with ``net.surface_input``:
    wrapped in :class:`~edofproj.compensation.surface_net.SurfaceAwareNet`)."""
    net = _architecture(net_cfg.architecture).build(net_cfg)
    if getattr(net_cfg, "surface_input", False):
        net = SurfaceAwareNet(net, leaky_slope=net_cfg.leaky_slope)
    return net


def describe_network(net_cfg) -> str:
    """One line naming the network of a ``net`` section, e.g. ``U-Net 16-128 (4 scales)
    + radial pre-filter (48 nodes)``."""
    text = _architecture(net_cfg.architecture).describe(net_cfg)
    return text + (" with the surface as input" if getattr(net_cfg, "surface_input", False) else "")


def network_from_widths(
    spec: str, space_to_depth: int = 1, prefilter_bins: int = 0, architecture: str = "unet"
) -> nn.Module:
    """An untrained network of a named width preset or comma-separated channel counts:
    :class:`CompensationUNet` or, for ``architecture="multirate"``, :class:`MultirateCompensationNet`
    (``space_to_depth`` is then its block size, ``prefilter_bins`` its filter's nodes)."""
    if spec.replace(",", "").replace(" ", "").isdigit():
        widths = [int(w) for w in spec.split(",")]
    else:
        widths = width_preset(spec)
    if architecture == "multirate":
        return MultirateCompensationNet(widths, block=space_to_depth, filter_bins=prefilter_bins)
    if architecture != "unet":
        raise EdofprojError(f"--architecture {architecture}: only unet and multirate are built from widths")
    return CompensationUNet(widths, space_to_depth=space_to_depth, prefilter_bins=prefilter_bins)
