"""The ``net`` section of a configuration: one dataclass per compensation-network architecture.

``net.architecture`` names the network; the rest of the section holds that network's options and no
others. Each architecture is a subclass of :class:`NetConfig` that carries its name
(``architecture``, a class attribute) and declares each option with :func:`option`: its meaning,
unit and range. The declarations are the one source of the validation (:meth:`NetConfig.validate`)
and of the tables of the configuration reference (``docs/site_scripts/gen_reference.py``).

Where each part lives (the layers of ``tests/test_layers.py``): this module is in the foundation
layer beside :mod:`edofproj.config`, which reads a ``net`` section through it without importing a
network; the networks are two layers up, and the registry
(:data:`edofproj.compensation.registry.NETWORKS`) pairs each class of :data:`NET_CONFIGS` with the
network it builds, under the class's own ``architecture`` name -- the names are written once, here.

**Adding an option**: a field with :func:`option` in its architecture's class (or in
:class:`NetConfig` if every architecture has it); the network reads it in its ``from_config``.
**Adding an architecture**: a subclass here, listed in :data:`NET_CONFIGS`, and its network in the
registry (a test checks that both name the same architectures).

**Configs of the single flat section.** Before the split, ``net`` was one section holding every key
of every architecture (:data:`FLAT_NET_KEYS`; ``config.yaml`` of older runs has them all).
:func:`convert_flat_net` reads such a section as its architecture's options: a key the architecture
does not have is dropped (it was ignored), one it names otherwise is renamed (:data:`RENAMED`), and
one line says so.

Switching architectures with ``--set net.architecture=NAME`` keeps the options the new architecture
shares with the old one and takes its defaults for the rest (:func:`override_net`); ``--set
net.KEY=VALUE`` for a key the chosen architecture does not have is an error.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import typing
from dataclasses import dataclass
from typing import Any, ClassVar

from .errors import ConfigError

# --------------------------------------------------------------------------- declaring options


@dataclass(frozen=True)
class Range:
    """The values a numeric option (or each element of a list option) may take: finite numbers
    from ``low`` to ``high`` (either bound open, or absent), and ``off`` besides (e.g. 0 = off)."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    off: float | None = None

    def allows(self, value: Any) -> bool:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            return False
        if self.off is not None and value == self.off:
            return True
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        return self.high is None or (value < self.high if self.high_open else value <= self.high)

    def text(self) -> str:
        """E.g. ``> 0``, ``>= 1``, ``in [0, 1)``, ``>= 2, or 0 (off)``."""
        if self.low is not None and self.high is not None:
            text = f"in {'(' if self.low_open else '['}{self.low:g}, {self.high:g}{')' if self.high_open else ']'}"
        elif self.low is not None:
            text = f"{'>' if self.low_open else '>='} {self.low:g}"
        elif self.high is not None:
            text = f"{'<' if self.high_open else '<='} {self.high:g}"
        else:
            text = "finite"
        return text + (f", or {self.off:g} (off)" if self.off is not None else "")


@dataclass(frozen=True)
class OptionSpec:
    """What :func:`option` declares about an option (kept in the field's metadata), and whether
    it takes integers (from its type: :func:`declared_options`)."""

    meaning: str
    unit: str = ""
    range: Range | None = None
    choices: tuple[str, ...] = ()
    min_items: int = 0
    integer: bool = False
    boolean: bool = False

    def rule(self) -> str:
        """The allowed values in words, e.g. ``>= 2, or 0 (off)``, ``one of conv, maxpool``."""
        if self.boolean:
            return "true or false"
        if self.choices:
            return "one of " + ", ".join(self.choices)
        if self.integer and self.range == Range(1):
            one, each = "a positive integer", "positive integers"
        elif self.integer:
            bound = f" {self.range.text()}" if self.range else ""
            one, each = f"an integer{bound}", f"integers{bound}"
        else:
            one = self.range.text() if self.range else "a number"
            each = f"numbers {self.range.text()}" if self.range else "numbers"
        return f"a list of at least {self.min_items} {each}" if self.min_items else one


