"""The smallest training configuration that still exercises every part of a step (shared by tests)."""

from edofproj.config import Config, apply_overrides

TINY_TRAINING = [
    "spectrum.wavelength_min_nm=460", "spectrum.wavelength_max_nm=620", "spectrum.wavelength_step_nm=80",
    "psf.pupil_samples=256", "psf.window=11", "psf.depth_min_mm=350", "psf.depth_max_mm=800",
    "doe.mlp_frequencies=6", "doe.mlp_hidden=16", "doe.mlp_layers=2",
    "net.widths=[4,8,8]", "data.crop=32", "train.threads=1",
]


def tiny_training_config(*extra: str) -> Config:
    """:data:`TINY_TRAINING` plus ``section.key=value`` overrides."""
    return apply_overrides(Config(), TINY_TRAINING + list(extra))
