"""Typed configuration: dataclasses loaded from YAML, validated with clear messages.

A config file mirrors :class:`Config`: one mapping per section (``optics``, ``spectrum``,
``doe``, ``psf``, ``imaging``, ``net``, ``loss``, ``data``, ``train``, ``evaluation``,
``fabrication``). Keys that do not exist raise :class:`~edofproj.errors.ConfigError` with a
"did you mean" suggestion; values are type-checked and range-checked by each section's
``validate``. Command-line ``--set section.key=value`` overrides are applied on top.

The ``net`` section is the configuration of one network architecture, the one ``net.architecture``
names: its class and options are declared in :mod:`edofproj.net_config`. A ``net`` section of the
single flat format of older files (a saved run's ``config.yaml``) is converted when it is read,
with a one-line :class:`~edofproj.errors.ConfigConversionWarning`.

Units: user-facing lengths are in mm or nm and say so in their names; the code converts
to SI (metres) at the boundary (see :mod:`edofproj.optics.geometry`).
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import types
import typing
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import yaml

from .errors import ConfigConversionWarning, ConfigError
from .limits import check_memory
from .net_config import (
    NetConfig,
    UNetConfig,
    check_net_keys,
    convert_flat_net,
    net_to_dict,
    override_net,
)
from .net_config import unknown_choice as _unknown_choice

#: Metres per millimetre. Configs and options speak millimetres; the code computes in metres, and
#: the conversion happens here, in the ``*_m`` properties of the sections, and nowhere else.
M_PER_MM = 1e-3

# --------------------------------------------------------------------------- sections


@dataclass
class OpticsConfig:
    """Projector geometry (paper Sec. 3.1, 5.1).

    ``throw_ratio`` = projection distance / image width (not given by the paper; 1.5 is
    our documented default). Screen pixel pitch: ``q(z) = z / (throw_ratio * width_px)``.

    Lens aberrations (:mod:`edofproj.optics.aberrations`; none: the ideal thin lens):
    ``zernike_um`` maps Noll indices to RMS-normalized Zernike coefficients in micrometres of
    wavefront (on axis, every wavelength), e.g. ``{11: 0.05}``; ``wavefront_map`` is a measured
    wavefront (``.npy``, micrometres, square over the aperture; 2-D engine only);
    ``aberration_csv`` a table ``field_x,field_y,wavelength_nm,noll,coefficient_um`` per field
    point and wavelength (field coordinates in [-1, 1]) for field-dependent PSFs.

    ``lens_prescription``: a multi-element lens (a Zemax ``.zmx`` or Optiland ``.json`` file, read
    by :mod:`edofproj.optics.lens_prescription`; the ``lens`` extra) whose traced wavefront and
    vignetting replace the thin lens's pupil (2-D engine; ``aperture_mm`` must be its entrance-pupil
    diameter) at the lens's normalized field point ``lens_field`` ``[Hx, Hy]`` (radius <= 1).
    """

    aperture_mm: float = 7.0
    focus_mm: float = 500.0
    throw_ratio: float = 1.5
    width_px: int = 800
    height_px: int = 600
    zernike_um: dict = field(default_factory=dict)
    wavefront_map: Optional[str] = None
    aberration_csv: Optional[str] = None
    lens_prescription: Optional[str] = None
    lens_field: list = field(default_factory=lambda: [0.0, 0.0])

    @property
    def aperture_m(self) -> float:
        return self.aperture_mm * M_PER_MM

    @property
    def focus_m(self) -> float:
        return self.focus_mm * M_PER_MM

    def validate(self) -> None:
        _positive(self, "aperture_mm", "optics.aperture_mm")
        _positive(self, "focus_mm", "optics.focus_mm")
        _positive(self, "throw_ratio", "optics.throw_ratio")
        _positive(self, "width_px", "optics.width_px")
        _positive(self, "height_px", "optics.height_px")
        if self.aperture_mm >= self.focus_mm:
            raise ConfigError(
                f"optics.aperture_mm={self.aperture_mm} must be much smaller than optics.focus_mm="
                f"{self.focus_mm} (paraxial model)"
            )
        if not isinstance(self.zernike_um, dict):
            raise ConfigError(
                f"optics.zernike_um={self.zernike_um!r} must map Noll indices to micrometres, e.g. {{11: 0.05}}"
            )
        for j, c in self.zernike_um.items():
            if isinstance(j, bool) or not isinstance(j, int) or j < 1:
                raise ConfigError(f"optics.zernike_um: Noll index {j!r} must be an integer >= 1")
            if isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(c):
                raise ConfigError(f"optics.zernike_um[{j}]={c!r} must be a finite number (micrometres)")
        self._validate_lens()

    def _validate_lens(self) -> None:
        lf = self.lens_field
        if (
            not isinstance(lf, (list, tuple))
            or len(lf) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in lf)
            or math.hypot(*lf) > 1.0
        ):
            raise ConfigError(f"optics.lens_field={lf!r} must be [Hx, Hy], the lens's normalized field (radius <= 1)")
        if self.lens_prescription is None:
            return
        if not isinstance(self.lens_prescription, str) or not self.lens_prescription.lower().endswith(
            (".zmx", ".json")
        ):
            raise ConfigError(
                f"optics.lens_prescription={self.lens_prescription!r} must be a Zemax .zmx or an Optiland .json file"
            )
        given = [k for k in ("zernike_um", "wavefront_map", "aberration_csv") if getattr(self, k)]
        if given:
            raise ConfigError(
                f"optics.lens_prescription gives the lens's whole wavefront: drop optics.{', optics.'.join(given)}"
            )


SPECTRAL_QUADRATURES = ("uniform", "gauss")


#: Keys that state something about a configuration without changing what it simulates or trains (the
#: measured accuracy of the spectral sampling only silences a warning): two runs that differ only here
#: have the same projector and the same recipe.
STATEMENT_KEYS = ("spectrum.stated_l1_error",)


def without_statements(section: str, values: dict) -> dict:
    """``values`` (a section as :func:`to_dict` gives it) without the :data:`STATEMENT_KEYS` of ``section``."""
    return {k: v for k, v in values.items() if f"{section}.{k}" not in STATEMENT_KEYS}


@dataclass
class SpectrumConfig:
    """Wavelength sampling and the RGB primaries' spectral power distributions.

    Default SPDs are an *assumption*: three LED-like Gaussian peaks (``peaks_nm`` with
    full widths at half maximum ``fwhm_nm``). Measured SPDs can be given as a CSV with
    columns ``wavelength_nm,r,g,b`` (``spd_csv``); they are interpolated onto the samples.

    Wavelengths: ``wavelength_min_nm`` to ``wavelength_max_nm`` in ``wavelength_step_nm``
    steps (10 nm: PSFs within 0.1 % L1 of a 1 nm sampling for the default primaries), minus the
    end samples that hold less than ``trim_power`` of every primary's power (a fraction, 0: keep
    all). ``quadrature: gauss`` instead takes ``nodes_per_primary`` wavelengths per primary: the
    Gauss rule of its SPD (on a 1 nm grid over ``wavelength_min_nm..max``), each channel weighting
    only its own nodes. :mod:`edofproj.optics.spectra` warns when a primary is undersampled, unless
    ``stated_l1_error`` gives the sampling's measured PSF error (worst channel, a fraction of the
    PSF's L1 norm, against a 1 nm sampling; null: none stated): a configuration that states its error
    accepts it. A statement belongs to the projector it was measured for: a config whose ``base``
    states one, or ``--set`` overrides, that change the projector (:data:`STATED_FOR_KEYS`) without
    stating their own do not inherit it (:func:`_load_on_base`, :func:`apply_overrides`).
    """

    wavelength_min_nm: float = 400.0
    wavelength_max_nm: float = 700.0
    wavelength_step_nm: float = 10.0
    trim_power: float = 1e-4
    peaks_nm: list[float] = field(default_factory=lambda: [620.0, 530.0, 460.0])
    fwhm_nm: list[float] = field(default_factory=lambda: [20.0, 35.0, 25.0])
    spd_csv: Optional[str] = None
    quadrature: str = "uniform"
    nodes_per_primary: int = 2
    stated_l1_error: Optional[float] = None

    def validate(self) -> None:
        for name in ("wavelength_min_nm", "wavelength_max_nm"):
            value = getattr(self, name)
            if not (350.0 <= value <= 1000.0):
                raise ConfigError(f"spectrum.{name}={value} is outside the allowed 350-1000 nm")
        if self.wavelength_max_nm < self.wavelength_min_nm:
            raise ConfigError("spectrum.wavelength_max_nm must be >= spectrum.wavelength_min_nm")
        _positive(self, "wavelength_step_nm", "spectrum.wavelength_step_nm")
        if not (0.0 <= self.trim_power < 0.01):
            raise ConfigError(f"spectrum.trim_power={self.trim_power} must be a fraction in [0, 0.01)")
        if self.quadrature not in SPECTRAL_QUADRATURES:
            raise ConfigError(_unknown_choice("spectrum.quadrature", self.quadrature, SPECTRAL_QUADRATURES))
        n = self.nodes_per_primary
        if isinstance(n, bool) or not isinstance(n, int) or not (1 <= n <= 16):
            raise ConfigError(f"spectrum.nodes_per_primary={n!r} must be an integer in 1-16")
        e = self.stated_l1_error
        if e is not None and (isinstance(e, bool) or not isinstance(e, (int, float)) or not (0.0 <= e < 1.0)):
            raise ConfigError(f"spectrum.stated_l1_error={e!r} must be a fraction in [0, 1), or null (none stated)")
        if len(self.peaks_nm) != 3 or len(self.fwhm_nm) != 3:
            raise ConfigError("spectrum.peaks_nm and spectrum.fwhm_nm need three values (R, G, B)")
        if any(not (350.0 <= p <= 1000.0) for p in self.peaks_nm):
            raise ConfigError(f"spectrum.peaks_nm={self.peaks_nm}: each must be in 350-1000 nm")
        if any(w <= 0 for w in self.fwhm_nm):
            raise ConfigError(f"spectrum.fwhm_nm={self.fwhm_nm}: each must be > 0")


DOE_KINDS = ("lens", "mlp", "free", "cubic", "axicon", "multifocal", "file")
#: DOE kinds with trainable parameters (the others are fixed designs).
LEARNED_DOE_KINDS = ("mlp", "free")
#: The ``doe`` keys that only the classic element of one kind reads: a DOE of another kind never does.
CLASSIC_DOE_KEYS = {
    "cubic": ("cubic_waves",),
    "axicon": ("axicon_near_mm", "axicon_far_mm"),
    "multifocal": ("multifocal_foci_mm",),
}


def unread_doe_keys(kind: str) -> tuple[str, ...]:
    """The classic elements' ``doe`` keys (:data:`CLASSIC_DOE_KEYS`) that a DOE of ``kind`` never reads."""
    return tuple(key for element, keys in CLASSIC_DOE_KEYS.items() if element != kind for key in keys)


