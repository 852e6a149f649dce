"""Structured light: Gray-code and multi-frequency phase-shift patterns, decoded into the
camera -> projector map with a validity per camera pixel.

Coordinates: projector ``(x, y)`` = (column, row), the centre of pixel ``(row 0, col 0)`` at
``(0, 0)`` (OpenCV). A pattern varies along one *axis* of the projector image: ``"x"`` (stripes
are columns, the code gives ``x``) or ``"y"`` (rows, the code gives ``y``); ``L`` is the
projector's length along it (``W`` or ``H``).

**Gray code.** ``n = ceil(log2 L)`` bit planes, most significant first. Plane ``b`` (0-based) of
pixel coordinate ``c`` is bit ``n - 1 - b`` of the reflected binary code ``g(c) = c XOR (c >> 1)``:
plane ``b`` is made of stripes ``2^(n - b)`` px wide (the first plane's are cut by the image
border), and each boundary between two neighbouring pixels is an edge in exactly one plane.
Decoding ``m <= n`` planes gives the stripe ``s`` of width ``w = 2^(n - m)``: the bits
``b_0 = g_0``, ``b_k = b_(k-1) XOR g_k``, ``s = sum_k b_k 2^(m - 1 - k)``, the coordinate its centre
``c = s w + (w - 1) / 2``. A bit is read against a per-pixel threshold: the inverse pattern's
capture where there is one (``bit = I > I_inv``), else the mid level ``(min + max) / 2`` of the
pixel's own captures -- every pixel but ``c = 0`` is lit in at least one plane and dark in another.
This threshold is per pixel (ambient light, reflectance, vignetting), and insensitive to an
exposure that drifts between frames as long as the drift is smaller than the contrast.

**Phase shift.** For each period count ``f`` (periods across ``L``) and each of ``N`` steps,

    I_(f,k)(c) = 1/2 + 1/2 cos(phi_f(c) + 2 pi k / N),    phi_f(c) = 2 pi f c / L,   k = 0..N-1.

A camera pixel seeing ``A + B cos(phi + 2 pi k / N)`` gives the wrapped phase and the modulation

    S = sum_k I_k exp(-2 pi i k / N) = (N B / 2) exp(i phi),   phi = arg S,   B = 2 |S| / N,

(for ``N = 4``: ``phi = atan2(I_3 - I_1, I_0 - I_2)`` with 0-based ``k``, the usual 4-step formula).
Frequencies are unwrapped from the coarsest, which must be one period (absolute):
``Phi_1 = phi_1``, ``Phi_j = phi_j + 2 pi round((Phi_(j-1) f_j / f_(j-1) - phi_j) / 2 pi)``, and
``c = Phi_last L / (2 pi f_last)``. A pixel is valid where every frequency's modulation ``B``
reaches ``min_modulation``, every rounding residual is below ``max_unwrap_residual`` periods, and
no frame is saturated or clipped to black there (a clipped sample bends the sinusoid and biases phi).
A rig whose phase origin is not at pixel centre 0 (e.g. 1-based columns) decodes to coordinates
shifted by a constant: :mod:`.psf_map` estimates that offset from dots.

**What a valid pixel needs, besides.** Its captures change by ``min_contrast`` (Gray code) or are
modulated by ``min_modulation`` (phase shift) in the captures' own units -- never only after the
frames are brought to one exposure, where a constant dark pixel divided by a small gain reaches any
contrast. And its decoded coordinate agrees with at least ``MIN_COHERENT_NEIGHBOURS`` of its four
neighbours' to ``COHERENCE_PX`` projector px (or two Gray-code stripes, the wider): a surface seen
by a camera decodes to a smooth map, noise decodes to coordinates that jump from pixel to pixel
(:func:`coherent`). This assumes the camera samples the projector at least once per
``COHERENCE_PX / 2`` projector px. A frame set in which no pixel changes is refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import EdofprojError
from ..fileio import save_npz_atomic
from ..limits import check_memory
from .geometry import apply_homography

AXES = ("x", "y")
CORRESPONDENCE_FORMAT = "edofproj-procams-correspondence"
DEFAULT_MIN_MODULATION = 8.0 / 255.0
"""Smallest phase-shift modulation ``B`` (image units, ``[0, 1]`` for 8-bit captures) of a valid pixel."""
DEFAULT_MIN_CONTRAST = 16.0 / 255.0
"""Smallest Gray-code contrast (bright minus dark, image units) of a valid pixel."""
DEFAULT_MAX_UNWRAP_RESIDUAL = 0.4
"""Largest rounding residual (periods) of the temporal unwrapping at a valid pixel. Rounding is right
below 0.5; a projector's gamma bends a one-period sinusoid enough to leave residuals of 0.3 period
on a real rig (4 steps cancel only the second harmonic), so the margin is kept small."""
COHERENCE_PX = 4.0
"""Largest difference (projector px) between the coordinates of two neighbouring camera pixels that
see one smooth surface (module docstring)."""
MIN_COHERENT_NEIGHBOURS = 2
"""Of a valid pixel's four neighbours, how many must decode within ``COHERENCE_PX`` of it."""
SATURATED = 1.0 - 0.5 / 255.0
"""A sample at or above this (image units) is saturated."""
CLIPPED_BLACK = 0.5 / 255.0
"""A sample at or below this (image units) is clipped to black."""