def option(
    default: Any,
    meaning: str,
    *,
    unit: str = "",
    range: Range | None = None,
    choices: tuple[str, ...] = (),
    min_items: int = 0,
) -> Any:
    """A dataclass field for an option, declared with its meaning, unit and allowed values
    (:class:`OptionSpec`); a list default is copied for each instance."""
    spec = OptionSpec(meaning, unit, range, tuple(choices), min_items)
    if isinstance(default, list):
        return dataclasses.field(default_factory=lambda: list(default), metadata={"option": spec})
    return dataclasses.field(default=default, metadata={"option": spec})


def declared_options(cls: type) -> list[tuple[dataclasses.Field, OptionSpec]]:
    """Each option of a :class:`NetConfig` class with its declaration (:func:`option`); whether it
    takes integers or true/false follows from its type (``int``, ``list[int]``, ``bool``)."""
    hints = typing.get_type_hints(cls)
    return [
        (
            f,
            dataclasses.replace(
                f.metadata["option"], integer=hints[f.name] in (int, list[int]), boolean=hints[f.name] is bool
            ),
        )
        for f in dataclasses.fields(cls)
    ]


def unknown_choice(label: str, value: Any, choices: typing.Iterable[str]) -> str:
    """``label=value is not one of a, b (did you mean 'a'?)``."""
    choices = list(choices)
    hint = difflib.get_close_matches(str(value), choices, n=1)
    did_you_mean = f" (did you mean '{hint[0]}'?)" if hint else ""
    return f"{label}={value!r} is not one of {', '.join(choices)}{did_you_mean}"


def _check(spec: OptionSpec, value: Any, label: str) -> None:
    """Raise a one-line :class:`ConfigError` unless ``value`` is one the declaration allows."""
    if spec.boolean:
        if not isinstance(value, bool):
            raise ConfigError(f"{label}={value!r} must be {spec.rule()}")
        return
    if spec.choices:
        if value not in spec.choices:
            raise ConfigError(unknown_choice(label, value, spec.choices))
        return
    values = value if spec.min_items else [value]
    ok = not spec.min_items or (isinstance(value, list) and len(value) >= spec.min_items)
    for item in values if ok else ():
        if spec.range is not None and not spec.range.allows(item):
            ok = False
        elif spec.integer and (isinstance(item, bool) or not isinstance(item, (int, float)) or int(item) != item):
            ok = False
    if not ok:
        raise ConfigError(f"{label}={value!r} must be {spec.rule()}")


# --------------------------------------------------------------------------- the architectures


@dataclass
class NetConfig:
    """The options every architecture has.

    ``linear_nsr`` and ``linear_radius`` define the depth-ensemble linear filter of the current DOE
    (:mod:`edofproj.training.linear_filter`): the yardstick that training validates every network
    against (``train.validate_every``), and the base of a safe U-Net (``linear_base: ensemble``).
    """

    #: The architecture's name (``net.architecture``), set by each subclass.
    architecture: ClassVar[str] = ""

    leaky_slope: float = option(
        0.2, "negative slope of the LeakyReLU activations", range=Range(0.0, 1.0, high_open=True)
    )
    linear_nsr: float = option(
        0.01,
        "noise-to-signal ratio of the depth-ensemble linear filter of the current DOE",
        range=Range(0.0, low_open=True),
    )
    linear_radius: int = option(
        33,
        "half-width r of that filter: (2r + 1)^2 taps (as doe+ensemble with r = psf.window)",
        unit="px",
        range=Range(1),
    )
    surface_input: bool = option(
        False,
        "the network also takes the surface (reflectance and ambient) and training draws textured surfaces "
        "(compensation.surface_net); false: a white screen",
    )

    def validate(self) -> None:
        """Every option against its declaration, then the rules between options (:meth:`check_together`)."""
        for f, spec in declared_options(type(self)):
            _check(spec, getattr(self, f.name), f"net.{f.name}")
        self.check_together()

    def check_together(self) -> None:
        """Rules that involve more than one option (none here; an architecture may add some)."""


