"""Fabrication: lithography masks (GDSII), manufacturability report, design rules, tolerance analysis.

* :mod:`.profile`: a quantized radial profile (rings, levels, zones);
* :mod:`.masks`: its binary masks (etch convention) and their features;
* :mod:`.gdsii`, :mod:`.raster`: the GDSII layout, the 16-bit height map and mask previews;
* :mod:`.efficiency`: scalar diffraction efficiency of N-level profiles across wavelength;
* :mod:`.report`: the manufacturability report; :mod:`.export`: ``edofproj export-doe``;
* :mod:`edofproj.doe.design_rules` (re-exported): the minimum-feature parametrization used in training;
* :mod:`.perturbation`, :mod:`.ring_engine`, :mod:`.tolerance`, :mod:`.tolerance_report`:
  ``edofproj tolerance``.
"""

from ..doe.design_rules import MinimumFeatureRadialDOE, apply_design_rules  # noqa: F401
from .efficiency import channel_efficiency, continuous_efficiency, multilevel_efficiency  # noqa: F401
from .export import export_doe  # noqa: F401
from .masks import MaskLayer, decompose  # noqa: F401
from .profile import RadialProfile  # noqa: F401
from .report import CriticalDimensionError  # noqa: F401
from .tolerance import ToleranceSettings, run_tolerance  # noqa: F401