def axis_length(projector_hw: tuple[int, int], axis: str) -> int:
    """``L``: the projector's width for axis ``"x"``, its height for ``"y"``."""
    if axis not in AXES:
        raise EdofprojError(f"axis '{axis}' must be 'x' (columns) or 'y' (rows)")
    return int(projector_hw[1] if axis == "x" else projector_hw[0])


def gray_code_bits(length_px: int) -> int:
    """``n = ceil(log2 L)``: the planes that give every pixel of a length-``L`` axis its own code."""
    if length_px < 2:
        raise EdofprojError(f"a Gray code needs an axis of at least 2 px, got {length_px}")
    return int(math.ceil(math.log2(length_px)))


def gray_code_profiles(length_px: int) -> np.ndarray:
    """``(n, L)`` 0/1 float: plane ``b`` along the axis (module docstring), most significant first."""
    n = gray_code_bits(length_px)
    c = np.arange(length_px)
    gray = c ^ (c >> 1)
    return np.stack([(gray >> (n - 1 - b)) & 1 for b in range(n)]).astype(np.float64)


def gray_code_stripe_width(length_px: int, plane: int) -> int:
    """Width in px of the stripes of plane ``plane`` (0-based, most significant first)."""
    return 2 ** (gray_code_bits(length_px) - plane)


def phase_shift_profiles(length_px: int, periods: list[int], steps: int) -> np.ndarray:
    """``(len(periods) * steps, L)`` in ``[0, 1]``: ``I_(f,k)``, all steps of a period count together."""
    check_phase_plan(length_px, periods, steps)
    c = np.arange(length_px, dtype=np.float64)
    rows = [
        0.5 + 0.5 * np.cos(2 * math.pi * f * c / length_px + 2 * math.pi * k / steps)
        for f in periods
        for k in range(steps)
    ]
    return np.stack(rows)


def check_phase_plan(length_px: int, periods: list[int], steps: int) -> None:
    """One line unless the periods rise from 1 (absolute phase) and every step count is at least 3."""
    if steps < 3:
        raise EdofprojError(f"a phase shift needs at least 3 steps, got {steps}")
    if not periods or periods[0] != 1:
        raise EdofprojError(f"the periods {periods} must start at 1 (one period across the image: absolute phase)")
    if any(b <= a for a, b in zip(periods, periods[1:])):
        raise EdofprojError(f"the periods {periods} must rise")
    if 2 * periods[-1] > length_px:
        raise EdofprojError(f"{periods[-1]} periods across {length_px} px is less than 2 px per period")


def profiles_to_images(profiles: np.ndarray, projector_hw: tuple[int, int], axis: str) -> np.ndarray:
    """``(n, H, W)`` images from ``(n, L)`` profiles along ``axis``."""
    H, W = projector_hw
    if axis == "x":
        return np.broadcast_to(profiles[:, None, :], (len(profiles), H, W)).copy()
    return np.broadcast_to(profiles[:, :, None], (len(profiles), H, W)).copy()