#: Channels per scale of the default U-Net (7 scales; :data:`edofproj.compensation.unet.UNET_WIDTH_PRESETS`).
DEFAULT_WIDTHS = [16, 32, 64, 128, 128, 128, 128]
_WIDTHS_MEANING = "channels per scale of the U-Net, finest first (named presets: compensation.unet.UNET_WIDTH_PRESETS)"


@dataclass
class UNetBodyConfig(NetConfig):
    """The options of the U-Net that a network is built around (no architecture of its own)."""

    widths: list[int] = option(DEFAULT_WIDTHS, _WIDTHS_MEANING, range=Range(1), min_items=2)
    downsampling: str = option("conv", "conv (stride-2 convolution) or maxpool", choices=("conv", "maxpool"))
    upsampling: str = option(
        "transpose",
        "transpose (transposed convolution) or bilinear (+ 3x3 convolution)",
        choices=("transpose", "bilinear"),
    )


@dataclass
class UNetConfig(UNetBodyConfig):
    """``unet``: the paper's compensation U-Net (Fig. 5, :class:`~edofproj.compensation.unet.CompensationUNet`).

    Images are padded to a multiple of ``2**(len(widths)-1)`` (times ``space_to_depth``) and cropped
    back. ``prefilter_bins > 0`` puts a learned rotationally symmetric Fourier filter of the target in
    front of the U-Net (:mod:`edofproj.compensation.radial_filter`). ``linear_base: ensemble`` makes it
    a safe network: ``x = E(I) + c`` with ``E`` the depth-ensemble linear filter of the current DOE
    (``linear_nsr``, ``linear_radius``; recomputed every ``train.linear_every`` steps) and
    ``|c| <= correction_bound`` everywhere, ``c`` free of local means beyond a Gaussian of
    ``correction_highpass_px`` (:mod:`edofproj.compensation.linear_base`).
    """

    architecture: ClassVar[str] = "unet"

    padding_mode: str = option(
        "replicate", "how images are padded to the U-Net's multiple", choices=("replicate", "reflect")
    )
    space_to_depth: int = option(
        1,
        "run the U-Net on s x s pixel blocks at 1/s resolution (1: the paper's full-resolution network)",
        unit="px",
        range=Range(1),
    )
    prefilter_bins: int = option(
        0,
        "radial nodes of a learned Fourier pre-filter of the target in front of the U-Net (0: none)",
        range=Range(2, off=0),
    )
    linear_base: str = option(
        "none",
        "ensemble: a bounded correction of its optics' (lens or DOE) depth-ensemble linear filter (the safe network); "
        "none: not",
        choices=("none", "ensemble"),
    )
    correction_bound: float = option(
        0.2,
        "with linear_base: ensemble, the largest |x - E(I)| anywhere (projector input units, [0, 1] = full range)",
        range=Range(0.0, low_open=True),
    )
    correction_highpass_px: float = option(
        8.0,
        "with linear_base: ensemble, the correction carries no local mean beyond a Gaussian of this sigma (0: off)",
        unit="px",
        range=Range(0.0),
    )

    def check_together(self) -> None:
        if self.linear_base != "none" and self.prefilter_bins:
            raise ConfigError(
                "net.linear_base=ensemble goes with net.prefilter_bins=0 (the linear filter replaces the learned pre-filter)"
            )


