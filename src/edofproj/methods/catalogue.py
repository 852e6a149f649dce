"""The compensation methods, by name: an optical design plus a compensation, all through one image formation.

For a target image ``I`` and a flat screen at depth ``z`` with the design's PSF ``p_z``, every
method goes through the same three steps (:mod:`edofproj.imaging.projection`):

    I*      = project(I, p_z)                        the uncompensated projection (simulated capture)
    x       = compensate(I, I*, p_z)                 the projector input
    display = project(clamp(x, 0, 1), p_z)           what the screen shows; scored against I

``project`` clamps its input to ``[0, 1]``: a projector emits no negative light and saturates.
The methods, by name:

==================== ================= =====================================================
name                 optics            compensation
==================== ================= =====================================================
``lens``             bare lens         none (``x = I``)
``lens+wiener``      bare lens         Wiener deconvolution with the known PSF; NSR tuned (for
                                       SSIM by default) on *training* images over the scored
                                       depth range
``lens+cls``         bare lens         box-constrained least squares with the known PSF
``lens+net``         bare lens         our U-Net trained on lens-only PSFs (a separate run)
``lens+onlineprodeb`` bare lens        OnlineProDeb (re-implementation), trained on the same
                                       simulated lens-only data (a separate run)
``doe``              the run's DOE     none
``doe+wiener``       the run's DOE     Wiener, NSR tuned for this design
``doe+cls``          the run's DOE     box-constrained least squares with the known PSF (scored
                                       only when named: what the DOE allows when the depth is
                                       known; least squares, not SSIM, so a reference, not a bound)
``doe+ensemble``     the run's DOE     one depth-ensemble Wiener filter for every depth (blind:
                                       the filter the real-time network starts from), NSR
                                       tuned on training images
``doe+net``          the run's DOE     the run's U-Net (ours): trained with the DOE, or, in a run
                                       of two phases, for the DOE the first phase found
``cubic+net``        cubic phase plate the U-Net trained with that plate (a separate run)
``axicon+net``       axicon            the U-Net trained with that axicon (a separate run)
``X``                classic element X none; X one of ``cubic``, ``axicon``, ``multifocal``, built
                                       from the run's configuration (``doe.cubic_waves``,
                                       ``doe.axicon_near_mm``/``far_mm``, ``doe.multifocal_foci_mm``)
``X+wiener``         classic element X Wiener, NSR tuned for this design (non-blind)
``X+ensemble``       classic element X the design's depth-ensemble Wiener filter (blind)
==================== ================= =====================================================

The classic elements' linear baselines ``X+wiener`` (non-blind) and ``X+ensemble`` (blind) are scored by
default, ``X`` alone when asked for by name (``--methods``; :attr:`MethodSpec.default` is False): their
parameters are those of the evaluated run's configuration, which ``edofproj tune-classic`` chooses for a
projector and a range (the presets hold the chosen values). Where the separate run of ``X+net`` has the same
element, all of ``X``'s methods share one design (:class:`~edofproj.methods.builder.MethodBuilder`).

**Blind and non-blind.** A *blind* method knows nothing of the screen's depth or PSF at run
time: no compensation, the networks (they see ``I`` and the simulated capture ``I*``, their
second input as in training, never the PSF) and the depth-ensemble filters (``doe+ensemble``,
``X+ensemble``: one fixed filter for the whole depth range). A *non-blind* method is given the exact PSF ``p_z`` of the depth it
compensates: Wiener (``*+wiener``) and constrained least squares (``*+cls``). A projector that
does not measure the screen's depth can only run a blind method; the non-blind ones are an
upper reference, not a competitor on equal terms (:attr:`MethodSpec.blind`).
Separate runs are found as sub-directories of a *baselines* directory, named by
:data:`BASELINE_RUN_DIRS` (``lens+net`` -> ``lens_net``, ...), and are trained with the
evaluated run's configuration plus :attr:`MethodSpec.train_overrides`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

from ..errors import EdofprojError


@dataclass(frozen=True)
class MethodSpec:
    """A method's definition: which optics, which compensation, and which run provides them.

    ``optics``: ``"lens"`` (the bare lens), ``"run"`` (the evaluated run's DOE),
    ``"baseline"`` (the DOE of the separate run ``run_dir``) or a classic element of
    :data:`CLASSIC_ELEMENTS` built from the evaluated run's configuration. ``default``: scored when no
    method is named. ``compensation``: ``"none"``,
    ``"wiener"``, ``"cls"``, ``"ensemble"`` (one depth-ensemble Wiener filter) or ``"net"`` (the network of the evaluated run when ``run_dir`` is
    None, else of ``run_dir``). ``train_overrides``: config overrides that turn the evaluated
    run's configuration into this baseline's training run.
    """

    name: str
    optics: str
    compensation: str
    summary: str
    run_dir: str | None = None
    train_overrides: tuple[str, ...] = field(default_factory=tuple)
    default: bool = True

    @property
    def needs_separate_run(self) -> bool:
        return self.run_dir is not None

    @property
    def design(self) -> str:
        """The optical design the method compensates, as the figures group methods: ``lens``, ``doe``
        (the run's learned DOE) or a classic element (``cubic``, ``axicon``, ``multifocal``) -- the part of
        the name before the first ``+``."""
        return self.name.split("+", 1)[0]

    @property
    def blind(self) -> bool:
        """True when the method runs without knowing the screen's depth or PSF (module docstring)."""
        return self.compensation not in NON_BLIND_COMPENSATIONS


#: Classic EDOF elements whose linear baselines are built from a configuration (``doe.kind`` values).
CLASSIC_ELEMENTS = ("cubic", "axicon", "multifocal")
CLASSIC_LABELS = {"cubic": "cubic phase plate", "axicon": "axicon", "multifocal": "multifocal zones"}


def classic_linear_methods(kind: str) -> tuple[MethodSpec, ...]:
    """``X``, ``X+wiener`` and ``X+ensemble`` of the classic element ``kind``; the two compensated ones
    are scored by default, ``X`` alone only by name."""
    label = CLASSIC_LABELS[kind]
    return (
        MethodSpec(kind, kind, "none", f"{label}, no compensation", default=False),
        MethodSpec(f"{kind}+wiener", kind, "wiener", f"{label} + non-blind Wiener deconvolution"),
        MethodSpec(
            f"{kind}+ensemble",
            kind,
            "ensemble",
            f"{label} + its depth-ensemble Wiener filter for every depth (blind linear baseline)",
        ),
    )


#: Compensations that are given the exact PSF of each depth.
NON_BLIND_COMPENSATIONS = frozenset({"wiener", "cls"})


METHODS: tuple[MethodSpec, ...] = (
    MethodSpec("lens", "lens", "none", "bare lens, no compensation"),
    MethodSpec("lens+wiener", "lens", "wiener", "bare lens + non-blind Wiener deconvolution"),
    MethodSpec("lens+cls", "lens", "cls", "bare lens + box-constrained least squares (non-blind)"),
    MethodSpec(
        "lens+net",
        "lens",
        "net",
        "bare lens + our U-Net trained on lens-only PSFs (separate run)",
        run_dir="lens_net",
        train_overrides=("doe.kind=lens",),
    ),
    MethodSpec(
        "lens+onlineprodeb",
        "lens",
        "net",
        "bare lens + OnlineProDeb (our re-implementation), trained on the same simulated lens-only data",
        run_dir="lens_onlineprodeb",
        train_overrides=("doe.kind=lens", "net.architecture=onlineprodeb", "train.refit_steps=0"),  # its own recipe
    ),
    MethodSpec("doe", "run", "none", "learned DOE, no compensation"),
    MethodSpec("doe+wiener", "run", "wiener", "learned DOE + non-blind Wiener deconvolution"),
    MethodSpec(
        "doe+ensemble",
        "run",
        "ensemble",
        "learned DOE + one depth-ensemble Wiener filter for every depth (blind linear baseline)",
    ),
    MethodSpec("doe+net", "run", "net", "learned DOE + our U-Net, trained with it or for it (ours)"),
    MethodSpec(
        "cubic+net",
        "baseline",
        "net",
        "cubic phase plate + the same U-Net trained with it (separate run)",
        run_dir="cubic_net",
        train_overrides=("doe.kind=cubic",),
    ),
    MethodSpec(
        "axicon+net",
        "baseline",
        "net",
        "axicon + the same U-Net trained with it (separate run)",
        run_dir="axicon_net",
        train_overrides=("doe.kind=axicon",),
    ),
    MethodSpec(
        "multifocal+net",
        "baseline",
        "net",
        "multifocal zones + the same U-Net trained with them (separate run; not in the demo)",
        run_dir="multifocal_net",
        train_overrides=("doe.kind=multifocal",),
        default=False,
    ),
    MethodSpec(
        "doe+cls",
        "run",
        "cls",
        "learned DOE + box-constrained least squares (non-blind; what the DOE allows with the depth known)",
        default=False,
    ),
    *(spec for kind in CLASSIC_ELEMENTS for spec in classic_linear_methods(kind)),
)

METHOD_NAMES: tuple[str, ...] = tuple(m.name for m in METHODS)
BASELINE_RUN_DIRS: dict[str, str] = {m.name: m.run_dir for m in METHODS if m.run_dir}
#: The method the evaluated run itself provides (its DOE and its network).
OURS = "doe+net"


def method_spec(name: str) -> MethodSpec:
    """The :class:`MethodSpec` called ``name``; unknown names raise with the list of known ones."""
    for spec in METHODS:
        if spec.name == name:
            return spec
    raise EdofprojError(f"unknown method '{name}' (known: {', '.join(METHOD_NAMES)})")


def select_methods(names: Sequence[str] | None) -> list[MethodSpec]:
    """The specs of ``names`` in the canonical order (None or empty: every method scored by default)."""
    if not names:
        return [spec for spec in METHODS if spec.default]
    wanted = {method_spec(name).name for name in names}
    return [spec for spec in METHODS if spec.name in wanted]
