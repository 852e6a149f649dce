"""Calibration patterns for a projector-camera system (paper Sec. 5.1-5.2) and their manifest.

One pattern set holds, all at the projector's resolution ``H x W`` (8-bit RGB PNG):

* ``bernoulli_XX.png`` -- Bernoulli colour noise for PSF estimation (paper Eq. 13): every
  pixel and channel independently 0 or 1 with probability 1/2. Single pixels, not blocks:
  white noise has a flat expected power spectrum ``E|F{B}|^2 = N/4`` at every non-zero
  frequency, so the deconvolution of Eq. 13 is equally well conditioned everywhere; blocks
  of ``b`` pixels multiply the spectrum by ``sinc^2(b f)``, whose zeros at ``f = k/b``
  cycles/pixel would leave those PSF frequencies unmeasured. Binary values also make the
  estimate insensitive to the projector's non-linear response: only its values at 0 and 1
  are used.
* ``dots.png`` -- a grid of ``rows x cols`` white discs on black (paper: 16 x 32) for
  geometric calibration; each disc is symmetric about an integer pixel, its centre.
* ``red.png``, ``green.png``, ``blue.png`` (role ``primary``), ``white.png``, ``black.png`` --
  full fields for the colour-mixing matrix (paper Sec. 5.2).
* ``color_XXX.png`` -- the colour samples: ``L^3`` *uniform* full fields, one per RGB value
  of an ``L x L x L`` grid of levels (8-bit values ``round(255 k / (L - 1))``). Uniform fields
  rather than tiles of many colours in one image, because a tile's measured colour would be
  biased by its neighbours' blur and by the haze (light a DOE throws far, docs/physics.md
  "Energy"), which is ``(1 - sum p) * mean(image)`` everywhere.

Coordinates: ``(x, y)`` in projector pixels, ``x`` the column, the centre of pixel
``(row 0, col 0)`` at ``(0, 0)`` (the OpenCV convention).

``manifest.json``::

    {"format": "edofproj-procams-patterns", "version": 1, "width": W, "height": H,
     "files": [{"file": "bernoulli_00.png", "role": "bernoulli", "index": 0},
               {"file": "dots.png", "role": "dots", "grid": [rows, cols], "radius_px": r,
                "dots": [[x, y], ...]},          # row-major: row 0 first, columns left to right
               {"file": "red.png", "role": "primary", "color": [1, 0, 0]}, ...
               {"file": "white.png", "role": "white", "color": [1, 1, 1]},
               {"file": "black.png", "role": "black", "color": [0, 0, 0]},
               {"file": "color_000.png", "role": "color_sample", "index": 0, "color": [r, g, b]}, ...]}

Colours are projector *input* values in ``[0, 1]`` (exactly the stored 8-bit value / 255).
Captures are read from a folder holding one capture per pattern under the same file name.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import EdofprojError
from ..limits import check_memory
from .capture_io import read_rgb

MANIFEST_NAME = "manifest.json"
MANIFEST_FORMAT = "edofproj-procams-patterns"
ROLES = ("bernoulli", "dots", "primary", "white", "black", "color_sample")
PRIMARY_COLORS = {"red": (1.0, 0.0, 0.0), "green": (0.0, 1.0, 0.0), "blue": (0.0, 0.0, 1.0)}


@dataclass
class PatternSpec:
    """How to build a pattern set. ``dot_grid`` is ``(rows, cols)``; ``dot_radius_px=None`` picks
    one eighth of the smaller dot spacing (at least 1 px)."""

    width: int
    height: int
    bernoulli_count: int = 5
    seed: int = 0
    dot_grid: tuple[int, int] = (16, 32)
    dot_radius_px: int | None = None
    color_levels: int = 6

    def validate(self) -> None:
        if self.width < 16 or self.height < 16:
            raise EdofprojError(
                f"pattern size {self.height}x{self.width} (height x width) is too small (at least 16x16 pixels)"
            )
        if self.bernoulli_count < 1:
            raise EdofprojError(f"--bernoulli {self.bernoulli_count} must be >= 1")
        rows, cols = self.dot_grid
        if rows < 2 or cols < 2:
            raise EdofprojError(f"the dot grid {rows}x{cols} needs at least 2 rows and 2 columns")
        if min(self.height / rows, self.width / cols) < 4:
            raise EdofprojError(
                f"a {rows}x{cols} dot grid does not fit {self.height}x{self.width} (height x width) pixels "
                f"(dot spacing {self.width / cols:.1f} x {self.height / rows:.1f} px; at least 4 px needed)"
            )
        if self.dot_radius_px is not None and self.dot_radius_px < 1:
            raise EdofprojError(f"--dot-radius {self.dot_radius_px} must be >= 1 px")
        if not (2 <= self.color_levels <= 17):
            raise EdofprojError(f"--color-levels {self.color_levels} must be in 2..17")
        check_memory(
            self.memory_bytes(),
            f"a set of {self.pattern_count} patterns of {self.height}x{self.width} px (height x width)",
            "use a smaller --width/--height (or fewer --bernoulli and --color-levels)",
        )

    @property
    def pattern_count(self) -> int:
        """Bernoulli patterns, the dot grid, three primaries, white, black and the colour samples."""
        return self.bernoulli_count + 6 + self.color_levels**3

    def memory_bytes(self) -> int:
        """The set is built in memory: each pattern ``(H, W, 3)`` float32 (12 bytes per pixel),
        plus the int64 draw of one Bernoulli pattern (24) and its 8-bit PNG encoding (6)."""
        return (12 * self.pattern_count + 30) * self.width * self.height


@dataclass
class PatternEntry:
    """One pattern file and its role data (see the module docstring)."""

    file: str
    role: str
    index: int | None = None
    color: tuple[float, float, float] | None = None
    grid: tuple[int, int] | None = None
    radius_px: int | None = None
    dots: np.ndarray | None = None  # (rows * cols, 2) x, y in projector pixels, row-major

    def to_json(self) -> dict:
        item: dict = {"file": self.file, "role": self.role}
        if self.index is not None:
            item["index"] = int(self.index)
        if self.color is not None:
            item["color"] = [float(c) for c in self.color]
        if self.grid is not None:
            if self.radius_px is None or self.dots is None:
                raise EdofprojError(f"pattern '{self.file}' has a dot grid but no dot radius or dot positions")
            item["grid"] = [int(g) for g in self.grid]
            item["radius_px"] = int(self.radius_px)
            item["dots"] = [[float(x), float(y)] for x, y in self.dots]
        return item


@dataclass
class PatternManifest:
    """The pattern set of a folder: projector size and the files with their roles."""

    width: int
    height: int
    entries: list[PatternEntry] = field(default_factory=list)

    # -- lookups -----------------------------------------------------------------------
    def with_role(self, role: str) -> list[PatternEntry]:
        return [e for e in self.entries if e.role == role]

    def one(self, role: str) -> PatternEntry:
        found = self.with_role(role)
        if len(found) != 1:
            raise EdofprojError(f"the pattern manifest needs exactly one '{role}' pattern, found {len(found)}")
        return found[0]

    def primary(self, name: str) -> PatternEntry:
        """The full field of primary ``red``, ``green`` or ``blue``."""
        want = PRIMARY_COLORS[name]
        for e in self.with_role("primary"):
            if e.color is not None and tuple(e.color) == want:
                return e
        raise EdofprojError(f"the pattern manifest has no {name} primary field")

    # -- files -------------------------------------------------------------------------
    def to_json(self) -> dict:
        return {
            "format": MANIFEST_FORMAT,
            "version": 1,
            "width": self.width,
            "height": self.height,
            "files": [e.to_json() for e in self.entries],
        }

    @classmethod
    def load(cls, folder: str | Path) -> "PatternManifest":
        """Read ``folder/manifest.json``; every field is checked (:meth:`validate`)."""
        path = Path(folder) / MANIFEST_NAME
        if not Path(folder).is_dir():
            raise EdofprojError(f"pattern folder '{folder}' does not exist")
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            if not isinstance(data, dict) or not isinstance(data.get("files"), list):
                raise ValueError("not a pattern manifest (an object with a list 'files')")
            width, height = _whole(data["width"], "width"), _whole(data["height"], "height")
            entries = []
            for item in data["files"]:
                if not isinstance(item, dict):
                    raise ValueError(f"file entry {item!r} is not an object")
                role = item["role"]
                if role not in ROLES:
                    raise ValueError(f"unknown role '{role}'")
                dots = np.asarray(item["dots"], dtype=float).reshape(-1, 2) if "dots" in item else None
                if dots is not None and len(dots) != int(np.prod(item["grid"])):
                    raise ValueError(f"'{item['file']}' lists {len(dots)} dots for a {item['grid']} grid")
                entries.append(
                    PatternEntry(
                        file=str(item["file"]),
                        role=role,
                        index=_whole(item["index"], "index") if "index" in item else None,
                        color=_color_triple(item["color"]) if "color" in item else None,
                        grid=_grid_pair(item["grid"]) if "grid" in item else None,
                        radius_px=_whole(item["radius_px"], "radius_px") if "radius_px" in item else None,
                        dots=dots,
                    )
                )
            manifest = cls(width=width, height=height, entries=entries)
            manifest.validate()
        except FileNotFoundError:
            raise EdofprojError(
                f"'{folder}' has no {MANIFEST_NAME} (make one with 'edofproj procams patterns')"
            ) from None
        except UnicodeDecodeError:
            raise EdofprojError(f"cannot read '{path}': not UTF-8 text") from None
        except (OSError, ValueError, KeyError, TypeError, OverflowError) as exc:
            raise EdofprojError(f"cannot read '{path}': {exc}") from None
        return manifest

    def validate(self) -> None:
        """Raise ValueError unless the manifest describes patterns this tool can show:
        a size of ``16..MAX_PATTERN_SIDE_PX`` per side that :func:`edofproj.limits.check_memory`
        admits for one pattern, at least one file, unique file names that are bare names inside
        the pattern folder (:func:`confined_file_name`), colours in ``[0, 1]`` and dots inside the image."""
        if not (16 <= self.width <= MAX_PATTERN_SIDE_PX and 16 <= self.height <= MAX_PATTERN_SIDE_PX):
            raise ValueError(
                f"size {self.height}x{self.width} (height x width) is not 16..{MAX_PATTERN_SIDE_PX} pixels per side"
            )
        check_memory(
            30 * self.width * self.height,
            f"a {self.height}x{self.width} (height x width) pattern",
            "regenerate the patterns at the projector's size with 'edofproj procams patterns'",
        )
        if not self.entries:
            raise ValueError("it lists no pattern files")
        seen: set[str] = set()
        for entry in self.entries:
            confined_file_name(entry.file, "pattern file")
            if entry.file in seen:
                raise ValueError(f"'{entry.file}' is listed twice")
            seen.add(entry.file)
            if entry.color is not None and not all(0.0 <= c <= 1.0 for c in entry.color):
                raise ValueError(f"'{entry.file}' has colour {list(entry.color)} outside [0, 1]")
            if entry.dots is not None:
                x, y = entry.dots[:, 0], entry.dots[:, 1]
                if not (np.all(np.isfinite(entry.dots)) and x.min() >= 0 and y.min() >= 0):
                    raise ValueError(
                        f"'{entry.file}' has dots outside the {self.height}x{self.width} (height x width) image"
                    )
                if x.max() > self.width - 1 or y.max() > self.height - 1:
                    raise ValueError(
                        f"'{entry.file}' has dots outside the {self.height}x{self.width} (height x width) image"
                    )
            if entry.radius_px is not None and entry.radius_px < 1:
                raise ValueError(f"'{entry.file}' has radius_px {entry.radius_px} < 1")

    def content_hash(self, folder: str | Path) -> str:
        """SHA-256 (hex) over the manifest's text and every pattern file's bytes, in manifest order:
        what a capture session is tied to (:mod:`.session`). Raises one line for a missing pattern."""
        digest = hashlib.sha256(manifest_json_text(self).encode("utf-8"))
        for entry in self.entries:
            pattern = Path(folder) / entry.file
            try:
                with open(pattern, "rb") as handle:
                    for block in iter(lambda: handle.read(1 << 20), b""):
                        digest.update(block)
            except OSError as exc:
                raise EdofprojError(f"cannot read pattern '{pattern}': {exc.strerror or exc}") from None
        return digest.hexdigest()


#: Largest pattern side a manifest may give (pixels): beyond any projector.
MAX_PATTERN_SIDE_PX = 32768


def confined_file_name(name: str, what: str = "file") -> str:
    """``name`` if it is a bare file name (no folder part, not absolute, not hidden, not ``..``),
    else ValueError: file names read from a manifest stay inside the manifest's folder."""
    if (
        not isinstance(name, str)
        or not name
        or name != Path(name).name
        or "/" in name
        or "\\" in name
        or name.startswith(".")
        or "\0" in name
    ):
        raise ValueError(f"{what} name {name!r} is not a bare file name inside the folder")
    return name


