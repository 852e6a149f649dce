"""edofproj: extended-depth-of-field projectors with learned diffractive optics.

The data path reads as a straight line:
config -> optics (PSF bank) -> imaging (projection) -> compensation -> evaluation (metrics, report).
"""

__version__ = "0.1.0"
