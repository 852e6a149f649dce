"""Fine-tuning on measured PSFs: interpolation, refusal, and a real improvement."""

import pytest
import torch

from edofproj.config import Config, apply_overrides
from edofproj.data import build_test_images
from edofproj.errors import EdofprojError
from edofproj.imaging.projection import project
from edofproj.metrics import ssim
from edofproj.optics.psf_bank import simulator_from_config
from edofproj.runs import load_run
from edofproj.training.finetune import MeasuredPSFTable, finetune
from edofproj.training.trainer import train
from tiny_configs import TINY_LENS_TRAINED_STEPS, tiny_lens_trained

pytestmark = pytest.mark.slow  # trains or runs the CLI in a subprocess


def test_measured_table_interpolates_linearly_in_inverse_depth():
    psf = torch.stack([torch.full((3, 3, 3), v) for v in (1.0, 2.0, 4.0)])
    table = MeasuredPSFTable(psf, [0.3, 0.5, 0.9])  # any order in, sorted inside
    assert torch.allclose(table([0.5])[0], torch.full((3, 3, 3), 2.0))
    z = 1 / (0.5 * (1 / 0.5 + 1 / 0.3))  # half-way in 1/z between 500 and 300 mm
    assert torch.allclose(table([z])[0], torch.full((3, 3, 3), 1.5))
    with pytest.raises(EdofprojError, match="outside the measured"):
        table([1.2])


@pytest.mark.arithmetic
def test_finetuning_on_measured_psfs_improves_compensation(tmp_path):
    """A network trained for 450-550 mm meets a projector measured at 300-400 mm (strong blur):
    fine-tuning on the measured PSFs raises SSIM of the compensated projection on held-out images."""
    cfg = apply_overrides(Config(), tiny_lens_trained())
    run_dir = tmp_path / "run"
    train(cfg, run_dir, progress=False)

    measured_cfg = apply_overrides(Config(), tiny_lens_trained())
    sim = simulator_from_config(measured_cfg)
    with torch.no_grad():
        bank = sim.bank(None, [0.3, 0.35, 0.4])
    bank.save(tmp_path / "measured.npz")

    images = torch.stack([img for _, img in build_test_images(cfg.data, size=64)])

    def mean_ssim(net):
        scores = []
        with torch.no_grad():
            for i, z in enumerate([0.3, 0.35, 0.4]):
                psf = bank.psf[i : i + 1].float()
                captured = project(images, psf)
                scores.append(ssim(project(net(images, captured).clamp(0, 1), psf), images).mean())
        return float(torch.stack(scores).mean())

    before = mean_ssim(load_run(run_dir).net)
    result = finetune(
        run_dir, [tmp_path / "measured.npz"], tmp_path / "tuned", steps=120, lr=3e-3, batch_size=4, progress=False
    )
    after = mean_ssim(load_run(result.run_dir).net)
    assert result.depth_range_m == pytest.approx((0.3, 0.4))
    print(f"SSIM before {before:.4f} after {after:.4f}")
    assert after > before + 0.01, (before, after)
    # the original run is untouched and a second fine-tune into the same place is refused
    assert load_run(run_dir).step == TINY_LENS_TRAINED_STEPS
    with pytest.raises(EdofprojError, match="not empty"):
        finetune(run_dir, [tmp_path / "measured.npz"], tmp_path / "tuned", steps=1, progress=False)
