"""Issue 6, item 7, last step: PSFs measured through the virtual ProCams (two depths) fine-tune a
network trained for another depth range, and the compensated projections with the *true* PSFs
get better on held-out images."""

import numpy as np
import pytest
import torch

from edofproj.config import Config, apply_overrides
from edofproj.data import build_test_images
from edofproj.imaging.projection import project
from edofproj.metrics import ssim
from edofproj.optics.psf_bank import simulator_from_config
from edofproj.procams.calibration import calibrate, calibration_files
from edofproj.procams.patterns import PatternSpec, build_pattern_set
from edofproj.procams.psf_estimation import bernoulli_files, measure_psf
from edofproj.procams.virtual import VirtualProCams
from edofproj.runs import load_run
from edofproj.training.finetune import finetune
from edofproj.training.trainer import train
from tiny_configs import tiny_lens_trained

pytestmark = pytest.mark.slow  # trains or runs the CLI in a subprocess

WINDOW = 21
DEPTHS_M = (0.3, 0.37)


@pytest.mark.arithmetic
def test_psfs_measured_through_the_virtual_procams_improve_the_network(tmp_path):
    torch.set_num_threads(1)
    cfg = apply_overrides(Config(), tiny_lens_trained() + [f"psf.window={WINDOW}"])
    true = simulator_from_config(cfg).bank(None, list(DEPTHS_M))
    manifest, images = build_pattern_set(PatternSpec(width=128, height=96, dot_grid=(6, 8), color_levels=4, seed=0))
    measured_files = []
    for i, depth in enumerate(DEPTHS_M):
        rig = VirtualProCams.example((96, 128), true.psf[i].numpy(), seed=i, noise_sigma=0.005)
        rng = np.random.default_rng(i)
        captures = {f: rig.capture(images[f], rng) for f in calibration_files(manifest) + bernoulli_files(manifest)}
        estimate = measure_psf(manifest, images, captures, calibrate(manifest, captures), WINDOW)
        l1 = np.abs(estimate.psf - true.psf[i].numpy()).sum() / true.psf[i].numpy().sum()
        assert l1 < 0.10 * 3  # summed over the three channels
        path = tmp_path / f"measured_{i}.npz"
        estimate.to_bank(depth, float(true.pixel_pitch_m[i])).save(path)
        measured_files.append(path)

    run_dir = tmp_path / "run"
    train(cfg, run_dir, progress=False)
    held_out = torch.stack([img for _, img in build_test_images(cfg.data, size=64)])

    def mean_ssim(net):
        with torch.no_grad():
            scores = []
            for i in range(len(DEPTHS_M)):
                psf = true.psf[i : i + 1].float()
                scores.append(ssim(project(net(held_out, project(held_out, psf)).clamp(0, 1), psf), held_out).mean())
        return float(torch.stack(scores).mean())

    before = mean_ssim(load_run(run_dir).net)
    tuned = finetune(run_dir, measured_files, tmp_path / "tuned", steps=120, lr=3e-3, batch_size=4, progress=False)
    after = mean_ssim(load_run(tuned.run_dir).net)
    print(f"SSIM with the true PSFs: before {before:.4f}, after fine-tuning on measured PSFs {after:.4f}")
    assert after > before + 0.01