# ---------------------------------------------------------------------------------- decoding
@dataclass
class AxisDecoding:
    """One projector coordinate per camera pixel: ``coordinate`` ``(Hc, Wc)`` (NaN where not
    ``valid``), ``valid`` ``(Hc, Wc)`` bool, and the per-pixel ``dark`` and ``bright`` levels the
    captures show (image units): what the camera sees of a projector pixel off and fully on."""

    coordinate: np.ndarray
    valid: np.ndarray
    dark: np.ndarray
    bright: np.ndarray


def _stack(frames) -> np.ndarray:
    stack = np.asarray(frames, dtype=np.float64)
    if stack.ndim != 3:
        raise EdofprojError(f"decoding needs grey frames (n, Hc, Wc), got shape {stack.shape}")
    return stack


def coherent(coordinate: np.ndarray, valid: np.ndarray, tolerance_px: float = COHERENCE_PX) -> np.ndarray:
    """``valid`` ``(Hc, Wc)`` where at least ``MIN_COHERENT_NEIGHBOURS`` of the pixel's four neighbours
    are valid too and decode within ``tolerance_px`` of it (module docstring)."""
    c = np.where(valid, coordinate, np.nan)
    padded = np.pad(c, 1, constant_values=np.nan)
    centre = padded[1:-1, 1:-1]
    agree = np.zeros(c.shape, dtype=np.int64)
    with np.errstate(invalid="ignore"):
        for dv, du in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            other = padded[1 + dv : padded.shape[0] - 1 + dv, 1 + du : padded.shape[1] - 1 + du]
            agree += np.abs(other - centre) <= tolerance_px
    return np.asarray(valid & (agree >= MIN_COHERENT_NEIGHBOURS))


def _require_pattern(changes: np.ndarray, least: float, what: str, count: int) -> None:
    """One line when no camera pixel's captures change by ``least`` (all black, all white, a projector off)."""
    if not np.any(changes >= least):
        raise EdofprojError(
            f"the {count} captures show no pattern: no camera pixel's {what} reaches {least * 255:.0f}/255 "
            f"(largest {float(np.max(changes)) * 255:.1f}/255): all black, all white, or the projector off?"
        )


def decode_phase_shift(
    frames,
    periods: list[int],
    steps: int,
    length_px: int,
    min_modulation: float = DEFAULT_MIN_MODULATION,
    max_unwrap_residual: float = DEFAULT_MAX_UNWRAP_RESIDUAL,
) -> AxisDecoding:
    """Projector coordinate from ``len(periods) * steps`` grey captures ``(n, Hc, Wc)`` in the order
    of :func:`phase_shift_profiles` (module docstring)."""
    check_phase_plan(length_px, periods, steps)
    stack = _stack(frames)
    if len(stack) != len(periods) * steps:
        raise EdofprojError(
            f"{len(periods)} periods x {steps} steps need {len(periods) * steps} captures, got {len(stack)}"
        )
    valid = np.all((stack < SATURATED) & (stack > CLIPPED_BLACK), axis=0)
    _require_pattern(stack.max(axis=0) - stack.min(axis=0), 2 * min_modulation, "range", len(stack))
    delta = 2 * math.pi * np.arange(steps) / steps
    weights = np.exp(-1j * delta)[:, None, None]
    unwrapped = np.zeros(stack.shape[1:])
    mean = np.zeros(stack.shape[1:])
    modulation_coarse = np.zeros(stack.shape[1:])
    for j, f in enumerate(periods):
        group = stack[j * steps : (j + 1) * steps]
        s = np.sum(group * weights, axis=0)
        modulation = 2.0 * np.abs(s) / steps
        valid &= modulation >= min_modulation
        phase = np.angle(s)  # (-pi, pi]
        if j == 0:
            # the pixels' footprints span phases [-pi / L, 2 pi - pi / L): wrap into that range
            low = -math.pi / length_px
            unwrapped = np.mod(phase - low, 2 * math.pi) + low
        else:
            predicted = unwrapped * f / periods[j - 1]
            turns = (predicted - phase) / (2 * math.pi)
            whole = np.round(turns)
            valid &= np.abs(turns - whole) <= max_unwrap_residual
            unwrapped = phase + 2 * math.pi * whole
        mean += group.mean(axis=0) / len(periods)
        if j == 0:
            modulation_coarse = modulation  # the least blurred: the fine sinusoids lose contrast to the PSF
    coordinate = unwrapped * length_px / (2 * math.pi * periods[-1])
    valid &= (coordinate > -0.5) & (coordinate < length_px - 0.5)
    valid = coherent(coordinate, valid)
    coordinate = np.where(valid, coordinate, np.nan)
    return AxisDecoding(
        coordinate=coordinate, valid=valid, dark=mean - modulation_coarse, bright=mean + modulation_coarse
    )


