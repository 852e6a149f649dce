"""Diffractive optical elements: height-map parametrizations, fixed designs, quantization, files."""

from .base import DOE, RadialDOE  # noqa: F401
from .factory import DOE_CHOICES, build_doe, build_run_doe  # noqa: F401
from .storage import load_doe, save_doe  # noqa: F401