@dataclass
class MultirateConfig(UNetBodyConfig):
    """``multirate``: the real-time network (:class:`~edofproj.compensation.multirate.MultirateCompensationNet`).

    Everything but the full-resolution input and output runs on ``block_px x block_px`` pixel blocks:
    a local linear filter per colour, a gain per colour and block, a U-Net of ``widths`` at
    ``1/block_px`` resolution and a radial Fourier filter of the block means (``filter_bins`` nodes).
    When it is trained for a fixed DOE, its local filter starts as the depth-ensemble Wiener filter of
    the DOE's training PSFs with the NSR ``init_nsr``
    (:func:`edofproj.compensation.wiener.depth_ensemble_wiener_kernel`; 0 starts it at zero); with
    ``linear_path: fixed`` it stays that filter, and follows a DOE being trained.
    ``correction_bound > 0`` gives it the safe form: the non-linear part (the depth gain and the
    U-Net's values) is a bounded correction of its own linear path, high-passed by
    ``correction_highpass_px`` (:func:`edofproj.compensation.multirate.bounded_block_correction`).
    """

    architecture: ClassVar[str] = "multirate"

    block_px: int = option(4, "block size s: the network runs at 1/s resolution", unit="px", range=Range(2))
    filter_bins: int = option(48, "radial nodes of the Fourier filter of the block means", range=Range(2))
    init_nsr: float = option(
        0.01,
        "NSR of the depth-ensemble Wiener filter its local filter starts as, for a fixed DOE (0: starts at zero)",
        range=Range(0.0),
    )
    linear_path: str = option(
        "trained",
        "trained: the linear path L U + B D learns with the rest; fixed: it is the depth-ensemble Wiener "
        "filter of the DOE cut to its taps (init_nsr; set once for a fixed DOE, every train.linear_every steps "
        "for a DOE being trained), and only the non-linear part trains",
        choices=("trained", "fixed"),
    )
    correction_bound: float = option(
        0.0,
        "the largest |x - (I + S(LU + BD))| anywhere, the non-linear part's bound around its own linear path "
        "(projector input units; 0: unbounded)",
        range=Range(0.0),
    )
    correction_highpass_px: float = option(
        0.0,
        "with correction_bound > 0, the non-linear part carries no local mean beyond a Gaussian of this sigma (0: off)",
        unit="px",
        range=Range(0.0),
    )

    def check_together(self) -> None:
        if self.linear_path == "fixed" and self.init_nsr <= 0:
            raise ConfigError(
                "net.linear_path=fixed keeps the depth-ensemble Wiener filter the linear path starts as: "
                "it needs net.init_nsr > 0"
            )


@dataclass
class OnlineProDebConfig(NetConfig):
    """``onlineprodeb``: the re-implementation of OnlineProDeb (a defocus network and a luminance
    network, :class:`~edofproj.compensation.onlineprodeb.OnlineProDebNet`), the demo's
    ``lens+onlineprodeb`` baseline, in its default preset: no options of its own."""

    architecture: ClassVar[str] = "onlineprodeb"


#: The configuration class of each architecture, by ``net.architecture`` (the first is the default).
NET_CONFIGS: dict[str, type[NetConfig]] = {
    cls.architecture: cls for cls in (UNetConfig, OnlineProDebConfig, MultirateConfig)
}
DEFAULT_ARCHITECTURE = UNetConfig.architecture


def net_config_class(name: Any) -> type[NetConfig]:
    """The configuration class of architecture ``name``, or a one-line :class:`ConfigError`."""
    if not isinstance(name, str) or name not in NET_CONFIGS:
        raise ConfigError(unknown_choice("net.architecture", name, NET_CONFIGS))
    return NET_CONFIGS[name]


def option_names(cls: type[NetConfig]) -> list[str]:
    """The options of an architecture, in declaration order (``architecture`` not included)."""
    return [f.name for f in dataclasses.fields(cls)]


def net_to_dict(net: NetConfig) -> dict:
    """A plain mapping of a ``net`` section: ``architecture`` first, then its options."""
    return {"architecture": net.architecture, **dataclasses.asdict(net)}


# --------------------------------------------------------------------------- keys and overrides

