"""Diffractive optical elements: height-map parametrizations, fixed designs, quantization, files."""

from .base import DOE, RadialDOE  # noqa: F401
from .factory import build_doe, DOE_CHOICES  # noqa: F401
from .storage import load_doe, save_doe  # noqa: F401