@dataclass
class DOEConfig:
    """The diffractive optical element placed right after the projector lens.

    ``kind``: ``lens`` (no DOE), ``mlp`` (the paper's radial MLP over a positional encoding
    of the radius), ``free`` (one height per ring), ``cubic`` (2-D cubic phase plate),
    ``axicon``, ``multifocal`` (equal-area zones focused at ``multifocal_foci_mm``), or
    ``file`` (a saved design, ``path``). Heights are wrapped to one 2pi wave at
    ``design_wavelength_nm`` (null: the centroid of the primaries' spectra,
    :func:`edofproj.optics.spectra.design_wavelength_nm`) and quantized to ``levels`` levels
    (straight-through estimator during training). ``clear_core_fraction`` (learned kinds ``mlp``
    and ``free``): the fraction of the aperture radius inside which the element is left clear, so
    the centre of the pupil keeps the bare lens's sharp focus and the DOE acts on the annulus.
    """

    kind: str = "mlp"
    path: Optional[str] = None
    levels: int = 16
    quantize: bool = True
    design_wavelength_nm: Optional[float] = None
    material: str = "fused_silica"
    mlp_frequencies: int = 9
    mlp_hidden: int = 64
    mlp_layers: int = 3
    cubic_waves: float = 20.0
    axicon_near_mm: float = 300.0
    axicon_far_mm: float = 800.0
    multifocal_foci_mm: list[float] = field(default_factory=lambda: [350.0, 500.0, 700.0])
    min_feature_um: float = 0.0
    clear_core_fraction: float = 0.0

    @property
    def axicon_near_m(self) -> float:
        return self.axicon_near_mm * M_PER_MM

    @property
    def axicon_far_m(self) -> float:
        return self.axicon_far_mm * M_PER_MM

    @property
    def multifocal_foci_m(self) -> list[float]:
        return [f * M_PER_MM for f in self.multifocal_foci_mm]

    def validate(self) -> None:
        if self.kind not in DOE_KINDS:
            raise ConfigError(_unknown_choice("doe.kind", self.kind, DOE_KINDS))
        if self.kind == "file" and not self.path:
            raise ConfigError("doe.kind=file needs doe.path (a saved DOE .npz or a run directory)")
        if self.levels < 2:
            raise ConfigError(f"doe.levels={self.levels} must be >= 2")
        if self.design_wavelength_nm is not None and not (350.0 <= self.design_wavelength_nm <= 1000.0):
            raise ConfigError(f"doe.design_wavelength_nm={self.design_wavelength_nm} is outside 350-1000 nm")
        if self.mlp_frequencies < 0 or self.mlp_hidden < 1 or self.mlp_layers < 1:
            raise ConfigError("doe.mlp_frequencies must be >= 0, doe.mlp_hidden and doe.mlp_layers >= 1")
        if not (0 < self.axicon_near_mm < self.axicon_far_mm):
            raise ConfigError("doe.axicon_near_mm and doe.axicon_far_mm must satisfy 0 < near < far")
        if not self.multifocal_foci_mm or any(f <= 0 for f in self.multifocal_foci_mm):
            raise ConfigError("doe.multifocal_foci_mm needs one or more positive distances")
        if self.min_feature_um < 0:
            raise ConfigError("doe.min_feature_um must be >= 0")
        if not (0.0 <= self.clear_core_fraction < 1.0):
            raise ConfigError(f"doe.clear_core_fraction={self.clear_core_fraction} must lie in [0, 1)")
        if self.clear_core_fraction > 0 and self.kind not in ("mlp", "free"):
            raise ConfigError(
                f"doe.clear_core_fraction applies to the learned radial kinds (mlp, free), not doe.kind={self.kind}"
            )


#: Bytes per window pixel of the smallest PSF simulation (3 colours x float64 x 3 copies).
PSF_WINDOW_BYTES_PER_PIXEL = 72
#: Least bytes per pixel of each training crop in one step: the smallest network's forward and
#: backward pass (peak RSS, 512x512 input: 281 B/px for the multi-rate network of widths 8,16;
#: 1828 B/px for the default U-Net; docs/experiments/2026-11-25-hostile-inputs.md) -- a lower bound.
TRAIN_BYTES_PER_CROP_PIXEL = 256
#: Least bytes per pixel of one scored image in ``evaluate``: its projection (80 B/px,
#: :data:`edofproj.imaging.projection.PROJECTION_BYTES_PER_PIXEL`) and the smallest network's
#: inference (184 B/px measured as above) -- a lower bound.
EVALUATION_BYTES_PER_PIXEL = 256