#: Every key of the single flat ``net`` section of configs before the split (a record of that
#: format: it does not grow with new options).
FLAT_NET_KEYS = (
    "widths", "leaky_slope", "architecture", "downsampling", "upsampling", "padding_mode", "space_to_depth",
    "prefilter_bins", "init_nsr", "linear_base", "linear_nsr", "linear_radius", "correction_bound",
    "correction_highpass_px",
)  # fmt: skip
#: Keys of the flat section that an architecture calls otherwise: ``{architecture: {old: new}}``.
RENAMED = {"multirate": {"space_to_depth": "block_px", "prefilter_bins": "filter_bins"}}


def not_an_option(cls: type[NetConfig], key: str, section: str = "net") -> ConfigError:
    """The error for ``net.KEY`` (or ``SECTION.KEY``: ``refit_net``), a key the architecture of ``cls``
    does not have."""
    names = option_names(cls)
    renamed = RENAMED.get(cls.architecture, {}).get(key)
    if renamed:
        hint = f"; the {cls.architecture} network calls it '{section}.{renamed}'"
    else:
        close = difflib.get_close_matches(str(key), names, n=1)
        hint = f"; did you mean '{section}.{close[0]}'?" if close else ""
    return ConfigError(
        f"unknown config key '{section}.{key}': the {cls.architecture} network has no such option{hint} "
        f"(its options: {', '.join(names) or 'none'})"
    )


def check_net_keys(data: dict, section: str = "net") -> tuple[type[NetConfig], dict]:
    """The class that ``data['architecture']`` names (default :data:`DEFAULT_ARCHITECTURE`) and the
    rest of the mapping, refusing a key the architecture does not have (:func:`not_an_option`)."""
    cls = net_config_class(data.get("architecture", DEFAULT_ARCHITECTURE))
    options = {k: v for k, v in data.items() if k != "architecture"}
    names = option_names(cls)
    for key in options:
        if key not in names:
            raise not_an_option(cls, key, section)
    return cls, options


def override_net(data: dict, key: str, value: Any, section: str = "net") -> dict:
    """The ``net`` mapping ``data`` with ``--set net.KEY=VALUE`` applied. ``net.architecture``
    switches the network: the options the new one shares with the old keep their values, the rest
    take the new one's defaults. Another key must be an option of the current architecture."""
    if key == "architecture":
        cls = net_config_class(value)
        return {"architecture": value, **{k: v for k, v in data.items() if k in option_names(cls)}}
    cls = net_config_class(data.get("architecture", DEFAULT_ARCHITECTURE))
    if key not in option_names(cls):
        raise not_an_option(cls, key, section)
    return {**data, key: value}


def convert_flat_net(data: Any) -> tuple[Any, str | None]:
    """A ``net`` mapping read as its architecture's options, and a one-line note when that changed it
    (None when it was already one architecture's options). Keys of the flat section
    (:data:`FLAT_NET_KEYS`) that the architecture does not have are dropped (the network ignored
    them), renamed ones (:data:`RENAMED`) renamed; any other key is left for the validation to refuse."""
    if not isinstance(data, dict) or data.get("architecture", DEFAULT_ARCHITECTURE) not in NET_CONFIGS:
        return data, None
    cls = NET_CONFIGS[data.get("architecture", DEFAULT_ARCHITECTURE)]
    names, renames = option_names(cls), RENAMED.get(cls.architecture, {})
    converted: dict = {}
    renamed, dropped = [], []
    for key, value in data.items():
        if key == "architecture" or key in names or key not in FLAT_NET_KEYS:
            converted[key] = value
        elif key in renames and renames[key] not in data:
            converted[renames[key]] = value
            renamed.append(f"{key} -> {renames[key]}")
        else:
            dropped.append(key)
    if not renamed and not dropped:
        return data, None
    parts = [f"renamed {', '.join(renamed)}"] if renamed else []
    if dropped:
        parts.append(f"dropped {', '.join(dropped)} (keys the {cls.architecture} network never read)")
    note = (
        f"net: a single flat section of an older edofproj, read as the {cls.architecture} network's options: "
        + "; ".join(parts)
    )
    return converted, note