def decode_gray_code(
    frames,
    length_px: int,
    inverse_frames=None,
    min_contrast: float = DEFAULT_MIN_CONTRAST,
    normalize_exposure: bool = True,
) -> AxisDecoding:
    """Projector coordinate from the first ``m`` Gray-code planes' grey captures ``(m, Hc, Wc)``,
    most significant first (module docstring): the centre of the decoded stripe, ``2^(n - m)`` px
    wide. ``inverse_frames``: the inverse patterns' captures, same shape, or None (then each pixel's
    threshold is its captures' mid level, which needs ``m >= 2``, after :func:`normalize_exposures`
    unless ``normalize_exposure`` is False; ``dark`` and ``bright`` are then in the normalized units)."""
    stack = _stack(frames)
    n = gray_code_bits(length_px)
    m = len(stack)
    if not 1 <= m <= n:
        raise EdofprojError(f"a {length_px}-px axis has {n} Gray-code planes, got {m} captures")
    raw_contrast = stack.max(axis=0) - stack.min(axis=0)
    if inverse_frames is not None:
        inverse = _stack(inverse_frames)
        if inverse.shape != stack.shape:
            raise EdofprojError(f"the inverse captures {inverse.shape} do not match the captures {stack.shape}")
        raw_contrast = np.min(np.abs(stack - inverse), axis=0)
        _require_pattern(raw_contrast, min_contrast, "difference from its inverse", 2 * m)
        bits = stack > inverse
        contrast = raw_contrast
        bright = np.maximum(stack, inverse).max(axis=0)
        dark = np.minimum(stack, inverse).min(axis=0)
    else:
        if m < 2:
            raise EdofprojError("Gray-code decoding without inverse patterns needs at least 2 planes")
        _require_pattern(raw_contrast, min_contrast, "range", m)
        if normalize_exposure:
            stack = normalize_exposures(stack, min_contrast)
        dark, bright = stack.min(axis=0), stack.max(axis=0)
        bits = stack > 0.5 * (dark + bright)
        contrast = bright - dark
    # in the captures' own units: normalized, a constant dark pixel divided by a small gain has any contrast
    valid = (contrast >= min_contrast) & (raw_contrast >= min_contrast)
    binary = np.zeros(stack.shape[1:], dtype=bool)
    stripe = np.zeros(stack.shape[1:], dtype=np.int64)
    for k in range(m):
        binary = binary ^ bits[k]
        stripe = 2 * stripe + binary
    width = 2 ** (n - m)
    coordinate = stripe * width + (width - 1) / 2.0
    valid &= coordinate <= length_px - 1
    valid = coherent(coordinate, valid, max(COHERENCE_PX, 2.0 * width))
    return AxisDecoding(
        coordinate=np.where(valid, coordinate, np.nan).astype(np.float64), valid=valid, dark=dark, bright=bright
    )


