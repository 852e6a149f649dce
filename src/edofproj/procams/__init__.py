"""Projector-camera (ProCams) tools: patterns, a virtual ProCams, calibration and PSF measurement.

The measurement pipeline (paper Sec. 5.1-5.2), one module per step:

* :mod:`.patterns` -- Bernoulli noise, dot grid, full fields and colour samples, ``manifest.json``;
* :mod:`.capture_io` -- image files, capture folders, folders written atomically;
* :mod:`.virtual` -- a simulated projector + camera (the test bed, with its ground truth);
* :mod:`.geometry` -- dot detection, grid matching, the dense camera map, warping;
* :mod:`.color` -- colour-mixing matrix and the projector's response (local linear interpolation);
* :mod:`.calibration` -- both calibrations together and the ``calib.npz`` file;
* :mod:`.frame_maps` -- a calibration's per-frame tables (rectification, inverse response);
* :mod:`.psf_estimation` -- the PSF from the Bernoulli captures (paper Eq. 13).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .calibration import ProCamsCalibration, calibrate, calibrate_folders  # noqa: F401
    from .patterns import PatternManifest, PatternSpec, build_pattern_set  # noqa: F401
    from .psf_estimation import PSFEstimate, estimate_psf, measure_psf  # noqa: F401
    from .virtual import VirtualProCams, simulate_captures  # noqa: F401

_EXPORTS = {
    **dict.fromkeys(("ProCamsCalibration", "calibrate", "calibrate_folders"), ".calibration"),
    **dict.fromkeys(("PatternManifest", "PatternSpec", "build_pattern_set"), ".patterns"),
    **dict.fromkeys(("PSFEstimate", "estimate_psf", "measure_psf"), ".psf_estimation"),
    **dict.fromkeys(("VirtualProCams", "simulate_captures"), ".virtual"),
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    # start-up: the re-exports load on first use (PEP 562), so that 'edofproj live --help' can read
    # the device table (devices/spec.py) without importing torch, OpenCV and SciPy
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
