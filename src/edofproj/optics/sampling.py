"""Pupil sampling: every requirement at once, and the one ``pupil_samples`` that meets them all.

Both engines sample the pupil with ``M = pupil_samples`` across the diameter ``D`` (pitch, or ring
pair width, ``D / M``). Each requirement is a lower bound on ``M``:

* **defocus**: the defocus phase step between samples at the rim,
  ``2 pi R (D / M) max|1/z - 1/v| / lambda_min``, stays below ``MAX_PHASE_STEP_RAD``;
* **field of view** (2-D engine): the FFT's periodic field, ``lambda_min T W M / D`` pixels, holds
  the window plus the geometric blur (at least 2 px of margin), else light wraps around;
* **aberration**: the lens aberration's phase step between neighbouring samples (the engine's own
  samples: ring centres or grid points) stays below ``MAX_PHASE_STEP_RAD``;
* **design**: the DOE's own rule (``doe.check_sampling(D / M)``: its finest ring, encoding period,
  zone power, ...), the smallest even ``M`` it accepts found by bisection.

:func:`check_pupil_sampling` evaluates all of them; when any fails it takes the largest bound,
evaluates all of them again there (the aberration and design rules are measured on the new
sampling, not extrapolated) until one ``M`` passes every check, and raises one
:class:`~edofproj.errors.SamplingError` naming each unmet requirement and that ``M``. Following the
message once is therefore enough.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable

import numpy as np

from ..errors import SamplingError
from .geometry import ProjectorGeometry

#: the largest phase step (rad) between neighbouring pupil samples
MAX_PHASE_STEP_RAD = math.pi / 2
#: the largest pupil sampling the search names
MAX_PUPIL_SAMPLES = 1 << 16


def _even_ceil(x: float) -> int:
    n = int(math.ceil(x - 1e-9))
    return max(n + n % 2, 16)


def defocus_step_rad(geometry: ProjectorGeometry, wavelengths_m, depths_m, pupil_samples: int) -> float:
    """``2 pi R (D / M) max|1/z - 1/v| / lambda_min``: the defocus phase step between samples at the rim."""
    worst = float(np.max(np.abs(1.0 / np.asarray(depths_m) - 1.0 / geometry.focus_distance_m)))
    dr = geometry.aperture_diameter_m / pupil_samples
    return 2 * math.pi * geometry.aperture_radius_m * dr * worst / float(np.min(wavelengths_m))


def field_of_view_px(geometry: ProjectorGeometry, wavelength_m: float, pupil_samples: int) -> float:
    """The 2-D engine's periodic field of view ``lambda T W M / D`` in pixels."""
    return wavelength_m * geometry.throw_width_m * pupil_samples / geometry.aperture_diameter_m


def unmet_requirements(
    pupil_samples: int,
    geometry: ProjectorGeometry,
    wavelengths_m,
    depths_m,
    window: int,
    engine: str,
    doe=None,
    aberration_step_rad: Callable[[int], float] | None = None,
    check_design: bool = True,
) -> dict[str, tuple[int, str]]:
    """The requirements that ``pupil_samples`` fails: ``{name: (pupil_samples needed, why)}``.

    ``aberration_step_rad(M)``: the engine's aberration phase step at ``M`` samples (None: no
    aberration). ``check_design``: apply the DOE's own rule (the radial engine skips it for a design
    on rings of its own, which it simulates exactly at any sampling)."""
    M = int(pupil_samples)
    lam_min = float(np.min(wavelengths_m))
    unmet: dict[str, tuple[int, str]] = {}
    step = defocus_step_rad(geometry, wavelengths_m, depths_m, M)
    if step > MAX_PHASE_STEP_RAD:
        z_mm = np.asarray(depths_m, dtype=float) * 1e3
        unmet["defocus"] = (
            _even_ceil(M * step / MAX_PHASE_STEP_RAD),
            f"the defocus phase at {z_mm.min():.0f}-{z_mm.max():.0f} mm ({step:.2f} rad per sample)",
        )
    if engine == "2d":
        blur = float(np.max(geometry.blur_diameter_px(depths_m)))
        span = window + max(blur, 2.0)
        fov = field_of_view_px(geometry, lam_min, M)
        if fov < span:
            unmet["field of view"] = (
                _even_ceil(M * span / fov),
                f"the field of view ({fov:.0f} px at {lam_min * 1e9:.0f} nm) for the {window}-px window plus the "
                f"{blur:.0f}-px blur",
            )
    if aberration_step_rad is not None:
        ab_step = aberration_step_rad(M)
        if ab_step > MAX_PHASE_STEP_RAD:
            unmet["aberration"] = (
                _even_ceil(M * ab_step / MAX_PHASE_STEP_RAD),
                f"the aberration phase ({ab_step:.2f} rad per sample)",
            )
    if doe is not None and check_design:
        reason = _design_refusal(doe, geometry, M)
        if reason is not None:
            unmet["design"] = (_design_needs(doe, geometry, M), reason)
    return unmet


def _design_refusal(doe, geometry: ProjectorGeometry, pupil_samples: int) -> str | None:
    """The design rule's message at ``pupil_samples`` without its own ``use pupil_samples >= N``
    (the combined message names the sampling), or None when the rule accepts it."""
    try:
        doe.check_sampling(geometry.aperture_diameter_m / pupil_samples)
    except SamplingError as exc:
        message = str(exc)
        fix = re.search(r":?\s*use pupil_samples >= \d+\s*", message)
        if fix is None:
            return message
        rest = message[fix.end() :].strip()  # another way out, e.g. "or lower doe.mlp_frequencies"
        return message[: fix.start()] + (f" ({rest})" if rest else "")
    return None


def _design_needs(doe, geometry: ProjectorGeometry, pupil_samples: int) -> int:
    """The smallest even ``M > pupil_samples`` that the design's rule accepts (doubling, then bisection)."""
    lo, hi = int(pupil_samples), int(pupil_samples)
    while _design_refusal(doe, geometry, hi) is not None:
        lo, hi = hi, 2 * hi
        if hi > MAX_PUPIL_SAMPLES:
            return hi
    while hi - lo > 2:
        mid = (lo + hi) // 2
        mid += mid % 2
        if _design_refusal(doe, geometry, mid) is None:
            hi = mid
        else:
            lo = mid
    return hi


def check_pupil_sampling(pupil_samples: int, **requirements) -> None:
    """Raise one :class:`~edofproj.errors.SamplingError` when ``pupil_samples`` fails any requirement
    (keyword arguments: those of :func:`unmet_requirements`), naming each failed requirement and the
    one ``pupil_samples`` at which every requirement holds (module docstring)."""
    unmet = unmet_requirements(pupil_samples, **requirements)
    if not unmet:
        return
    reasons = {name: why for name, (_, why) in unmet.items()}
    target = int(pupil_samples)
    while unmet and target <= MAX_PUPIL_SAMPLES:
        target = max(target + 2, *(need for need, _ in unmet.values()))
        unmet = unmet_requirements(target, **requirements)
        for name, (_, why) in unmet.items():
            reasons.setdefault(name, why)
    listed = "; ".join(reasons.values())
    if unmet:
        raise SamplingError(
            f"pupil_samples={pupil_samples} cannot resolve {listed}, and no sampling up to {MAX_PUPIL_SAMPLES} can"
        )
    raise SamplingError(f"pupil_samples={pupil_samples} cannot resolve {listed}: use pupil_samples >= {target}")