def normalize_exposures(
    stack: np.ndarray, min_contrast: float = DEFAULT_MIN_CONTRAST, iterations: int = 5
) -> np.ndarray:
    """Binary captures ``(n, Hc, Wc)`` brought to one exposure, ``(I_i - beta_i) / g_i``.

    Model: ``I_i(q) = g_i (D(q) + C(q) s_i(q)) + beta_i`` -- a per-pixel dark level ``D`` and
    contrast ``C``, bits ``s_i(q)`` in ``{0, 1}``, and per frame a gain ``g_i`` and offset
    ``beta_i`` (an auto-exposure, a projector that dims when more of the image is lit, stray light
    that grows with the lit area). Alternating least squares over the pixels whose captures differ
    by at least ``min_contrast``: bits from the per-pixel mid level, then ``D`` and ``C`` per pixel,
    then ``(g_i, beta_i)`` per frame, ``iterations``
    times. Starts from each frame split at its Otsu threshold
    (:func:`skimage.filters.threshold_otsu`) and scaled to its two classes' medians."""
    from skimage.filters import threshold_otsu

    active = (stack.max(axis=0) - stack.min(axis=0)) >= min_contrast
    if active.sum() < 16:
        return stack
    frames = stack[:, active]  # (n, p)
    gain, offset = np.ones(len(frames)), np.zeros(len(frames))
    for i, values in enumerate(frames):
        level = threshold_otsu(values)
        dark, lit = np.median(values[values <= level]), np.median(values[values > level])
        gain[i], offset[i] = max(lit - dark, 1e-6), dark
    for _ in range(iterations):
        norm = (frames - offset[:, None]) / gain[:, None]
        low, high = norm.min(axis=0), norm.max(axis=0)
        bits = norm > 0.5 * (low + high)
        count = bits.sum(axis=0)
        usable = (count > 0) & (count < len(frames))
        lit_mean = np.where(usable, (norm * bits).sum(axis=0) / np.maximum(count, 1), high)
        dark_mean = np.where(usable, (norm * ~bits).sum(axis=0) / np.maximum(len(frames) - count, 1), low)
        for i, values in enumerate(frames):
            model = np.where(bits[i], lit_mean, dark_mean)[usable]
            A = np.c_[model, np.ones(model.size)]
            (g, b), *_ = np.linalg.lstsq(A, values[usable], rcond=None)
            if g > 1e-6:
                gain[i], offset[i] = g, b
    return (stack - offset[:, None, None]) / gain[:, None, None]


