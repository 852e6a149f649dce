"""The smallest configurations that still exercise every part of the code (shared by tests).

* :data:`TINY_TRAINING` -- a joint training step (MLP DOE, U-Net, radial engine);
* :data:`TINY_EVALUATION` -- a physically valid run small enough to train and evaluate in seconds
  (384 pupil samples resolve the defocus phase at 300 mm);
* :data:`TINY_LENS_FINETUNE` -- a lens-only run for fine-tuning on measured PSFs;
* :data:`tiny_lens_trained` -- the same run trained long enough (300 steps) that what fine-tuning adds
  does not hang on the rounding of a near-untrained network, in the arithmetic under test.

``conftest.py`` turns them into the ``tiny_config`` fixture.
"""

from edofproj.config import Config, apply_overrides

TINY_TRAINING = [
    "spectrum.wavelength_min_nm=460",
    "spectrum.wavelength_max_nm=620",
    "spectrum.wavelength_step_nm=80",
    "psf.pupil_samples=256",
    "psf.window=11",
    "psf.depth_min_mm=350",
    "psf.depth_max_mm=800",
    "doe.mlp_frequencies=6",
    "doe.mlp_hidden=16",
    "doe.mlp_layers=2",
    "net.widths=[4,8,8]",
    "data.crop=32",
    "train.threads=1",
]

TINY_EVALUATION = [
    "psf.pupil_samples=384",
    "psf.window=15",
    "doe.mlp_frequencies=4",
    "doe.mlp_hidden=8",
    "spectrum.wavelength_min_nm=460",
    "spectrum.wavelength_max_nm=620",
    "spectrum.wavelength_step_nm=80",
    "net.widths=[4,8]",
    "data.crop=32",
    "train.steps=2",
    "train.batch_size=1",
    "train.psf_table_depths=4",
    "train.checkpoint_every=2",
    "train.threads=1",
    "evaluation.image_size=[48,64]",
    "evaluation.depths_mm=[300,500]",
    "evaluation.comparison_depths_mm=[320]",
    "evaluation.cls_iterations=5",
    "evaluation.wiener_tuning_images=2",
    "evaluation.wiener_tuning_depths=2",
    "imaging.depth_layers=2",
    "data.max_test_images=2",
]

TINY_LENS_FINETUNE = [
    "doe.kind=lens",
    "spectrum.wavelength_min_nm=460",
    "spectrum.wavelength_max_nm=620",
    "spectrum.wavelength_step_nm=80",
    "psf.pupil_samples=512",
    "psf.window=15",
    "psf.depth_min_mm=450",
    "psf.depth_max_mm=550",
    "net.widths=[8,16,16]",
    "data.crop=48",
    "train.batch_size=2",
    "train.threads=1",
    "train.steps=4",
    "train.checkpoint_every=4",
    "train.psf_table_depths=4",
]

TINY_LENS_TRAINED_STEPS = 300


def tiny_lens_trained() -> list[str]:
    """:data:`TINY_LENS_FINETUNE` trained for :data:`TINY_LENS_TRAINED_STEPS` steps in the arithmetic
    under test (:func:`arithmetic.mixed_precision_under_test`).

    Four steps leave the network near its initialisation; what 80-120 fine-tuning steps then add to
    its compensation ranged over +0.008 to +0.052 SSIM with the seed and the CPU's float32 kernels
    (AVX2 or AVX-512), across a test's +0.01. Trained for 300 steps it ranged over +0.030 to +0.066
    (seeds 0-3, float32 and bfloat16), AVX2 and AVX-512 within 0.0011 of each other.
    """
    from arithmetic import mixed_precision_under_test

    return TINY_LENS_FINETUNE + [
        f"train.steps={TINY_LENS_TRAINED_STEPS}",
        f"train.checkpoint_every={TINY_LENS_TRAINED_STEPS}",
        f"train.mixed_precision={mixed_precision_under_test()}",
    ]


TINY = {"training": TINY_TRAINING, "evaluation": TINY_EVALUATION, "lens-finetune": TINY_LENS_FINETUNE}


def tiny_training_config(*extra: str) -> Config:
    """:data:`TINY_TRAINING` plus ``section.key=value`` overrides."""
    return apply_overrides(Config(), TINY_TRAINING + list(extra))
