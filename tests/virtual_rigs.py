"""A virtual ProCams whose camera looks straight at the projector (camera pixel ``q`` sees
projector pixel ``q``: identity homography, no distortion, one sub-sample), for tests of what
comes after calibration; its calibration is :meth:`VirtualProCams.ideal_calibration`."""

import numpy as np

from edofproj.procams.calibration import ProCamsCalibration
from edofproj.procams.virtual import VirtualProCams


def delta_psf(window: int = 5) -> np.ndarray:
    psf = np.zeros((3, window, window))
    psf[:, window // 2, window // 2] = 1.0
    return psf


def straight_rig(height_width, psf, noise_sigma: float = 0.0, gamma: float = 2.2) -> VirtualProCams:
    return VirtualProCams(
        projector_hw=tuple(height_width),
        camera_hw=tuple(height_width),
        psf=psf,
        homography=np.eye(3),
        supersampling=1,
        noise_sigma=noise_sigma,
        gamma=(gamma, gamma, gamma),
    )


def exact_calibration(rig: VirtualProCams, lut_size: int = 33) -> ProCamsCalibration:
    calibration = rig.ideal_calibration(response_lut_size=lut_size)
    H, W = rig.projector_hw
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    np.testing.assert_allclose(calibration.camera_map.map_x, x, atol=1e-9)  # the rig is straight
    np.testing.assert_allclose(calibration.camera_map.map_y, y, atol=1e-9)
    return calibration


def write_dots_lab(folder, height_width, spacing_px: int, background: str = "background") -> None:
    """``folder/lab.json``: a lab manifest of one dot grid ``dots`` (``dots.png``, every ``spacing_px``)
    and one dark capture named ``background`` (``{background}.png``); the images are the caller's."""
    import json
    from pathlib import Path

    manifest = {
        "format": "edofproj-lab-captures",
        "version": 1,
        "projector": {"height": int(height_width[0]), "width": int(height_width[1])},
        "sequences": [
            {"name": "dots", "kind": "dots", "spacing_px": [spacing_px, spacing_px], "files": {"list": ["dots.png"]}},
            {"name": background, "kind": "black", "files": {"list": [f"{background}.png"]}},
        ],
    }
    (Path(folder) / "lab.json").write_text(json.dumps(manifest))