@dataclass
class PSFConfig:
    """PSF simulation: engine, window, pupil sampling, depth range.

    ``pupil_samples`` counts samples across the aperture diameter (the paper: 2048); the
    radial engine uses ``pupil_samples // 2`` rings, the 2-D engine a square grid.
    """

    engine: str = "radial"
    window: int = 33
    pupil_samples: int = 1024
    depth_min_mm: float = 300.0
    depth_max_mm: float = 800.0
    precision: str = "float64"

    @property
    def depth_min_m(self) -> float:
        return self.depth_min_mm * M_PER_MM

    @property
    def depth_max_m(self) -> float:
        return self.depth_max_mm * M_PER_MM

    def validate(self) -> None:
        if self.engine not in ("radial", "2d"):
            raise ConfigError(_unknown_choice("psf.engine", self.engine, ("radial", "2d")))
        if self.window < 3 or self.window % 2 == 0:
            raise ConfigError(f"psf.window={self.window} must be odd and >= 3")
        if self.pupil_samples < 16:
            raise ConfigError(f"psf.pupil_samples={self.pupil_samples} must be >= 16")
        # the least any simulation with these settings holds: three K x K float64 PSFs per colour,
        # and for the 2-D engine one (2M)^2 complex128 FFT (the engines check their full estimates)
        check_memory(
            PSF_WINDOW_BYTES_PER_PIXEL * self.window**2,
            f"psf.window={self.window}",
            "use a smaller psf.window (the largest blur diameter in pixels plus a margin is enough)",
        )
        if self.engine == "2d":
            check_memory(
                16 * (2 * self.pupil_samples) ** 2,
                f"psf.pupil_samples={self.pupil_samples} with the 2-D engine",
                "use fewer psf.pupil_samples",
            )
        _positive(self, "depth_min_mm", "psf.depth_min_mm")
        if self.depth_max_mm < self.depth_min_mm:
            raise ConfigError("psf.depth_max_mm must be >= psf.depth_min_mm")
        if self.precision not in ("float32", "float64"):
            raise ConfigError(_unknown_choice("psf.precision", self.precision, ("float32", "float64")))


@dataclass
class ImagingConfig:
    """Image formation: depth layers for non-planar screens."""

    depth_layers: int = 8

    def validate(self) -> None:
        if self.depth_layers < 1:
            raise ConfigError("imaging.depth_layers must be >= 1")


@dataclass
class LossConfig:
    """Loss ``alpha * MSE + beta * perceptual`` (paper Eq. 12)."""

    alpha: float = 1.0
    beta: float = 0.05
    perceptual: str = "ms-ssim"
    weights_dir: Optional[str] = None

    def validate(self) -> None:
        choices = ("dists", "ms-ssim", "ssim", "none")
        if self.perceptual not in choices:
            raise ConfigError(_unknown_choice("loss.perceptual", self.perceptual, choices))
        if self.alpha < 0 or self.beta < 0:
            raise ConfigError("loss.alpha and loss.beta must be >= 0")


@dataclass
class DataConfig:
    """Training images: ``builtin`` photographs, ``dead-leaves``, or an image ``folder``.

    Held-out test images: a deterministic ``test_fraction`` of the built-in photographs or of
    ``folder`` (see :mod:`edofproj.data`), or all of ``test_folder`` when given
    (then ``folder`` is used for training in full). ``max_test_images``: 0 keeps all.
    Dead leaves: disk radii with density ~ r^-3 between the two radii (pixels);
    ``dead_leaves_fraction`` > 0 mixes that share of dead-leaves images into a photo source.
    ``procedural`` (source) / ``procedural_fraction``: textured dead leaves and smooth random
    fields (:mod:`edofproj.data.procedural`), alone or mixed into photographs.
    ``colour_augment``: the share of training images given a random colour transform (saturated,
    dark, high-key, one primary nearly empty; with ``colour_gratings`` also fine sinusoidal
    gratings of 2.5-12 px periods; :mod:`edofproj.data.colour`).
    """

    source: str = "builtin"
    folder: Optional[str] = None
    test_folder: Optional[str] = None
    crop: int = 128
    test_fraction: float = 0.3
    max_test_images: int = 0
    dead_leaves_min_radius_px: float = 1.0
    dead_leaves_max_radius_px: float = 128.0
    dead_leaves_fraction: float = 0.0
    procedural_fraction: float = 0.0
    colour_augment: float = 0.0
    colour_gratings: bool = False

    def validate(self) -> None:
        if not (0.0 <= self.colour_augment <= 1.0):
            raise ConfigError(f"data.colour_augment={self.colour_augment} must be in [0, 1]")
        choices = ("builtin", "dead-leaves", "folder", "procedural")
        if self.source not in choices:
            raise ConfigError(_unknown_choice("data.source", self.source, choices))
        if self.source == "folder" and not self.folder:
            raise ConfigError("data.source=folder needs data.folder")
        if self.test_folder and self.source != "folder":
            raise ConfigError("data.test_folder goes with data.source=folder")
        if self.crop < 16:
            raise ConfigError(f"data.crop={self.crop} must be >= 16")
        if not (0.0 < self.test_fraction < 1.0):
            raise ConfigError("data.test_fraction must be in (0, 1)")
        if self.max_test_images < 0:
            raise ConfigError(f"data.max_test_images={self.max_test_images} must be >= 0 (0: all)")
        if not (0.0 <= self.dead_leaves_fraction <= 1.0):
            raise ConfigError(f"data.dead_leaves_fraction={self.dead_leaves_fraction} must be in [0, 1]")
        if (self.dead_leaves_fraction > 0 or self.procedural_fraction > 0) and self.source in (
            "dead-leaves",
            "procedural",
        ):
            raise ConfigError(
                "data.dead_leaves_fraction and data.procedural_fraction mix synthetic images into "
                "photographs: use them with data.source=builtin or folder"
            )
        if not (0.0 <= self.procedural_fraction <= 1.0) or self.dead_leaves_fraction + self.procedural_fraction > 1.0:
            raise ConfigError(
                f"data.procedural_fraction={self.procedural_fraction} must be in [0, 1], and with "
                f"data.dead_leaves_fraction={self.dead_leaves_fraction} sum to at most 1"
            )
        _positive(self, "dead_leaves_min_radius_px", "data.dead_leaves_min_radius_px")
        if not (self.dead_leaves_min_radius_px >= 0.5):
            raise ConfigError(
                f"data.dead_leaves_min_radius_px={self.dead_leaves_min_radius_px} must be >= 0.5 (smaller disks cover no pixel)"
            )
        if not (
            math.isfinite(self.dead_leaves_max_radius_px)
            and self.dead_leaves_max_radius_px >= self.dead_leaves_min_radius_px
        ):
            raise ConfigError(
                f"data.dead_leaves_max_radius_px={self.dead_leaves_max_radius_px} must be >= "
                f"data.dead_leaves_min_radius_px={self.dead_leaves_min_radius_px}"
            )


DEPTH_SPACINGS = ("depth", "defocus")
MIXED_PRECISION = ("none", "bf16", "auto")