# ---------------------------------------------------------------------------------- the map
@dataclass
class CorrespondenceMap:
    """The camera -> projector map of one camera pose: for every camera pixel ``(v, u)`` the
    projector point ``(proj_x, proj_y)`` it sees, ``(Hc, Wc)`` each, NaN where unknown; ``valid``
    where both are known. ``proj_y`` may be all NaN (a column code only): such a map still
    predicts images that vary along ``x`` only (:meth:`is_complete`)."""

    proj_x: np.ndarray
    proj_y: np.ndarray
    projector_hw: tuple[int, int]

    @property
    def camera_hw(self) -> tuple[int, int]:
        return int(self.proj_x.shape[0]), int(self.proj_x.shape[1])

    @property
    def valid(self) -> np.ndarray:
        """Camera pixels whose projector ``x`` is known (and ``y`` too where the map has rows)."""
        known = np.isfinite(self.proj_x)
        return known & np.isfinite(self.proj_y) if self.is_complete else known

    @property
    def is_complete(self) -> bool:
        """Whether the map gives rows as well as columns."""
        return bool(np.isfinite(self.proj_y).any())

    @classmethod
    def from_decodings(
        cls, x: AxisDecoding | None, y: AxisDecoding | None, projector_hw: tuple[int, int]
    ) -> "CorrespondenceMap":
        if x is None and y is None:
            raise EdofprojError("a correspondence map needs a code along x, y or both")
        shape = (x or y).coordinate.shape  # type: ignore[union-attr]
        nan = np.full(shape, np.nan)
        proj_x = x.coordinate if x is not None else nan
        proj_y = y.coordinate if y is not None else nan
        if proj_x.shape != proj_y.shape:
            raise EdofprojError(f"the x code ({proj_x.shape}) and y code ({proj_y.shape}) differ in camera size")
        if x is not None and y is not None:
            both = np.isfinite(proj_x) & np.isfinite(proj_y)
            proj_x, proj_y = np.where(both, proj_x, np.nan), np.where(both, proj_y, np.nan)
        return cls(proj_x=proj_x, proj_y=proj_y, projector_hw=(int(projector_hw[0]), int(projector_hw[1])))

    def fit_homography(self, max_points: int = 20000, ransac_px: float = 1.0, seed: int = 0):
        """The camera -> projector homography (:func:`cv2.findHomography`, RANSAC with a threshold of
        ``ransac_px`` projector px over at most ``max_points`` valid pixels drawn at random) and
        the residual ``|P(q) - H q|`` in projector px at every valid pixel (NaN elsewhere): how far
        the decoded map is from one plane seen by two pinholes. Returns ``(H, residual, inliers)``
        with ``inliers`` the valid pixels within ``ransac_px``."""
        if not self.is_complete:
            raise EdofprojError("a homography needs a map with both columns and rows")
        v, u = np.nonzero(self.valid)
        if len(u) < 8:
            raise EdofprojError(f"the map has {len(u)} valid pixels: too few for a homography")
        rng = np.random.default_rng(seed)
        pick = rng.choice(len(u), size=min(max_points, len(u)), replace=False)
        cam = np.c_[u[pick], v[pick]].astype(np.float64)
        proj = np.c_[self.proj_x[v[pick], u[pick]], self.proj_y[v[pick], u[pick]]]
        homography, _ = cv2.findHomography(cam, proj, cv2.RANSAC, ransac_px, maxIters=5000)
        if homography is None:
            raise EdofprojError("no homography fits the decoded map")
        mapped = apply_homography(homography, np.c_[u, v].astype(np.float64))
        error = np.hypot(mapped[:, 0] - self.proj_x[v, u], mapped[:, 1] - self.proj_y[v, u])
        residual = np.full(self.camera_hw, np.nan)
        residual[v, u] = error
        return homography, residual, np.isfinite(residual) & (residual <= ransac_px)

    def moved(self, camera_homography: np.ndarray) -> "CorrespondenceMap":
        """The map of the camera after it moved: ``P'(q) = P(G q)``, with ``G`` the 3x3 homography from
        the new camera's pixels to the old one's (a camera turned, or moved in front of a plane)."""
        Hc, Wc = self.camera_hw
        v, u = np.mgrid[0:Hc, 0:Wc].astype(np.float64)
        old = apply_homography(camera_homography, np.c_[u.ravel(), v.ravel()]).reshape(Hc, Wc, 2).astype(np.float32)
        sampled = [
            cv2.remap(np.nan_to_num(a, nan=-1e6).astype(np.float32), old[..., 0], old[..., 1], cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_CONSTANT, borderValue=-1e6)
            for a in (self.proj_x, self.proj_y)
        ]  # fmt: skip
        known = [
            cv2.remap(np.isfinite(a).astype(np.float32), old[..., 0], old[..., 1], cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            for a in (self.proj_x, self.proj_y)
        ]  # fmt: skip
        out = [np.where(k > 0.999, s, np.nan).astype(np.float64) for s, k in zip(sampled, known)]
        return CorrespondenceMap(proj_x=out[0], proj_y=out[1], projector_hw=self.projector_hw)

    def save(self, path, **extra: np.ndarray) -> None:
        """``path`` (.npz, format ``edofproj-procams-correspondence``): ``proj_x``, ``proj_y``
        float32 ``(Hc, Wc)`` with NaN where unknown, ``projector_hw``, and ``extra`` arrays."""
        save_npz_atomic(
            path,
            format=np.array(CORRESPONDENCE_FORMAT),
            proj_x=self.proj_x.astype(np.float32),
            proj_y=self.proj_y.astype(np.float32),
            projector_hw=np.array(self.projector_hw),
            **extra,
        )

    @classmethod
    def load(cls, path) -> "CorrespondenceMap":
        """Read and check a map written by :meth:`save`."""
        from ..fileio import read_tagged_arrays

        keys = ("proj_x", "proj_y", "projector_hw")
        make = "make one with 'edofproj procams decode'"
        data = read_tagged_arrays(path, "correspondence map", CORRESPONDENCE_FORMAT, keys, make)
        source = f"correspondence map '{path}'"
        proj_x, proj_y, hw = data["proj_x"], data["proj_y"], data["projector_hw"]
        if proj_x.ndim != 2 or proj_x.shape != proj_y.shape or proj_x.dtype.kind != "f" or proj_y.dtype.kind != "f":
            raise EdofprojError(f"{source} has maps of shapes {proj_x.shape} and {proj_y.shape}, not two (Hc, Wc)")
        if hw.shape != (2,) or np.any(hw < 1) or np.any(hw != np.round(hw)):
            raise EdofprojError(f"{source} gives projector_hw {hw.tolist()}, not two whole numbers >= 1")
        H, W = (int(v) for v in hw)
        for name, values, top in (("proj_x", proj_x, W), ("proj_y", proj_y, H)):
            known = values[np.isfinite(values)]
            if np.isinf(values).any() or (known.size and (known.min() < -0.5 or known.max() > top - 0.5)):
                raise EdofprojError(f"{source} has '{name}' outside the {W}x{H} projector")
        return cls(proj_x=proj_x.astype(np.float64), proj_y=proj_y.astype(np.float64), projector_hw=(H, W))


def check_decoding_memory(camera_hw: tuple[int, int], frames: int) -> None:
    """:func:`edofproj.limits.check_memory` of decoding ``frames`` captures (float64 stack, complex sums)."""
    check_memory(
        (8 * frames + 64) * camera_hw[0] * camera_hw[1],
        f"decoding {frames} captures of {camera_hw[1]}x{camera_hw[0]} px",
        "decode fewer captures at once",
    )


def anchor_to_code(
    corr: CorrespondenceMap, decoding: AxisDecoding, axis: str, degree: int = 3, outlier_px: float | None = None
) -> tuple[CorrespondenceMap, np.ndarray]:
    """``corr`` with its ``axis`` coordinate corrected by a smooth field fitted to a coarser decoding
    of the same camera pose (e.g. a Gray code's first planes, stripes ``w`` px wide).

    ``corr`` carries the fine, distorted shape (a map of another session, :meth:`CorrespondenceMap.moved`
    by a camera motion that is only approximately known); ``decoding`` is exact up to its stripes'
    quantization, which is zero-mean (stripe centres). The correction is a polynomial of total
    degree ``degree`` in the normalized camera coordinates, ``delta(q) = sum c_ij u^i v^j``, fitted by
    least squares to ``decoding - corr`` over the pixels valid in both, refitted once without the
    pixels off by more than ``outlier_px`` (default: the stripe width). Returns the corrected map and
    the coefficients."""
    mine = corr.proj_x if axis == "x" else corr.proj_y
    both = np.isfinite(mine) & decoding.valid
    v, u = np.nonzero(both)
    if len(u) < 100:
        raise EdofprojError(f"{len(u)} pixels are decoded in both maps: too few to anchor one to the other")
    Hc, Wc = corr.camera_hw
    powers = [(i, j) for i in range(degree + 1) for j in range(degree + 1 - i)]

    def design(uu: np.ndarray, vv: np.ndarray) -> np.ndarray:
        un, vn = 2 * uu / max(Wc - 1, 1) - 1, 2 * vv / max(Hc - 1, 1) - 1
        return np.stack([un**i * vn**j for i, j in powers], axis=-1)

    target = decoding.coordinate[v, u] - mine[v, u]
    widths = np.diff(np.unique(decoding.coordinate[decoding.valid]))
    limit = outlier_px if outlier_px is not None else float(np.median(widths)) if widths.size else 8.0
    A = design(u.astype(np.float64), v.astype(np.float64))
    coef, *_ = np.linalg.lstsq(A, target, rcond=None)
    keep = np.abs(A @ coef - target) <= limit
    coef, *_ = np.linalg.lstsq(A[keep], target[keep], rcond=None)
    vv, uu = np.mgrid[0:Hc, 0:Wc].astype(np.float64)
    corrected = mine + design(uu, vv) @ coef
    if axis == "x":
        return CorrespondenceMap(corrected, corr.proj_y.copy(), corr.projector_hw), coef
    return CorrespondenceMap(corr.proj_x.copy(), corrected, corr.projector_hw), coef
