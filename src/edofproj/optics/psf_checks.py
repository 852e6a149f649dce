"""The one check every PSF passes on its way into the project (files, measurements, simulations).

A PSF stack ``psf (n_depths, C, K, K)`` is physical when

* it is finite;
* ``K`` is odd (the optical axis on pixel ``(K//2, K//2)``) and the window square;
* it is non-negative: a simulated PSF to float rounding, ``min >= -SIMULATED_NEGATIVE * max``; a
  measured one (or a file, which may hold one) within the noise of the measurement: its most
  negative value at most :data:`MEASURED_NEGATIVE` of its peak and its negative values together
  at most :data:`MEASURED_NEGATIVE_ENERGY` of its positive ones (an unclipped estimate has
  zero-mean noise around zero, never lobes of negative light);
* each depth and channel holds light, and not more than the pupil let through:
  ``0 < E = sum_xy psf <= 1 + tolerance`` (``E`` is the in-window energy, ``1 - E`` the haze);
* there is one depth per PSF (``len(depths_m) == n_depths``), each depth positive and finite.

:func:`validate_psf` raises :class:`~edofproj.errors.EdofprojError` with one line naming the
source (e.g. the file), the depth and channel, and what to do.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from ..errors import EdofprojError

#: Allowed negative values of a simulated PSF, relative to its peak (float rounding of the FFTs).
SIMULATED_NEGATIVE = 1e-5
#: Allowed energy above 1 of a simulated PSF (float rounding).
SIMULATED_ENERGY_TOLERANCE = 1e-3
#: Allowed most negative value of a measured PSF (or a file), relative to its peak: noise deeper
#: than the PSF is high leaves nothing measured. (The virtual projector-camera system's estimates
#: reach -0.03; a defocused PSF's low peak sits closer to the noise.)
MEASURED_NEGATIVE = 1.0
#: Allowed sum of the negative values of a measured PSF, relative to the sum of its positive values
#: (zero-mean noise adds as much below zero as above; the virtual system's estimates: <= 0.025).
MEASURED_NEGATIVE_ENERGY = 0.5
#: Allowed energy above 1 of a measured PSF (or a file): the colour calibration's accuracy.
MEASURED_ENERGY_TOLERANCE = 0.05


def _channel(c: int, channels: int) -> str:
    return "RGB"[c] if channels == 3 else str(c)


def validate_psf(
    psf: torch.Tensor | np.ndarray,
    depths_m: Sequence[float] | np.ndarray | None = None,
    source: str = "the PSF",
    measured: bool = True,
    fix: str = "",
) -> None:
    """Raise a one-line error unless ``psf (n_depths, C, K, K)`` is physical (module docstring).

    ``measured``: the tolerances of a measurement (also for files, which may hold one); False:
    those of a simulation. ``depths_m``: the depth of each PSF (checked when given). ``source``
    names it in messages (e.g. ``"PSF file 'x.npz'"``); ``fix`` is appended (what to do).
    """
    array = psf.detach().cpu().double().numpy() if torch.is_tensor(psf) else np.asarray(psf, dtype=np.float64)
    hint = f"; {fix}" if fix else ""
    if array.ndim != 4:
        raise EdofprojError(f"{source}: a PSF stack must be (n_depths, channels, K, K), got shape {array.shape}{hint}")
    n, channels, height, width = array.shape
    if n == 0 or channels == 0:
        raise EdofprojError(f"{source} holds no PSF (shape {array.shape}){hint}")
    if height != width or width % 2 == 0:
        raise EdofprojError(
            f"{source}: the PSF window must be square with an odd side K (the axis on the centre pixel), "
            f"got {height}x{width}{hint}"
        )
    if depths_m is not None:
        depths = np.asarray(depths_m, dtype=np.float64).reshape(-1)
        if len(depths) != n:
            raise EdofprojError(f"{source}: {n} PSF(s) but {len(depths)} depth(s){hint}")
        if not np.all(np.isfinite(depths) & (depths > 0)):
            raise EdofprojError(f"{source}: depths must be positive and finite, got {depths.tolist()} m{hint}")
    else:
        depths = None
    finite = np.isfinite(array)
    if not finite.all():
        i, c = np.argwhere(~finite.all(axis=(-1, -2)))[0]
        raise EdofprojError(
            f"{source}: NaN or infinite values (depth {_where(i, depths)}, channel {_channel(c, channels)}){hint}"
        )

    energy = array.sum(axis=(-1, -2))  # (n, C)
    peak = array.max(axis=(-1, -2))
    lowest = array.min(axis=(-1, -2))
    negative_energy = np.where(array < 0, -array, 0.0).sum(axis=(-1, -2))
    positive_energy = np.where(array > 0, array, 0.0).sum(axis=(-1, -2))
    energy_tolerance = MEASURED_ENERGY_TOLERANCE if measured else SIMULATED_ENERGY_TOLERANCE
    kind = "measured" if measured else "simulated"
    for i in range(n):
        for c in range(channels):
            where = f"depth {_where(i, depths)}, channel {_channel(c, channels)}"
            if not peak[i, c] > 0 or not energy[i, c] > 0:
                what = "all zero" if np.all(array[i, c] == 0) else f"in-window energy {energy[i, c]:.3g}"
                raise EdofprojError(
                    f"{source} holds no light at {where} ({what}): a PSF's energy must be in (0, 1]{hint}"
                )
            if energy[i, c] > 1 + energy_tolerance:
                raise EdofprojError(
                    f"{source}: in-window energy {energy[i, c]:.4g} at {where} exceeds 1 (the light through "
                    f"the pupil; {kind} tolerance {energy_tolerance:g}){hint}"
                )
            if measured:
                too_negative = lowest[i, c] < -MEASURED_NEGATIVE * peak[i, c]
                too_much = negative_energy[i, c] > MEASURED_NEGATIVE_ENERGY * positive_energy[i, c]
            else:
                too_negative = lowest[i, c] < -SIMULATED_NEGATIVE * peak[i, c]
                too_much = False
            if too_negative or too_much:
                raise EdofprojError(
                    f"{source} has negative light at {where} (minimum {lowest[i, c]:.3g} against a peak of "
                    f"{peak[i, c]:.3g}; negative values sum to {negative_energy[i, c]:.3g}), beyond the "
                    f"{kind} noise a PSF may have{hint}"
                )


def _where(i: int, depths: np.ndarray | None) -> str:
    return f"{i} ({depths[i] * 1e3:.1f} mm)" if depths is not None else str(i)