@dataclass
class TrainConfig:
    """Joint training of DOE and compensation network (paper Sec. 4.1, Fig. 2).

    Each step draws ``batch_size`` crops and one screen depth per crop in
    ``[psf.depth_min_mm, psf.depth_max_mm]`` (``depth_sampling``: ``uniform`` or
    ``stratified`` over the batch; ``depth_spacing``: ``depth``, uniform in ``z``, or
    ``defocus``, uniform in ``1/z``, i.e. in defocus, which puts half the draws of 300-800 mm
    below 436 mm where the blur grows fastest), and updates the DOE (Adam, ``lr_optics``) and the network
    (Adam, ``lr_net``). Both learning rates decay exponentially to ``lr_final_fraction`` of
    their start over ``steps`` (the paper: x0.99 per iteration for 150 iterations), after a
    linear warm-up over the first ``warmup_steps`` (0: none);
    gradients of the DOE and of the network are each clipped to the norm ``grad_clip``
    (0: no clipping). ``train_doe``/``train_net`` freeze either part; a fixed DOE's PSFs are
    precomputed at ``psf_table_depths`` depths (uniform in 1/z) and interpolated.
    The camera that observes ``I*`` adds Gaussian noise ``noise_sigma`` and, with
    ``quantize_capture``, rounds to 8 bits. ``threads``: torch CPU threads (0: torch's
    default). ``device``: ``auto`` (a CUDA GPU when available), ``cpu`` or ``cuda``.
    ``mixed_precision``: ``none`` (float32 throughout) or ``bf16``: the compensation network's
    convolutions run under bfloat16 autocast, while the PSF simulation, image formation, every
    FFT (the network's Fourier filter included) and the loss stay in float32 or float64;
    ``auto``: ``bf16`` where the device computes bfloat16 natively (a CUDA GPU that supports it,
    a CPU with AVX512-BF16 or AMX), ``none`` elsewhere (emulated bfloat16 would be slower).
    Checkpoints every ``checkpoint_every`` steps; the newest ``keep_checkpoints`` step files
    are kept (0: all). ``screens``: ``flat`` (one depth per crop, the paper) or ``varying``
    (each crop on a random depth-varying screen: flat, tilted, a step or smooth relief,
    :mod:`edofproj.scenes.random_screens`, rendered with ``imaging.depth_layers`` layers spanning
    the PSF range).
    ``linear_every``: steps between recomputations of a ``net.linear_base`` network's linear filter
    from the current DOE. ``validate_every`` (0: never): every that many steps (and at the end) the
    network and the linear filter of the current DOE are scored on ``validation_images`` held-back
    validation images (:mod:`edofproj.training.validation`; ``validation_log.csv``).
    ``teacher`` (empty: none): a trained run (a directory or ``builtin:NAME``) whose network the
    network imitates, for a fixed DOE that must be the teacher's: the loss gains
    ``teacher_weight * mean|clamp(x, 0, 1) - clamp(x_T, 0, 1)|``, the mean absolute difference
    between the projector images the two networks emit for the same target and capture
    (:mod:`edofproj.training.distillation`).

    ``refit_steps`` (0: none): a second phase that trains a fresh network, for that many steps, on the
    DOE the first phase learned, frozen as fabricated (``doe.npz``): learning rate ``refit_lr_net``
    after ``refit_warmup_steps`` of warm-up (decayed as the first phase's, over ``refit_steps``), training
    crops colour-transformed at the rate ``refit_colour_augment`` (``data.colour_augment`` in the first
    phase), in batches of ``refit_batch_size`` crops (0: ``batch_size``); its network is the top-level
    ``refit_net`` section's where there is one (:attr:`Config.refit_net`), else ``net``'s; every other
    setting is the first phase's. A run whose DOE does not train (a fixed or classic
    element, ``train_doe: false``) has only this phase: its network is trained as a learned DOE's final
    network is (:mod:`edofproj.training.phases`).
    """

    steps: int = 400
    batch_size: int = 4
    lr_optics: float = 1e-3
    lr_net: float = 1e-3
    lr_final_fraction: float = 0.99**150
    warmup_steps: int = 0
    grad_clip: float = 1.0
    seed: int = 0
    checkpoint_every: int = 50
    keep_checkpoints: int = 3
    train_doe: bool = True
    train_net: bool = True
    depth_sampling: str = "uniform"
    depth_spacing: str = "depth"
    psf_table_depths: int = 128
    noise_sigma: float = 0.0
    quantize_capture: bool = False
    threads: int = 0
    device: str = "auto"
    mixed_precision: str = "none"
    screens: str = "flat"
    linear_every: int = 10
    validate_every: int = 0
    validation_images: int = 5
    teacher: str = ""
    teacher_weight: float = 1.0
    refit_steps: int = 0
    refit_lr_net: float = 3e-3
    refit_warmup_steps: int = 300
    refit_colour_augment: float = 0.0
    refit_batch_size: int = 0

    def validate(self) -> None:
        if self.refit_steps < 0 or self.refit_warmup_steps < 0 or self.refit_lr_net < 0:
            raise ConfigError("train.refit_steps, train.refit_warmup_steps and train.refit_lr_net must be >= 0")
        if self.refit_batch_size < 0:
            raise ConfigError(
                f"train.refit_batch_size={self.refit_batch_size} must be >= 0 (0: train.batch_size, as the first phase)"
            )
        if self.refit_steps > 0 and self.refit_warmup_steps > self.refit_steps:
            raise ConfigError(
                f"train.refit_warmup_steps={self.refit_warmup_steps} is longer than its phase, "
                f"train.refit_steps={self.refit_steps}: the network would never leave its warm-up; "
                "give a shorter train.refit_warmup_steps"
            )
        if not (0.0 <= self.refit_colour_augment <= 1.0):
            raise ConfigError(f"train.refit_colour_augment={self.refit_colour_augment} must be in [0, 1]")
        if self.teacher_weight < 0:
            raise ConfigError(f"train.teacher_weight={self.teacher_weight} must be >= 0")
        if self.linear_every < 1 or self.validate_every < 0 or self.validation_images < 1:
            raise ConfigError(
                "train.linear_every and train.validation_images must be >= 1, train.validate_every >= 0 (0: never)"
            )
        if self.screens not in ("flat", "varying"):
            raise ConfigError(f"train.screens={self.screens!r} must be flat or varying")
        if self.steps < 1 or self.batch_size < 1 or self.checkpoint_every < 1:
            raise ConfigError("train.steps, train.batch_size and train.checkpoint_every must be >= 1")
        if self.keep_checkpoints < 0:
            raise ConfigError("train.keep_checkpoints must be >= 0 (0 keeps all)")
        if self.lr_optics < 0 or self.lr_net < 0:
            raise ConfigError("train.lr_optics and train.lr_net must be >= 0")
        if not (0.0 < self.lr_final_fraction <= 1.0):
            raise ConfigError("train.lr_final_fraction must be in (0, 1]")
        if self.warmup_steps < 0:
            raise ConfigError(f"train.warmup_steps={self.warmup_steps} must be >= 0")
        if self.warmup_steps > self.steps:
            raise ConfigError(
                f"train.warmup_steps={self.warmup_steps} is longer than its phase, train.steps={self.steps}: "
                "the learning rate would never reach its peak; give a shorter train.warmup_steps "
                f"(e.g. --set train.warmup_steps={self.steps // 10})"
            )
        if self.grad_clip < 0:
            raise ConfigError("train.grad_clip must be >= 0 (0 disables clipping)")
        if self.noise_sigma < 0:
            raise ConfigError("train.noise_sigma must be >= 0")
        if self.depth_sampling not in ("uniform", "stratified"):
            raise ConfigError(_unknown_choice("train.depth_sampling", self.depth_sampling, ("uniform", "stratified")))
        if self.depth_spacing not in DEPTH_SPACINGS:
            raise ConfigError(_unknown_choice("train.depth_spacing", self.depth_spacing, DEPTH_SPACINGS))
        if self.psf_table_depths < 2:
            raise ConfigError("train.psf_table_depths must be >= 2")
        if self.threads < 0:
            raise ConfigError("train.threads must be >= 0 (0: torch's default)")
        if self.device not in ("auto", "cpu", "cuda"):
            raise ConfigError(_unknown_choice("train.device", self.device, ("auto", "cpu", "cuda")))
        if self.mixed_precision not in MIXED_PRECISION:
            raise ConfigError(_unknown_choice("train.mixed_precision", self.mixed_precision, MIXED_PRECISION))