def _whole(value, what: str) -> int:
    """A JSON whole number (ValueError for booleans, fractions, text)."""
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or value != int(value)
    ):
        raise ValueError(f"'{what}' {value!r} is not a whole number")
    return int(value)


def _color_triple(values) -> tuple[float, float, float]:
    """A manifest colour ``[r, g, b]`` (ValueError unless it has three values)."""
    r, g, b = (float(c) for c in values)
    return r, g, b


def _grid_pair(values) -> tuple[int, int]:
    """A manifest dot grid ``[rows, cols]`` (ValueError unless it has two values)."""
    rows, cols = (int(g) for g in values)
    return rows, cols


# ----------------------------------------------------------------------------- builders


def bernoulli_noise(height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """An ``(H, W, 3)`` float image of independent fair coin flips (0 or 1) per pixel and channel."""
    return rng.integers(0, 2, size=(height, width, 3)).astype(np.float32)


def dot_grid_centers(height: int, width: int, rows: int, cols: int) -> np.ndarray:
    """Integer dot centres ``(rows * cols, 2)`` as ``(x, y)``: the centres of a ``rows x cols`` cell
    grid over the image, rounded to pixels, row-major."""
    ys = np.round((np.arange(rows) + 0.5) * height / rows - 0.5)
    xs = np.round((np.arange(cols) + 0.5) * width / cols - 0.5)
    grid_x, grid_y = np.meshgrid(xs, ys)
    return np.stack([grid_x.ravel(), grid_y.ravel()], axis=1)


def dot_grid_image(height: int, width: int, centers: np.ndarray, radius_px: int) -> np.ndarray:
    """White discs ``(x - cx)^2 + (y - cy)^2 <= r^2`` on black, ``(H, W, 3)`` float."""
    image = np.zeros((height, width), np.float32)
    offsets = np.arange(-radius_px, radius_px + 1)
    oy, ox = np.meshgrid(offsets, offsets, indexing="ij")
    disc = (ox**2 + oy**2) <= radius_px**2
    for cx, cy in centers.astype(int):
        ys, xs = cy + oy[disc], cx + ox[disc]
        keep = (ys >= 0) & (ys < height) & (xs >= 0) & (xs < width)
        image[ys[keep], xs[keep]] = 1.0
    return np.repeat(image[:, :, None], 3, axis=2)


def color_sample_values(levels: int) -> np.ndarray:
    """The ``levels^3`` RGB input colours of the sampling grid, ``(levels^3, 3)``, red slowest.

    Each value is an exact 8-bit level divided by 255."""
    steps = np.round(np.linspace(0.0, 255.0, levels)) / 255.0
    r, g, b = np.meshgrid(steps, steps, steps, indexing="ij")
    return np.stack([r.ravel(), g.ravel(), b.ravel()], axis=1)


def uniform_field(height: int, width: int, color) -> np.ndarray:
    return np.broadcast_to(np.asarray(color, np.float32), (height, width, 3)).copy()


def build_pattern_set(spec: PatternSpec) -> tuple[PatternManifest, dict[str, np.ndarray]]:
    """All patterns of ``spec``: the manifest and ``{file name: (H, W, 3) float image in [0, 1]}``."""
    spec.validate()
    H, W = spec.height, spec.width
    rng = np.random.default_rng(spec.seed)
    manifest = PatternManifest(width=W, height=H)
    images: dict[str, np.ndarray] = {}

    def add(entry: PatternEntry, image: np.ndarray) -> None:
        manifest.entries.append(entry)
        images[entry.file] = image

    for i in range(spec.bernoulli_count):
        add(PatternEntry(f"bernoulli_{i:02d}.png", "bernoulli", index=i), bernoulli_noise(H, W, rng))

    rows, cols = spec.dot_grid
    radius = spec.dot_radius_px or max(1, int(min(H / rows, W / cols) // 8))
    centers = dot_grid_centers(H, W, rows, cols)
    add(
        PatternEntry("dots.png", "dots", grid=(rows, cols), radius_px=radius, dots=centers),
        dot_grid_image(H, W, centers, radius),
    )

    for name, color in PRIMARY_COLORS.items():
        add(PatternEntry(f"{name}.png", "primary", color=color), uniform_field(H, W, color))
    add(PatternEntry("white.png", "white", color=(1.0, 1.0, 1.0)), uniform_field(H, W, (1, 1, 1)))
    add(PatternEntry("black.png", "black", color=(0.0, 0.0, 0.0)), uniform_field(H, W, (0, 0, 0)))

    digits = max(3, len(str(spec.color_levels**3 - 1)))
    for i, color in enumerate(color_sample_values(spec.color_levels)):
        add(
            PatternEntry(f"color_{i:0{digits}d}.png", "color_sample", index=i, color=tuple(color)),
            uniform_field(H, W, color),
        )
    return manifest, images


def read_pattern(folder: str | Path, entry: PatternEntry, manifest: PatternManifest) -> np.ndarray:
    """A pattern image ``(H, W, 3)`` float in ``[0, 1]``, checked against the manifest's size."""
    image = read_rgb(Path(folder) / entry.file, what="pattern")
    if image.shape[:2] != (manifest.height, manifest.width):
        raise EdofprojError(
            f"pattern '{entry.file}' is {image.shape[0]}x{image.shape[1]} but the manifest says "
            f"{manifest.height}x{manifest.width} (height x width)"
        )
    return image


def parse_grid(text: str) -> tuple[int, int]:
    """``"16x32"`` -> ``(16, 32)`` (rows x columns)."""
    try:
        rows, cols = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise EdofprojError(f"--dots '{text}' must look like ROWSxCOLS, e.g. 16x32") from None
    return rows, cols


def manifest_json_text(manifest: PatternManifest) -> str:
    return json.dumps(manifest.to_json(), indent=1) + "\n"


__all__ = [
    "PatternSpec",
    "PatternEntry",
    "PatternManifest",
    "build_pattern_set",
    "bernoulli_noise",
    "dot_grid_centers",
    "dot_grid_image",
    "color_sample_values",
    "read_pattern",
    "parse_grid",
    "MANIFEST_NAME",
    "confined_file_name",
]
