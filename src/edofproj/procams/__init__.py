"""Projector-camera (ProCams) tools: patterns, a virtual ProCams, calibration and PSF measurement.

The measurement pipeline (paper Sec. 5.1-5.2), one module per step:

* :mod:`.patterns` -- Bernoulli noise, dot grid, full fields and colour samples, ``manifest.json``;
* :mod:`.capture_io` -- image files, capture folders, folders written atomically;
* :mod:`.virtual` -- a simulated projector + camera (the test bed, with its ground truth);
* :mod:`.geometry` -- dot detection, grid matching, the dense camera map, warping;
* :mod:`.color` -- colour-mixing matrix and the projector's response (local linear interpolation);
* :mod:`.calibration` -- both calibrations together and the ``calib.npz`` file;
* :mod:`.psf_estimation` -- the PSF from the Bernoulli captures (paper Eq. 13).
"""

from .calibration import ProCamsCalibration, calibrate, calibrate_folders  # noqa: F401
from .patterns import PatternManifest, PatternSpec, build_pattern_set  # noqa: F401
from .psf_estimation import PSFEstimate, estimate_psf, measure_psf  # noqa: F401
from .virtual import VirtualProCams, simulate_captures  # noqa: F401