@dataclass
class EvaluationConfig:
    """Depth sweep and methods for ``edofproj evaluate`` (see :mod:`edofproj.evaluation.pipeline`).

    ``depths_mm``: flat-screen depths of the sweep. ``comparison_depths_mm``: the rows of the
    side-by-side figure (paper Fig. 6: 320, 630, 800 mm), each drawn at the nearest depth of
    ``depths_mm`` (a scored one: its tiles can be found in the tables). Tilted screen (paper
    Sec. 5.3): a plane turned by ``tilt_deg`` whose depth runs across the image from ``tilt_range_mm``'s
    near to its far depth (``[]``: the scored range, ``score_range_mm`` or else the training range; the
    paper's is ``[v, v + 200]``; a saved config's former ``tilt_span_mm: S`` reads as ``[v, v + S]``). ``image_size``: ``[height, width]`` of the scored images (``[]``:
    native sizes); ``image_scaling``: ``crop`` takes the centre of each image at its native
    resolution (the pixel scale of the training crops; smaller images are scaled up to cover),
    ``cover`` scales each image to cover the size first. ``cls_iterations``: iterations of the
    box-constrained solver. The Wiener NSR is tuned on ``wiener_tuning_images`` training crops
    at ``wiener_tuning_depths`` depths of the scored range. ``score_range_mm``: ``[near, far]``
    over which summaries and the demo's claims take the mean and the worst depth (``[]``: the
    training range ``psf.depth_min_mm`` - ``psf.depth_max_mm``). ``wiener_tuning_metric``: what
    the NSR maximizes, ``ssim`` (the metric of the demo's claims, so the baseline is as strong as
    it can be there) or ``psnr`` (the MSE-optimal choice). ``display_guard``: a safe network's input
    is sent only where its display, predicted at three depths of the scored range, scores at least
    the SSIM of its linear filter's, else the filter's (:mod:`edofproj.methods.guard`; ``false``:
    the network's input always).
    """

    depths_mm: list[float] = field(
        default_factory=lambda: [
            250.0,
            300.0,
            350.0,
            400.0,
            450.0,
            500.0,
            550.0,
            600.0,
            650.0,
            700.0,
            750.0,
            800.0,
            900.0,
        ]
    )
    comparison_depths_mm: list[float] = field(default_factory=lambda: [320.0, 630.0, 800.0])
    tilt_deg: float = 50.0
    tilt_range_mm: list[float] = field(default_factory=list)
    image_size: list[int] = field(default_factory=lambda: [256, 256])
    image_scaling: str = "crop"
    cls_iterations: int = 100
    wiener_tuning_images: int = 8
    wiener_tuning_depths: int = 6
    score_range_mm: list[float] = field(default_factory=list)
    wiener_tuning_metric: str = "ssim"
    display_guard: bool = True

    def validate(self) -> None:
        if self.wiener_tuning_metric not in ("ssim", "psnr"):
            raise ConfigError(
                _unknown_choice("evaluation.wiener_tuning_metric", self.wiener_tuning_metric, ("ssim", "psnr"))
            )
        if self.score_range_mm and (
            len(self.score_range_mm) != 2
            or any(
                isinstance(d, bool) or not isinstance(d, (int, float)) or not math.isfinite(d)
                for d in self.score_range_mm
            )
            or not 0 < self.score_range_mm[0] < self.score_range_mm[1]
        ):
            raise ConfigError(
                f"evaluation.score_range_mm={self.score_range_mm} must be [near, far] with "
                "0 < near < far (mm), or [] (the training range)"
            )
        if not self.depths_mm or any(not (math.isfinite(d) and d > 0) for d in self.depths_mm):
            raise ConfigError("evaluation.depths_mm needs one or more positive depths")
        if not self.comparison_depths_mm or any(not (math.isfinite(d) and d > 0) for d in self.comparison_depths_mm):
            raise ConfigError("evaluation.comparison_depths_mm needs one or more positive depths")
        if not (math.isfinite(self.tilt_deg) and 0 < abs(self.tilt_deg) < 90):
            raise ConfigError(f"evaluation.tilt_deg={self.tilt_deg} must be between 0 and 90 degrees (exclusive)")
        if self.tilt_range_mm and (
            len(self.tilt_range_mm) != 2
            or not all(math.isfinite(d) for d in self.tilt_range_mm)
            or not 0 < self.tilt_range_mm[0] < self.tilt_range_mm[1]
        ):
            raise ConfigError(
                f"evaluation.tilt_range_mm={self.tilt_range_mm} must be [near, far] with 0 < near < far (mm), "
                "or [] (the scored range)"
            )
        if self.image_size and (
            len(self.image_size) != 2
            or any(
                isinstance(s, bool) or not isinstance(s, (int, float)) or int(s) != s or s < 16 for s in self.image_size
            )
        ):
            raise ConfigError(
                f"evaluation.image_size={self.image_size} must be [height, width] with integers >= 16, or [] (native)"
            )
        if self.image_scaling not in ("crop", "cover"):
            raise ConfigError(_unknown_choice("evaluation.image_scaling", self.image_scaling, ("crop", "cover")))
        if self.cls_iterations < 1:
            raise ConfigError("evaluation.cls_iterations must be >= 1")
        if self.wiener_tuning_images < 1 or self.wiener_tuning_depths < 1:
            raise ConfigError("evaluation.wiener_tuning_images and evaluation.wiener_tuning_depths must be >= 1")


