"""A virtual ProCams whose camera looks straight at the projector, and its exact calibration.

Camera pixel ``q`` sees projector pixel ``q`` (identity homography, no distortion, one
sub-sample), so the calibration is known in closed form from the rig's parameters: identity
camera map, mixing matrix ``M (1 - b)``, black capture ``M b 1 + a``, response ``u^gamma``
sampled on a grid. Tests of the live loop and of the evaluation use it without running the
(slow) calibration.
"""

import numpy as np

from edofproj.procams.calibration import ProCamsCalibration
from edofproj.procams.color import ColorCalibration
from edofproj.procams.geometry import CameraMap
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


def exact_calibration(rig: VirtualProCams, levels: int = 6, lut_size: int = 33) -> ProCamsCalibration:
    H, W = rig.projector_hw
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    camera_map = CameraMap(
        map_x=x, map_y=y, homography=np.eye(3), dots_proj=np.zeros((0, 2)), dots_cam=np.zeros((0, 2)), camera_hw=(H, W)
    )
    values = np.linspace(0.0, 1.0, levels)
    inputs = np.stack(np.meshgrid(values, values, values, indexing="ij"), axis=-1).reshape(-1, 3)
    color = ColorCalibration(
        mixing_matrix=rig.effective_mixing_matrix,
        black_level=rig.black_capture_level,
        sample_inputs=inputs,
        sample_outputs=rig.normalized_response(inputs),
    )
    return ProCamsCalibration(
        camera_map=camera_map, color=color, black_image=np.broadcast_to(rig.black_capture_level, (H, W, 3)).copy()
    )
