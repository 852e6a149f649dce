"""Binary lithography masks of an N = 2^k level profile: one etch cycle per mask.

Etch convention (height measured from the deepest etch floor): the un-etched wafer surface
is the top level ``N - 1``; a zone at level ``L`` is etched to the depth ``(N - 1 - L) s``.
Mask ``j`` (``j = 0 .. k-1``) is etched ``2^j s`` deep and is *open* (etched) where bit ``j``
of the etch code ``c = N - 1 - L`` is set, so

    depth(L)  = sum_j bit_j(N - 1 - L) 2^j s = (N - 1 - L) s,
    height(L) = (N - 1) s - depth(L) = L s.

16 levels at 550 nm in fused silica (h_2pi = 1195.9 nm): ``s = 74.7 nm``, masks etched 74.7,
149.5, 299.0 and 597.9 nm deep (the paper's 75/150/300/600 nm cycles), total 1121.1 nm. The design
height is the glass thickness the light crosses (the phase delay grows with it), which is
why level 0 is the most deeply etched zone rather than the un-etched one.

Each mask is a set of concentric etched annuli ``[inner, outer)`` (``inner = 0``: a disk);
adjacent zones with the same bit are merged into one annulus.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .profile import RadialProfile, mask_count


def etch_code(level, levels: int) -> np.ndarray:
    """Etch code ``c = N - 1 - L``: bit ``j`` set means mask ``j`` etches there."""
    return (levels - 1) - np.asarray(level, dtype=np.int64)


@dataclass(frozen=True)
class Feature:
    """One printed feature of a mask: an etched annulus or the un-etched gap between two."""

    etched: bool
    inner_m: float
    outer_m: float

    @property
    def width_m(self) -> float:
        """Radial width; a central disk (``inner = 0``) counts with its diameter."""
        return 2 * self.outer_m if self.inner_m == 0.0 else self.outer_m - self.inner_m


@dataclass(frozen=True)
class MaskLayer:
    """Mask ``index`` (etch cycle j): etch depth and etched annuli (m, 2) = (inner, outer) radii."""

    index: int
    etch_depth_m: float
    annuli_m: np.ndarray

    @property
    def gds_layer(self) -> int:
        """GDSII layer number: mask j is layer j + 1."""
        return self.index + 1

    @property
    def ring_count(self) -> int:
        return int(len(self.annuli_m))

    def etched(self, r_m) -> np.ndarray:
        """True where this mask etches, at radii ``r_m`` (annuli are ``[inner, outer)``)."""
        flat = self.annuli_m.reshape(-1)
        return np.searchsorted(flat, np.asarray(r_m, dtype=float), side="right") % 2 == 1

    def features(self) -> list[Feature]:
        """Etched annuli and the un-etched gaps between them (a central un-etched disk included).

        The un-etched region beyond the last annulus is open to the aperture stop and is no
        narrow feature."""
        out: list[Feature] = []
        previous_outer = 0.0
        for inner, outer in self.annuli_m:
            if inner > previous_outer:
                out.append(Feature(False, previous_outer, float(inner)))
            out.append(Feature(True, float(inner), float(outer)))
            previous_outer = float(outer)
        return out


def decompose(profile: RadialProfile) -> list[MaskLayer]:
    """The ``k = log2(N)`` binary masks of a profile (see the module docstring for the convention)."""
    edges, zone_level = profile.zones()
    code = etch_code(zone_level, profile.levels)
    masks = []
    for j in range(mask_count(profile.levels)):
        bit = ((code >> j) & 1).astype(bool)
        # annulus boundaries: where the bit switches on (start) or off (end), over merged zones
        padded = np.concatenate([[False], bit, [False]])
        starts = np.nonzero(~padded[:-1] & padded[1:])[0]
        ends = np.nonzero(padded[:-1] & ~padded[1:])[0]
        annuli = np.stack([edges[starts], edges[ends]], axis=1) if len(starts) else np.empty((0, 2))
        masks.append(MaskLayer(index=j, etch_depth_m=profile.step_m * 2**j, annuli_m=annuli))
    return masks


def depth_from_masks(r_m, masks: list[MaskLayer]) -> np.ndarray:
    """Total etched depth at radii ``r_m``: the sum of the depths of the masks that etch there."""
    r = np.asarray(r_m, dtype=float)
    return sum((m.etch_depth_m * m.etched(r) for m in masks), np.zeros_like(r))


def level_from_etched(etched_by_mask: np.ndarray, levels: int) -> np.ndarray:
    """Level from the per-mask etch flags (k, ...) (bool): ``L = N - 1 - sum_j 2^j bit_j``."""
    flags = np.asarray(etched_by_mask, dtype=np.int64)
    weights = (2 ** np.arange(flags.shape[0])).reshape((-1,) + (1,) * (flags.ndim - 1))
    return (levels - 1) - (flags * weights).sum(axis=0)


def top_surface_m(profile: RadialProfile) -> float:
    """Height of the un-etched wafer surface above the deepest etch floor, ``(N - 1) s``."""
    return (profile.levels - 1) * profile.step_m
