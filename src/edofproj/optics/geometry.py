"""Projector geometry: aperture, in-focus distance and the screen pixel pitch.

A projector's image grows with distance, so PSFs are expressed in projector pixels.
With throw ratio ``T`` (distance / image width) and image width ``W`` pixels, the pitch of
one projector pixel on a screen at depth ``z`` is

    q(z) = z / (T * W).

In pixel units the Fresnel/Hankel kernel ``J0(2 pi r rho / (lambda z))`` becomes
``J0(2 pi r rho_px / (lambda T W))``, independent of ``z``.

A screen depth lies in ``[MIN_SCREEN_DEPTH_MM, MAX_SCREEN_DEPTH_MM]`` (:func:`check_screen_depths_mm`). Nearer
than 1 mm a screen would touch the projection lens (its aperture alone is millimetres wide): such a
depth is a unit mistake (``1e-3`` for 1 m), not a screen. The defocus
grows with ``|1/z - 1/v|``, which beyond 100 m differs from its value at infinity by less than
0.01 m^-1 (0.5 % of ``1/v`` for a projector focused at 0.5 m), so a farther depth says nothing a
100 m one does not, and is a unit mistake (``1e9`` for 1 m) rather than a screen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import EdofprojError

#: The nearest and the farthest screen depth a command takes (module docstring), mm.
MIN_SCREEN_DEPTH_MM, MAX_SCREEN_DEPTH_MM = 1.0, 100_000.0


def check_screen_depths_mm(depths_mm, option: str) -> np.ndarray:
    """``depths_mm`` as a float array, or one line naming ``option`` unless every depth is a number in
    ``[MIN_SCREEN_DEPTH_MM, MAX_SCREEN_DEPTH_MM]`` (NaN allowed nowhere; depth maps mark 'nothing hit'
    before this)."""
    values = np.atleast_1d(np.asarray(depths_mm, dtype=float))
    bad = values[~(np.isfinite(values) & (values >= MIN_SCREEN_DEPTH_MM) & (values <= MAX_SCREEN_DEPTH_MM))]
    if values.size == 0 or bad.size:
        shown = f"{bad[0]:g}" if bad.size else "nothing"
        if bad.size and 0 < bad[0] < MIN_SCREEN_DEPTH_MM:
            why = f"a screen nearer than {MIN_SCREEN_DEPTH_MM:g} mm would touch the lens (depths are in mm: 500 for 0.5 m)"
        elif bad.size and bad[0] <= 0:
            why = "a depth is the screen's distance in front of the lens, in mm (500 for 0.5 m)"
        else:
            why = f"a depth beyond {MAX_SCREEN_DEPTH_MM / 1000:g} m blurs as one at infinity"
        raise EdofprojError(
            f"{option} must be screen depths in [{MIN_SCREEN_DEPTH_MM:g}, {MAX_SCREEN_DEPTH_MM:g}] mm, got {shown}: {why}"
        )
    return values


@dataclass(frozen=True)
class ProjectorGeometry:
    """Paraxial projector optics in SI units (metres)."""

    aperture_diameter_m: float = 7e-3
    focus_distance_m: float = 0.5
    throw_ratio: float = 1.5
    width_px: int = 800
    height_px: int = 600

    def __post_init__(self) -> None:
        for name in ("aperture_diameter_m", "focus_distance_m", "throw_ratio"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise EdofprojError(f"{name}={value} must be a positive number")
        if self.width_px < 1 or self.height_px < 1:
            raise EdofprojError("width_px and height_px must be >= 1")

    @classmethod
    def from_config(cls, optics) -> "ProjectorGeometry":
        """From an :class:`~edofproj.config.OpticsConfig` (its ``*_m`` properties)."""
        return cls(
            aperture_diameter_m=optics.aperture_m,
            focus_distance_m=optics.focus_m,
            throw_ratio=optics.throw_ratio,
            width_px=int(optics.width_px),
            height_px=int(optics.height_px),
        )

    @property
    def aperture_radius_m(self) -> float:
        return self.aperture_diameter_m / 2

    @property
    def throw_width_m(self) -> float:
        """``T * W``: the screen distance per metre of pixel pitch, q(z) = z / (T W)."""
        return self.throw_ratio * self.width_px

    def pixel_pitch_m(self, depth_m):
        """Projector pixel pitch on a screen at ``depth_m``: q(z) = z / (T W)."""
        return np.asarray(depth_m, dtype=float) / self.throw_width_m

    def blur_diameter_px(self, depth_m):
        """Geometric defocus blur disk ``D |1 - z/v|`` in projector pixels at ``depth_m``."""
        z = np.asarray(depth_m, dtype=float)
        return self.aperture_diameter_m * np.abs(1.0 - z / self.focus_distance_m) / self.pixel_pitch_m(z)

    def airy_first_zero_px(self, wavelength_m: float) -> float:
        """First dark ring of the in-focus Airy pattern, 1.22 lambda z / D, in pixels."""
        return 1.22 * wavelength_m * self.throw_width_m / self.aperture_diameter_m