@dataclass
class FabricationConfig:
    """Lithography: the process's limits and the error model of ``edofproj tolerance``.

    ``critical_dimension_um``: narrowest ring or gap the process can print.
    ``arc_tolerance_um``: largest sagitta of the GDSII polygons that approximate the circles
    (also kept below 1 % of the narrowest feature). ``etch_error_pct``: standard deviation
    of each mask's etch depth, in percent of its target. ``misalignment_um``: standard
    deviation, per axis, of each mask's overlay error against the first mask.
    ``decentre_um``: standard deviation, per axis, of the DOE's decentre against the lens.
    ``tolerance_trials``: Monte Carlo trials. The die and substrate (:mod:`edofproj.fabrication.layout`):
    ``die_mm``, the side of the square die (0: the smallest multiple of 0.5 mm that holds the aperture
    and its alignment marks with a 1 mm margin); ``substrate_diameter_mm``, ``substrate_thickness_mm``
    and ``edge_exclusion_mm`` of the wafer (of the DOE's material); ``resist``: ``positive`` (the etch
    masks are dark field, their polygons clear) or ``negative`` (clear field, polygons chrome).
    """

    critical_dimension_um: float = 1.0
    arc_tolerance_um: float = 0.01
    etch_error_pct: float = 3.0
    misalignment_um: float = 0.5
    decentre_um: float = 0.0
    tolerance_trials: int = 20
    die_mm: float = 0.0
    substrate_diameter_mm: float = 100.0
    substrate_thickness_mm: float = 0.5
    edge_exclusion_mm: float = 3.0
    resist: str = "positive"

    def validate(self) -> None:
        if not (math.isfinite(self.critical_dimension_um) and self.critical_dimension_um > 0):
            raise ConfigError(f"fabrication.critical_dimension_um={self.critical_dimension_um} must be > 0")
        if not (0.001 <= self.arc_tolerance_um <= 1.0):
            raise ConfigError(f"fabrication.arc_tolerance_um={self.arc_tolerance_um} must be in 0.001-1 um")
        for name in ("etch_error_pct", "misalignment_um", "decentre_um"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"fabrication.{name}={value} must be >= 0")
        if self.tolerance_trials < 1:
            raise ConfigError(f"fabrication.tolerance_trials={self.tolerance_trials} must be >= 1")
        for name in ("die_mm", "edge_exclusion_mm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"fabrication.{name}={value} must be >= 0")
        _positive(self, "substrate_diameter_mm", "fabrication.substrate_diameter_mm")
        _positive(self, "substrate_thickness_mm", "fabrication.substrate_thickness_mm")
        if self.resist not in ("positive", "negative"):
            raise ConfigError(_unknown_choice("fabrication.resist", self.resist, ("positive", "negative")))


@dataclass
class Config:
    """The whole configuration of a run.

    ``refit_net`` (absent: ``net``): the network of the refit phase (``train.refit_steps``), the one a
    two-phase run ends with and ships, when it is not the first phase's: e.g. a U-Net that shapes the DOE
    in the joint phase, then a cheaper network trained for the DOE found. :meth:`network_at` says which
    of the two a checkpoint holds.
    """

    name: str = "run"
    optics: OpticsConfig = field(default_factory=OpticsConfig)
    spectrum: SpectrumConfig = field(default_factory=SpectrumConfig)
    doe: DOEConfig = field(default_factory=DOEConfig)
    psf: PSFConfig = field(default_factory=PSFConfig)
    imaging: ImagingConfig = field(default_factory=ImagingConfig)
    net: NetConfig = field(default_factory=UNetConfig)
    refit_net: Optional[NetConfig] = None
    loss: LossConfig = field(default_factory=LossConfig)
    data: DataConfig = field(default_factory=DataConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    evaluation: EvaluationConfig = field(default_factory=EvaluationConfig)
    fabrication: FabricationConfig = field(default_factory=FabricationConfig)

    def validate(self) -> "Config":
        for f in dataclasses.fields(self):
            section = getattr(self, f.name)
            if hasattr(section, "validate"):
                section.validate()
        self.check_memory()
        return self

    def doe_learns(self) -> bool:
        """Whether the run optimizes its DOE: ``train.train_doe`` and a learned kind
        (:data:`LEARNED_DOE_KINDS`; the others are fixed designs)."""
        return bool(self.train.train_doe) and self.doe.kind in LEARNED_DOE_KINDS

    def network_at(self, step: int) -> NetConfig:
        """The network a checkpoint of run step ``step`` holds: ``refit_net`` once the refit phase has
        begun (a run whose DOE does not learn has only that phase), ``net`` before it and in a
        one-phase run (``train.refit_steps = 0``) (:mod:`edofproj.training.phases`)."""
        if self.refit_net is None or self.train.refit_steps <= 0:
            return self.net
        if self.doe_learns() and step <= self.train.steps:
            return self.net
        return self.refit_net

    def final_network(self) -> NetConfig:
        """The network the run ends with and ships (:meth:`network_at` its last step)."""
        return self.network_at(self.train.steps + self.train.refit_steps)

    def check_memory(self) -> None:
        """Refuse sizes that cannot fit before anything is allocated (:func:`edofproj.limits.check_memory`):
        a training step (``train.batch_size`` crops of ``data.crop``, :data:`TRAIN_BYTES_PER_CROP_PIXEL`),
        one scored image of ``evaluation.image_size`` padded by the PSF window
        (:data:`EVALUATION_BYTES_PER_PIXEL`) and the PSFs of every ``evaluation.depths_mm``
        (:data:`PSF_WINDOW_BYTES_PER_PIXEL` each). Lower bounds: what passes may still not fit."""
        crop, batch = self.data.crop, self.train.batch_size
        check_memory(
            float(TRAIN_BYTES_PER_CROP_PIXEL) * batch * crop * crop,
            f"a training step of train.batch_size={batch} crops of {crop}x{crop} px",
            "use a smaller train.batch_size (or data.crop)",
        )
        if self.evaluation.image_size:
            height, width = (int(s) for s in self.evaluation.image_size)
            padding = self.psf.window - 1
            check_memory(
                float(EVALUATION_BYTES_PER_PIXEL) * (height + padding) * (width + padding),
                f"evaluation.image_size={[height, width]}",
                "use a smaller evaluation.image_size",
            )
        depths = len(self.evaluation.depths_mm) + len(self.evaluation.comparison_depths_mm)
        check_memory(
            float(PSF_WINDOW_BYTES_PER_PIXEL) * self.psf.window**2 * depths,
            f"the PSFs of {depths} evaluation depths",
            "use fewer evaluation.depths_mm",
        )


# --------------------------------------------------------------------------- helpers


def _positive(obj: Any, attr: str, label: str) -> None:
    value = getattr(obj, attr)
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ConfigError(f"{label}={value} must be a positive number")


_FLOAT_LITERAL = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


def _coerce(value: Any, annotation: Any, label: str) -> Any:
    """Convert a YAML value to the annotated type, or raise a ConfigError."""
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _coerce(value, inner[0], label)
    if annotation is NetConfig:  # one class per architecture: the one net.architecture names
        return net_from_dict(value, label)
    if isinstance(annotation, type) and dataclasses.is_dataclass(annotation):
        if not isinstance(value, dict):
            raise ConfigError(f"{label} must be a mapping of keys, got {value!r}")
        return from_dict(annotation, value, prefix=label + ".")
    if annotation is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{label}={value!r} must be true or false")
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or float(value) != int(value):
            raise ConfigError(f"{label}={value!r} must be an integer")
        return int(value)
    if annotation is float:
        if isinstance(value, str) and _FLOAT_LITERAL.fullmatch(value.strip()):
            value = float(value)  # PyYAML (YAML 1.1) reads 3e-3 (no dot) as a string
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{label}={value!r} must be a number")
        if not math.isfinite(float(value)):
            raise ConfigError(f"{label}={value!r} must be finite")
        return float(value)
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{label}={value!r} must be a string")
        return value
    if annotation is list or origin is list:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = [value]
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{label}={value!r} must be a list")
        if args:  # a typed list: every element checked, e.g. spectrum.peaks_nm[0]='red' must be a number
            return [_coerce(item, args[0], f"{label}[{i}]") for i, item in enumerate(value)]
        return list(value)
    return value


def from_dict(cls: type, data: dict, prefix: str = "") -> Any:
    """Build dataclass ``cls`` from a mapping; unknown keys raise with a suggestion."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{prefix.rstrip('.') or 'config'} must be a mapping, got {data!r}")
    if cls is Config and isinstance(data.get("evaluation"), dict) and "tilt_span_mm" in data["evaluation"]:
        data = {**data, "evaluation": dict(data["evaluation"])}  # converted on a copy: the caller's mapping stays
        _convert_tilt_span(data, OpticsConfig.focus_mm)
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    kwargs = {}
    for key, value in data.items():
        if key not in names:
            hint = difflib.get_close_matches(str(key), names, n=1)
            did_you_mean = f"; did you mean '{prefix}{hint[0]}'?" if hint else ""
            raise ConfigError(f"unknown config key '{prefix}{key}'{did_you_mean} (known: {', '.join(names)})")
        kwargs[key] = _coerce(value, hints[key], prefix + key)
    return cls(**kwargs)


def net_from_dict(data: Any, label: str = "net") -> NetConfig:
    """The ``net`` section: the configuration class of the architecture that ``data['architecture']``
    names (:data:`edofproj.net_config.NET_CONFIGS`), built from the rest of the mapping; a key that
    architecture does not have raises (:func:`edofproj.net_config.check_net_keys`)."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{label} must be a mapping of keys, got {data!r}")
    cls, options = check_net_keys(data, label)
    return from_dict(cls, options, prefix=label + ".")


def to_dict(cfg: Any) -> dict:
    """A plain mapping of a config or of one section (for YAML); the ``net`` section starts with its
    ``architecture``."""
    if isinstance(cfg, NetConfig):
        return net_to_dict(cfg)
    data = dataclasses.asdict(cfg)
    if isinstance(cfg, Config):
        data["net"] = net_to_dict(cfg.net)
        data["refit_net"] = None if cfg.refit_net is None else net_to_dict(cfg.refit_net)
    return data


def apply_overrides(cfg: Config, overrides: typing.Sequence[str]) -> Config:
    """Apply ``section.key=value`` strings (values parsed as YAML) to a config."""
    data = to_dict(cfg)
    stated_here = False
    for item in overrides or ():
        if "=" not in item:
            raise ConfigError(f"override '{item}' must look like section.key=value")
        dotted, raw = item.split("=", 1)
        if not raw.strip():
            raise ConfigError(f"override '{item}' has no value: give one, e.g. {dotted.strip()}=VALUE (null for none)")
        set_key(data, dotted.strip(), _parse_override_value(raw))
        stated_here |= dotted.strip() in STATEMENT_KEYS
    result = from_dict(Config, data).validate()
    if overrides and not stated_here and stated_measurement_changed(cfg, result):
        result.spectrum.stated_l1_error = None  # measured for the projector before the overrides, not this one
    return result


def set_key(data: dict, dotted: str, value: Any) -> None:
    """Set ``section.key`` of a config mapping (:func:`to_dict`'s form) to ``value``, in place; a key
    of the ``net`` section is one of the chosen architecture's (:func:`~edofproj.net_config.override_net`:
    ``net.architecture`` switches the network). An unknown key raises with a suggestion."""
    keys = dotted.split(".")
    if len(keys) == 2 and keys[0] in NET_SECTIONS:
        # refit_net starts as a copy of net: --set refit_net.architecture=multirate keeps net's shared options
        section = data.get(keys[0]) or dict(data["net"])
        data[keys[0]] = override_net(section, keys[1], value, keys[0])
        return
    node = data
    for depth, key in enumerate(keys[:-1]):
        if not isinstance(node, dict) or key not in node:
            known = list(node) if isinstance(node, dict) else []
            prefix = ".".join(keys[:depth])
            raise ConfigError(f"unknown config key '{'.'.join(keys[: depth + 1])}'{_suggestion(key, known, prefix)}")
        node = node[key]
    if not isinstance(node, dict) or keys[-1] not in node:
        known = list(node) if isinstance(node, dict) else []
        raise ConfigError(f"unknown config key '{dotted}'{_suggestion(keys[-1], known, '.'.join(keys[:-1]))}")
    node[keys[-1]] = value


def _suggestion(key: str, known: list, prefix: str) -> str:
    """``; did you mean 'prefix.match'?`` for the closest of ``known``, else the valid keys there
    (``; valid: prefix.a, prefix.b, ...``; the reference: docs/reference/config.md)."""
    hint = difflib.get_close_matches(key, [str(k) for k in known], n=1)
    dotted = [f"{prefix}.{k}" if prefix else str(k) for k in known]
    if hint:
        return f"; did you mean '{f'{prefix}.{hint[0]}' if prefix else hint[0]}'?"
    if not dotted:
        return f" ('{prefix}' holds no keys)"
    return f"; valid: {', '.join(dotted)} (every key: docs/reference/config.md)"


def _base_statements(data: dict) -> list[tuple[str, Any]]:
    """The ``(section.key, value)`` pairs of a config mapping that names a ``base``, in file order, with
    ``net.architecture`` before the other ``net`` keys (switching the network first; ``refit_net`` alike)."""
    pairs: list[tuple[str, Any]] = []
    for section, values in data.items():
        if not isinstance(values, dict):
            raise ConfigError(f"'{section}' must be a section (a mapping of keys), got {values!r}")
        keys = sorted(values, key=lambda k: section not in NET_SECTIONS or k != "architecture")
        pairs += [(f"{section}.{key}", values[key]) for key in keys]
    return pairs


def _convert_tilt_span(data: dict, default_focus_mm: float) -> None:
    """A config mapping's former ``evaluation.tilt_span_mm: S`` (the tilted screen from ``v`` to ``v + S``) as
    the same screen in ``evaluation.tilt_range_mm``, in place (a run saved before the key changed)."""
    evaluation = data.get("evaluation")
    if not isinstance(evaluation, dict) or "tilt_span_mm" not in evaluation:
        return
    span = evaluation.pop("tilt_span_mm")
    optics = data.get("optics")
    focus = optics.get("focus_mm", default_focus_mm) if isinstance(optics, dict) else default_focus_mm
    if "tilt_range_mm" not in evaluation and isinstance(span, (int, float)) and isinstance(focus, (int, float)):
        evaluation["tilt_range_mm"] = [float(focus), float(focus) + float(span)]


def _parse_override_value(raw: str) -> Any:
    """The value of a ``--set`` override: YAML, or the text itself where it is not YAML."""
    try:
        return safe_load_yaml(raw)
    except yaml.YAMLError:
        return raw


class DuplicateKeyError(yaml.YAMLError):
    """A YAML mapping names a key twice (one line: the key and its line)."""


class _UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses a mapping holding a key twice, instead of keeping the last
    value silently (YAML 1.2 requires keys to be unique)."""

    def construct_mapping(self, node, deep=False):
        seen: set = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise DuplicateKeyError(f"key '{key}' appears twice (line {key_node.start_mark.line + 1})")
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _UniqueKeyLoader.construct_mapping)


def safe_load_yaml(text: str):
    """``yaml.safe_load`` that refuses duplicate keys (:class:`DuplicateKeyError`): every YAML file
    edofproj reads (configs, scene files) and every ``--set`` value goes through it."""
    return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass


#: The presets ship inside the package (``edofproj/presets/*.yaml``), so any install finds them.
PRESET_DIR = Path(__file__).resolve().parent / "presets"


def preset_names() -> list[str]:
    """The names of the shipped presets (``cpu``, ``cpu-realtime``, ``paper``, ``realtime``)."""
    return sorted(p.stem for p in PRESET_DIR.glob("*.yaml")) if PRESET_DIR.is_dir() else []


def resolve_config_path(name_or_path: str) -> Path:
    """A config file path, or the name of a shipped preset (:func:`preset_names`)."""
    path = Path(name_or_path)
    if path.is_file():
        return path
    preset = PRESET_DIR / f"{name_or_path}.yaml"
    if preset.is_file():
        return preset
    presets = preset_names()
    raise ConfigError(f"config file '{name_or_path}' not found (presets: {', '.join(presets) or 'none'})")


def load_config(path: str | None = None, overrides: typing.Sequence[str] = ()) -> Config:
    """Load a YAML config (or the defaults when ``path`` is None) and apply overrides.

    A config that names ``base: PRESET_OR_FILE`` is that config with its own keys set on top, as
    ``--set`` would set them (:func:`set_key`; ``name`` too): a preset that differs from another in a
    few keys states only those. A run directory's ``config.yaml`` is always written whole."""
    cfg = Config() if path is None else _load_file(resolve_config_path(path), ())
    return apply_overrides(cfg, overrides)


def _load_file(file: Path, chain: tuple[Path, ...]) -> Config:
    """The config of the YAML ``file``; ``chain``: the files whose ``base`` led here (to refuse a loop)."""
    try:
        data = safe_load_yaml(file.read_text(encoding="utf-8")) or {}
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read config '{file}': {exc}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"config '{file}' is not valid YAML: {str(exc).splitlines()[0]}") from None
    if isinstance(data, dict) and "base" in data:
        return _load_on_base(file, data, chain)
    if isinstance(data, dict) and "net" in data:
        data["net"], note = convert_flat_net(data["net"])
        if note:  # once per file and process (Python's default warning filter)
            warnings.warn(f"{file}: {note}", ConfigConversionWarning, stacklevel=3)
    return from_dict(Config, data)


def _load_on_base(file: Path, data: dict, chain: tuple[Path, ...]) -> Config:
    """The config of ``file`` (its mapping ``data``) set on top of the config its ``base`` names."""
    base = data.pop("base")
    if not isinstance(base, str) or not base.strip():
        raise ConfigError(f"config '{file}': base must name a preset or a config file, got {base!r}")
    here = file.resolve()
    if here in chain:
        raise ConfigError(f"config '{file}': its bases form a loop ({' -> '.join(p.name for p in (*chain, here))})")
    beside = file.parent / base  # a file named relative to the config that names it, else a preset or a path
    base_cfg = _load_file(beside if beside.is_file() else resolve_config_path(base), (*chain, here))
    merged = to_dict(base_cfg)
    name = data.pop("name", None)
    if name is not None:
        merged["name"] = name
    _convert_tilt_span(data, merged["optics"]["focus_mm"])
    statements = _base_statements(data)
    for dotted, value in statements:
        set_key(merged, dotted, value)
    cfg = from_dict(Config, merged).validate()
    stated_here = {dotted for dotted, _ in statements}
    data_after = to_dict(cfg)
    for key, (depends_on, cleared) in PROJECTOR_BOUND_KEYS.items():
        if key not in stated_here and keys_changed(base_cfg, cfg, depends_on, exclude=(key,)):
            section, name = key.split(".")
            data_after[section][name] = cleared  # set for the base's projector, not this one
    return from_dict(Config, data_after).validate()


#: The keys a measured accuracy (``spectrum.stated_l1_error``) depends on: the projector's optics, its
#: spectra and sampling, and the depths the PSFs span. A statement holds for these values only.
STATED_FOR_KEYS = ("optics.", "spectrum.", "psf.depth_min_mm", "psf.depth_max_mm")
#: The keys a depth range of the evaluation is chosen for: the projector's focus and training range.
RANGE_FOR_KEYS = ("optics.focus_mm", "psf.depth_min_mm", "psf.depth_max_mm")

#: Keys that belong to the projector they were set for: ``key -> (the keys it depends on (prefixes), the value
#: that follows the new projector)``. A config whose ``base`` sets one and that changes what it depends on
#: without setting it again does not inherit it: a stated accuracy is dropped (the sampling check speaks
#: again), the scored and tilted-screen ranges follow the new training range.
PROJECTOR_BOUND_KEYS: dict[str, tuple[tuple[str, ...], Any]] = {
    "spectrum.stated_l1_error": (STATED_FOR_KEYS, None),
    "evaluation.score_range_mm": (RANGE_FOR_KEYS, []),
    "evaluation.tilt_range_mm": (RANGE_FOR_KEYS, []),
    "doe.design_wavelength_nm": (("spectrum.peaks_nm", "spectrum.fwhm_nm", "spectrum.spd_csv"), None),
}


def keys_changed(base: Config, cfg: Config, prefixes: tuple[str, ...], exclude: tuple[str, ...] = ()) -> bool:
    """Whether ``cfg`` differs from ``base`` in a key that starts with one of ``prefixes`` (``exclude`` and the
    :data:`STATEMENT_KEYS` aside)."""
    a, b = flatten_config(base), flatten_config(cfg)
    keys = [k for k in set(a) | set(b) if k.startswith(prefixes) and k not in STATEMENT_KEYS and k not in exclude]
    return any(a.get(k) != b.get(k) for k in keys)


def stated_measurement_changed(base: Config, cfg: Config) -> bool:
    """Whether ``cfg`` differs from ``base`` in a key a stated accuracy depends on (:data:`STATED_FOR_KEYS`)."""
    return keys_changed(base, cfg, STATED_FOR_KEYS)


def flatten_config(cfg: Config) -> dict:
    """``{"section.key": value}`` of a whole configuration (:func:`to_dict`)."""
    return {
        f"{section}.{key}": value
        for section, values in to_dict(cfg).items()
        if isinstance(values, dict)
        for key, value in values.items()
    }


#: The configuration sections that describe a projector and the simulation of its PSFs (lens, pixel grid,
#: throw ratio, spectra, PSF sampling, training depth range): a design is simulated with exactly these
#: settings of the run that made it (:func:`config_on_run`).
PROJECTOR_SECTIONS = ("optics", "spectrum", "psf")
#: The sections that hold a network (:mod:`edofproj.net_config`): the run's and its refit phase's.
NET_SECTIONS = ("net", "refit_net")


def projector_keys(cfg: Config) -> dict:
    """``{"section.key": value}`` of the :data:`PROJECTOR_SECTIONS` of ``cfg``, stated accuracies
    (:data:`STATEMENT_KEYS`) aside."""
    data = to_dict(cfg)
    return {
        f"{section}.{key}": value
        for section in PROJECTOR_SECTIONS
        for key, value in without_statements(section, data[section]).items()
    }


def projector_differences(reference: Config, other: Config) -> list[tuple[str, Any, Any]]:
    """``(key, reference value, other value)`` of every projector key (:func:`projector_keys`) that differs."""
    a, b = projector_keys(reference), projector_keys(other)
    return [(k, a.get(k), b.get(k)) for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]


def describe_differences(differences: typing.Sequence[tuple[str, Any, Any]], limit: int = 4) -> str:
    """``key (a -> b), ...`` of the first ``limit`` differences, and how many more."""
    shown = ", ".join(f"{k} ({a!r} -> {b!r})" for k, a, b in differences[:limit])
    more = f" and {len(differences) - limit} more" if len(differences) > limit else ""
    return shown + more


def config_on_run(
    run_config: str | Path, config_arg: str | None, overrides: typing.Sequence[str] = (), label: str = "the run"
) -> Config:
    """The configuration of a command given a run (whose ``config.yaml`` is ``run_config``; ``label``
    names the run in messages): the run's own, with ``overrides`` on top; ``config_arg`` (a config
    file or preset) only where it describes the run's projector (:func:`projector_differences` empty),
    else a :class:`ConfigError` naming the keys that differ. No default fills a key the run has."""
    own = load_config(str(run_config))
    if config_arg is None:
        return apply_overrides(own, overrides)
    differences = projector_differences(own, load_config(config_arg))
    if differences:
        raise ConfigError(
            f"--config '{config_arg}' describes another projector than {label} ({describe_differences(differences)}): "
            "leave out --config (the run's own projector is used), or change a key deliberately with --set"
        )
    return load_config(config_arg, overrides)


def dump_config(cfg: Config) -> str:
    """The config as YAML text."""
    return yaml.safe_dump(to_dict(cfg), sort_keys=False)
